#include "services/detector/core/estimators.h"

#include <Eigen/Dense>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

#include "libs/errors/errors.h"

namespace picking::detector {
namespace {

using Clock = std::chrono::steady_clock;

double SecondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// A box model's half sides and centre, item frame, from its points.
struct BoxExtent {
  Eigen::Vector3d half_size;
  Eigen::Vector3d p_ItemCentre;
};
BoxExtent BoxExtentOf(const geometry::PointCloud& cloud) {
  Eigen::AlignedBox3d box;
  for (const auto& p : cloud.points) box.extend(p.cast<double>());
  return {0.5 * box.sizes(), box.center()};
}

void CheckInput(const EstimatorInput& input, const SceneContext& context, const char* who) {
  if (input.scene == nullptr) throw std::invalid_argument(std::string(who) + ": null scene");
  if (input.scene != &context.scene()) {
    throw std::invalid_argument(std::string(who) +
                                ": the input scene is not the scene of the estimator's context");
  }
}

// Best first by score, with the appearance (where there is evidence) as a bonus.
// Score plus the appearance as a bonus; a pose whose print gives no evidence either way ranks
// as one at the contradiction threshold: below a pose the print confirms, above one it
// contradicts.
void SortByScore(std::vector<Detection>* detections, const RefineVerifyOptions& options) {
  const double weight = options.appearance_rank_weight;
  const double neutral = options.verify.min_appearance_correlation;
  const auto rank = [weight, neutral](const Detection& d) {
    return d.score + weight * (std::isfinite(d.appearance) ? d.appearance : neutral);
  };
  std::stable_sort(detections->begin(), detections->end(),
                   [&rank](const Detection& a, const Detection& b) { return rank(a) > rank(b); });
}

// An estimator's candidates, best first, each with the estimator's whole time since `start`.
std::vector<Detection> Finish(std::vector<Detection> out, const RefineVerifyOptions& options,
                              Clock::time_point start) {
  SortByScore(&out, options);
  for (auto& d : out) d.timings.total_s = SecondsSince(start);
  return out;
}

}  // namespace

// --- SceneContext ---------------------------------------------------------------------------

SceneContext::SceneContext(const geometry::PointCloud& scene, const Eigen::Isometry3d& X_BaseSensor,
                           std::optional<PinholeCamera> camera, SceneContextOptions options)
    : scene_(&scene),
      X_BaseSensor_(X_BaseSensor),
      camera_(std::move(camera)),
      options_(std::move(options)) {
  if (options_.max_clusters < 1) {
    throw std::invalid_argument("SceneContext: max_clusters must be >= 1");
  }
  const bool any_finite = std::any_of(scene.points.begin(), scene.points.end(),
                                      [](const Eigen::Vector3f& p) { return p.allFinite(); });
  if (!any_finite) throw std::invalid_argument("SceneContext: the scene has no finite point");
}

SceneContext::~SceneContext() = default;

void SceneContext::CheckDeadline() const {
  if (Clock::now() > deadline_) {
    throw TimeoutError("detection did not finish within the call's deadline");
  }
}

const PpfScene& SceneContext::PpfSceneFor(const LoadedModel& model) {
  std::lock_guard<std::mutex> lock(mutex_);
  auto& slot = ppf_scenes_[model.spec.item];
  if (!slot) {
    PpfSceneOptions options;
    options.viewpoint = X_BaseSensor_.translation().cast<float>();
    slot = std::make_unique<PpfScene>(PreparePpfScene(*scene_, *model.object, options));
  }
  return *slot;
}

const VerificationScene* SceneContext::Verification() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!verification_built_) {
    if (camera_) {
      std::vector<SensorView> sensors = {SensorView{X_BaseSensor_, *camera_}};
      sensors.insert(sensors.end(), options_.other_sensors.begin(), options_.other_sensors.end());
      verification_ = std::make_unique<VerificationScene>(*scene_, std::move(sensors));
    }
    verification_built_ = true;
  }
  return verification_.get();
}

const SceneContext::Clusters& SceneContext::SceneClusters() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!clusters_) {
    auto c = std::make_unique<Clusters>();
    PlaneRemovalOptions plane = options_.plane;
    plane.keep_organized = true;
    c->cloud = options_.remove_dominant_plane ? RemoveDominantPlane(*scene_, plane).cloud : *scene_;
    c->clusters = EuclideanClusters(c->cloud, options_.clusters, &c->representatives);
    if (c->clusters.size() > static_cast<std::size_t>(options_.max_clusters)) {
      c->clusters.resize(static_cast<std::size_t>(options_.max_clusters));
      c->representatives.resize(static_cast<std::size_t>(options_.max_clusters));
    }
    for (const auto& cluster : c->clusters) {
      Eigen::AlignedBox3f box;
      for (int i : cluster) box.extend(c->cloud.points[i]);
      c->extent_m.push_back(cluster.empty() ? 0.0 : static_cast<double>(box.diagonal().norm()));
    }
    clusters_ = std::move(c);
  }
  return *clusters_;
}

