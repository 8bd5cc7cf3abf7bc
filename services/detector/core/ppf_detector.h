#pragma once

#include <Eigen/Geometry>

#include <chrono>
#include <cstdint>
#include <functional>
#include <vector>

#include "libs/geometry/point_cloud.h"
#include "services/detector/core/appearance.h"
#include "services/detector/core/budget_clock.h"
#include "services/detector/core/icp.h"
#include "services/detector/core/kdtree.h"
#include "services/detector/core/model.h"
#include "services/detector/core/ppf.h"

namespace picking::detector {

/// The smallest range (distance from a viewpoint, metres) of a scene's points per cell of an
/// angular grid around the scene's mean viewing direction: what the sensor saw along each ray.
class ViewRangeGrid final {
 public:
  ViewRangeGrid() = default;

  /// Grid of `cell_rad` radians (> 0) over the directions of `points_S` (scene frame) seen
  /// from `viewpoint_S`; points behind the viewpoint's half-space of the mean direction are
  /// left out, and the cell is enlarged so that the grid has at most 2^22 cells. Throws
  /// std::invalid_argument for a non-positive or non-finite cell_rad.
  ViewRangeGrid(const std::vector<Eigen::Vector3f>& points_S, const Eigen::Vector3f& viewpoint_S,
                float cell_rad);

  bool empty() const { return ranges_.empty(); }
  float cell_rad() const { return cell_rad_; }

  /// Smallest scene range in the cell of the direction of p_S (metres); +infinity when the
  /// cell holds no scene point or lies outside the grid.
  float MinRange(const Eigen::Vector3f& p_S) const;

  /// Smallest scene range over the cell of p_S and the cells within `radius_cells` of it
  /// (a (2r+1)^2 window): what the sensor saw anywhere around the ray, so that a point next
  /// to a depth edge is not compared with the background behind the edge alone. +infinity
  /// when none of those cells holds a scene point or p_S lies outside the grid.
  float MinRangeNear(const Eigen::Vector3f& p_S, int radius_cells) const;

 private:
  bool Cell(const Eigen::Vector3f& p_S, int* u, int* v) const;

  Eigen::Vector3f viewpoint_ = Eigen::Vector3f::Zero();
  Eigen::Matrix3f R_ = Eigen::Matrix3f::Identity();  // rows: mean direction, two normals
  float cell_rad_ = 1.0f;
  float u0_ = 0.0f, v0_ = 0.0f;
  int width_ = 0, height_ = 0;
  std::vector<float> ranges_;
};

/// Whether one more step of a loop that began at `start` and has done `done` (> 0) steps fits
/// before `deadline`, judged on `clock` by the mean time of the steps so far. With done == 0
/// it does (the first step always runs).
inline bool TimeForAnother(const BudgetClock& clock, std::chrono::steady_clock::time_point start,
                           std::int64_t done, std::chrono::steady_clock::time_point deadline) {
  if (done <= 0) return true;
  const auto now = clock.Now();
  return now + (now - start) / done <= deadline;
}

/// A scene prepared for one object model: the fine cloud with normals (ICP target and
/// verification) and the cloud sampled with the model's distance step (PPF voting), both in
/// the scene frame S, metres, with their search trees. `fine` keeps the scene's intensities
/// (voxel-averaged; the luma of its colours when it has colours only) for the appearance
/// check.
struct PpfScene {
  geometry::PointCloud fine;
  geometry::PointCloud sampled;
  KdTree fine_tree;
  KdTree sampled_tree;
  Eigen::Vector3f viewpoint = Eigen::Vector3f::Zero();  ///< Sensor origin in S, metres.
  /// Ranges of `fine` seen from the viewpoint (free-space checks); empty: no check.
  ViewRangeGrid view_ranges;
};

/// Options of PreparePpfScene.
struct PpfSceneOptions {
  /// Sensor origin in the scene frame, metres; normals are oriented toward it.
  Eigen::Vector3f viewpoint = Eigen::Vector3f::Zero();
  /// Keep the scene's own unit normals instead of estimating them.
  bool use_input_normals = false;
};

/// Drops invalid points, samples the scene with the model's fine voxel, estimates normals
/// with the model's radius (or keeps the input ones) and samples again with the model's
/// distance step. Throws std::invalid_argument for an empty scene or one with no valid
/// point, mismatched channels, or use_input_normals without normals.
PpfScene PreparePpfScene(const geometry::PointCloud& scene, const ObjectModel& model,
                         const PpfSceneOptions& options = {});

/// Options of SearchAppearancePose.
struct AppearanceSearchOptions {
  /// Step halvings of the search (>= 0; 0: no search) ...
  int levels = 4;
  /// ... starting at this translation step, metres (> 0); rotation steps move the samples'
  /// mean radius about their centroid as far.
  double start_step_m = 0.004;
  /// The search compares at most this many of the samples (evenly spaced, >= 30); the
  /// result is scored on all of them.
  int max_samples = 400;
  /// Moves (>= 1) tried per level before the step is halved.
  int max_moves_per_level = 8;

