#pragma once

#include <Eigen/Geometry>

#include <chrono>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "libs/geometry/point_cloud.h"
#include "services/detector/core/box_faces.h"
#include "services/detector/core/detection.h"
#include "services/detector/core/icp.h"
#include "services/detector/core/kdtree.h"
#include "services/detector/core/model_library.h"
#include "services/detector/core/ppf_cloud.h"
#include "services/detector/core/ppf_detector.h"
#include "services/detector/core/preprocess.h"
#include "services/detector/core/sift.h"
#include "services/detector/core/templates.h"
#include "services/detector/core/verify.h"

namespace picking::detector {

/// Options of SceneContext's shared pre-processing.
struct SceneContextOptions {
  /// Range templates: the dominant plane (table, bin floor) is removed before clustering,
  /// unless the pre-processing already removed the support (a region's walls and floor: a
  /// large flat or gently curved item face would otherwise be taken for the plane).
  bool remove_dominant_plane = true;
  PlaneRemovalOptions plane;
  /// Euclidean clusters of the scene; grown over 3 mm voxels (a scan's sub-millimetre
  /// points made exact clustering of a bin take seconds).
  ClusterOptions clusters = [] {
    ClusterOptions o;
    o.subsample_voxel_m = 0.003;
    return o;
  }();
  /// Range templates: at most this many clusters (the largest) are matched.
  int max_clusters = 16;
  /// The scene merges the scans of these sensor positions besides the main one (whose
  /// intrinsics are the context's `camera`): verification then judges a model point's
  /// visibility from every sensor (VerificationScene).
  std::vector<SensorView> other_sensors;
};

/// One scene as every estimator of one request sees it (points in the base frame B), with
/// the work shared between methods and items done once, on first use: per-model PPF scenes
/// (fine cloud with normals and search trees, also the ICP target of every method), the
/// verification scene and the euclidean clusters. Holds a pointer to `scene`, which must
/// outlive it. Thread-safe.
class SceneContext final {
 public:
  /// `camera`: the sensor's intrinsics; without them there is no visibility-based
  /// verification (scores fall back to ICP fitness) and no range templates.
  /// Throws std::invalid_argument when the scene has no finite point.
  SceneContext(const geometry::PointCloud& scene, const Eigen::Isometry3d& X_BaseSensor,
               std::optional<PinholeCamera> camera, SceneContextOptions options = {});
  ~SceneContext();
  SceneContext(const SceneContext&) = delete;
  SceneContext& operator=(const SceneContext&) = delete;

  const geometry::PointCloud& scene() const { return *scene_; }
  const Eigen::Isometry3d& X_BaseSensor() const { return X_BaseSensor_; }
  const std::optional<PinholeCamera>& camera() const { return camera_; }

  /// Work after this time point throws TimeoutError (checked between stages). The call's
  /// deadline, which its client counts in wall time: judged on the steady clock, not on the
  /// items' budget clock (EstimatorInput::clock).
  void set_deadline(std::chrono::steady_clock::time_point deadline) { deadline_ = deadline; }
  /// Throws TimeoutError (libs/errors) when the deadline has passed.
  void CheckDeadline() const;

  /// The scene prepared for `model` (sampled with its voxel sizes, normals toward the
  /// sensor). Throws as PreparePpfScene.
  const PpfScene& PpfSceneFor(const LoadedModel& model);
  /// Null without camera.
  const VerificationScene* Verification();
  /// The scene without its dominant plane (organisation kept) and its clusters, largest
  /// first, indexing that cloud.
  struct Clusters {
    geometry::PointCloud cloud;
    std::vector<std::vector<int>> clusters;
    /// Each cluster thinned to one point per clustering voxel (EuclideanClusters'
    /// representatives), for ClusterLabels.
    std::vector<std::vector<int>> representatives;
    /// Bounding-box diagonal of each cluster, metres.
    std::vector<double> extent_m;
  };
  const Clusters& SceneClusters();
  /// For each of `points` (base frame): the index into SceneClusters().clusters of the
  /// cluster of the nearest clustered scene point within max_distance_m (metres), -1 when
  /// there is none; the points searched are the clusters' representatives (one per
  /// clustering voxel, SceneContextOptions::clusters.subsample_voxel_m). Their search tree
  /// is built on first use.
  std::vector<std::int32_t> ClusterLabels(const std::vector<Eigen::Vector3f>& points,
                                          float max_distance_m);

