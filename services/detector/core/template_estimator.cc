// RangeTemplateEstimator: range image templates aligned to the scene's clusters.
#include "services/detector/core/estimators.h"

#include <stdexcept>
#include <utility>

#include "services/detector/core/estimator_stages.h"

namespace picking::detector {

using estimator_stages::CheckInput;
using estimator_stages::Clock;
using estimator_stages::Finish;
using estimator_stages::SecondsSince;

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
  if (!model->templates) {
    throw MethodNotApplicableError("'" + input.item +
                                   "' has no range templates (range_templates is not in its "
                                   "chain in the model manifest)");
  }
  if (!context_->camera()) {
    throw MethodNotApplicableError(
        "range templates need the sensor's intrinsics (an organised scan, or the camera)");
  }
  context_->CheckDeadline();
  const auto preprocess_start = Clock::now();
  const SceneContext::Clusters& clusters = context_->SceneClusters();
  const double preprocess_s = SecondsSince(preprocess_start);
  if (clusters.clusters.empty()) {
    throw NoCandidateError("no cluster of a plausible size in the scene (" +
                           std::to_string(clusters.cloud.size()) + " points clustered)");
  }
  context_->CheckDeadline();
  if (input.clock.Now() > input.budget_end) {
    throw NoCandidateError("the item's time budget was spent before a cluster was matched");
  }
  const auto estimate_start = Clock::now();
  TemplateMatchOptions match = match_;
  match.deadline = std::min(match.deadline, input.budget_end);
  match.clock = input.clock;  // the budget's; a configured deadline is judged on it too
  const std::vector<TemplateMatch> matches =
      MatchTemplates(*model->templates, clusters.cloud, clusters.clusters, context_->X_BaseSensor(),
                     *context_->camera(), match);
  const double estimate_s = SecondsSince(estimate_start);
  if (matches.empty()) {
    throw NoCandidateError("no template matched any of the " +
                           std::to_string(clusters.clusters.size()) + " clusters");
  }
  std::vector<Detection> out;
  for (const TemplateMatch& m : matches) {
    context_->CheckDeadline();
    if (!out.empty() && input.clock.Now() > input.budget_end) break;
    Detection d =
        RefineAndVerify(*model, *context_, Method::kRangeTemplates, m.X_BaseItem, true, refine_);
    d.timings.preprocess_s = preprocess_s;
    d.timings.estimate_s = estimate_s;
    out.push_back(std::move(d));
  }
  return Finish(std::move(out), refine_, start);
}

}  // namespace picking::detector
