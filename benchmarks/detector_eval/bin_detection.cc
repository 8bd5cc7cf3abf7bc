#include "benchmarks/detector_eval/bin_detection.h"

#include <algorithm>
#include <chrono>
#include <optional>
#include <stdexcept>

#include "services/detector/core/appearance.h"
#include "services/detector/core/estimators.h"
#include "services/detector/core/preprocess.h"

namespace picking::detector_eval {

namespace {

geometry::PointCloud Region(const BinScan& scan, const BinDetectionOptions& options) {
  geometry::PointCloud region = detector::CropToBox(scan.cloud, scan.bin_box);
  if (options.wall_margin_m > 0.0) {
    detector::WallRemovalOptions walls;
    walls.margin_m = options.wall_margin_m;
    walls.faces = options.wall_faces;
    region = detector::RemoveBoxWalls(region, scan.bin_box, walls);
  }
  if (options.remove_floor) region = detector::RemoveBoxFloor(region, scan.bin_box).cloud;
  return region;
}

}  // namespace

BinScan MergeViews(const std::vector<BinScan>& views) {
  if (views.empty()) throw std::invalid_argument("MergeViews: no view");
  BinScan merged = views.front();
  merged.cloud = geometry::PointCloud();
  merged.render_s = 0.0;
  merged.process_s = 0.0;
  merged.valid_fraction = 0.0;
  const geometry::PointCloud& first = views.front().cloud;
  for (const BinScan& v : views) {
    if (v.bin != merged.bin) {
      throw std::invalid_argument("MergeViews: views of " + merged.bin + " and " + v.bin);
    }
    if (!v.view_poses.empty()) throw std::invalid_argument("MergeViews: a view is merged already");
    if (!v.cloud.is_organized() || v.cloud.width != first.width || v.cloud.height != first.height ||
        v.cloud.has_normals() != first.has_normals() ||
        v.cloud.has_intensities() != first.has_intensities() ||
        v.cloud.has_colors() != first.has_colors()) {
      throw std::invalid_argument(
          "MergeViews: the views must be organised clouds of one size with the same channels");
    }
    const geometry::PointCloud& c = v.cloud;
    merged.cloud.points.insert(merged.cloud.points.end(), c.points.begin(), c.points.end());
    merged.cloud.normals.insert(merged.cloud.normals.end(), c.normals.begin(), c.normals.end());
    merged.cloud.intensities.insert(merged.cloud.intensities.end(), c.intensities.begin(),
                                    c.intensities.end());
    merged.cloud.colors.insert(merged.cloud.colors.end(), c.colors.begin(), c.colors.end());
    merged.view_poses.push_back(v.X_BaseCamera);
    merged.render_s += v.render_s;
    merged.process_s += v.process_s;
    merged.valid_fraction += v.valid_fraction / static_cast<double>(views.size());
  }
  merged.cloud.width = first.width;
  merged.cloud.height = first.height * static_cast<std::uint32_t>(views.size());
  if (views.size() == 1) merged.view_poses.clear();
  return merged;
}

namespace {

// The region of `scan` as the detector service prepares it: cropped (organised), then for
// stacked views split into one cloud with each view's shading divided out and each view's
// sensor (MergeStackedViews), else with intrinsics fitted to the organised cloud (the scan's
// own when that fails).
struct PreparedScene {
  geometry::PointCloud cloud;
  std::optional<detector::PinholeCamera> camera;
  bool intrinsics_fitted = false;
  detector::SceneContextOptions context;
  detector::EstimatorOptions estimators;
};

PreparedScene Prepare(const BinScan& scan, const BinDetectionOptions& options) {
  PreparedScene out;
  out.context.remove_dominant_plane = !options.remove_floor;
  out.estimators = options.estimators;
  if (scan.view_poses.size() > 1) {
    // As the detector service: split first (each view's intrinsics fitted to its whole block),
    // keeping the bin's points only, then the walls and floor.
    detector::StackedViews views = detector::MergeStackedViews(
        scan.cloud, scan.view_poses, scan.camera, options.estimators.ppf.appearance, &scan.bin_box);
    BinScan merged;
    merged.cloud = std::move(views.cloud);
    merged.bin_box = scan.bin_box;
    out.cloud = Region(merged, options);
    out.camera = views.sensors.front().camera;
    out.intrinsics_fitted = views.fitted_cameras == static_cast<int>(views.sensors.size());
    if (options.multi_sensor_verification) {
      out.context.other_sensors.assign(views.sensors.begin() + 1, views.sensors.end());
    }
    detector::UseScreenedViews(&out.estimators);
    return out;
  }
  out.cloud = Region(scan, options);
  out.camera = detector::FitOrganizedIntrinsics(out.cloud, scan.X_BaseCamera);
  out.intrinsics_fitted = out.camera.has_value();
  if (!out.camera) out.camera = scan.camera;
  return out;
}

}  // namespace

detector::Detection ScoreTruePose(const std::shared_ptr<const detector::ModelLibrary>& library,
                                  const BinScan& scan, const std::string& item,
                                  const Eigen::Isometry3d& X_BaseItem,
                                  const BinDetectionOptions& options) {
  const PreparedScene prepared = Prepare(scan, options);
  detector::SceneContext context(prepared.cloud, scan.X_BaseCamera, prepared.camera,
                                 prepared.context);
  return detector::RefineAndVerify(*library->Get(item), context, detector::Method::kPpf, X_BaseItem,
                                   /*refine=*/false, prepared.estimators.refine);
}

detector::SceneAgreement TruePoseAgreement(
    const std::shared_ptr<const detector::ModelLibrary>& library, const BinScan& scan,
    const std::string& item, const Eigen::Isometry3d& X_BaseItem,
    const BinDetectionOptions& options) {
  const PreparedScene prepared = Prepare(scan, options);
  detector::SceneContext context(prepared.cloud, scan.X_BaseCamera, prepared.camera,
                                 prepared.context);
  const auto model = library->Get(item);
  const detector::PpfScene& scene = context.PpfSceneFor(*model);
  const detector::PpfDetectorOptions ppf;
  const float step = model->object->sampling_distance_m();
  return detector::MeasureAgreement(*model->object, scene, X_BaseItem,
                                    ppf.support_distance_rel * step, ppf.support_normal_angle_rad,
                                    ppf.conflict_distance_rel * step);
}

BinDetectionResult DetectInBin(const std::shared_ptr<const detector::ModelLibrary>& library,
                               const BinScan& scan, const std::string& item,
                               std::optional<detector::Method> method,
                               const BinDetectionOptions& options) {
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  BinDetectionResult result;
  const PreparedScene prepared = Prepare(scan, options);
  const geometry::PointCloud& region = prepared.cloud;
  for (const auto& p : region.points) result.points_in_region += p.allFinite() ? 1 : 0;
  result.intrinsics_fitted = prepared.intrinsics_fitted;
  auto context = std::make_shared<detector::SceneContext>(region, scan.X_BaseCamera,
                                                          prepared.camera, prepared.context);
  detector::ObjectConfig config = library->ConfigFor(item);
  config.item = item;
  if (!(options.budget_scale > 0.0)) {
    throw std::invalid_argument("BinDetectionOptions: budget_scale must be positive");
  }
  config.time_budget_s *= options.budget_scale;
  if (method) {
    config.preferred = *method;
    config.fallbacks.clear();
    config.time_budget_s = 0.0;  // One method on its own: its whole search.
  }
  const detector::DetectionChain chain(
      detector::DetectorConfig(config, {{item, config}}),
      detector::MakeEstimators(library, context, prepared.estimators));
  detector::EstimatorInput input;
  input.item = item;
  input.scene = &region;
  input.X_BaseSensor = scan.X_BaseCamera;
  input.camera = prepared.camera;
  input.budget_start = start;  // As the detector service does: the pre-processing counts.
  result.chain = chain.Run(input);
  result.total_s = std::chrono::duration<double>(Clock::now() - start).count();
  return result;
}

}  // namespace picking::detector_eval