 private:
  const geometry::PointCloud* scene_;
  Eigen::Isometry3d X_BaseSensor_;
  std::optional<PinholeCamera> camera_;
  SceneContextOptions options_;
  std::chrono::steady_clock::time_point deadline_ = std::chrono::steady_clock::time_point::max();
  std::mutex mutex_;
  std::map<std::string, std::unique_ptr<PpfScene>> ppf_scenes_;
  std::unique_ptr<VerificationScene> verification_;
  bool verification_built_ = false;
  std::unique_ptr<Clusters> clusters_;
  std::unique_ptr<KdTree> cluster_tree_;      // over the clustered points
  std::vector<std::int32_t> cluster_labels_;  // cluster of each point of cluster_tree_
};

/// Refinement and scoring shared by all estimators.
struct RefineVerifyOptions {
  /// Final point-to-plane ICP of the model's ICP cloud onto the prepared scene; the
  /// correspondence distance is icp_distance_rel times the model's sampling distance.
  IcpOptions icp;
  float icp_distance_rel = 1.0f;
  /// Verification of the refined pose (verify.h); its score is Detection.score. The
  /// model's symmetry turns are added, so that the appearance picks the turn whose printing
  /// matches the scan (the pose then becomes that turn), and a pose whose appearance
  /// contradicts the scan (correlation below min_appearance_correlation) has its score
  /// halved: a same-size neighbour with other printing falls below the acceptance score.
  VerifyOptions verify = [] {
    VerifyOptions o;
    o.appearance_contradiction_scale = 0.5;
    return o;
  }();
  /// Candidates of one method are ranked by score + appearance_rank_weight * appearance:
  /// between two poses of similar support the one whose printing matches. A pose without
  /// print evidence ranks with verify.min_appearance_correlation, as neither confirmed nor
  /// contradicted.
  double appearance_rank_weight = 0.5;
  /// Box models: the verified score is multiplied by 1 - box_continuation_weight *
  /// BoxSurfaceContinuation (seen from the reference sensor), in [0, 1]: a thin box laid
  /// along the edge strip of a bigger one is supported everywhere it is visible, but the
  /// bigger one's surface runs on past its edges.
  double box_continuation_weight = 1.0;
  ContinuationOptions continuation;
};

/// Refines `X_BaseItem` with ICP (when `refine`) and scores it with Verify (or with the ICP
/// fitness when the context has no camera), turning a box or cylinder pose to the symmetric
/// turn whose appearance fits best. Fills every Detection field but the timings of the
/// estimation stage; the score is the support's alone, for the search to rank by (Finish
/// scales it by Detection::outline_factor). Throws as RunIcp / Verify.
Detection RefineAndVerify(const LoadedModel& model, SceneContext& context, Method method,
                          const Eigen::Isometry3d& X_BaseItem, bool refine,
                          const RefineVerifyOptions& options = {});

/// How PpfEstimator searches a scene beyond DetectPpf's own options.
struct PpfSearchOptions {
  /// Hypotheses per scene segment: the scene's euclidean clusters (SceneContext) label the
  /// PPF reference points and every cluster contributes its best poses
  /// (PpfMatchOptions::segments), so an item next to larger ones is not outvoted.
  bool per_segment_hypotheses = true;
  /// Clusters whose bounding-box diagonal is below this fraction of the model's diameter
  /// cannot hold a visible part of it worth a pose: their reference points join the rest.
  float min_segment_extent_rel = 0.2f;
  /// Scenes with at most this many PPF-sampled points (a large model's coarse sampling) use
  /// every sampled point as a reference point (PpfMatchOptions::reference_step 1): their
  /// voting costs little next to the refinement of the hypotheses.
  std::size_t dense_reference_max_points = 2000;
  /// With a time budget (EstimatorInput::budget_end), voting stops after this fraction of
  /// the remaining budget, leaving the rest to refinement and verification; in (0, 1].
  float voting_budget_fraction = 0.5f;
  /// ... and refinement stops this fraction of it before the budget's end, leaving that to
  /// the verification of the refined poses; >= 0, with voting_budget_fraction below 1.
  float verify_budget_fraction = 0.15f;
  /// Sphere models (ModelSourceKind::kShapeSphere) are found by FindSpheres with the
  /// model's radius instead of PPF voting: a ball's pose is its centre, and every pair of a
  /// sphere votes alike, which makes voting slow and its peaks flat.
  bool fit_spheres = true;
  SphereSearchOptions sphere;
  /// Box models (ModelSourceKind::kShapeBox) fall back on poses that put a box face on the
  /// scene's planar patches (FindPlanarPatches, BoxPosesOnPatch) when no voted hypothesis is
  /// good enough (PpfDetectorOptions::seed_source): a box mostly hidden behind others shows
  /// one or two flat faces, whose point pairs vote alike all over the face so that PPF's
  /// peaks go flat, while a face's plane and a visible corner fix the pose.
  /// `box.neighbour_radius_m` is raised to 2.5 fine voxels of the model where that is larger.
  bool fit_boxes = true;
  BoxFaceOptions box;
  /// The face poses are screened by PPF's agreement check (MeasureAgreement: support minus
  /// conflicts) on this many model points (>= 30), its distance tolerance widened by
  /// box_screen_tolerance_scale (>= 1) for the unrefined pose; a pose showing fewer than
  /// box_screen_min_points unhidden points scores 0 ...
  int box_screen_points = 300;
  double box_screen_tolerance_scale = 2.0;
  int box_screen_min_points = 10;
  /// ... and at most box_max_refined (>= 0) of those scoring at least box_min_screen_score
  /// are refined and verified.
  int box_max_refined = 4;
  double box_min_screen_score = 0.4;
  /// Seeds closer than this (metres and radians, up to the model's symmetry turns) to a
  /// better-screened one are left out.
  double box_seed_distance_m = 0.01;
  double box_seed_angle_rad = 0.2;
  /// With a time budget, the screening stops after this fraction of what remains of it; in
  /// (0, 1].
  float box_budget_fraction = 0.25f;
  /// A box whose face is nearly square (its two sides differ by at most this fraction of
  /// the longer; >= 0, 0: off) fits a scan of that face about as well quarter-turned about
  /// its normal, and its symmetry turns (half-turns) do not cover that: the best-scored
  /// candidate is also refined and verified quarter-turned about each such face's normal,
  /// and the scan's side faces and edges pick the turn.
  double box_near_square_tolerance = 0.1;
  /// The best box candidate and the best of its quarter-turns are then polished on the
  /// verification score (PolishTranslation), each in its share of the time left: moved
  /// along the box's two longer sides while that scores higher, in steps of
  /// box_polish_step_m (> 0), then of half that, box_polish_levels (>= 0, 0: off) step
  /// sizes in all. A box on a flat surface slides freely under ICP along it; its visible
  /// edges and the free space beside it, which the score weighs, place it.
  double box_polish_step_m = 0.008;
  int box_polish_levels = 3;
  /// Also polish the candidate whose shape fits best among those whose print contradicts
  /// them, when its score before the contradiction's scaling beats every other candidate
  /// (estimator_stages::ContradictedShapeFit): ICP slides a box along its face, and a pose
  /// slid along the right item's face fits the shape but shows its print shifted, which halves
  /// its score. The polish weighs the print (the verification score), so it slides the pose
  /// back to where the print agrees, or leaves it contradicted.
  bool box_polish_contradicted = true;
};

/// PPF voting, pose clustering and ICP (ppf_detector.h), then verification. Candidates are
/// the hypotheses that pass DetectPpf's own support check, best score first. Sphere models
/// are found by a sphere fit instead (PpfSearchOptions::fit_spheres), refined by ICP and
/// verified the same way.
class PpfEstimator final : public Estimator {
 public:
  /// Throws std::invalid_argument on a null library or context or bad search options.
  PpfEstimator(std::shared_ptr<const ModelLibrary> library, std::shared_ptr<SceneContext> context,
               PpfDetectorOptions ppf = {}, RefineVerifyOptions refine = {},
               PpfSearchOptions search = {});
  Method method() const override { return Method::kPpf; }
  /// Throws NotFoundError for an unknown item, std::invalid_argument when input.scene is
  /// not the context's scene.
  std::vector<Detection> Estimate(const EstimatorInput& input) override;