std::vector<std::int32_t> SceneContext::ClusterLabels(const std::vector<Eigen::Vector3f>& points,
                                                      float max_distance_m) {
  const Clusters& clusters = SceneClusters();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!cluster_tree_) {
      std::vector<Eigen::Vector3f> clustered;
      for (std::size_t c = 0; c < clusters.representatives.size(); ++c) {
        for (int i : clusters.representatives[c]) {
          clustered.push_back(clusters.cloud.points[i]);
          cluster_labels_.push_back(static_cast<std::int32_t>(c));
        }
      }
      cluster_tree_ = std::make_unique<KdTree>(clustered);
    }
  }
  std::vector<std::int32_t> labels(points.size(), -1);
  if (cluster_tree_->empty()) return labels;
  const float max_sq = max_distance_m * max_distance_m;
  for (std::size_t i = 0; i < points.size(); ++i) {
    const std::int32_t j = cluster_tree_->Nearest(points[i], nullptr, max_sq);
    if (j != KdTree::kNone) labels[i] = cluster_labels_[j];
  }
  return labels;
}

// --- Refinement and verification ------------------------------------------------------------

Detection RefineAndVerify(const LoadedModel& model, SceneContext& context, Method method,
                          const Eigen::Isometry3d& X_BaseItem, bool refine,
                          const RefineVerifyOptions& options) {
  const ObjectModel& object = *model.object;
  const PpfScene& scene = context.PpfSceneFor(model);
  Detection d;
  d.item = model.spec.item;
  d.method = ToString(method);
  d.X_BaseItem = X_BaseItem;

  const auto refine_start = Clock::now();
  IcpOptions icp = options.icp;
  icp.max_correspondence_distance_m = options.icp_distance_rel * object.sampling_distance_m();
  icp.loss_scale_m = std::max(1e-4f, 0.25f * object.sampling_distance_m());
  if (refine && !scene.fine.empty()) {
    const IcpResult r = RunIcp(object.icp_cloud(), scene.fine, scene.fine_tree, X_BaseItem, icp);
    if (r.correspondences >= icp.min_correspondences) d.X_BaseItem = r.X_TargetSource;
    d.fitness = r.fitness;
    d.inlier_rmse_m = r.inlier_rmse_m;
  } else if (!scene.fine.empty()) {
    // Quality figures of the given pose without moving it: one ICP iteration's
    // correspondences would move it, so count partners directly.
    const float max_sq = icp.max_correspondence_distance_m * icp.max_correspondence_distance_m;
    std::size_t partners = 0;
    double sum_sq = 0.0;
    const Eigen::Isometry3f X = X_BaseItem.cast<float>();
    for (const auto& p : object.icp_cloud().points) {
      float dist_sq = 0.0f;
      if (scene.fine_tree.Nearest(X * p, &dist_sq, max_sq) != KdTree::kNone) {
        ++partners;
        sum_sq += dist_sq;
      }
    }
    const std::size_t n = object.icp_cloud().size();
    d.fitness = n == 0 ? 0.0 : static_cast<double>(partners) / static_cast<double>(n);
    d.inlier_rmse_m = partners == 0 ? 0.0 : std::sqrt(sum_sq / static_cast<double>(partners));
  }
  d.timings.refine_s = SecondsSince(refine_start);

  const auto verify_start = Clock::now();
  if (const VerificationScene* verification = context.Verification()) {
    VerifyOptions verify = options.verify;
    verify.symmetries = object.symmetries();
    const VerifyResult v = Verify(*verification, object.icp_cloud(), d.X_BaseItem, verify);
    d.score = v.score;
    if (model.spec.kind == ModelSourceKind::kShapeBox && options.box_continuation_weight > 0.0 &&
        d.score > 0.0) {
      const BoxExtent box = BoxExtentOf(object.icp_cloud());
      Eigen::Isometry3d X_BaseBox = d.X_BaseItem;
      X_BaseBox.translation() += d.X_BaseItem.linear() * box.p_ItemCentre;
      const double continuation =
          BoxSurfaceContinuation(scene.fine, scene.fine_tree, X_BaseBox, box.half_size,
                                 context.X_BaseSensor().translation(), options.continuation);
      d.score *= 1.0 - options.box_continuation_weight * continuation;
    }
    if (v.appearance.defined) {
      d.appearance = v.appearance.correlation;
      d.X_BaseItem = v.X_BaseItem_appearance;
    }
  } else {
    d.score = d.fitness;
  }
  d.timings.verify_s = SecondsSince(verify_start);
  return d;
}

// --- PPF ------------------------------------------------------------------------------------

