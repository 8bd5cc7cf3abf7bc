// SiftPoseEstimator: SIFT matches to rendered model views, pose from the measured points.
#include "services/detector/core/estimators.h"

#include <stdexcept>
#include <string>
#include <utility>

#include "services/detector/core/estimator_stages.h"

namespace picking::detector {

using estimator_stages::CheckInput;
using estimator_stages::Clock;
using estimator_stages::Finish;
using estimator_stages::SecondsSince;

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
  if (!model->sift) {
    throw MethodNotApplicableError(
        "the model of '" + input.item +
        "' has no SIFT views (it has no colours or printed albedo, or too little texture)");
  }
  const geometry::PointCloud& scene = context_->scene();
  if (!scene.is_organized() || !scene.has_intensities()) {
    throw MethodNotApplicableError(
        "SIFT needs an organised scan with intensities (or colours); this one is " +
        std::string(scene.is_organized() ? "organised without intensities" : "unorganised"));
  }
  context_->CheckDeadline();
  const auto estimate_start = Clock::now();
  const SiftPoseResult r =
      EstimateSiftPose(*model->sift, scene, context_->X_BaseSensor(), context_->camera(), sift_);
  const double estimate_s = SecondsSince(estimate_start);
  if (!r.found) {
    throw NoCandidateError("no pose from the SIFT matches: " + std::to_string(r.num_matches) +
                           " matched the best view, " + std::to_string(r.num_with_3d) +
                           " with a measured point, " + std::to_string(r.num_inliers) +
                           " consistent");
  }
  context_->CheckDeadline();
  Detection d = RefineAndVerify(*model, *context_, Method::kSift, r.X_BaseItem, true, refine_);
  d.timings.estimate_s = estimate_s;
  return Finish({d}, refine_, start);
}

}  // namespace picking::detector
