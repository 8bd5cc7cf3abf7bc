#pragma once

// Stages the estimators (estimators.h) share, each estimator in its own file:
// ppf_estimator.cc, sift_estimator.cc, template_estimator.cc. Not part of the detector
// core's interface.

#include <Eigen/Geometry>

#include <chrono>
#include <cstddef>
#include <optional>
#include <vector>

#include "libs/geometry/point_cloud.h"
#include "services/detector/core/estimators.h"

namespace picking::detector::estimator_stages {

// Measures the durations reported in DetectionTimings. Decisions on the time budget read
// EstimatorInput::clock instead (budget_clock.h).
using Clock = std::chrono::steady_clock;

double SecondsSince(Clock::time_point start);

/// A box model's half sides and centre, item frame, from its points.
struct BoxExtent {
  Eigen::Vector3d half_size;
  Eigen::Vector3d p_ItemCentre;
};
BoxExtent BoxExtentOf(const geometry::PointCloud& cloud);

/// Throws std::invalid_argument when `input` has no scene or not the context's.
void CheckInput(const EstimatorInput& input, const SceneContext& context, const char* who);

/// The box candidate to polish besides the best-scored one (PpfSearchOptions::
/// box_polish_contradicted): among the candidates whose print contradicts them (appearance
/// below options.verify.min_appearance_correlation, so that Verify scaled their score by
/// options.verify.appearance_contradiction_scale), the one whose shape fits best, when that
/// unscaled score is above the score of every candidate the print does not contradict.
/// ICP leaves a box free to slide along its face: a pose slid part of its length along the
/// right item's face still fits the shape, but its shifted print contradicts it, and the
/// halved score ranks it behind poses on other items that have no print to contradict them.
/// Index into `candidates`; nullopt when there is no such candidate or the contradiction
/// scale is not in (0, 1) (no scaling to undo).
std::optional<std::size_t> ContradictedShapeFit(const std::vector<Detection>& candidates,
                                                const RefineVerifyOptions& options);

/// An estimator's candidates, each with its score scaled by its outline factor (the search
/// ranked them by their support alone), best first (score plus the appearance as a bonus),
/// each with the estimator's whole time since `start`.
std::vector<Detection> Finish(std::vector<Detection> out, const RefineVerifyOptions& options,
                              Clock::time_point start);

}  // namespace picking::detector::estimator_stages