PpfEstimator::PpfEstimator(std::shared_ptr<const ModelLibrary> library,
                           std::shared_ptr<SceneContext> context, PpfDetectorOptions ppf,
                           RefineVerifyOptions refine, PpfSearchOptions search)
    : library_(std::move(library)),
      context_(std::move(context)),
      ppf_(std::move(ppf)),
      refine_(std::move(refine)),
      search_(std::move(search)) {
  if (!library_ || !context_) throw std::invalid_argument("PpfEstimator: null library or context");
  if (!(search_.voting_budget_fraction > 0.0f && search_.voting_budget_fraction <= 1.0f)) {
    throw std::invalid_argument("PpfSearchOptions: voting_budget_fraction must be in (0, 1]");
  }
  if (!(search_.box_budget_fraction > 0.0f && search_.box_budget_fraction <= 1.0f)) {
    throw std::invalid_argument("PpfSearchOptions: box_budget_fraction must be in (0, 1]");
  }
  if (!(search_.verify_budget_fraction >= 0.0f &&
        search_.voting_budget_fraction + search_.verify_budget_fraction < 1.0f)) {
    throw std::invalid_argument(
        "PpfSearchOptions: verify_budget_fraction must be >= 0 and leave room for refinement "
        "after voting_budget_fraction");
  }
  if (search_.box_screen_points < 30) {
    throw std::invalid_argument("PpfSearchOptions: box_screen_points must be >= 30");
  }
  if (!(search_.box_screen_tolerance_scale >= 1.0)) {
    throw std::invalid_argument("PpfSearchOptions: box_screen_tolerance_scale must be >= 1");
  }
  if (search_.box_max_refined < 0) {
    throw std::invalid_argument("PpfSearchOptions: box_max_refined must be >= 0");
  }
  if (!(search_.box_polish_step_m > 0.0) || search_.box_polish_levels < 0) {
    throw std::invalid_argument(
        "PpfSearchOptions: box_polish_step_m must be > 0 and box_polish_levels >= 0");
  }
  if (!(search_.box_near_square_tolerance >= 0.0)) {
    throw std::invalid_argument("PpfSearchOptions: box_near_square_tolerance must be >= 0");
  }
  search_.box.Validate();
}

std::vector<Eigen::Isometry3d> PpfEstimator::BoxFaceSeeds(const LoadedModel& model,
                                                          const PpfScene& scene,
                                                          Clock::time_point deadline) {
  if (search_.box_max_refined == 0) return {};
  const geometry::PointCloud& icp_cloud = model.object->icp_cloud();
  const auto [half_size, p_ItemCentre] = BoxExtentOf(icp_cloud);
  BoxFaceOptions faces = search_.box;
  faces.neighbour_radius_m =
      std::max(faces.neighbour_radius_m, 2.5 * static_cast<double>(model.object->fine_voxel_m()));
  const std::vector<PlanarPatch> patches = FindPlanarPatches(scene.fine, scene.fine_tree, faces);

  // Screening: the support of a few hundred model points, geometry only.
  const geometry::PointCloud screen_model = EveryNthPoint(
      icp_cloud, std::max<std::size_t>(
                     1, icp_cloud.size() / static_cast<std::size_t>(search_.box_screen_points)));
  // PPF's own check of a hypothesis (seen from the reference sensor), widened for a pose
  // not yet refined.
  const float step = model.object->sampling_distance_m();
  const float screen_distance_m =
      static_cast<float>(search_.box_screen_tolerance_scale) * ppf_.support_distance_rel * step;
  const float screen_conflict_m = ppf_.conflict_distance_rel * step;
  std::vector<std::pair<double, Eigen::Isometry3d>> screened;
  for (const PlanarPatch& patch : patches) {
    if (Clock::now() > deadline) break;
    for (Eigen::Isometry3d X : BoxPosesOnPatch(patch, half_size, faces)) {
      // BoxPosesOnPatch places the box's centre; the item frame may sit elsewhere in it.
      X.translation() -= X.linear() * p_ItemCentre;
      const SceneAgreement a = MeasureAgreement(screen_model, scene, X, screen_distance_m,
                                                ppf_.support_normal_angle_rad, screen_conflict_m);
      const double score = a.visible_points - a.occluded_points < search_.box_screen_min_points
                               ? 0.0
                               : a.support - a.conflict_fraction;
      if (score >= search_.box_min_screen_score) screened.emplace_back(score, X);
    }
  }
  std::stable_sort(screened.begin(), screened.end(),
                   [](const auto& a, const auto& b) { return a.first > b.first; });
  // Distinct seeds only: a face seen whole gives the same pose from its two rectangle
  // sides of equal length, and neighbouring patches of one face give nearly the same.
  const auto& symmetries = model.object->symmetries();
  const auto same = [&](const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
    if ((a.translation() - b.translation()).norm() > search_.box_seed_distance_m) return false;
    if (symmetries.empty()) {
      return RotationAngle(a.linear(), b.linear()) < search_.box_seed_angle_rad;
    }
    for (const Eigen::Isometry3d& turn : symmetries) {
      if (RotationAngle(a.linear(), b.linear() * turn.linear()) < search_.box_seed_angle_rad) {
        return true;
      }
    }
    return false;
  };
  std::vector<Eigen::Isometry3d> seeds;
  for (const auto& [score, X] : screened) {
    if (seeds.size() >= static_cast<std::size_t>(search_.box_max_refined)) break;
    if (std::any_of(seeds.begin(), seeds.end(),
                    [&](const Eigen::Isometry3d& kept) { return same(kept, X); })) {
      continue;
    }
    seeds.push_back(X);
  }
  return seeds;
}

