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

TEST(MergeViewsTest, KeepsEveryFinitePointWithItsChannelsInOneUnorganisedCloud) {
  const BinScan merged = MergeViews({View(0.0f, 1.0), View(0.5f, 2.0), View(-0.5f, 3.0)});
  ASSERT_EQ(merged.cloud.size(), 9u);
  EXPECT_FALSE(merged.cloud.is_organized());
  EXPECT_EQ(merged.cloud.width, 9u);
  ASSERT_EQ(merged.cloud.normals.size(), 9u);
  ASSERT_EQ(merged.cloud.intensities.size(), 9u);
  EXPECT_FLOAT_EQ(merged.cloud.points[3].x(), 0.5f);
  // Every view's intensities compensated for its own shading (all points face their
  // sensors at least as steeply as min_sample_cos).
  const detector::AppearanceOptions appearance;
  const Eigen::Vector3f n = Eigen::Vector3f::UnitZ();
  for (std::size_t i = 0; i < 9; ++i) {
    const float own_x = i < 3 ? 0.0f : (i < 6 ? 0.5f : -0.5f);
    const float measured = 0.1f * static_cast<float>(i % 3 + 1);
    EXPECT_FLOAT_EQ(merged.cloud.intensities[i],
                    detector::ShadingCompensatedIntensity(measured, merged.cloud.points[i], n,
                                                          Eigen::Vector3f(own_x, 0.0f, 0.0f),
                                                          appearance.min_cos))
        << i;
  }
  // The other views' sensors, for verification from every view.
  ASSERT_EQ(merged.other_sensors.size(), 2u);
  EXPECT_DOUBLE_EQ(merged.other_sensors[0].X_BaseSensor.translation().x(), 0.5);
  EXPECT_DOUBLE_EQ(merged.other_sensors[1].X_BaseSensor.translation().x(), -0.5);
  // The first view's sensor; timings summed.
  EXPECT_DOUBLE_EQ(merged.X_BaseCamera.translation().x(), 0.0);
  EXPECT_DOUBLE_EQ(merged.render_s, 6.0);
  EXPECT_DOUBLE_EQ(merged.valid_fraction, 0.75);
  EXPECT_EQ(merged.bin, "bin_C");
}

TEST(MergeViewsTest, DropsTheIntensitiesAViewSawAtAGrazingAngle) {
  // The second view's sensor sees the points (normals along z) about 84 degrees off their
  // normal: its intensities there are NaN, its points and normals are kept.
  BinScan grazing = View(0.0f, 1.0);
  grazing.X_BaseCamera.translation() = Eigen::Vector3d(5.0, 0.0, 0.5);
  const BinScan merged = MergeViews({View(0.0f, 1.0), grazing});
  ASSERT_EQ(merged.cloud.size(), 6u);
  for (std::size_t i = 0; i < 3; ++i) EXPECT_TRUE(std::isfinite(merged.cloud.intensities[i]));
  for (std::size_t i = 3; i < 6; ++i) {
    EXPECT_TRUE(std::isnan(merged.cloud.intensities[i])) << i;
    EXPECT_TRUE(merged.cloud.normals[i].allFinite());
  }
}

TEST(MergeViewsTest, RefusesNoViewAndViewsOfDifferentBins) {
  EXPECT_THROW(MergeViews({}), std::invalid_argument);
  BinScan other = View(0.0f, 1.0);
  other.bin = "bin_D";
  EXPECT_THROW(MergeViews({View(0.0f, 1.0), other}), std::invalid_argument);
}

}  // namespace
}  // namespace picking::detector_eval
