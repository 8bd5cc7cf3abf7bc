#include "benchmarks/detector_eval/bin_detection.h"

#include <pthread.h>

#include <algorithm>
#include <chrono>
#include <optional>
#include <stdexcept>

#include "services/detector/core/detect_in_region.h"

namespace picking::detector_eval {

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

BinScan ScanViews(SimulatedBinScanner& scanner, const std::string& bin,
                  const BinScanOptions& options, const std::vector<world::BinScanView>& views) {
  std::vector<BinScan> scans;
  for (const world::BinScanView& view : views) {
    BinScanOptions one = options;
    one.view = view;
    scans.push_back(scanner.Scan(bin, one));
  }
  return scans.size() == 1 ? std::move(scans.front()) : MergeViews(scans);
}

namespace {

// The detector service's preparation of a Detect request with the bin as region.
detector::SceneOptions SceneOptionsFor(const BinScan& scan, const BinDetectionOptions& options) {
  detector::SceneOptions scene;
  scene.region = scan.bin_box;
  scene.wall_margin_m = options.wall_margin_m;
  scene.wall_faces = options.wall_faces;
  scene.remove_floor = options.remove_floor;
  if (scan.view_poses.size() > 1) scene.view_poses = scan.view_poses;
  scene.multi_sensor_verification = options.multi_sensor_verification;
  scene.fallback_camera = scan.camera;
  scene.estimators = options.estimators;
  return scene;
}

detector::PreparedScene Prepare(const BinScan& scan, const BinDetectionOptions& options) {
  return detector::PrepareScene(scan.cloud, scan.X_BaseCamera, SceneOptionsFor(scan, options));
}

}  // namespace

detector::Detection ScoreTruePose(const std::shared_ptr<const detector::ModelLibrary>& library,
                                  const BinScan& scan, const std::string& item,
                                  const Eigen::Isometry3d& X_BaseItem,
                                  const BinDetectionOptions& options) {
  const detector::PreparedScene prepared = Prepare(scan, options);
  const auto context = detector::MakeSceneContext(prepared);
  detector::Detection d =
      detector::RefineAndVerify(*library->Get(item), *context, detector::Method::kPpf, X_BaseItem,
                                /*refine=*/false, prepared.estimators.refine);
  d.score *= d.outline_factor;  // as an estimator's answer is scored
  return d;
}

detector::SceneAgreement TruePoseAgreement(
    const std::shared_ptr<const detector::ModelLibrary>& library, const BinScan& scan,
    const std::string& item, const Eigen::Isometry3d& X_BaseItem,
    const BinDetectionOptions& options) {
  const detector::PreparedScene prepared = Prepare(scan, options);
  const auto context = detector::MakeSceneContext(prepared);
  const auto model = library->Get(item);
  const detector::PpfScene& scene = context->PpfSceneFor(*model);
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
  // The item's budget runs on this thread's CPU time, as the detector service judges it
  // (budget_clock=thread_cpu): the search is the one a quiet machine makes, whatever the load.
  detector::ItemQuery query;
  query.budget_clock = detector::BudgetClock::ThreadCpu(pthread_self());
  const auto budget_start = query.budget_clock.Now();
  BinDetectionResult result;
  const detector::PreparedScene prepared = Prepare(scan, options);
  result.points_in_region = prepared.finite_points;
  result.intrinsics_fitted = prepared.intrinsics_fitted;
  query.item = item;
  query.method = method;
  query.budget_scale = options.budget_scale;
  query.max_results = options.max_results;
  // As the detector service does: the pre-processing counts in the item's budget.
  detector::ItemDetections found = detector::DetectItem(
      library, prepared, detector::MakeSceneContext(prepared), query, budget_start);
  result.chain = std::move(found.chain);
  result.poses = std::move(found.poses);
  result.total_s = std::chrono::duration<double>(Clock::now() - start).count();
  return result;
}

}  // namespace picking::detector_eval