std::vector<Detection> PpfEstimator::EstimateSpheres(const LoadedModel& model,
                                                     const PpfScene& scene, double preprocess_s) {
  const auto estimate_start = Clock::now();
  const std::vector<SphereFit> spheres =
      FindSpheres(scene.fine, 0.5 * model.object->diameter_m(), search_.sphere);
  const double estimate_s = SecondsSince(estimate_start);
  std::vector<Detection> out;
  for (const SphereFit& sphere : spheres) {
    context_->CheckDeadline();
    // The model frame's origin is the sphere's centre; any rotation places it alike.
    Detection d =
        RefineAndVerify(model, *context_, Method::kPpf,
                        Eigen::Isometry3d(Eigen::Translation3d(sphere.p_Centre)), true, refine_);
    d.timings.preprocess_s = preprocess_s;
    d.timings.estimate_s = estimate_s;
    out.push_back(std::move(d));
  }
  return out;
}

PpfDetectorOptions PpfEstimator::VotingOptions(const std::shared_ptr<const LoadedModel>& model,
                                               const PpfScene& scene, const EstimatorInput& input,
                                               double* seed_s) {
  PpfDetectorOptions ppf = ppf_;
  if (search_.fit_boxes && model->spec.kind == ModelSourceKind::kShapeBox) {
    ppf.seed_source = [this, model, &scene, seed_s, budget_end = input.budget_end]() {
      const auto seed_start = Clock::now();
      const Clock::time_point deadline =
          budget_end == Clock::time_point::max()
              ? budget_end
              : seed_start + std::chrono::duration_cast<Clock::duration>(
                                 std::max(Clock::duration::zero(), budget_end - seed_start) *
                                 search_.box_budget_fraction);
      std::vector<Eigen::Isometry3d> seeds = BoxFaceSeeds(*model, scene, deadline);
      *seed_s = SecondsSince(seed_start);
      return seeds;
    };
  }
  if (scene.sampled.size() <= search_.dense_reference_max_points) ppf.match.reference_step = 1;
  if (search_.per_segment_hypotheses) {
    const float diameter = model->object->diameter_m();
    std::vector<std::int32_t> labels =
        context_->ClusterLabels(scene.sampled.points, model->object->sampling_distance_m());
    const SceneContext::Clusters& clusters = context_->SceneClusters();
    for (std::int32_t& label : labels) {
      if (label >= 0 && clusters.extent_m[static_cast<std::size_t>(label)] <
                            search_.min_segment_extent_rel * diameter) {
        label = -1;
      }
    }
    ppf.match.segments = std::move(labels);
  }
  if (input.budget_end != Clock::time_point::max()) {
    const auto now = Clock::now();
    const auto remaining = std::max(Clock::duration::zero(), input.budget_end - now);
    ppf.match.deadline = now + std::chrono::duration_cast<Clock::duration>(
                                   remaining * search_.voting_budget_fraction);
    ppf.refine_deadline = input.budget_end - std::chrono::duration_cast<Clock::duration>(
                                                 remaining * search_.verify_budget_fraction);
  }
  return ppf;
}

