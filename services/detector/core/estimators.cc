#include "services/detector/core/estimators.h"

#include <Eigen/Dense>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>

#include "services/detector/core/estimator_stages.h"

namespace picking::detector {
namespace estimator_stages {
namespace {

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
  // Equal ranks (scores cap at 1: every visible point supported) go to the pose that more of
  // the scan supports: more of the item seen where the pose says it is.
  std::stable_sort(detections->begin(), detections->end(),
                   [&rank](const Detection& a, const Detection& b) {
                     const double ra = rank(a), rb = rank(b);
                     if (std::abs(ra - rb) > 1e-9) return ra > rb;
                     return a.supported_points > b.supported_points;
                   });
}

}  // namespace

double SecondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

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

std::optional<std::size_t> ContradictedShapeFit(const std::vector<Detection>& candidates,
                                                const RefineVerifyOptions& options) {
  const double scale = options.verify.appearance_contradiction_scale;
  if (!(scale > 0.0 && scale < 1.0)) return std::nullopt;
  std::optional<std::size_t> found;
  double best_shape = 0.0;     // unscaled score of the best contradicted candidate
  double best_unscaled = 0.0;  // score of the best candidate the print does not contradict
  for (std::size_t i = 0; i < candidates.size(); ++i) {
    const Detection& d = candidates[i];
    // NaN (no print evidence) is no contradiction, as in Verify.
    const bool contradicted =
        std::isfinite(d.appearance) && d.appearance < options.verify.min_appearance_correlation;
    if (!contradicted) {
      best_unscaled = std::max(best_unscaled, d.score);
    } else if (d.score / scale > best_shape) {
      best_shape = d.score / scale;
      found = i;
    }
  }
  if (!found || !(best_shape > best_unscaled)) return std::nullopt;
  return found;
}

// An estimator's candidates, best first, each with its score scaled by its outline factor (the
// search ranked them by their support) and the estimator's whole time since `start`.
std::vector<Detection> Finish(std::vector<Detection> out, const RefineVerifyOptions& options,
                              Clock::time_point start) {
  for (auto& d : out) d.score *= d.outline_factor;
  SortByScore(&out, options);
  for (auto& d : out) d.timings.total_s = SecondsSince(start);
  return out;
}

}  // namespace estimator_stages

using estimator_stages::BoxExtent;
using estimator_stages::BoxExtentOf;
using estimator_stages::Clock;
using estimator_stages::SecondsSince;

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
    d.score = v.support_score;
    d.outline_factor = v.outline_factor;
    d.visible_points = v.num_visible;
    d.occluded_points = v.num_occluded;
    d.supported_points = v.num_supported;
    d.conflict_points = v.num_conflicts;
    d.outline_points = v.num_outline;
    d.outline_continued = v.num_outline_continued;
    d.outline_hidden = v.num_outline_hidden;
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

std::vector<std::shared_ptr<Estimator>> MakeEstimators(
    const std::shared_ptr<const ModelLibrary>& library,
    const std::shared_ptr<SceneContext>& context, const EstimatorOptions& options) {
  return {std::make_shared<PpfEstimator>(library, context, options.ppf, options.refine,
                                         options.ppf_search),
          std::make_shared<SiftPoseEstimator>(library, context, options.sift, options.refine),
          std::make_shared<RangeTemplateEstimator>(library, context, options.templates,
                                                   options.refine)};
}

}  // namespace picking::detector
