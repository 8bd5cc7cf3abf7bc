#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>

#include "benchmarks/detector_eval/bin_detection.h"
#include "services/detector/core/appearance.h"

namespace picking::detector_eval {
namespace {

// A 2 x 2 organised view whose first pixel was not decoded.
BinScan View(float x, double render_s) {
  BinScan v;
  v.bin = "bin_C";
  const float nan = std::numeric_limits<float>::quiet_NaN();
  v.cloud.points = {{nan, nan, nan}, {x, 0.0f, 1.0f}, {x, 0.1f, 1.0f}, {x, 0.2f, 1.0f}};
  v.cloud.normals.assign(4, Eigen::Vector3f::UnitZ());
  v.cloud.intensities = {0.0f, 0.1f, 0.2f, 0.3f};
  v.cloud.width = 2;
  v.cloud.height = 2;
  v.X_BaseCamera.translation() = Eigen::Vector3d(x, 0.0, 0.0);
  v.render_s = render_s;
  v.valid_fraction = 0.75;
  return v;
}

TEST(MergeViewsTest, StacksTheOrganisedViewsRowWiseWithTheirSensorPoses) {
  const BinScan merged = MergeViews({View(0.0f, 1.0), View(0.5f, 2.0), View(-0.5f, 3.0)});
  ASSERT_EQ(merged.cloud.size(), 12u);
  EXPECT_TRUE(merged.cloud.is_organized());
  EXPECT_EQ(merged.cloud.width, 2u);
  EXPECT_EQ(merged.cloud.height, 6u);
  ASSERT_EQ(merged.cloud.normals.size(), 12u);
  ASSERT_EQ(merged.cloud.intensities.size(), 12u);
  // View k's pixels are rows [2k, 2k + 2), as measured (NaN kept).
  EXPECT_TRUE(std::isnan(merged.cloud.points[4].x()));
  EXPECT_FLOAT_EQ(merged.cloud.points[5].x(), 0.5f);
  EXPECT_FLOAT_EQ(merged.cloud.intensities[11], 0.3f);
  ASSERT_EQ(merged.view_poses.size(), 3u);
  EXPECT_DOUBLE_EQ(merged.view_poses[1].translation().x(), 0.5);
  EXPECT_DOUBLE_EQ(merged.view_poses[2].translation().x(), -0.5);
  // The first view's sensor; timings summed.
  EXPECT_DOUBLE_EQ(merged.X_BaseCamera.translation().x(), 0.0);
  EXPECT_DOUBLE_EQ(merged.render_s, 6.0);
  EXPECT_DOUBLE_EQ(merged.valid_fraction, 0.75);
  EXPECT_EQ(merged.bin, "bin_C");
  // One view stays a one-view scan.
  EXPECT_TRUE(MergeViews({View(0.0f, 1.0)}).view_poses.empty());
}

TEST(MergeViewsTest, RefusesNoViewAndViewsThatDoNotStack) {
  EXPECT_THROW(MergeViews({}), std::invalid_argument);
  BinScan other = View(0.0f, 1.0);
  other.bin = "bin_D";
  EXPECT_THROW(MergeViews({View(0.0f, 1.0), other}), std::invalid_argument);
  BinScan wider = View(0.0f, 1.0);
  wider.cloud.width = 4;
  wider.cloud.height = 1;
  EXPECT_THROW(MergeViews({View(0.0f, 1.0), wider}), std::invalid_argument);
  BinScan no_intensities = View(0.0f, 1.0);
  no_intensities.cloud.intensities.clear();
  EXPECT_THROW(MergeViews({View(0.0f, 1.0), no_intensities}), std::invalid_argument);
  const BinScan merged = MergeViews({View(0.0f, 1.0), View(0.5f, 1.0)});
  EXPECT_THROW(MergeViews({merged, View(0.0f, 1.0)}), std::invalid_argument);
}

}  // namespace
}  // namespace picking::detector_eval