void PpfEstimator::RefineBoxCandidates(const LoadedModel& model, const EstimatorInput& input,
                                       Clock::time_point verify_start,
                                       const std::function<void(Detection)>& add,
                                       std::vector<Detection>& out) {
  const auto by_score = [](const Detection& a, const Detection& b) { return a.score < b.score; };
  const auto time_for_another = [&]() {
    context_->CheckDeadline();
    return TimeForAnother(verify_start, static_cast<std::int64_t>(out.size()), input.budget_end);
  };
  const auto [half_size, p_ItemCentre] = BoxExtentOf(model.object->icp_cloud());
  const std::size_t turned_from = out.size();
  if (search_.box_near_square_tolerance > 0.0) {
    const Eigen::Isometry3d X_best = std::max_element(out.begin(), out.end(), by_score)->X_BaseItem;
    for (const Eigen::Isometry3d& turn :
         NearSquareQuarterTurns(half_size, p_ItemCentre, search_.box_near_square_tolerance)) {
      if (!time_for_another()) break;
      add(RefineAndVerify(model, *context_, Method::kPpf, X_best * turn, true, refine_));
    }
  }
  if (search_.box_polish_levels <= 0) return;
  // Along the box's two longer sides, where a box lying on a flat surface slides freely
  // under ICP; the verification score weighs its edges and the free space beside them.
  int thin = 0;
  half_size.minCoeff(&thin);
  std::vector<int> axes;
  for (int axis = 0; axis < 3; ++axis) {
    if (axis != thin) axes.push_back(axis);
  }
  // Each start polished in its share of the time left (the budget's end, or the
  // verification's pace without a budget).
  const auto polish = [&](Detection best, Clock::time_point deadline) {
    const double start_score = best.score;
    Clock::duration last = Clock::duration::zero();
    const PosePolish polished = PolishTranslation(
        best.X_BaseItem, best.score, axes, search_.box_polish_step_m, search_.box_polish_levels,
        [&](const Eigen::Isometry3d& X) -> std::optional<double> {
          const auto now = Clock::now();
          if (!time_for_another() || now + last > deadline) return std::nullopt;
          Detection d = RefineAndVerify(model, *context_, Method::kPpf, X, false, refine_);
          last = Clock::now() - now;
          const double score = d.score;
          if (score > best.score) best = std::move(d);
          return score;
        });
    // `best` is the detection of the highest score seen: the polished pose's.
    if (polished.score > start_score) add(std::move(best));
  };
  // The best candidate, and the best of its quarter-turns: a near-square face's two
  // turns score alike until each is placed.
  const auto best = std::max_element(out.begin(), out.end(), by_score);
  const auto turned_begin = out.begin() + static_cast<std::ptrdiff_t>(turned_from);
  const auto best_turned = std::max_element(turned_begin, out.end(), by_score);
  std::vector<Detection> starts = {*best};
  if (best_turned != out.end() && best_turned != best) starts.push_back(*best_turned);
  for (std::size_t i = 0; i < starts.size(); ++i) {
    Clock::time_point deadline = Clock::time_point::max();
    if (input.budget_end != Clock::time_point::max()) {
      const auto now = Clock::now();
      deadline = now + std::max(Clock::duration::zero(), input.budget_end - now) /
                           static_cast<int>(starts.size() - i);
    }
    polish(std::move(starts[i]), deadline);
  }
}

// Stages: the scene's PPF preparation; spheres by a direct fit; otherwise voting (with box
// face seeds and per-segment hypotheses), verification of the hypotheses while the budget
// leaves time, and for boxes the quarter-turns and the polish of the best.
std::vector<Detection> PpfEstimator::Estimate(const EstimatorInput& input) {
  CheckInput(input, *context_, "PpfEstimator");
  const auto start = Clock::now();
  const auto model = library_->Get(input.item);
  context_->CheckDeadline();
  const auto preprocess_start = Clock::now();
  const PpfScene& scene = context_->PpfSceneFor(*model);
  const double preprocess_s = SecondsSince(preprocess_start);
  context_->CheckDeadline();
  if (search_.fit_spheres && model->spec.kind == ModelSourceKind::kShapeSphere) {
    return Finish(EstimateSpheres(*model, scene, preprocess_s), refine_, start);
  }
  // The verification scene is built once per scene, on first use, and before the time left
  // is shared out between voting, refinement and verification.
  context_->Verification();
  double seed_s = 0.0;
  const PpfDetectorOptions ppf = VotingOptions(model, scene, input, &seed_s);
  context_->CheckDeadline();
  const PpfDetectionResult result = DetectPpf(*model->object, scene, ppf);
  std::vector<Detection> out;
  const auto add = [&](Detection d) {
    d.timings.preprocess_s = preprocess_s;
    d.timings.estimate_s = seed_s + result.match_s;
    d.timings.refine_s += result.refine_s;
    out.push_back(std::move(d));
  };
  const auto verify_start = Clock::now();
  for (const PpfDetection& hypothesis : result.detections) {
    context_->CheckDeadline();
    // The best come first; the next is verified when the mean time so far leaves room for it.
    if (!TimeForAnother(verify_start, static_cast<std::int64_t>(out.size()), input.budget_end)) {
      break;
    }
    // DetectPpf has refined the pose with ICP already.
    Detection d =
        RefineAndVerify(*model, *context_, Method::kPpf, hypothesis.X_SceneModel, false, refine_);
    d.fitness = hypothesis.icp.fitness;
    d.inlier_rmse_m = hypothesis.icp.inlier_rmse_m;
    add(std::move(d));
  }
  if (model->spec.kind == ModelSourceKind::kShapeBox && !out.empty()) {
    RefineBoxCandidates(*model, input, verify_start, add, out);
  }
  return Finish(std::move(out), refine_, start);
}

// --- SIFT -----------------------------------------------------------------------------------

SiftPoseEstimator::SiftPoseEstimator(std::shared_ptr<const ModelLibrary> library,
                                     std::shared_ptr<SceneContext> context, SiftPoseOptions sift,
                                     RefineVerifyOptions refine)
    : library_(std::move(library)),
      context_(std::move(context)),
      sift_(std::move(sift)),
      refine_(std::move(refine)) {
  if (!library_ || !context_) {
    throw std::invalid_argument("SiftPoseEstimator: null library or context");
  }
}

