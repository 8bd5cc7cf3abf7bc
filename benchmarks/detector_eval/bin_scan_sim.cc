#include "benchmarks/detector_eval/bin_scan_sim.h"

#include <chrono>
#include <set>
#include <stdexcept>
#include <utility>

#include "libs/apc/catalogue.h"
#include "libs/world/cell_config.h"
#include "libs/world/item_models.h"
#include "services/scanner/core/calibration_io.h"
#include "services/scanner/core/merge.h"
#include "services/scanner/core/patterns.h"
#include "services/scanner/core/scan_pipeline.h"
#include "services/simulator/core/renderer.h"
#include "services/simulator/core/rgbd_sensor.h"
#include "services/simulator/core/sim_world.h"

namespace picking::detector_eval {
namespace {

using Clock = std::chrono::steady_clock;

double SecondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

}  // namespace

struct SimulatedBinScanner::Impl {
  std::shared_ptr<world::ItemModelLibrary> models;
  std::unique_ptr<simulator::SimWorld> world;
  std::unique_ptr<scanner::ScanPipeline> pipeline;
  Eigen::Isometry3d X_CameraProjector = Eigen::Isometry3d::Identity();
  std::set<int> hidden_ids;
};

SimulatedBinScanner::SimulatedBinScanner(const std::string& data_dir)
    : impl_(std::make_unique<Impl>()) {
  world::CellModel cell =
      world::LoadCellModel(world::ReadCellConfig(data_dir + "/cell/default_cell.yaml"));
  impl_->models = std::make_shared<world::ItemModelLibrary>(
      apc::Catalogue::FromCsvFile(data_dir + "/apc2016/items/item_data.csv"));
  impl_->world = std::make_unique<simulator::SimWorld>(std::move(cell), impl_->models);

  const std::string sensor = data_dir + "/scanner/sim_sensor/";
  using scanner::CalibrationKind;
  const camera::PinholeCamera cam =
      scanner::LoadIntrinsics(sensor + "camera_intrinsics.json", CalibrationKind::kCameraIntrinsics)
          .intrinsics.ToPinholeCamera();
  const camera::PinholeCamera projector =
      scanner::LoadIntrinsics(sensor + "projector_intrinsics.json",
                              CalibrationKind::kProjectorIntrinsics)
          .intrinsics.ToPinholeCamera();
  impl_->X_CameraProjector = scanner::LoadPose(sensor + "camera_projector.json",
                                               CalibrationKind::kCameraProjectorExtrinsics)
                                 .pose;
  impl_->pipeline = std::make_unique<scanner::ScanPipeline>(
      scanner::ScanCalibration{cam, projector, impl_->X_CameraProjector, std::nullopt},
      scanner::PatternSequence(projector.width(), projector.height()));
}

SimulatedBinScanner::~SimulatedBinScanner() = default;

apc::Task SimulatedBinScanner::ReadTask(const std::string& path) const {
  return apc::ReadTaskFile(path, impl_->models->catalogue());
}

void SimulatedBinScanner::LoadTask(const apc::Task& task, std::uint32_t seed,
                                   simulator::LayoutMode mode) {
  simulator::LayoutOptions layout;
  layout.mode = mode;
  impl_->world->LoadTask(task, seed, layout);
  impl_->hidden_ids.clear();
}

void SimulatedBinScanner::RemoveItems(const std::string& bin, const std::string& item) {
  for (const simulator::ItemState& s : impl_->world->ItemsIn(bin)) {
    if (s.name == item) impl_->hidden_ids.insert(s.id);
  }
}

namespace {

// One frame of the commodity RGB-D camera from the scan's camera pose: its organised cloud
// (holes NaN) moved into the base frame, with the colour image.
void ScanWithRgbdCamera(const simulator::StructuredLightRenderer& renderer,
                        const BinScanOptions& options, BinScan* scan) {
  simulator::RgbdSensorOptions rgbd;
  rgbd.seed = options.seed;
  const simulator::RgbdFrame frame =
      simulator::RenderRgbd(renderer, simulator::XtionDepthCamera(), scan->X_BaseCamera, rgbd);
  geometry::PointCloud cloud = simulator::ToOrganisedCloud(frame);
  scanner::TransformCloud(scan->X_BaseCamera, "base", &cloud);
  scan->valid_fraction = static_cast<double>(frame.valid()) / static_cast<double>(frame.size());
  scan->cloud = std::move(cloud);
  scan->camera = frame.camera;
}

}  // namespace

BinScan SimulatedBinScanner::Scan(const std::string& bin, const BinScanOptions& options) {
  const simulator::SimWorld& world = *impl_->world;
  const world::BinGeometry& geometry = world.cell().bin(bin);  // Throws for unknown bins.
  const Eigen::Isometry3d& X_BaseShelf = world.cell().config.X_BaseShelf;

  BinScan scan;
  scan.bin = bin;
  scan.bin_box.X_BaseBox = X_BaseShelf * Eigen::Translation3d(geometry.inner_S.center());
  scan.bin_box.size_m = geometry.inner_S.sizes();
  for (const simulator::ItemState& s : world.ItemsIn(bin)) {
    if (impl_->hidden_ids.count(s.id) == 0) scan.items.push_back({s.name, s.X_BaseItem});
  }

  // The camera in front of the opening, looking at the floor's middle (shelf frame: x out of
  // the opening, z up).
  const Eigen::Vector3d p_ShelfTarget = world::BinScanTarget_S(geometry, options.view);
  const Eigen::Vector3d p_ShelfCamera = world::BinScanEye_S(geometry, options.view);
  const Eigen::Vector3d z_S = (p_ShelfTarget - p_ShelfCamera).normalized();
  const Eigen::Vector3d x_S = Eigen::Vector3d::UnitZ().cross(z_S).normalized() * -1.0;
  const Eigen::Vector3d y_S = z_S.cross(x_S);
  Eigen::Isometry3d X_ShelfCamera = Eigen::Isometry3d::Identity();
  X_ShelfCamera.linear() << x_S, y_S, z_S;
  X_ShelfCamera.translation() = p_ShelfCamera;
  scan.X_BaseCamera = X_BaseShelf * X_ShelfCamera;

  const auto render_start = Clock::now();
  const std::vector<simulator::SceneObject> all = world.SceneMeshes();
  std::vector<simulator::SceneObject> objects;
  for (std::size_t i = 0; i < all.size(); ++i) {
    const bool is_item = i >= 3;
    if (is_item && impl_->hidden_ids.count(world.items()[i - 3].id) > 0) continue;
    objects.push_back(all[i]);
  }
  const simulator::StructuredLightRenderer renderer(objects);
  if (options.sensor == BinSensor::kRgbd) {
    ScanWithRgbdCamera(renderer, options, &scan);
    scan.render_s = SecondsSince(render_start);
    return scan;
  }

  // Render the 42 captures.
  const scanner::ScanCalibration& calibration = impl_->pipeline->calibration();
  const simulator::ScanPose pose{calibration.camera, scan.X_BaseCamera, calibration.projector,
                                 scan.X_BaseCamera * impl_->X_CameraProjector};
  const simulator::ScanGeometry rays = renderer.Prepare(pose);
  const scanner::PatternSequence& patterns = impl_->pipeline->patterns();
  simulator::RenderOptions render;
  render.ambient = options.ambient;
  render.read_noise_dn = options.read_noise_dn;
  render.seed = options.seed;
  std::vector<scanner::GrayImage> images;
  images.reserve(static_cast<std::size_t>(patterns.num_images()));
  simulator::GrayImage projected(patterns.projector_width(), patterns.projector_height());
  for (int i = 0; i < patterns.num_images(); ++i) {
    projected.pixels = patterns.Render(i);
    const simulator::GrayImage image = simulator::RenderImage(rays, projected, render, i);
    scanner::GrayImage out(static_cast<std::uint32_t>(image.width),
                           static_cast<std::uint32_t>(image.height));
    out.pixels = image.pixels;
    images.push_back(std::move(out));
  }
  scan.render_s = SecondsSince(render_start);

  // Decode, triangulate, normals: the scanner service's defaults.
  const auto process_start = Clock::now();
  scanner::ScanOptions scan_options;
  scan_options.decode.min_contrast = 20;
  scan_options.decode.min_bit_contrast = 5;
  scan_options.triangulation.max_residual_projector_px = 0.001 * calibration.projector.fx();
  scan_options.triangulation.min_depth_m = 0.1;
  scan_options.triangulation.max_depth_m = 3.0;
  scan_options.triangulation.remove_isolated = true;
  scan_options.triangulation.min_neighbors = 3;
  scan_options.normals.step = 2;
  scan_options.frame = scanner::ScanFrame::kCamera;
  geometry::PointCloud cloud =
      impl_->pipeline->ProcessView(images, scan_options, &scan.valid_fraction);
  scanner::TransformCloud(scan.X_BaseCamera, "base", &cloud);
  scan.cloud = std::move(cloud);
  scan.process_s = SecondsSince(process_start);
  scan.camera = calibration.camera;
  return scan;
}

}  // namespace picking::detector_eval
