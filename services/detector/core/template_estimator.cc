// RangeTemplateEstimator: range image templates aligned to the scene's clusters.
#include "services/detector/core/estimators.h"

#include <cmath>
#include <iomanip>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>

#include "services/detector/core/estimator_stages.h"

namespace picking::detector {

using estimator_stages::CheckInput;
using estimator_stages::Clock;
using estimator_stages::Finish;
using estimator_stages::SecondsSince;

namespace {

// Why a template search matched nothing, in numbers a person can act on: the clusters it could
// not use, those it searched, and how far the best of them missed the accepted cost.
std::string NoMatchReason(const TemplateSearchReport& seen, const TemplateMatchOptions& options) {
  std::ostringstream why;
  why << "no template matched any of the " << seen.clusters << " clusters (";
  if (seen.implausible_clusters > 0) {
    why << seen.implausible_clusters << " too small or of a size implausible for the item, ";
  }
  why << seen.searched_clusters << " searched";
  if (std::isfinite(seen.best_rejected_cost_m)) {
    why << "; the best fit left a mean range residual of " << std::fixed << std::setprecision(1)
        << 1e3 * seen.best_rejected_cost_m << " mm, above the " << 1e3 * options.max_cost_m
        << " mm accepted";
  }
  if (seen.searched_clusters + seen.implausible_clusters < seen.clusters) {
    why << "; the time budget ended the search";
  }
  why << ")";
  return why.str();
}

}  // namespace

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
  TemplateSearchReport seen;
  const std::vector<TemplateMatch> matches =
      MatchTemplates(*model->templates, clusters.cloud, clusters.clusters, context_->X_BaseSensor(),
                     *context_->camera(), match, &seen);
  const double estimate_s = SecondsSince(estimate_start);
  if (matches.empty()) throw NoCandidateError(NoMatchReason(seen, match));
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
