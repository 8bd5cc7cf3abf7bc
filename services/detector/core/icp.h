#pragma once

#include <Eigen/Geometry>

#include <optional>

#include "libs/geometry/point_cloud.h"
#include "services/detector/core/kdtree.h"

namespace picking::detector {

/// Robust weighting of the point-to-plane residuals.
enum class IcpLoss {
  kLeastSquares,  ///< All correspondences weigh 1.
  kHuber,         ///< 1 within loss_scale_m, loss_scale_m / |r| beyond.
  kTukey,         ///< (1 - (r / loss_scale_m)^2)^2 within loss_scale_m, 0 beyond.
};

/// Options of RunIcp; defaults suit a Kinect-class scene sampled at a few millimetres.
struct IcpOptions {
  int max_iterations = 30;                      ///< >= 1.
  float max_correspondence_distance_m = 0.01f;  ///< Pairs further apart are rejected (> 0).
  /// Pairs whose normals differ by more than this are rejected (radians, (0, pi]); only
  /// applied when the source has normals.
  float max_normal_angle_rad = 0.6f;
  /// Fraction of the surviving pairs with the smallest residuals kept per iteration, (0, 1].
  float trim_fraction = 0.9f;
  IcpLoss loss = IcpLoss::kHuber;
  float loss_scale_m = 0.002f;  ///< > 0.
  /// Converged when an update moves less than both thresholds.
  double convergence_translation_m = 1e-4;
  double convergence_rotation_rad = 1e-4;
  /// Largest rotation of one update, radians (> 0); the translation of one update is
  /// limited to max_correspondence_distance_m.
  double max_step_rotation_rad = 0.1;
  int min_correspondences = 6;  ///< Fewer surviving pairs stop the iteration.
  /// Coarse-to-fine: iterations first use every coarse_stride-th source point, until an
  /// update moves less than 10 times the convergence thresholds (or half of max_iterations
  /// have run), then all points; the result is always measured on all points. 1 = all
  /// points throughout. Ignored when the subsample would have fewer than
  /// 20 * min_correspondences points.
  int coarse_stride = 4;
  /// Where the sensor saw the target from (target frame), when known: source points whose
  /// normal, at the current pose, points away from it by more than max_view_angle_rad are
  /// not matched while iterating (the sensor cannot have measured the far side of a model,
  /// and its look-ups are a third to half of the work). The angle is well past 90 degrees
  /// so that a cloud merged from views a little to the side keeps the faces those views
  /// saw. The final figures (fitness, RMSE) count every source point as without it.
  std::optional<Eigen::Vector3f> viewpoint;
  float max_view_angle_rad = 2.1f;  ///< About 120 degrees; in (0, pi].
  /// Degenerate directions: an update is not taken along a direction (of rotation about the
  /// pairs' centroid, scaled by their spread, and translation) whose eigenvalue in the
  /// normal equations is below this fraction of the largest, i.e. that the pairs hardly
  /// constrain (a plane sliding along itself). The pose keeps its start there. In [0, 1);
  /// 0: every direction is solved for.
  double min_constraint_ratio = 3e-5;
};

/// Quality figures of a registration.
struct IcpResult {
  Eigen::Isometry3d X_TargetSource = Eigen::Isometry3d::Identity();  ///< Proper rotation.
  double fitness = 0.0;        ///< Source points with an accepted pair / source points.
  double inlier_rmse_m = 0.0;  ///< RMS point-to-point distance of the accepted pairs.
  int iterations = 0;
  int correspondences = 0;  ///< Accepted pairs at the final pose.
  bool converged = false;
};

/// Point-to-plane ICP of `source` (points in its frame, optional normals) onto `target`
/// (points and unit normals in the target frame), started at X_TargetSource_init.
/// Correspondences are nearest neighbours from `target_tree` (which must index
/// target.points), rejected by distance and normal angle, trimmed and robustly weighted.
/// Each step solves the linearised 6x6 system and applies the update as an exact rotation.
/// Throws std::invalid_argument for an empty source or target, a target without normals,
/// a tree of another size, or invalid options.
IcpResult RunIcp(const geometry::PointCloud& source, const geometry::PointCloud& target,
                 const KdTree& target_tree, const Eigen::Isometry3d& X_TargetSource_init,
                 const IcpOptions& options = {});

}  // namespace picking::detector
