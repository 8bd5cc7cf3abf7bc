#include "services/detector/core/box_faces.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <random>
#include <stdexcept>
#include <vector>

namespace picking::detector {
namespace {

constexpr double kDeg = M_PI / 180.0;

// Samples the faces of a box (centre pose X_SceneBox, half sides `half`) that face
// `viewpoint`, on a grid of `step` with seeded noise along the normal, keeping the points
// `keep` accepts (to cut away what another object hides).
template <typename Keep>
void SampleBox(const Eigen::Isometry3d& X_SceneBox, const Eigen::Vector3d& half,
               const Eigen::Vector3d& viewpoint, double step, double noise_m, std::mt19937* rng,
               Keep keep, geometry::PointCloud* cloud) {
  std::normal_distribution<double> noise(0.0, noise_m);
  for (int k = 0; k < 3; ++k) {
    for (double sign : {1.0, -1.0}) {
      const Eigen::Vector3d n = sign * X_SceneBox.linear().col(k);
      const Eigen::Vector3d c = X_SceneBox.translation() + n * half[k];
      if (n.dot(viewpoint - c) <= 0.0) continue;
      const int a = (k + 1) % 3, b = (k + 2) % 3;
      for (double s = -half[a] + 0.5 * step; s < half[a]; s += step) {
        for (double t = -half[b] + 0.5 * step; t < half[b]; t += step) {
          const Eigen::Vector3d p =
              c + X_SceneBox.linear().col(a) * s + X_SceneBox.linear().col(b) * t + n * noise(*rng);
          if (!keep(p)) continue;
          cloud->points.push_back(p.cast<float>());
          cloud->normals.push_back(n.cast<float>());
        }
      }
    }
  }
  cloud->width = static_cast<std::uint32_t>(cloud->points.size());
  cloud->height = 1;
}

// A flat plane of points (the top of something larger), normal +z at height z.
void SamplePlane(double x0, double x1, double y0, double y1, double z, double step,
                 geometry::PointCloud* cloud) {
  for (double x = x0; x < x1; x += step) {
    for (double y = y0; y < y1; y += step) {
      cloud->points.emplace_back(static_cast<float>(x), static_cast<float>(y),
                                 static_cast<float>(z));
      cloud->normals.emplace_back(0.0f, 0.0f, 1.0f);
    }
  }
  cloud->width = static_cast<std::uint32_t>(cloud->points.size());
  cloud->height = 1;
}

// Rotation angle between two box orientations, up to the box's half turns about its axes.
double BoxRotationError(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  double best = std::numeric_limits<double>::infinity();
  for (const Eigen::Vector3d& flip : {Eigen::Vector3d(1, 1, 1), Eigen::Vector3d(1, -1, -1),
                                      Eigen::Vector3d(-1, 1, -1), Eigen::Vector3d(-1, -1, 1)}) {
    const Eigen::Matrix3d turned = b * flip.asDiagonal();
    best = std::min(best, Eigen::AngleAxisd(a.transpose() * turned).angle());
  }
  return best;
}

Eigen::Isometry3d BoxPose() {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::AngleAxisd(35.0 * kDeg, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  X.translation() = Eigen::Vector3d(1.0, -0.2, 0.3);
  return X;
}

TEST(FindPlanarPatchesTest, FindsTheVisibleFacesOfABoxWithTheirSides) {
  const Eigen::Vector3d half(0.10, 0.06, 0.02);
  const Eigen::Isometry3d X = BoxPose();
  const Eigen::Vector3d viewpoint(0.4, -0.2, 0.6);
  std::mt19937 rng(5);
  geometry::PointCloud cloud;
  SampleBox(
      X, half, viewpoint, 0.003, 0.0005, &rng, [](const Eigen::Vector3d&) { return true; }, &cloud);
  const KdTree tree(cloud.points);
  const std::vector<PlanarPatch> patches = FindPlanarPatches(cloud, tree);
  ASSERT_GE(patches.size(), 2u);
  // The largest is the top (+z): 0.2 x 0.12, with its sides along the box's x and y.
  const PlanarPatch& top = patches.front();
  EXPECT_GT(top.normal.z(), std::cos(2.0 * kDeg));
  EXPECT_NEAR(std::max(top.half_u, top.half_v), half.x(), 0.003);
  EXPECT_NEAR(std::min(top.half_u, top.half_v), half.y(), 0.003);
  EXPECT_LT((top.centre - (X.translation() + Eigen::Vector3d(0, 0, half.z()))).norm(), 0.003);
  EXPECT_LT(top.rms_m, 0.001);
  EXPECT_NEAR(top.axis_u.cross(top.axis_v).dot(top.normal), 1.0, 1e-9);
  // The patches are largest first and hold every point at most once.
  std::size_t total = 0;
  for (std::size_t i = 0; i < patches.size(); ++i) {
    total += patches[i].points;
    if (i > 0) {
      EXPECT_LE(patches[i].points, patches[i - 1].points);
    }
  }
  EXPECT_LE(total, cloud.size());
}

TEST(BoxPosesOnPatchTest, AHalfHiddenTopGivesThePoseFromItsVisibleCorner) {
  const Eigen::Vector3d half(0.10, 0.06, 0.02);
  const Eigen::Isometry3d X = BoxPose();
  const Eigen::Vector3d viewpoint(0.4, -0.2, 0.6);
  std::mt19937 rng(6);
  geometry::PointCloud cloud;
  // Something in front hides the box's far half along its long side (box x > 0.01).
  const Eigen::Isometry3d X_BoxScene = X.inverse();
  SampleBox(
      X, half, viewpoint, 0.003, 0.0005, &rng,
      [&](const Eigen::Vector3d& p) { return (X_BoxScene * p).x() < 0.01; }, &cloud);
  const KdTree tree(cloud.points);
  const std::vector<PlanarPatch> patches = FindPlanarPatches(cloud, tree);
  ASSERT_FALSE(patches.empty());
  const PlanarPatch& top = patches.front();
  ASSERT_GT(top.normal.z(), 0.99);
  EXPECT_LT(std::max(top.half_u, top.half_v), 0.07);  // only about 0.11 of 0.2 is seen
  const std::vector<Eigen::Isometry3d> poses = BoxPosesOnPatch(top, half);
  ASSERT_FALSE(poses.empty());
  double best_translation = std::numeric_limits<double>::infinity();
  double best_rotation = 0.0;
  for (const Eigen::Isometry3d& P : poses) {
    EXPECT_TRUE(P.linear().isUnitary(1e-9));
    EXPECT_NEAR(P.linear().determinant(), 1.0, 1e-9);
    const double t = (P.translation() - X.translation()).norm();
    if (t < best_translation) {
      best_translation = t;
      best_rotation = BoxRotationError(P.linear(), X.linear());
    }
  }
  EXPECT_LT(best_translation, 0.004);
  EXPECT_LT(best_rotation, 2.0 * kDeg);
}

TEST(BoxPosesOnPatchTest, APatchLargerThanEveryFaceGivesNoPose) {
  PlanarPatch patch;
  patch.half_u = 0.2;
  patch.half_v = 0.15;
  EXPECT_TRUE(BoxPosesOnPatch(patch, Eigen::Vector3d(0.1, 0.06, 0.02)).empty());
  // A patch that fits only the largest face, one way round: centred and flush placements.
  patch.half_u = 0.1;
  patch.half_v = 0.03;
  const std::vector<Eigen::Isometry3d> poses =
      BoxPosesOnPatch(patch, Eigen::Vector3d(0.1, 0.06, 0.02));
  ASSERT_EQ(poses.size(), 3u);
  for (const Eigen::Isometry3d& P : poses) {
    EXPECT_NEAR(P.translation().z(), -0.02, 1e-12);  // behind the patch by the half height
    EXPECT_NEAR(std::abs(P.linear().col(0).dot(patch.axis_u)), 1.0, 1e-12);
  }
}

TEST(BoxFacesTest, BadInputThrows) {
  geometry::PointCloud cloud;
  SamplePlane(0.0, 0.1, 0.0, 0.1, 0.0, 0.01, &cloud);
  const KdTree tree(cloud.points);
  BoxFaceOptions bad;
  bad.normal_tolerance_rad = 2.0;
  EXPECT_THROW(FindPlanarPatches(cloud, tree, bad), std::invalid_argument);
  geometry::PointCloud no_normals = cloud;
  no_normals.normals.clear();
  EXPECT_THROW(FindPlanarPatches(no_normals, tree), std::invalid_argument);
  EXPECT_THROW(FindPlanarPatches(cloud, KdTree()), std::invalid_argument);
  EXPECT_THROW(BoxPosesOnPatch(PlanarPatch{}, Eigen::Vector3d(0.1, 0.0, 0.1)),
               std::invalid_argument);
  ContinuationOptions bad_probe;
  bad_probe.offset_m = 0.0;
  EXPECT_THROW(
      BoxSurfaceContinuation(cloud, tree, Eigen::Isometry3d::Identity(),
                             Eigen::Vector3d(0.1, 0.1, 0.1), Eigen::Vector3d(0, 0, 1), bad_probe),
      std::invalid_argument);
}

// A thin box laid along the edge strip of a larger flat surface is supported wherever it is
// visible, but the surface runs on past its edge; the real thin box, with nothing coplanar
// around it, ends at its edges.
TEST(BoxSurfaceContinuationTest, TellsAStripOfALargerSurfaceFromABox) {
  const Eigen::Vector3d viewpoint(0.0, 0.0, 0.6);
  geometry::PointCloud scene;
  SamplePlane(-0.2, 0.2, -0.2, 0.2, 0.1, 0.002, &scene);
  const KdTree tree(scene.points);
  const Eigen::Vector3d half(0.1, 0.0125, 0.008);
  // Inside the large surface, top flush with it.
  Eigen::Isometry3d strip = Eigen::Isometry3d::Identity();
  strip.translation() = Eigen::Vector3d(0.0, 0.0, 0.1 - half.z());
  EXPECT_GT(BoxSurfaceContinuation(scene, tree, strip, half, viewpoint), 0.5);

  // The box on its own: its top at 0.15 with the surface 5 cm below.
  geometry::PointCloud with_box = scene;
  std::mt19937 rng(8);
  Eigen::Isometry3d on_top = Eigen::Isometry3d::Identity();
  on_top.translation() = Eigen::Vector3d(0.0, 0.0, 0.15 - half.z());
  SampleBox(
      on_top, half, viewpoint, 0.002, 0.0, &rng, [](const Eigen::Vector3d&) { return true; },
      &with_box);
  const KdTree with_box_tree(with_box.points);
  EXPECT_LT(BoxSurfaceContinuation(with_box, with_box_tree, on_top, half, viewpoint), 0.05);
}

// A folded T-shirt's 0.224 x 0.218 m top is nearly square: its quarter-turn about the top's
// normal is offered, and lands the box on itself but for the sides' difference.
TEST(NearSquareQuarterTurnsTest, TurnsAboutTheNormalsOfNearlySquareFacesOnly) {
  const Eigen::Vector3d half(0.112, 0.109, 0.025);
  const Eigen::Vector3d centre(0.01, -0.02, 0.025);
  const auto turns = NearSquareQuarterTurns(half, centre, 0.1);
  ASSERT_EQ(turns.size(), 1u);
  const Eigen::Isometry3d& T = turns.front();
  EXPECT_NEAR((T * centre - centre).norm(), 0.0, 1e-12);  // about the box's centre
  EXPECT_NEAR(std::abs(T.linear().col(2).dot(Eigen::Vector3d::UnitZ())), 1.0, 1e-12);
  EXPECT_NEAR(Eigen::AngleAxisd(T.linear()).angle(), 0.5 * M_PI, 1e-9);
  // Every corner lands within the sides' difference of a corner.
  for (int k = 0; k < 8; ++k) {
    const Eigen::Vector3d corner =
        centre + Eigen::Vector3d((k & 1) ? half.x() : -half.x(), (k & 2) ? half.y() : -half.y(),
                                 (k & 4) ? half.z() : -half.z());
    const Eigen::Vector3d d = ((T * corner - centre).cwiseAbs() - half).cwiseAbs();
    EXPECT_LE(d.maxCoeff(), half.x() - half.y() + 1e-12);
  }
  EXPECT_TRUE(NearSquareQuarterTurns(half, centre, 0.01).empty());  // 2.7 % apart
  EXPECT_EQ(NearSquareQuarterTurns(Eigen::Vector3d::Constant(0.05), centre, 0.0).size(), 3u);
  EXPECT_TRUE(NearSquareQuarterTurns(Eigen::Vector3d(0.1, 0.03, 0.01), centre, 0.1).empty());
  EXPECT_THROW(NearSquareQuarterTurns(Eigen::Vector3d(0.1, 0.0, 0.01), centre, 0.1),
               std::invalid_argument);
  EXPECT_THROW(NearSquareQuarterTurns(half, centre, -0.1), std::invalid_argument);
}

// The pattern search climbs a score peaked off the start along the pose's own axes, to
// within its last step, and never along an axis it was not given.
TEST(PolishTranslationTest, ClimbsToThePeakAlongTheGivenAxesOnly) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  X.translation() = Eigen::Vector3d(1.0, -0.3, 0.8);
  // Peak 13 mm along the pose's x and -9 mm along its y, from the start.
  const Eigen::Vector3d peak =
      X.translation() + X.linear().col(0) * 0.013 - X.linear().col(1) * 0.009;
  const auto score = [&](const Eigen::Isometry3d& P) {
    return 1.0 - 100.0 * (P.translation() - peak).squaredNorm();
  };
  const auto score_of = [&](const Eigen::Isometry3d& P) -> std::optional<double> {
    return score(P);
  };
  const PosePolish polished = PolishTranslation(X, score(X), {0, 1}, 0.008, 4, score_of);
  EXPECT_LE((polished.X.translation() - peak).norm(), 0.0011);  // last step 1 mm
  EXPECT_TRUE(polished.X.linear().isApprox(X.linear()));
  EXPECT_NEAR(polished.score, score(polished.X), 1e-12);
  EXPECT_GT(polished.evaluations, 8);
  // Along z only: the peak's offset is across it, so the pose stays.
  const PosePolish across = PolishTranslation(X, score(X), {2}, 0.008, 4, score_of);
  EXPECT_TRUE(across.X.isApprox(X));
  EXPECT_EQ(across.score, score(X));
  // Out of time after three evaluations: the best of those.
  int calls = 0;
  const PosePolish hurried = PolishTranslation(
      X, score(X), {0, 1}, 0.008, 4, [&](const Eigen::Isometry3d& P) -> std::optional<double> {
        if (++calls > 3) return std::nullopt;
        return score(P);
      });
  EXPECT_EQ(hurried.evaluations, 3);
  EXPECT_GT(hurried.score, score(X));  // the move along +x, the first two evaluations' best
  EXPECT_NEAR(hurried.score, score(hurried.X), 1e-12);
  // A score rising without end along x: the walk stops after kMaxPolishMoves moves.
  const PosePolish walk = PolishTranslation(
      X, 0.0, {0}, 0.01, 1, [&](const Eigen::Isometry3d& P) -> std::optional<double> {
        return X.linear().col(0).dot(P.translation() - X.translation());
      });
  EXPECT_NEAR((walk.X.translation() - X.translation()).norm(), 0.01 * kMaxPolishMoves, 1e-9);
  EXPECT_THROW(PolishTranslation(X, 0.0, {0}, 0.0, 1, score_of), std::invalid_argument);
  EXPECT_THROW(PolishTranslation(X, 0.0, {3}, 0.01, 1, score_of), std::invalid_argument);
  EXPECT_THROW(PolishTranslation(X, 0.0, {0}, 0.01, -1, score_of), std::invalid_argument);
}

}  // namespace
}  // namespace picking::detector
