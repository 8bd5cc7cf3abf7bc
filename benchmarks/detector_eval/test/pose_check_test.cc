#include "benchmarks/detector_eval/pose_check.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace picking::detector_eval {
namespace {

// Points on the surface of a 0.2 x 0.1 x 0.05 m box (item frame at its centre).
geometry::PointCloud BoxModel() {
  geometry::PointCloud model;
  std::mt19937 rng(4);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  const Eigen::Vector3f half(0.1f, 0.05f, 0.025f);
  for (int i = 0; i < 3000; ++i) {
    Eigen::Vector3f p(u(rng), u(rng), u(rng));
    const int axis = i % 3;
    p[axis] = p[axis] > 0.0f ? 1.0f : -1.0f;
    model.points.push_back(p.cwiseProduct(half));
  }
  model.width = static_cast<std::uint32_t>(model.size());
  return model;
}

Eigen::Isometry3d Pose(double angle, const Eigen::Vector3d& axis, const Eigen::Vector3d& t) {
  return Eigen::Translation3d(t) * Eigen::AngleAxisd(angle, axis.normalized());
}

TEST(PoseCheckTest, ABoxTurnedHalfWayIsTheSamePoseButNotForAnAsymmetricModel) {
  const geometry::PointCloud model = BoxModel();
  const Eigen::Isometry3d X_true = Pose(0.4, {0.2, 0.3, 1.0}, {1.0, 0.2, 0.8});
  const Eigen::Isometry3d X_flipped = X_true * Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitZ());
  const PoseErrorResult box = PoseError(model, "box", X_flipped, X_true);
  EXPECT_LT(box.add_m, 1e-9);
  EXPECT_LT(box.rotation_rad, 1e-6);
  const PoseErrorResult none = PoseError(model, "none", X_flipped, X_true);
  EXPECT_GT(none.add_m, 0.03);
  EXPECT_NEAR(none.rotation_rad, M_PI, 1e-6);
  // A quarter turn is not a symmetry of a box with three different sides.
  const Eigen::Isometry3d X_quarter =
      X_true * Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ());
  EXPECT_GT(PoseError(model, "box", X_quarter, X_true).add_m, 0.02);
}

TEST(PoseCheckTest, CylinderSymmetryIgnoresTurnsAboutItsAxisAndEndOverEnd) {
  const geometry::PointCloud model = BoxModel();  // Only the rotations matter here.
  const Eigen::Isometry3d X_true = Pose(1.1, {1.0, -0.5, 0.2}, {0.3, -0.4, 1.2});
  for (double angle : {0.6, 1.5, 2.2}) {
    const Eigen::Isometry3d X_turned = X_true * Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitX()) *
                                       Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitY());
    // Within the 5 degree sampling of the turns about the axis.
    EXPECT_LT(PoseError(model, "cylinder-x", X_turned, X_true).rotation_rad, 0.05) << angle;
    EXPECT_GT(PoseError(model, "cylinder-z", X_turned, X_true).rotation_rad, 0.3) << angle;
  }
}

TEST(PoseCheckTest, SphereAndTranslationErrors) {
  const geometry::PointCloud model = BoxModel();
  const Eigen::Isometry3d X_true = Pose(0.0, {0, 0, 1}, {0.0, 0.0, 0.0});
  const Eigen::Isometry3d X_moved = Pose(2.0, {1, 1, 0}, {0.003, 0.004, 0.0});
  const PoseErrorResult sphere = PoseError(model, "sphere", X_moved, X_true);
  EXPECT_NEAR(sphere.add_m, 0.005, 1e-12);
  EXPECT_NEAR(sphere.translation_m, 0.005, 1e-12);
  EXPECT_THROW(PoseError(geometry::PointCloud(), "box", X_true, X_true), std::invalid_argument);
}

}  // namespace
}  // namespace picking::detector_eval
