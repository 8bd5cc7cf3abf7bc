#include "services/scanner/core/synthetic_capture.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <stdexcept>

namespace picking::scanner {
namespace {

SyntheticScene TiltedPlane() {
  SyntheticScene scene;
  SyntheticPlane plane;
  plane.normal = Eigen::Vector3d(0.2, -0.1, 1.0).normalized();
  plane.offset_m = plane.normal.dot(Eigen::Vector3d(0, 0, 1.0));
  scene.planes.push_back(plane);
  return scene;
}

TEST(SyntheticCaptureTest, GroundTruthCoordinatesRoundToTheLitMirror) {
  const ScannerRig rig = MakeExampleRig(320, 256);
  const PatternSequence patterns;
  const SyntheticCapture capture =
      RenderSyntheticCapture(rig, patterns, TiltedPlane(), SyntheticCaptureOptions{});
  std::size_t lit = 0;
  for (std::size_t i = 0; i < capture.column.size(); ++i) {
    if (capture.column[i] < 0) {
      EXPECT_TRUE(std::isnan(capture.column_exact[i]));
      EXPECT_TRUE(std::isnan(capture.row_exact[i]));
      continue;
    }
    ++lit;
    ASSERT_LE(std::abs(capture.column_exact[i] - capture.column[i]), 0.5f);
    ASSERT_LE(std::abs(capture.row_exact[i] - capture.row[i]), 0.5f);
  }
  EXPECT_GT(lit, capture.column.size() * 9 / 10);
}

// Area sampling mixes the two sides of a stripe edge inside a pixel; point sampling never
// does. Away from edges both agree.
TEST(SyntheticCaptureTest, AreaSamplingMixesPixelsAtStripeEdges) {
  const ScannerRig rig = MakeExampleRig(320, 256);
  const PatternSequence patterns;
  SyntheticCaptureOptions point_options;
  point_options.ambient_level = 20.0;
  SyntheticCaptureOptions area_options = point_options;
  area_options.samples_per_axis = 4;
  const SyntheticCapture point =
      RenderSyntheticCapture(rig, patterns, TiltedPlane(), point_options);
  const SyntheticCapture area = RenderSyntheticCapture(rig, patterns, TiltedPlane(), area_options);
  EXPECT_TRUE(point.column == area.column);  // The ground truth is the pixel centre's.

  // The coarsest column bit has one edge (the middle of the projector), the finest an edge
  // every second column.
  const int coarse = patterns.ColumnImageIndex(0, false);
  const int fine = patterns.ColumnImageIndex(patterns.column_bits() - 1, false);
  const auto count_mixed = [&](const SyntheticCapture& capture, int k) {
    std::size_t mixed = 0;
    for (std::size_t i = 0; i < capture.column.size(); ++i) {
      if (capture.column[i] < 0) continue;
      const int on = capture.images[PatternSequence::kWhiteIndex][i];
      const int off = capture.images[PatternSequence::kBlackIndex][i];
      const int value = capture.images[k][i];
      mixed += value > off + 0.2 * (on - off) && value < on - 0.2 * (on - off);
    }
    return mixed;
  };
  EXPECT_EQ(count_mixed(point, fine), 0u);
  EXPECT_EQ(count_mixed(point, coarse), 0u);
  // 320 camera pixels see ~400 columns: nearly every pixel holds a fine-stripe edge.
  EXPECT_GT(count_mixed(area, fine), area.column.size() / 4);
  EXPECT_LT(count_mixed(area, coarse), area.column.size() / 50);

  // The all-white image is smooth shading: the average over the pixel ~ the centre value.
  for (std::size_t i = 0; i < area.column.size(); ++i) {
    if (area.column[i] < 0) continue;
    ASSERT_LE(std::abs(area.images[PatternSequence::kWhiteIndex][i] -
                       point.images[PatternSequence::kWhiteIndex][i]),
              2)
        << "pixel " << i;
  }
}

TEST(SyntheticCaptureTest, RejectsBadOptions) {
  const ScannerRig rig = MakeExampleRig(32, 24);
  const PatternSequence patterns;
  SyntheticCaptureOptions options;
  options.samples_per_axis = 0;
  EXPECT_THROW(RenderSyntheticCapture(rig, patterns, TiltedPlane(), options),
               std::invalid_argument);
  options.samples_per_axis = 17;
  EXPECT_THROW(RenderSyntheticCapture(rig, patterns, TiltedPlane(), options),
               std::invalid_argument);
  options = SyntheticCaptureOptions{};
  options.gamma = 0.0;
  EXPECT_THROW(RenderSyntheticCapture(rig, patterns, TiltedPlane(), options),
               std::invalid_argument);
  options = SyntheticCaptureOptions{};
  options.noise_sigma = -1.0;
  EXPECT_THROW(RenderSyntheticCapture(rig, patterns, TiltedPlane(), options),
               std::invalid_argument);
}

}  // namespace
}  // namespace picking::scanner
