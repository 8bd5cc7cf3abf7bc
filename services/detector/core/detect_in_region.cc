#include "services/detector/core/detect_in_region.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <utility>

namespace picking::detector {
namespace {

std::size_t CountFinite(const geometry::PointCloud& cloud) {
  return static_cast<std::size_t>(std::count_if(cloud.points.begin(), cloud.points.end(),
                                                [](const auto& p) { return p.allFinite(); }));
}

void ValidateOptions(const SceneOptions& options) {
  if (!options.region) return;
  options.region->Validate();
  if (!(options.wall_margin_m >= 0.0) ||
      2.0 * options.wall_margin_m >= options.region->size_m.minCoeff()) {
    throw std::invalid_argument(
        "the wall margin must be >= 0 and less than half the smallest side of the region");
  }
}

// The region's crop, then its walls and measured floor.
geometry::PointCloud CropToRegion(const geometry::PointCloud& scene, const SceneOptions& options,
                                  const char* what) {
  if (!options.region) return scene;
  const OrientedBox& box = *options.region;
  geometry::PointCloud cropped;
  try {
    cropped = CropToBox(scene, box);
  } catch (const std::invalid_argument& e) {  // the region lies outside the cloud's bounds
    throw EmptyRegionError(e.what());
  }
  if (options.wall_margin_m > 0.0) {
    WallRemovalOptions walls;
    walls.margin_m = options.wall_margin_m;
    walls.faces = options.wall_faces;
    cropped = RemoveBoxWalls(cropped, box, walls);
    if (options.remove_floor) cropped = RemoveBoxFloor(cropped, box).cloud;
  }
  if (CountFinite(cropped) == 0) {
    throw EmptyRegionError(std::string("no point of the ") + what + " lies inside the region");
  }
  return cropped;
}

// Stacked views: split first (each view's intrinsics fitted to its whole block), keeping only
// the region's points; the region's walls and floor go after.
void PrepareStackedViews(geometry::PointCloud scene, const SceneOptions& options,
                         PreparedScene* out) {
  StackedViews views;
  try {
    views = MergeStackedViews(
        scene, options.view_poses, options.camera ? *options.camera : options.fallback_camera,
        options.estimators.ppf.appearance, options.region ? &*options.region : nullptr);
  } catch (const std::invalid_argument& e) {
    throw ViewPosesError(e.what());
  }
  if (CountFinite(views.cloud) == 0) {
    throw EmptyRegionError("no point of the views lies inside the region");
  }
  out->cloud = CropToRegion(views.cloud, options, "views");
  out->X_BaseSensor = views.sensors.front().X_BaseSensor;
  out->camera = views.sensors.front().camera;
  out->intrinsics_fitted = views.fitted_cameras == static_cast<int>(views.sensors.size());
  if (options.multi_sensor_verification) {
    out->context.other_sensors.assign(views.sensors.begin() + 1, views.sensors.end());
  }
  UseScreenedViews(&out->estimators);
}

// Poses closer than these are the same detection.
bool SamePose(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b, double diameter_m) {
  const double dt = (a.translation() - b.translation()).norm();
  const Eigen::AngleAxisd r(a.linear().transpose() * b.linear());
  return dt < 0.1 * diameter_m && std::abs(r.angle()) < 0.3;
}

// Wraps an estimator to keep its candidates (for max_results > 1) and to stop at the
// context's deadline before starting.
class RecordingEstimator final : public Estimator {
 public:
  RecordingEstimator(std::shared_ptr<Estimator> inner, std::shared_ptr<SceneContext> context)
      : inner_(std::move(inner)), context_(std::move(context)) {}
  Method method() const override { return inner_->method(); }
  std::vector<Detection> Estimate(const EstimatorInput& input) override {
    context_->CheckDeadline();
    candidates_ = inner_->Estimate(input);
    return candidates_;
  }
  const std::vector<Detection>& candidates() const { return candidates_; }

