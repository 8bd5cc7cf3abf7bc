// PpfEstimator: point pair features (ppf_detector.h) with box face seeds and sphere fits.
#include "services/detector/core/estimators.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <optional>
#include <stdexcept>
#include <utility>

#include "services/detector/core/estimator_stages.h"

namespace picking::detector {

using estimator_stages::BoxExtentOf;
using estimator_stages::CheckInput;
using estimator_stages::Clock;
using estimator_stages::ContradictedShapeFit;
using estimator_stages::Finish;
using estimator_stages::SecondsSince;

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
                                                          const BudgetClock& clock,
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
    if (clock.Now() > deadline) break;
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
    ppf.seed_source = [this, model, &scene, seed_s, budget_end = input.budget_end,
                       clock = input.clock]() {
      const auto seed_start = Clock::now();  // measures seed_s
      const auto budget_now = clock.Now();   // shares out the budget
      const Clock::time_point deadline =
          budget_end == Clock::time_point::max()
              ? budget_end
              : budget_now + std::chrono::duration_cast<Clock::duration>(
                                 std::max(Clock::duration::zero(), budget_end - budget_now) *
                                 search_.box_budget_fraction);
      std::vector<Eigen::Isometry3d> seeds = BoxFaceSeeds(*model, scene, clock, deadline);
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
  ppf.match.clock = input.clock;
  ppf.clock = input.clock;
  if (input.budget_end != Clock::time_point::max()) {
    const auto now = input.clock.Now();
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
    return TimeForAnother(input.clock, verify_start, static_cast<std::int64_t>(out.size()),
                          input.budget_end);
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
          const auto now = input.clock.Now();
          if (!time_for_another() || now + last > deadline) return std::nullopt;
          Detection d = RefineAndVerify(model, *context_, Method::kPpf, X, false, refine_);
          last = input.clock.Now() - now;
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
  // And the best shape fit among the poses the print contradicts, when it fits better than
  // any other: a box slid along the right item's face, which the polish may slide back.
  if (search_.box_polish_contradicted) {
    const std::optional<std::size_t> contradicted = ContradictedShapeFit(out, refine_);
    if (contradicted && out.begin() + static_cast<std::ptrdiff_t>(*contradicted) != best &&
        out.begin() + static_cast<std::ptrdiff_t>(*contradicted) != best_turned) {
      starts.push_back(out[*contradicted]);
    }
  }
  for (std::size_t i = 0; i < starts.size(); ++i) {
    Clock::time_point deadline = Clock::time_point::max();
    if (input.budget_end != Clock::time_point::max()) {
      const auto now = input.clock.Now();
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
  const auto verify_start = input.clock.Now();
  for (const PpfDetection& hypothesis : result.detections) {
    context_->CheckDeadline();
    // The best come first; the next is verified when the mean time so far leaves room for it.
    if (!TimeForAnother(input.clock, verify_start, static_cast<std::int64_t>(out.size()),
                        input.budget_end)) {
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

}  // namespace picking::detector
