#include "services/scanner/core/calibration_shelf.h"

#include <gtest/gtest.h>

#include <random>

namespace picking::scanner {
namespace {

using Eigen::Isometry3d;
using Eigen::Vector3d;

// Shelf frame: x to the shelf's right, y toward its back, z up; the top face at 1.9 m.
ShelfTopModel KivaTop() {
  return {Vector3d(0.0, 0.0, 1.9), Vector3d(0.87, 0.0, 1.9), Vector3d(0.87, 0.87, 1.9),
          Vector3d(0.0, 0.87, 1.9)};
}

Isometry3d TrueBaseShelf() {
  Isometry3d X = Isometry3d::Identity();
  // The shelf's front (-y) faces the robot (-x of the base), turned a little and tilted.
  X.linear() = (Eigen::AngleAxisd(-M_PI / 2 + 0.05, Vector3d::UnitZ()) *
                Eigen::AngleAxisd(0.01, Vector3d::UnitX()))
                   .toRotationMatrix();
  X.translation() = Vector3d(1.05, 0.42, 0.02);
  return X;
}

// The top region as a scanner above and in front of the shelf sees it: the front part of
// the top face, the front face of the top cap, part of the left side, noise and outliers.
geometry::PointCloud ScanShelfTop(const Isometry3d& X_BaseShelf, bool with_front,
                                  std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 0.001);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  geometry::PointCloud cloud;
  cloud.frame_id = "base";
  const auto add = [&](const Vector3d& p_Shelf) {
    const Vector3d p = X_BaseShelf * p_Shelf + Vector3d(noise(rng), noise(rng), noise(rng));
    cloud.points.push_back(p.cast<float>());
  };
  const double step = 0.005;
  for (double x = 0.0; x <= 0.87; x += step) {
    for (double y = 0.0; y <= 0.35; y += step) add(Vector3d(x, y, 1.9));  // top
    if (with_front) {
      for (double z = 1.78; z <= 1.9; z += step) add(Vector3d(x, 0.0, z));  // front
    }
  }
  for (double y = 0.0; y <= 0.2; y += step) {
    for (double z = 1.78; z <= 1.9; z += step) add(Vector3d(0.0, y, z));  // left side
  }
  const std::size_t outliers = cloud.points.size() / 50;
  for (std::size_t i = 0; i < outliers; ++i) {
    add(Vector3d(-0.2 + 1.3 * unit(rng), -0.3 + 0.8 * unit(rng), 1.6 + 0.5 * unit(rng)));
  }
  cloud.width = static_cast<std::uint32_t>(cloud.points.size());
  cloud.height = 1;
  return cloud;
}

TEST(ShelfPoseTest, RecoversPoseOfNoisyBoxTop) {
  const Isometry3d truth = TrueBaseShelf();
  const ShelfTopModel model = KivaTop();
  const ShelfPoseResult result = EstimateShelfPose(ScanShelfTop(truth, true, 11), model);
  const double translation_error = (result.X_BaseShelf.translation() - truth.translation()).norm();
  const double rotation_error =
      Eigen::AngleAxisd(result.X_BaseShelf.linear().transpose() * truth.linear()).angle();
  EXPECT_LT(translation_error, 0.004);
  EXPECT_LT(rotation_error, 0.3 * M_PI / 180.0);
  EXPECT_LT((result.p_BaseFrontLeft - truth * model.p_ShelfFrontLeft).norm(), 0.01);
  EXPECT_LT((result.p_BaseFrontRight - truth * model.p_ShelfFrontRight).norm(), 0.01);
  EXPECT_LT(std::abs(result.edge_length_error_m), 0.01);
  EXPECT_GT(result.top_inliers, 1000);
  EXPECT_GT(result.front_inliers, 1000);
  EXPECT_GT(result.top_normal_Base.dot(truth.linear().col(2)), 0.9999);
  EXPECT_GT(result.front_normal_Base.dot(-truth.linear().col(1)), 0.9999);
}

TEST(ShelfPoseTest, MissingFrontFaceIsAnError) {
  try {
    EstimateShelfPose(ScanShelfTop(TrueBaseShelf(), false, 12), KivaTop());
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("front face"), std::string::npos) << e.what();
  }
}

TEST(ShelfPoseTest, ModelOfAnotherSizeIsAnError) {
  ShelfTopModel wide = KivaTop();
  wide.p_ShelfFrontRight.x() = 1.2;
  wide.p_ShelfBackRight.x() = 1.2;
  EXPECT_THROW(EstimateShelfPose(ScanShelfTop(TrueBaseShelf(), true, 13), wide),
               std::invalid_argument);
  ShelfTopModel skewed = KivaTop();
  skewed.p_ShelfBackRight.x() = 0.95;
  EXPECT_THROW(EstimateShelfPose(ScanShelfTop(TrueBaseShelf(), true, 13), skewed),
               std::invalid_argument);
}

TEST(ShelfPoseTest, CloudInAnotherFrameIsAnError) {
  geometry::PointCloud cloud = ScanShelfTop(TrueBaseShelf(), true, 14);
  cloud.frame_id = "camera";
  EXPECT_THROW(EstimateShelfPose(cloud, KivaTop()), std::invalid_argument);
}

TEST(FitRigidTransformTest, RecoversExactTransform) {
  Isometry3d X = Isometry3d::Identity();
  X.linear() = Eigen::AngleAxisd(1.1, Vector3d(0.3, -1, 2).normalized()).toRotationMatrix();
  X.translation() = Vector3d(0.5, -0.2, 1.0);
  std::vector<Vector3d> p_B = {Vector3d(0, 0, 0), Vector3d(1, 0, 0), Vector3d(0, 1, 0),
                               Vector3d(0, 0, 1), Vector3d(0.3, 0.7, -0.2)};
  std::vector<Vector3d> p_A;
  for (const auto& p : p_B) p_A.push_back(X * p);
  EXPECT_TRUE(FitRigidTransform(p_A, p_B).isApprox(X, 1e-9));
  p_A.pop_back();
  EXPECT_THROW(FitRigidTransform(p_A, p_B), std::invalid_argument);
}

}  // namespace
}  // namespace picking::scanner
