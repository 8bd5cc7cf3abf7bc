#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <optional>
#include <vector>

#include "services/detector/core/estimator_stages.h"

namespace picking::detector {
namespace {

using estimator_stages::ContradictedShapeFit;

constexpr double kNoPrint = std::numeric_limits<double>::quiet_NaN();

Detection Candidate(double score, double appearance) {
  Detection d;
  d.score = score;
  d.appearance = appearance;
  return d;
}

// The chain's default: a print below 0.2 halves the score.
RefineVerifyOptions Defaults() { return RefineVerifyOptions{}; }

TEST(ContradictedShapeFitTest, PicksAShapeFitWhosePrintHalvedItBehindAPoseWithoutPrint) {
  // A box slid along the right item's face (0.9 before halving) behind a pose on another
  // item that has no print to contradict it (0.8).
  const std::vector<Detection> candidates = {Candidate(0.8, kNoPrint), Candidate(0.45, 0.05),
                                             Candidate(0.3, 0.1)};
  const std::optional<std::size_t> found = ContradictedShapeFit(candidates, Defaults());
  ASSERT_TRUE(found.has_value());
  EXPECT_EQ(*found, 1u);
}

TEST(ContradictedShapeFitTest, PicksTheBestShapeAmongSeveralContradictedOnes) {
  const std::vector<Detection> candidates = {Candidate(0.6, 0.9), Candidate(0.35, -0.2),
                                             Candidate(0.48, 0.19), Candidate(0.4, 0.0)};
  const std::optional<std::size_t> found = ContradictedShapeFit(candidates, Defaults());
  ASSERT_TRUE(found.has_value());
  EXPECT_EQ(*found, 2u);  // 0.96 unscaled
}

TEST(ContradictedShapeFitTest, NoneWhenAnUncontradictedPoseFitsAsWell) {
  // 0.4 / 0.5 = 0.8 does not beat the 0.85 the print confirms.
  const std::vector<Detection> candidates = {Candidate(0.85, 0.9), Candidate(0.4, 0.1)};
  EXPECT_FALSE(ContradictedShapeFit(candidates, Defaults()).has_value());
  // Nor a tie.
  const std::vector<Detection> tie = {Candidate(0.8, kNoPrint), Candidate(0.4, 0.1)};
  EXPECT_FALSE(ContradictedShapeFit(tie, Defaults()).has_value());
}

TEST(ContradictedShapeFitTest, NoPrintEvidenceIsNoContradiction) {
  const std::vector<Detection> candidates = {Candidate(0.3, kNoPrint), Candidate(0.2, kNoPrint)};
  EXPECT_FALSE(ContradictedShapeFit(candidates, Defaults()).has_value());
  EXPECT_FALSE(ContradictedShapeFit({}, Defaults()).has_value());
}

TEST(ContradictedShapeFitTest, NoneWithoutAScalingToUndo) {
  const std::vector<Detection> candidates = {Candidate(0.5, kNoPrint), Candidate(0.45, 0.0)};
  RefineVerifyOptions options = Defaults();
  options.verify.appearance_contradiction_scale = 1.0;  // the print only reported
  EXPECT_FALSE(ContradictedShapeFit(candidates, options).has_value());
  options.verify.appearance_contradiction_scale = 0.0;  // a contradiction zeroes the score
  EXPECT_FALSE(ContradictedShapeFit(candidates, options).has_value());
}

TEST(ContradictedShapeFitTest, FollowsTheContradictionThresholdAndScale) {
  const std::vector<Detection> candidates = {Candidate(0.7, kNoPrint), Candidate(0.3, 0.25)};
  RefineVerifyOptions options = Defaults();
  // 0.25 is above the default 0.2: not contradicted.
  EXPECT_FALSE(ContradictedShapeFit(candidates, options).has_value());
  options.verify.min_appearance_correlation = 0.3;
  options.verify.appearance_contradiction_scale = 0.4;  // 0.3 / 0.4 = 0.75 > 0.7
  const std::optional<std::size_t> found = ContradictedShapeFit(candidates, options);
  ASSERT_TRUE(found.has_value());
  EXPECT_EQ(*found, 1u);
}

}  // namespace
}  // namespace picking::detector
