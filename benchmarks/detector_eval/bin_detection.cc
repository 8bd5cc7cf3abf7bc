#include "benchmarks/detector_eval/bin_detection.h"

#include <algorithm>
#include <chrono>
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
  const bool normals = std::all_of(views.begin(), views.end(),
                                   [](const BinScan& v) { return v.cloud.has_normals(); });
  const bool intensities = std::all_of(views.begin(), views.end(),
                                       [](const BinScan& v) { return v.cloud.has_intensities(); });
  const bool colors = std::all_of(views.begin(), views.end(),
                                  [](const BinScan& v) { return v.cloud.has_colors(); });
  const detector::AppearanceOptions appearance;
  for (const BinScan& v : views) {
    if (v.bin != merged.bin) {
      throw std::invalid_argument("MergeViews: views of " + merged.bin + " and " + v.bin);
    }
    const Eigen::Vector3f viewpoint = v.X_BaseCamera.translation().cast<float>();
    for (std::size_t i = 0; i < v.cloud.size(); ++i) {
      if (!v.cloud.points[i].allFinite()) continue;
      const Eigen::Vector3f& p = v.cloud.points[i];
      merged.cloud.points.push_back(p);
      if (normals) merged.cloud.normals.push_back(v.cloud.normals[i]);
      if (intensities) {
        // Each view's shading divided out by its own sensor's position, and NaN where that
        // view grazed the surface (CompensatedViewIntensity; detect with screened_per_view).
        float intensity = std::numeric_limits<float>::quiet_NaN();
        if (normals) {
          intensity = detector::CompensatedViewIntensity(v.cloud.intensities[i], p,
                                                         v.cloud.normals[i], viewpoint, appearance)
                          .value_or(intensity);
        }
        merged.cloud.intensities.push_back(intensity);
      }
      if (colors) merged.cloud.colors.push_back(v.cloud.colors[i]);
    }
    if (&v != &views.front()) {
      merged.other_sensors.push_back(detector::SensorView{v.X_BaseCamera, v.camera});
      merged.other_sensors.insert(merged.other_sensors.end(), v.other_sensors.begin(),
                                  v.other_sensors.end());
    }
    merged.render_s += v.render_s;
    merged.process_s += v.process_s;
    merged.valid_fraction += v.valid_fraction / static_cast<double>(views.size());
  }
  merged.cloud.width = static_cast<std::uint32_t>(merged.cloud.points.size());
  merged.cloud.height = 1;
  return merged;
}

detector::Detection ScoreTruePose(const std::shared_ptr<const detector::ModelLibrary>& library,
                                  const BinScan& scan, const std::string& item,
                                  const Eigen::Isometry3d& X_BaseItem,
                                  const BinDetectionOptions& options) {
  const geometry::PointCloud region = Region(scan, options);
  detector::SceneContextOptions context_options;
  context_options.remove_dominant_plane = !options.remove_floor;
  if (options.multi_sensor_verification) context_options.other_sensors = scan.other_sensors;
  detector::SceneContext context(region, scan.X_BaseCamera, scan.camera, context_options);
  return detector::RefineAndVerify(*library->Get(item), context, detector::Method::kPpf, X_BaseItem,
                                   /*refine=*/false, options.estimators.refine);
}

detector::SceneAgreement TruePoseAgreement(
    const std::shared_ptr<const detector::ModelLibrary>& library, const BinScan& scan,
    const std::string& item, const Eigen::Isometry3d& X_BaseItem,
    const BinDetectionOptions& options) {
  const geometry::PointCloud region = Region(scan, options);
  detector::SceneContext context(region, scan.X_BaseCamera, scan.camera);
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
  const geometry::PointCloud region = Region(scan, options);
  for (const auto& p : region.points) result.points_in_region += p.allFinite() ? 1 : 0;
  std::optional<detector::PinholeCamera> camera =
      detector::FitOrganizedIntrinsics(region, scan.X_BaseCamera);
  result.intrinsics_fitted = camera.has_value();
  if (!camera) camera = scan.camera;

  detector::SceneContextOptions context_options;
  context_options.remove_dominant_plane = !options.remove_floor;
  if (options.multi_sensor_verification) context_options.other_sensors = scan.other_sensors;
  auto context =
      std::make_shared<detector::SceneContext>(region, scan.X_BaseCamera, camera, context_options);
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
      detector::MakeEstimators(library, context, options.estimators));
  detector::EstimatorInput input;
  input.item = item;
  input.scene = &region;
  input.X_BaseSensor = scan.X_BaseCamera;
  input.camera = camera;
  input.budget_start = start;  // As the detector service does: the pre-processing counts.
  result.chain = chain.Run(input);
  result.total_s = std::chrono::duration<double>(Clock::now() - start).count();
  return result;
}

}  // namespace picking::detector_eval