 private:
  // Box poses on the scene's planar patches that pass the screening, best first, for
  // DetectPpf to refine and verify (PpfSearchOptions::fit_boxes); none without a
  // verification scene. Patches are no longer screened after `deadline` (on `clock`).
  std::vector<Eigen::Isometry3d> BoxFaceSeeds(const LoadedModel& model, const PpfScene& scene,
                                              const BudgetClock& clock,
                                              std::chrono::steady_clock::time_point deadline);
  // Spheres by a direct fit of the item's radius, each refined and verified.
  std::vector<Detection> EstimateSpheres(const LoadedModel& model, const PpfScene& scene,
                                         double preprocess_s);
  // The voting's options for this model and scene: box face seeds (their time in *seed_s),
  // per-segment hypotheses, the shares of the budget for voting and verification.
  PpfDetectorOptions VotingOptions(const std::shared_ptr<const LoadedModel>& model,
                                   const PpfScene& scene, const EstimatorInput& input,
                                   double* seed_s);
  // For a box: the best candidate's near-square quarter-turns, then the translation polish
  // of the best and of its best turn, each result passed to `add` (which appends to `out`).
  // `verify_start` is a time point of input.clock.
  void RefineBoxCandidates(const LoadedModel& model, const EstimatorInput& input,
                           std::chrono::steady_clock::time_point verify_start,
                           const std::function<void(Detection)>& add, std::vector<Detection>& out);

