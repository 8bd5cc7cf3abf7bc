#pragma once

// The detector's request-level workflow, shared by the service, the evaluation programs and
// the tests: a scene prepared for the estimators (the region's crop, walls and floor, the
// camera's intrinsics fitted, stacked views split and screened), then each item's method
// chain on it, with its distinct poses above the thresholds.

#include <Eigen/Geometry>

#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "libs/geometry/point_cloud.h"
#include "services/detector/core/budget_clock.h"
#include "services/detector/core/detection.h"
#include "services/detector/core/estimators.h"
#include "services/detector/core/model_library.h"
#include "services/detector/core/preprocess.h"

namespace picking::detector {

/// How a scene is prepared (PrepareScene).
struct SceneOptions {
  /// Only the points inside this box (base frame) are kept; none: the whole cloud.
  std::optional<OrientedBox> region;
  /// With a region: points within this distance of its faces (`wall_faces`) are removed,
  /// metres (>= 0) ...
  double wall_margin_m = 0.0;
  std::uint32_t wall_faces = kAllFaces;
  /// ... and, where wall_margin_m > 0, then the measured floor (RemoveBoxFloor: shelf boards
  /// are tilted and rise above the box's bottom). The range templates' clustering removes the
  /// dominant plane itself only when the floor is still there.
  bool remove_floor = true;
  /// The cloud is several organised views stacked row-wise, one sensor pose each (empty: one
  /// view, at the cloud's sensor pose). Each view's intrinsics are fitted to its whole block
  /// and its shading divided out (MergeStackedViews) before the crop.
  std::vector<Eigen::Isometry3d> view_poses;
  /// Stacked views: poses are verified from every view's sensor, not the first one's alone.
  bool multi_sensor_verification = true;
  /// The camera where the intrinsics cannot be fitted (an unorganised cloud).
  PinholeCamera fallback_camera{640, 480, 525.0, 525.0, 319.5, 239.5};
  /// The sensor's intrinsics as the caller knows them (a commodity camera's, sent with its
  /// depth image): one view uses them as they are instead of fitting them to the points;
  /// stacked views fall back to them.
  std::optional<PinholeCamera> camera;
  EstimatorOptions estimators;
};

/// The view poses do not fit the stacked cloud (their number, a non-finite pose).
class ViewPosesError final : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

/// No point of the cloud lies inside the region.
class EmptyRegionError final : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

/// A scene ready for the estimators.
struct PreparedScene {
  geometry::PointCloud cloud;
  Eigen::Isometry3d X_BaseSensor = Eigen::Isometry3d::Identity();  ///< The (first) view's.
  std::optional<PinholeCamera> camera;
  bool intrinsics_fitted = false;  ///< Every view's camera was fitted, none fell back.
  std::size_t finite_points = 0;
  SceneContextOptions context;
  EstimatorOptions estimators;
};

/// Prepares `scene` (seen from X_BaseSensor) as `options` say. Throws ViewPosesError,
/// EmptyRegionError, or std::invalid_argument for an invalid region box or margin.
PreparedScene PrepareScene(geometry::PointCloud scene, const Eigen::Isometry3d& X_BaseSensor,
                           const SceneOptions& options);

/// The shared per-scene state of PreparedScene's estimators (clusters, PPF scenes, ...).
std::shared_ptr<SceneContext> MakeSceneContext(const PreparedScene& scene);

/// One item to look for.
struct ItemQuery {
  std::string item;
  /// Only this method, to the end of its search (the item's time budget limits its
  /// configured chain only); none: the item's chain.
  std::optional<Method> method;
  /// > 0: replaces the minimum score of every method's thresholds.
  double min_score = 0.0;
  /// Up to this many distinct poses (>= 1), best first.
  std::size_t max_results = 1;
  /// Multiplies the item's time budget (> 0): a detector sharing its cores with other work
  /// keeps the search a quiet machine would make.
  double budget_scale = 1.0;
  /// The clock the item's time budget is judged by (DetectItem's `budget_start` is one of its
  /// time points): the steady clock, or a test's (BudgetClock::Frozen: the same search
  /// whatever the machine's load).
  BudgetClock budget_clock;
};

struct ItemDetections {
  ChainResult chain;
  /// The accepted detection and then the method's other candidates above its thresholds,
  /// each farther than a tenth of the model's diameter or 0.3 rad from those before.
  std::vector<Detection> poses;
};

/// Runs the item's chain on the prepared scene. The item's time budget counts from
/// `budget_start`, a time point of query.budget_clock (the first item's includes the shared
/// preparation). Throws NotFoundError (libs/errors) for an unknown item, TimeoutError when the
/// context's deadline passes.
ItemDetections DetectItem(const std::shared_ptr<const ModelLibrary>& library,
                          const PreparedScene& scene, const std::shared_ptr<SceneContext>& context,
                          const ItemQuery& query,
                          std::chrono::steady_clock::time_point budget_start);

}  // namespace picking::detector