std::vector<Detection> SiftPoseEstimator::Estimate(const EstimatorInput& input) {
  CheckInput(input, *context_, "SiftPoseEstimator");
  const auto start = Clock::now();
  const auto model = library_->Get(input.item);
  if (!model->sift) return {};
  const geometry::PointCloud& scene = context_->scene();
  if (!scene.is_organized() || !scene.has_intensities()) {
    throw std::invalid_argument(
        "SIFT needs an organised scan with intensities (or colours); this one is " +
        std::string(scene.is_organized() ? "organised without intensities" : "unorganised"));
  }
  context_->CheckDeadline();
  const auto estimate_start = Clock::now();
  const SiftPoseResult r =
      EstimateSiftPose(*model->sift, scene, context_->X_BaseSensor(), context_->camera(), sift_);
  const double estimate_s = SecondsSince(estimate_start);
  if (!r.found) return {};
  context_->CheckDeadline();
  Detection d = RefineAndVerify(*model, *context_, Method::kSift, r.X_BaseItem, true, refine_);
  d.timings.estimate_s = estimate_s;
  d.timings.total_s = SecondsSince(start);
  return {d};
}

// --- Range templates ------------------------------------------------------------------------

RangeTemplateEstimator::RangeTemplateEstimator(std::shared_ptr<const ModelLibrary> library,
                                               std::shared_ptr<SceneContext> context,
                                               TemplateMatchOptions match,
                                               RefineVerifyOptions refine)
    : library_(std::move(library)),
      context_(std::move(context)),
      match_(std::move(match)),
      refine_(std::move(refine)) {
  if (!library_ || !context_) {
    throw std::invalid_argument("RangeTemplateEstimator: null library or context");
  }
}

std::vector<Detection> RangeTemplateEstimator::Estimate(const EstimatorInput& input) {
  CheckInput(input, *context_, "RangeTemplateEstimator");
  const auto start = Clock::now();
  const auto model = library_->Get(input.item);
  if (!model->templates) return {};
  if (!context_->camera()) {
    throw std::invalid_argument("range templates need the sensor's intrinsics");
  }
  context_->CheckDeadline();
  const auto preprocess_start = Clock::now();
  const SceneContext::Clusters& clusters = context_->SceneClusters();
  const double preprocess_s = SecondsSince(preprocess_start);
  if (clusters.clusters.empty()) return {};
  context_->CheckDeadline();
  if (Clock::now() > input.budget_end) return {};  // No time left to match a cluster.
  const auto estimate_start = Clock::now();
  TemplateMatchOptions match = match_;
  match.deadline = std::min(match.deadline, input.budget_end);
  const std::vector<TemplateMatch> matches =
      MatchTemplates(*model->templates, clusters.cloud, clusters.clusters, context_->X_BaseSensor(),
                     *context_->camera(), match);
  const double estimate_s = SecondsSince(estimate_start);
  std::vector<Detection> out;
  for (const TemplateMatch& m : matches) {
    context_->CheckDeadline();
    if (!out.empty() && Clock::now() > input.budget_end) break;
    Detection d =
        RefineAndVerify(*model, *context_, Method::kRangeTemplates, m.X_BaseItem, true, refine_);
    d.timings.preprocess_s = preprocess_s;
    d.timings.estimate_s = estimate_s;
    out.push_back(std::move(d));
  }
  return Finish(std::move(out), refine_, start);
}

std::vector<std::shared_ptr<Estimator>> MakeEstimators(
    const std::shared_ptr<const ModelLibrary>& library,
    const std::shared_ptr<SceneContext>& context, const EstimatorOptions& options) {
  return {std::make_shared<PpfEstimator>(library, context, options.ppf, options.refine,
                                         options.ppf_search),
          std::make_shared<SiftPoseEstimator>(library, context, options.sift, options.refine),
          std::make_shared<RangeTemplateEstimator>(library, context, options.templates,
                                                   options.refine)};
}

// --- Scene helpers --------------------------------------------------------------------------