  std::shared_ptr<const ModelLibrary> library_;
  std::shared_ptr<SceneContext> context_;
  PpfDetectorOptions ppf_;
  RefineVerifyOptions refine_;
  PpfSearchOptions search_;
};

/// SIFT features of the scene's intensity image matched to the model's rendered views
/// (sift.h), pose from the measured 3D points (or EPnP), then ICP and verification. Needs an
/// organised scene with intensities; finds nothing for a model without SIFT views.
class SiftPoseEstimator final : public Estimator {
 public:
  SiftPoseEstimator(std::shared_ptr<const ModelLibrary> library,
                    std::shared_ptr<SceneContext> context, SiftPoseOptions sift = {},
                    RefineVerifyOptions refine = {});
  Method method() const override { return Method::kSift; }
  /// Throws std::invalid_argument when the scene is not organised or has no intensities.
  std::vector<Detection> Estimate(const EstimatorInput& input) override;

 private:
  std::shared_ptr<const ModelLibrary> library_;
  std::shared_ptr<SceneContext> context_;
  SiftPoseOptions sift_;
  RefineVerifyOptions refine_;
};

/// Range-image templates aligned to the euclidean clusters of the scene without its
/// dominant plane (templates.h), then ICP and verification.
class RangeTemplateEstimator final : public Estimator {
 public:
  RangeTemplateEstimator(std::shared_ptr<const ModelLibrary> library,
                         std::shared_ptr<SceneContext> context, TemplateMatchOptions match = {},
                         RefineVerifyOptions refine = {});
  Method method() const override { return Method::kRangeTemplates; }
  /// Throws std::invalid_argument without camera intrinsics.
  std::vector<Detection> Estimate(const EstimatorInput& input) override;

