// Triangulator::Run with normals (one streamed pass) against Run followed by
// EstimateNormals: the same cloud, normals and counts, bit for bit, whatever the image height
// (chunk boundaries), normal step, filter options, thread count and correspondence type.

#include "services/scanner/core/decoder.h"
#include "services/scanner/core/normals.h"
#include "services/scanner/core/synthetic_capture.h"
#include "services/scanner/core/triangulation.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstddef>
#include <stdexcept>
#include <vector>

namespace picking::scanner {
namespace {

// Equal floats, or both NaN.
bool Same(float a, float b) { return a == b || (std::isnan(a) && std::isnan(b)); }

std::size_t Mismatches(const std::vector<Eigen::Vector3f>& a,
                       const std::vector<Eigen::Vector3f>& b) {
  if (a.size() != b.size()) return a.size() + b.size();
  std::size_t count = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    count += !(Same(a[i].x(), b[i].x()) && Same(a[i].y(), b[i].y()) && Same(a[i].z(), b[i].z()));
  }
  return count;
}

struct View {
  ScannerRig rig;
  PatternSequence patterns;
  SyntheticCapture capture;
  CorrespondenceMap integer;
  CorrespondenceMap subpixel;

  View(int width, int height) : rig(MakeExampleRig(width, height)) {
    SyntheticScene scene;
    SyntheticPlane plane;
    plane.normal = Eigen::Vector3d(0.25, -0.1, 1.0).normalized();
    plane.offset_m = plane.normal.dot(Eigen::Vector3d(0, 0, 1.0));
    scene.planes.push_back(plane);
    SyntheticSphere sphere;
    sphere.center_m = Eigen::Vector3d(-0.03, 0.02, 0.85);
    sphere.radius_m = 0.09;
    scene.spheres.push_back(sphere);
    SyntheticCaptureOptions options;
    options.blur_sigma_px = 0.6;
    options.noise_sigma = 2.0;
    options.ambient_level = 25.0;
    options.seed = 5;
    capture = RenderSyntheticCapture(rig, patterns, scene, options);
    const std::vector<ImageView> views = capture.views();
    integer = GrayCodeDecoder(patterns).Decode(views);
    // Misread correspondences, so that the residual and isolated-point filters have work.
    for (std::size_t i = 0; i < integer.valid.size(); i += 211) {
      if (integer.valid[i] && integer.column[i] + 40 < patterns.projector_width()) {
        integer.column[i] = static_cast<std::uint16_t>(integer.column[i] + 40);
      }
    }
    for (std::size_t i = 5; i < integer.valid.size(); i += 307) {
      if (integer.valid[i] && integer.row[i] + 2 < patterns.projector_height()) {
        integer.row[i] = static_cast<std::uint16_t>(integer.row[i] + 2);
      }
    }
    subpixel = integer;
    RefinementOptions refinement;
    refinement.reject_unrefined = false;
    SubpixelRefiner(patterns, refinement).Refine(views, &subpixel);
  }
};

void ExpectSameAsTwoPasses(const View& view, const CorrespondenceMap& map,
                           const TriangulationOptions& options, const NormalOptions& normals) {
  const Triangulator triangulator(view.rig.camera, view.rig.projector, view.rig.X_CameraProjector,
                                  options);
  const ImageView white = view.capture.views()[PatternSequence::kWhiteIndex];
  TriangulationResult expected = triangulator.Run(map, &white);
  const NormalResult expected_normals = EstimateNormals(&expected.cloud, normals);

  TriangulationResult actual;
  NormalResult actual_normals;
  triangulator.Run(map, &white, normals, &actual, &actual_normals);
  EXPECT_EQ(actual.num_points, expected.num_points);
  EXPECT_EQ(actual.num_rejected_residual, expected.num_rejected_residual);
  EXPECT_EQ(actual.num_rejected_depth, expected.num_rejected_depth);
  EXPECT_EQ(actual.num_removed_isolated, expected.num_removed_isolated);
  EXPECT_EQ(actual_normals.num_normals, expected_normals.num_normals);
  EXPECT_EQ(Mismatches(actual.cloud.points, expected.cloud.points), 0u);
  EXPECT_EQ(Mismatches(actual.cloud.normals, expected.cloud.normals), 0u);
  EXPECT_TRUE(actual.cloud.intensities == expected.cloud.intensities);
  EXPECT_EQ(actual.cloud.width, expected.cloud.width);
  EXPECT_EQ(actual.cloud.height, expected.cloud.height);
  EXPECT_EQ(actual.cloud.frame_id, expected.cloud.frame_id);
  EXPECT_GT(expected.num_points, map.valid.size() / 3);
  EXPECT_GT(expected_normals.num_normals, expected.num_points / 2);
  if (options.remove_isolated) EXPECT_GT(expected.num_removed_isolated, 0u);
  EXPECT_GT(expected.num_rejected_residual, 0u);
}

TEST(TriangulationNormalsTest, MatchesTwoPassesWithSubpixelCorrespondences) {
  const View view(320, 203);  // Chunks of 64 rows and a short last one.
  for (const int threads : {1, 2, 3}) {
    for (const int step : {1, 2, 3}) {
      SCOPED_TRACE(testing::Message() << "threads " << threads << ", step " << step);
      TriangulationOptions options;
      options.num_threads = threads;
      NormalOptions normals;
      normals.step = step;
      ExpectSameAsTwoPasses(view, view.subpixel, options, normals);
    }
  }
}

TEST(TriangulationNormalsTest, MatchesTwoPassesWithIntegerCorrespondencesAndOtherFilters) {
  const View view(256, 130);
  TriangulationOptions options;
  options.num_threads = 2;
  NormalOptions normals;
  ExpectSameAsTwoPasses(view, view.integer, options, normals);
  options.remove_isolated = false;
  ExpectSameAsTwoPasses(view, view.integer, options, normals);
  options.remove_isolated = true;
  options.min_neighbors = 6;
  options.neighbor_depth_tolerance_m = 0.002;
  normals.max_depth_jump_m = 0.003;
  ExpectSameAsTwoPasses(view, view.subpixel, options, normals);
}

TEST(TriangulationNormalsTest, RejectsBadNormalOptionsWithoutTouchingTheResult) {
  const View view(64, 48);
  const Triangulator triangulator(view.rig.camera, view.rig.projector, view.rig.X_CameraProjector);
  TriangulationResult result;
  result.num_points = 7;
  NormalOptions bad;
  bad.step = 0;
  EXPECT_THROW(triangulator.Run(view.integer, nullptr, bad, &result), std::invalid_argument);
  bad = NormalOptions{};
  bad.max_depth_jump_m = 0;
  EXPECT_THROW(triangulator.Run(view.integer, nullptr, bad, &result), std::invalid_argument);
  EXPECT_EQ(result.num_points, 7u);
  EXPECT_TRUE(result.cloud.points.empty());
}

}  // namespace
}  // namespace picking::scanner