namespace {

// Gauss-Newton fit of (fx, fy, cx, cy, k1, k2, p1, p2) to samples (x/z, y/z, u, v), started
// from the pinhole fit u = fu[0] x/z + fu[1], v = fv[0] y/z + fv[1].
std::optional<PinholeCamera> FitDistortedIntrinsics(const std::vector<Eigen::Vector4d>& all,
                                                    int width, int height,
                                                    const Eigen::Vector2d& fu,
                                                    const Eigen::Vector2d& fv, double max_rms_px) {
  using Vector8d = Eigen::Matrix<double, 8, 1>;
  using Matrix8d = Eigen::Matrix<double, 8, 8>;
  const std::size_t stride = std::max<std::size_t>(1, all.size() / 4000);
  std::vector<Eigen::Vector4d> samples;
  for (std::size_t i = 0; i < all.size(); i += stride) samples.push_back(all[i]);
  Vector8d k;
  k << fu[0], fv[0], fu[1], fv[1], 0.0, 0.0, 0.0, 0.0;
  // Pixel of normalised (x, y) and its Jacobian with respect to the parameters.
  const auto project = [](const Vector8d& c, double x, double y,
                          Eigen::Matrix<double, 2, 8>* J) -> Eigen::Vector2d {
    const double r2 = x * x + y * y;
    const double radial = 1.0 + c[4] * r2 + c[5] * r2 * r2;
    const double xd = x * radial + 2.0 * c[6] * x * y + c[7] * (r2 + 2.0 * x * x);
    const double yd = y * radial + c[6] * (r2 + 2.0 * y * y) + 2.0 * c[7] * x * y;
    if (J) {
      J->setZero();
      (*J)(0, 0) = xd;
      (*J)(0, 2) = 1.0;
      (*J)(1, 1) = yd;
      (*J)(1, 3) = 1.0;
      (*J)(0, 4) = c[0] * x * r2;
      (*J)(0, 5) = c[0] * x * r2 * r2;
      (*J)(0, 6) = c[0] * 2.0 * x * y;
      (*J)(0, 7) = c[0] * (r2 + 2.0 * x * x);
      (*J)(1, 4) = c[1] * y * r2;
      (*J)(1, 5) = c[1] * y * r2 * r2;
      (*J)(1, 6) = c[1] * (r2 + 2.0 * y * y);
      (*J)(1, 7) = c[1] * 2.0 * x * y;
    }
    return {c[0] * xd + c[2], c[1] * yd + c[3]};
  };
  const auto rms = [&](const Vector8d& c) {
    double sum = 0.0;
    for (const auto& s : samples) {
      sum += (project(c, s[0], s[1], nullptr) - s.tail<2>()).squaredNorm();
    }
    return std::sqrt(sum / static_cast<double>(samples.size()));
  };
  double current = rms(k);
  for (int iteration = 0; iteration < 20; ++iteration) {
    Matrix8d JtJ = Matrix8d::Zero();
    Vector8d Jtr = Vector8d::Zero();
    Eigen::Matrix<double, 2, 8> J;
    for (const auto& s : samples) {
      const Eigen::Vector2d r = project(k, s[0], s[1], &J) - s.tail<2>();
      JtJ += J.transpose() * J;
      Jtr += J.transpose() * r;
    }
    const Vector8d step = JtJ.ldlt().solve(-Jtr);
    if (!step.allFinite()) break;
    const Vector8d next = k + step;
    const double next_rms = rms(next);
    if (!(next_rms < current)) break;
    const bool converged = current - next_rms < 1e-6 * current;
    k = next;
    current = next_rms;
    if (converged) break;
  }
  if (!(current <= max_rms_px) || !(k[0] > 0.0) || !(k[1] > 0.0)) return std::nullopt;
  try {
    Distortion distortion;
    distortion.k1 = k[4];
    distortion.k2 = k[5];
    distortion.p1 = k[6];
    distortion.p2 = k[7];
    return PinholeCamera(width, height, k[0], k[1], k[2], k[3], distortion);
  } catch (const std::invalid_argument&) {
    return std::nullopt;  // A distortion that cannot be inverted over the image.
  }
}

}  // namespace

std::optional<PinholeCamera> FitOrganizedIntrinsics(const geometry::PointCloud& cloud,
                                                    const Eigen::Isometry3d& X_BaseSensor,
                                                    double max_rms_px, int pixel_step) {
  if (!cloud.is_organized() ||
      static_cast<std::size_t>(cloud.width) * cloud.height != cloud.points.size()) {
    return std::nullopt;
  }
  const std::uint32_t step = static_cast<std::uint32_t>(std::max(1, pixel_step));
  const Eigen::Isometry3d X_SensorBase = X_BaseSensor.inverse();
  // Normal equations of [a 1] [f c]^T = pixel for each axis.
  Eigen::Matrix2d Au = Eigen::Matrix2d::Zero(), Av = Eigen::Matrix2d::Zero();
  Eigen::Vector2d bu = Eigen::Vector2d::Zero(), bv = Eigen::Vector2d::Zero();
  std::size_t n = 0;
  std::vector<Eigen::Vector4d> samples;  // (x/z, y/z, u, v)
  for (std::uint32_t v = 0; v < cloud.height; v += step) {
    for (std::uint32_t u = 0; u < cloud.width; u += step) {
      const Eigen::Vector3f& p = cloud.points[static_cast<std::size_t>(v) * cloud.width + u];
      if (!p.allFinite()) continue;
      const Eigen::Vector3d q = X_SensorBase * p.cast<double>();
      if (!(q.z() > 1e-6)) continue;
      const double a = q.x() / q.z();
      const double b = q.y() / q.z();
      Au += Eigen::Vector2d(a, 1.0) * Eigen::Vector2d(a, 1.0).transpose();
      bu += Eigen::Vector2d(a, 1.0) * static_cast<double>(u);
      Av += Eigen::Vector2d(b, 1.0) * Eigen::Vector2d(b, 1.0).transpose();
      bv += Eigen::Vector2d(b, 1.0) * static_cast<double>(v);
      samples.emplace_back(a, b, u, v);
      ++n;
    }
  }
  if (n < 100) return std::nullopt;
  const Eigen::Vector2d fu = Au.ldlt().solve(bu);
  const Eigen::Vector2d fv = Av.ldlt().solve(bv);
  if (!fu.allFinite() || !fv.allFinite() || !(fu[0] > 0.0) || !(fv[0] > 0.0)) return std::nullopt;
  double sum_sq = 0.0;
  for (const auto& s : samples) {
    const double du = fu[0] * s[0] + fu[1] - s[2];
    const double dv = fv[0] * s[1] + fv[1] - s[3];
    sum_sq += du * du + dv * dv;
  }
  const int width = static_cast<int>(cloud.width);
  const int height = static_cast<int>(cloud.height);
  if (std::sqrt(sum_sq / static_cast<double>(n)) <= max_rms_px) {
    return PinholeCamera(width, height, fu[0], fv[0], fu[1], fv[1]);
  }
  return FitDistortedIntrinsics(samples, width, height, fu, fv, max_rms_px);
}