 private:
  std::shared_ptr<const ModelLibrary> library_;
  std::shared_ptr<SceneContext> context_;
  TemplateMatchOptions match_;
  RefineVerifyOptions refine_;
};

/// Options of the three estimators made by MakeEstimators.
struct EstimatorOptions {
  /// PPF in a region of a scan (a shelf bin, the tote): every second sampled scene point is
  /// a reference point and twelve hypotheses are refined, because a partly visible item
  /// among others collects fewer votes than the clutter. DetectPpf's own support check only
  /// pre-filters (min_support 0.4, conflicts not checked there: the pre-processing removed
  /// walls and floor, which its free-space test cannot tell from free space); each candidate
  /// is then scored by Verify against the sensor's depth image, where removed pixels are
  /// unknown rather than free, and the item's thresholds decide.
  PpfDetectorOptions ppf = [] {
    PpfDetectorOptions o;
    o.match.reference_step = 2;
    o.match.max_hypotheses = 12;
    o.hypotheses_to_verify = 12;
    o.min_support = 0.4f;
    o.max_conflict_fraction = 1.0f;
    o.min_appearance_correlation = 0.0f;
    return o;
  }();
  PpfSearchOptions ppf_search;
  SiftPoseOptions sift;
  TemplateMatchOptions templates;
  RefineVerifyOptions refine;
};

/// Sets both copies of the appearance options (PPF's and verification's) for a cloud merged
/// from several views whose intensities were compensated and screened per view
/// (MergeStackedViews, AppearanceOptions::screened_per_view).
void UseScreenedViews(EstimatorOptions* options);

/// The three estimators above for one scene.
std::vector<std::shared_ptr<Estimator>> MakeEstimators(
    const std::shared_ptr<const ModelLibrary>& library,
    const std::shared_ptr<SceneContext>& context, const EstimatorOptions& options = {});

/// Intrinsics of an organised cloud: least-squares fit of the pixel (u, v) of each finite
/// point (points in the sensor frame S) by the pinhole model u = fx x/z + cx, v = fy y/z + cy;
/// when that leaves more than `max_rms_px` RMS residual, by the model with OpenCV lens
/// distortion (k1, k2, p1, p2; Gauss-Newton from the pinhole fit). nullopt when the cloud is
/// not organised, has fewer than 100 finite points (of those used) or neither fit is within
/// `max_rms_px`. `pixel_step` > 1 uses every pixel_step-th pixel of every pixel_step-th row
/// (a full scan's megapixel needs far fewer than all its points to fit eight parameters).
std::optional<PinholeCamera> FitOrganizedIntrinsics(const geometry::PointCloud& cloud,
                                                    const Eigen::Isometry3d& X_BaseSensor,
                                                    double max_rms_px = 1.0, int pixel_step = 1);

/// A scan of several views (the scanner's merge without voxels stacks the views' organised
/// clouds: rows [k h, (k + 1) h) are view k's, h = height / views), turned into what the
/// detector takes from several views: one unorganised cloud of the finite points whose
/// intensities have each view's own shading divided out (CompensatedViewIntensity: NaN where
/// that view grazed the surface; detect with AppearanceOptions::screened_per_view), and each
/// view's sensor (its pose in X_BaseSensors, its intrinsics fitted to its organised block,
/// else `fallback_camera`). Without normals the intensities cannot be compensated and are
/// dropped.
struct StackedViews {
  geometry::PointCloud cloud;
  std::vector<SensorView> sensors;  ///< One per view, the first the reference.
  int fitted_cameras = 0;           ///< Views whose intrinsics were fitted (not the fallback).
};
/// With `keep_inside`, only the points inside that box are kept (the views' intrinsics are
/// still fitted to the whole of each view): a region's crop before the per-point work.
/// Throws std::invalid_argument when X_BaseSensors is empty or holds a non-finite pose, or
/// the cloud is not organised in as many blocks of rows as there are poses.
StackedViews MergeStackedViews(const geometry::PointCloud& stacked,
                               const std::vector<Eigen::Isometry3d>& X_BaseSensors,
                               const PinholeCamera& fallback_camera,
                               const AppearanceOptions& appearance = {},
                               const OrientedBox* keep_inside = nullptr);

}  // namespace picking::detector