  /// Throws std::invalid_argument naming the bad field.
  void Validate() const;
};

/// Options of DetectPpf.
struct PpfDetectorOptions {
  PpfMatchOptions match;
  /// ICP defaults; the correspondence distance and loss scale are overridden by the
  /// relative values below (fractions of the model's sampling distance).
  IcpOptions icp;
  float icp_distance_rel = 1.0f;
  float icp_loss_scale_rel = 0.25f;
  /// Coarse ICP pass (correspondences up to coarse_icp_distance_rel) before the fine one, to
  /// pull in hypotheses whose rotation is off by up to one angle step.
  float coarse_icp_distance_rel = 2.5f;
  int coarse_icp_iterations = 10;
  /// The coarse pass matches every coarse_icp_stride-th model point (>= 1): it only pulls
  /// the pose in, which a quarter of the model's points does as well as all of them.
  int coarse_icp_stride = 4;
  /// Verification: a visible model point is supported when a scene point lies within
  /// support_distance_rel (of the sampling distance) and its normal within
  /// support_normal_angle_rad.
  float support_distance_rel = 0.5f;
  float support_normal_angle_rad = 0.5f;
  /// Detections need at least this support (fraction of the visible model points). A wrong
  /// object can lean on a scene's planes and edges for up to about two thirds of its
  /// visible points (the Stanford bunny in the PCL milk scene: 0.67), while true poses of a
  /// present object score above 0.8.
  float min_support = 0.75f;
  /// Detections may have at most this fraction of their visible model points in conflict:
  /// unsupported, and the scene was measured more than conflict_distance_rel (of the
  /// sampling distance) behind them along the same ray, so the sensor saw through where
  /// the model would be. A wrong object leaning on the scene's surfaces sticks out into
  /// free space; a true pose has few conflicts. The check assumes the scene was seen from
  /// `viewpoint`; for a cloud merged from several views set this to 1 (no check).
  float max_conflict_fraction = 0.1f;
  float conflict_distance_rel = 2.0f;
  /// Detections need at least this fraction of the model's ICP points facing the sensor: a
  /// pose that turns the model's unscanned side (or an edge) to the sensor shows too few
  /// points for the support to mean anything.
  float min_visible_fraction = 0.15f;
  /// ... and at least this many (a support over a handful of points means nothing).
  int min_visible_points = 30;
  /// Hypotheses (by votes) refined by ICP and verified.
  int hypotheses_to_verify = 6;
  /// Poses found otherwise (e.g. a box's faces on the scene's planes, BoxPosesOnPatch),
  /// X_SceneModel, best first: a fallback. When no voted hypothesis passes with a support of
  /// at least seed_fallback_support, seed_source is called (once) and its poses are refined
  /// (fine ICP only, no print search: they sit on the scene's surfaces already) and
  /// verified like the voted ones. They are not held to min_support nor to
  /// min_appearance_correlation (their source screened them, and the support and print here
  /// are seen from one viewpoint: the caller's verification judges them). DetectPpf throws
  /// std::invalid_argument when a pose is not a finite rigid motion.
  std::function<std::vector<Eigen::Isometry3d>()> seed_source;
  /// With a seed_source and a refine_deadline, the voted hypotheses stop this fraction of
  /// the refinement time early, leaving it to the seeds; in [0, 1).
  float seed_refine_fraction = 0.25f;
  float seed_fallback_support = 0.75f;
  /// A refined seed keeps its unrefined pose when that agrees with the scene (support minus
  /// conflicts, MeasureAgreement) by more than this (>= 0) better than ICP's.
  float seed_keep_margin = 0.05f;
  /// No further hypothesis is refined after this time (the best-voted hypothesis and, when
  /// the seeds are tried, the first seed always are): a
  /// caller's time budget, as PpfMatchOptions::deadline is for the voting.
  std::chrono::steady_clock::time_point refine_deadline =
      std::chrono::steady_clock::time_point::max();
  /// The clock refine_deadline (and the seeds' share of it) is judged by, also the one that
  /// times the refinements for that judgement; the voting's deadline is judged by match.clock.
  BudgetClock clock;
  /// Appearance: when the model has albedo and the scene intensities, each refined
  /// hypothesis is also tried turned by the model's symmetries (a box's 180 degree flips, a
  /// cylinder's turns) and the turn whose albedo best explains the scene's intensities is
  /// kept (MatchSymmetricAppearance). Hypotheses are ranked by support - conflict_fraction +
  /// appearance_weight * correlation (correlation 0 without evidence) ...
  AppearanceOptions appearance;
  float appearance_weight = 0.5f;
  /// ... and rejected when the appearance has evidence and its correlation is below this: the
  /// shape fits, the printing does not (a neighbour of the same size).
  float min_appearance_correlation = 0.2f;
  /// After the symmetric turns, each hypothesis with appearance evidence is moved to the
  /// nearby pose whose print best explains the scene (SearchAppearancePose), and keeps it
  /// when that ranks higher: point-to-plane ICP leaves a box face's slide along itself and a
  /// flat item's turn in its plane to where the hypothesis started. levels = 0: off.
  AppearanceSearchOptions appearance_search;
};

/// A verified pose of the model in the scene.
struct PpfDetection {
  Eigen::Isometry3d X_SceneModel = Eigen::Isometry3d::Identity();
  double support = 0.0;  ///< Supported / visible model points, [0, 1].
  /// Visible model points in measured free space / visible model points, [0, 1].
  double conflict_fraction = 0.0;
  int visible_points = 0;
  double votes = 0.0;  ///< Votes of the PPF cluster it came from.
  IcpResult icp;
  /// Model albedo against scene intensity at X_SceneModel (not defined without texture).
  AppearanceScore appearance;
  /// Index into the model's symmetries() of the turn applied after ICP (0: none).
  int symmetry = 0;
  /// Refined from PpfDetectorOptions::seed_source's poses rather than voted.
  bool seed = false;
};

struct PpfDetectionResult {
  /// Hypotheses with support >= min_support, conflict_fraction <= max_conflict_fraction,
  /// enough visible points (min_visible_fraction) and no contradicting appearance, best
  /// ranking (support - conflict_fraction + appearance_weight * correlation) first; distinct
  /// poses only.
  std::vector<PpfDetection> detections;
  /// The best verified hypothesis even when below min_support (support 0 when none).
  PpfDetection best;
  PpfMatchResult match;
  double match_s = 0.0;
  double refine_s = 0.0;
  /// Hypotheses refined and verified (fewer than hypotheses_to_verify when the match had
  /// fewer or the refine_deadline passed).
  int refined_hypotheses = 0;
};

/// Scene support of a model pose: the fraction of the model's ICP points that face the
/// viewpoint and have a scene point within `distance_m` with normals within `normal_angle_rad`.
/// `visible_points` (optional) receives the number of facing points.
double SceneSupport(const ObjectModel& model, const PpfScene& scene,
                    const Eigen::Isometry3d& X_SceneModel, float distance_m, float normal_angle_rad,
                    int* visible_points = nullptr);

/// Agreement of a model pose with the scene (see SceneSupport): support, and the fraction of
/// the facing model points that are unsupported and lie more than `conflict_distance_m` in
/// front of the scene's range around their ray (0 when the scene has no range image). Only
/// points seen at least kMinConflictViewCos (about 75 degrees from their normal) count as
/// conflicts: a surface seen edge-on is mostly not measured, and its model points share range
/// cells with the background beyond the item's silhouette.
struct SceneAgreement {
  double support = 0.0;            ///< Supported / (visible - occluded) model points.
  double conflict_fraction = 0.0;  ///< In conflict / (visible - occluded) model points.
  int visible_points = 0;          ///< Model points facing the viewpoint.
  /// Facing points behind a measured surface (nearer than them on their ray by more than
  /// max(conflict_distance_m, 2 distance_m)): hidden by other objects, no evidence either way.
  int occluded_points = 0;
};
inline constexpr float kMinConflictViewCos = 0.26f;
SceneAgreement MeasureAgreement(const ObjectModel& model, const PpfScene& scene,
                                const Eigen::Isometry3d& X_SceneModel, float distance_m,
                                float normal_angle_rad, float conflict_distance_m);
/// The same over any model points with normals (e.g. a subsample of the ICP cloud, for a
/// quick screening). Throws std::invalid_argument when a point lacks its normal.
SceneAgreement MeasureAgreement(const geometry::PointCloud& model_points, const PpfScene& scene,
                                const Eigen::Isometry3d& X_SceneModel, float distance_m,
                                float normal_angle_rad, float conflict_distance_m);

/// Appearance of a model pose: over the model's ICP points that face the viewpoint, are not
/// seen at a grazing angle (AppearanceOptions::min_sample_cos) and have a scene point within
/// `distance_m` (normals within `normal_angle_rad`), the correlation of
/// the model's albedo at the scene point's position with the scene point's shading-
/// compensated intensity (AppearanceSample with the posed model's normal, which
/// is exact where a grazing face's scan normals are noisy, and the scene viewpoint). Not
/// defined when the model has no albedo or the scene no intensities.
AppearanceScore MeasureAppearance(const ObjectModel& model, const PpfScene& scene,
                                  const Eigen::Isometry3d& X_SceneModel, float distance_m,
                                  float normal_angle_rad, const AppearanceOptions& options = {});

/// The best of the geometrically equivalent poses X_SceneModel * R (R in model.symmetries())
/// by appearance: the scene points matched at X_SceneModel are compared with the albedo of
/// every turned model; for a cylinder the best turn is then refined within +-3/8 of a step
/// about the axis. `symmetry` indexes model.symmetries() (the grid turn the refinement
/// started from); the identity (0) when no turn has evidence.
struct SymmetricAppearance {
  Eigen::Isometry3d X_SceneModel = Eigen::Isometry3d::Identity();
  int symmetry = 0;
  AppearanceScore appearance;
  /// The identity's score, for comparison.
  AppearanceScore unturned;
};
SymmetricAppearance MatchSymmetricAppearance(const ObjectModel& model, const PpfScene& scene,
                                             const Eigen::Isometry3d& X_SceneModel,
                                             float distance_m, float normal_angle_rad,
                                             const AppearanceOptions& options = {});

/// The pose near X_SceneModel whose model print best explains the scene: the scene points
/// matched at X_SceneModel (as in MeasureAppearance) stay fixed while the model moves under
/// them, by a compass search over the six directions of rotation (about the points'
/// centroid) and of translation, keeping a move only when it raises the correlation. Where
/// the shape leaves a direction free (a box's face sliding along itself, a flat item's
/// in-plane turn, which point-to-plane ICP cannot fix) the print decides it. The objective
/// subtracts the points' mean truncated squared point-to-plane distance to the model
/// (over (distance_m / 2)^2), so that the surface stays where it was. Returns the start
/// pose with its score when there is no appearance evidence or search.levels is 0.
struct AppearancePose {
  Eigen::Isometry3d X_SceneModel = Eigen::Isometry3d::Identity();
  AppearanceScore appearance;
};
AppearancePose SearchAppearancePose(const ObjectModel& model, const PpfScene& scene,
                                    const Eigen::Isometry3d& X_SceneModel, float distance_m,
                                    float normal_angle_rad, const AppearanceOptions& options = {},
                                    const AppearanceSearchOptions& search = {});

/// PPF voting, pose clustering, ICP refinement and verification of the best hypotheses.
PpfDetectionResult DetectPpf(const ObjectModel& model, const PpfScene& scene,
                             const PpfDetectorOptions& options = {});

}  // namespace picking::detector