void UseScreenedViews(EstimatorOptions* options) {
  options->ppf.appearance.screened_per_view = true;
  options->refine.verify.appearance.screened_per_view = true;
}

namespace {
// Every 4th pixel of every 4th row: some 50 000 points of a megapixel view.
constexpr int kViewFitPixelStep = 4;
}  // namespace

StackedViews MergeStackedViews(const geometry::PointCloud& stacked,
                               const std::vector<Eigen::Isometry3d>& X_BaseSensors,
                               const PinholeCamera& fallback_camera,
                               const AppearanceOptions& appearance,
                               const OrientedBox* keep_inside) {
  const std::size_t views = X_BaseSensors.size();
  if (views == 0) throw std::invalid_argument("MergeStackedViews: no view sensor pose");
  for (std::size_t k = 0; k < views; ++k) {
    if (!X_BaseSensors[k].matrix().allFinite()) {
      throw std::invalid_argument("MergeStackedViews: the sensor pose of view " +
                                  std::to_string(k) + " is not finite");
    }
  }
  if (!stacked.is_organized() || stacked.height % views != 0 ||
      static_cast<std::size_t>(stacked.width) * stacked.height != stacked.points.size()) {
    throw std::invalid_argument(
        "MergeStackedViews: " + std::to_string(views) +
        " views need an organised cloud whose height is a multiple of the view count (the "
        "views stacked row-wise), got " +
        std::to_string(stacked.width) + " x " + std::to_string(stacked.height));
  }
  const std::size_t rows = stacked.height / views;
  const std::size_t block = rows * stacked.width;
  const bool normals = stacked.has_normals();
  const bool intensities = stacked.has_intensities() && normals;
  StackedViews out;
  const BoxContainment inside(keep_inside != nullptr ? *keep_inside : OrientedBox{});
  for (std::size_t k = 0; k < views; ++k) {
    geometry::PointCloud view;
    view.width = stacked.width;
    view.height = static_cast<std::uint32_t>(rows);
    const auto first = stacked.points.begin() + static_cast<std::ptrdiff_t>(k * block);
    view.points.assign(first, first + static_cast<std::ptrdiff_t>(block));
    const std::optional<PinholeCamera> fitted =
        FitOrganizedIntrinsics(view, X_BaseSensors[k], 1.0, kViewFitPixelStep);
    out.fitted_cameras += fitted ? 1 : 0;
    out.sensors.push_back(SensorView{X_BaseSensors[k], fitted.value_or(fallback_camera)});
    const Eigen::Vector3f viewpoint = X_BaseSensors[k].translation().cast<float>();
    for (std::size_t i = k * block; i < (k + 1) * block; ++i) {
      if (!stacked.points[i].allFinite()) continue;
      if (keep_inside != nullptr && !inside(stacked.points[i])) continue;
      out.cloud.points.push_back(stacked.points[i]);
      if (normals) out.cloud.normals.push_back(stacked.normals[i]);
      if (stacked.has_colors()) out.cloud.colors.push_back(stacked.colors[i]);
      if (intensities) {
        out.cloud.intensities.push_back(
            CompensatedViewIntensity(stacked.intensities[i], stacked.points[i], stacked.normals[i],
                                     viewpoint, appearance)
                .value_or(std::numeric_limits<float>::quiet_NaN()));
      }
    }
  }
  out.cloud.width = static_cast<std::uint32_t>(out.cloud.points.size());
  out.cloud.height = 1;
  return out;
}

}  // namespace picking::detector