 private:
  std::shared_ptr<Estimator> inner_;
  std::shared_ptr<SceneContext> context_;
  std::vector<Detection> candidates_;
};

// The item's configuration as the query changes it.
ObjectConfig QueryConfig(const LoadedModel& model, const ItemQuery& query) {
  if (!(query.budget_scale > 0.0) || !std::isfinite(query.budget_scale)) {
    throw std::invalid_argument("the time budget's scale must be positive and finite");
  }
  if (!(query.min_score >= 0.0 && query.min_score <= 1.0)) {
    throw std::invalid_argument("min_score must be in [0, 1]");
  }
  ObjectConfig config = model.config;
  config.item = query.item;
  if (query.method) {
    config.preferred = *query.method;
    config.fallbacks.clear();
    config.time_budget_s = 0.0;  // one method on its own: its whole search
  }
  config.time_budget_s *= query.budget_scale;
  if (query.min_score > 0.0) {
    config.thresholds.min_score = query.min_score;
    for (auto& [method, thresholds] : config.method_thresholds) {
      (void)method;
      thresholds.min_score = query.min_score;
    }
  }
  return config;
}

}  // namespace

PreparedScene PrepareScene(geometry::PointCloud scene, const Eigen::Isometry3d& X_BaseSensor,
                           const SceneOptions& options) {
  ValidateOptions(options);
  PreparedScene out;
  out.estimators = options.estimators;
  // A region with a wall margin has lost its floor already.
  out.context.remove_dominant_plane =
      !(options.region && options.wall_margin_m > 0.0 && options.remove_floor);
  out.X_BaseSensor = X_BaseSensor;
  if (!options.view_poses.empty()) {
    PrepareStackedViews(std::move(scene), options, &out);
  } else {
    out.cloud = CropToRegion(scene, options, "cloud");
    if (options.camera) {
      out.camera = options.camera;
    } else {
      out.camera = FitOrganizedIntrinsics(out.cloud, X_BaseSensor);
      out.intrinsics_fitted = out.camera.has_value();
      if (!out.camera) out.camera = options.fallback_camera;
    }
  }
  out.finite_points = CountFinite(out.cloud);
  return out;
}

std::shared_ptr<SceneContext> MakeSceneContext(const PreparedScene& scene) {
  return std::make_shared<SceneContext>(scene.cloud, scene.X_BaseSensor, scene.camera,
                                        scene.context);
}

ItemDetections DetectItem(const std::shared_ptr<const ModelLibrary>& library,
                          const PreparedScene& scene, const std::shared_ptr<SceneContext>& context,
                          const ItemQuery& query,
                          std::chrono::steady_clock::time_point budget_start) {
  const auto model = library->Get(query.item);  // NotFoundError: this item only
  const ObjectConfig config = QueryConfig(*model, query);
  std::vector<std::shared_ptr<RecordingEstimator>> recorders;
  std::vector<std::shared_ptr<Estimator>> estimators;
  for (const auto& e : MakeEstimators(library, context, scene.estimators)) {
    recorders.push_back(std::make_shared<RecordingEstimator>(e, context));
    estimators.push_back(recorders.back());
  }
  const DetectionChain chain(DetectorConfig(config, {{config.item, config}}), estimators);
  EstimatorInput input;
  input.item = query.item;
  input.scene = &scene.cloud;
  input.X_BaseSensor = scene.X_BaseSensor;
  input.camera = scene.camera;
  input.budget_start = budget_start;
  input.clock = query.budget_clock;
  ItemDetections out;
  out.chain = chain.Run(input);
  context->CheckDeadline();  // an estimator stopped by the deadline is not "not found"
  if (!out.chain.detection) return out;
  const Detection& best = *out.chain.detection;
  const std::size_t max_results = std::max<std::size_t>(1, query.max_results);
  out.poses = {best};
  const Thresholds& thresholds = config.ThresholdsFor(MethodFromString(best.method));
  for (const auto& recorder : recorders) {
    if (ToString(recorder->method()) != best.method) continue;
    for (const Detection& d : recorder->candidates()) {
      if (out.poses.size() >= max_results) break;
      if (!thresholds.Accepts(d)) continue;
      const bool duplicate = std::any_of(out.poses.begin(), out.poses.end(), [&](const auto& a) {
        return SamePose(a.X_BaseItem, d.X_BaseItem, model->object->diameter_m());
      });
      if (!duplicate) out.poses.push_back(d);
    }
  }
  return out;
}

}  // namespace picking::detector
