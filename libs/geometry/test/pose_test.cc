#include "libs/geometry/pose.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

namespace picking::geometry {
namespace {

constexpr double kPi = 3.14159265358979323846;

Eigen::Isometry3d RandomPose(std::mt19937* rng) {
  std::normal_distribution<double> normal(0.0, 1.0);
  Eigen::Quaterniond q(normal(*rng), normal(*rng), normal(*rng), normal(*rng));
  q.normalize();
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = q.toRotationMatrix();
  X.translation() = Eigen::Vector3d(normal(*rng), normal(*rng), normal(*rng));
  return X;
}

std::string ErrorOf(const Eigen::Isometry3d& X, const char* field) {
  try {
    ValidatePose(X, field);
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

TEST(PoseTest, ValidPosesPass) {
  std::mt19937 rng(7);
  EXPECT_NO_THROW(ValidatePose(Eigen::Isometry3d::Identity(), "X_WorldTool"));
  for (int i = 0; i < 100; ++i) {
    const Eigen::Isometry3d X = RandomPose(&rng);
    EXPECT_TRUE(IsValidPose(X));
    EXPECT_NO_THROW(ValidatePose(X, "X"));
    EXPECT_NO_THROW(ValidatePose(X.inverse(), "X_inverse"));
  }
}

TEST(PoseTest, NanAndInfAreRejectedNamingTheField) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation().y() = std::numeric_limits<double>::quiet_NaN();
  std::string message = ErrorOf(X, "X_BaseCamera");
  EXPECT_NE(message.find("X_BaseCamera"), std::string::npos) << message;
  EXPECT_NE(message.find("entry (1, 3)"), std::string::npos) << message;
  X = Eigen::Isometry3d::Identity();
  X.linear()(2, 2) = std::numeric_limits<double>::infinity();
  message = ErrorOf(X, "X_ShelfBin");
  EXPECT_NE(message.find("X_ShelfBin"), std::string::npos);
  EXPECT_FALSE(IsValidPose(X));
}

TEST(PoseTest, NonOrthonormalAndReflectionsAreRejected) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear()(0, 0) = 1.001;  // Scaled.
  std::string message = ErrorOf(X, "X_AB");
  EXPECT_NE(message.find("X_AB: invalid pose: rotation is not orthonormal"), std::string::npos)
      << message;
  X = Eigen::Isometry3d::Identity();
  X.linear()(0, 1) = 0.01;  // Sheared.
  EXPECT_FALSE(IsValidPose(X));
  X = Eigen::Isometry3d::Identity();
  X.linear()(2, 2) = -1.0;  // Mirror.
  message = ErrorOf(X, "X_AB");
  EXPECT_NE(message.find("determinant"), std::string::npos) << message;
  X = Eigen::Isometry3d::Identity();
  X.matrix()(3, 0) = 0.5;
  EXPECT_NE(ErrorOf(X, "X_AB").find("last row"), std::string::npos);
  // Within tolerance passes; a looser tolerance can be asked for.
  X = Eigen::Isometry3d::Identity();
  X.linear()(0, 0) = 1.0 + 1e-8;
  EXPECT_TRUE(IsValidPose(X));
  X.linear()(0, 0) = 1.0 + 1e-4;
  EXPECT_FALSE(IsValidPose(X));
  EXPECT_TRUE(IsValidPose(X, 1e-3));
}

TEST(PoseTest, TranslationQuaternionRoundTrip) {
  std::mt19937 rng(11);
  for (int i = 0; i < 200; ++i) {
    const Eigen::Isometry3d X = RandomPose(&rng);
    const TranslationQuaternion tq = ToTranslationQuaternion(X);
    EXPECT_GE(tq.q_AB.w(), 0.0);
    EXPECT_NEAR(tq.q_AB.norm(), 1.0, 1e-12);
    const Eigen::Isometry3d Y = FromTranslationQuaternion(tq.p_AB, tq.q_AB);
    EXPECT_TRUE(X.isApprox(Y, 1e-12));
    // The negated quaternion is the same rotation and gives the same canonical form.
    const Eigen::Quaterniond negated(-tq.q_AB.w(), -tq.q_AB.x(), -tq.q_AB.y(), -tq.q_AB.z());
    const TranslationQuaternion again =
        ToTranslationQuaternion(FromTranslationQuaternion(tq.p_AB, negated));
    EXPECT_TRUE(again.q_AB.coeffs().isApprox(tq.q_AB.coeffs(), 1e-12));
  }
}

TEST(PoseTest, KnownRotationFromQuaternion) {
  // 90 degrees about z: x axis goes to y.
  const Eigen::Quaterniond q(std::cos(kPi / 4), 0, 0, std::sin(kPi / 4));
  const Eigen::Isometry3d X = FromTranslationQuaternion(Eigen::Vector3d(1, 2, 3), q, "X_WB");
  EXPECT_TRUE((X * Eigen::Vector3d(1, 0, 0)).isApprox(Eigen::Vector3d(1, 3, 3), 1e-12));
}

TEST(PoseTest, QuaternionNormMustBeNearOne) {
  const Eigen::Vector3d p(0, 0, 0);
  // Within 1e-3: accepted and normalised.
  const Eigen::Isometry3d X =
      FromTranslationQuaternion(p, Eigen::Quaterniond(1.0009, 0, 0, 0), "grasp.X_ObjectTool");
  EXPECT_TRUE(IsValidPose(X, 1e-12));
  try {
    FromTranslationQuaternion(p, Eigen::Quaterniond(1.002, 0, 0, 0), "grasp.X_ObjectTool");
    FAIL();
  } catch (const std::invalid_argument& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find("grasp.X_ObjectTool"), std::string::npos) << message;
    EXPECT_NE(message.find("grasp.X_ObjectTool.orientation must be a unit quaternion"),
              std::string::npos)
        << message;
  }
  EXPECT_THROW(FromTranslationQuaternion(p, Eigen::Quaterniond(0, 0, 0, 0), "q"),
               std::invalid_argument);
  EXPECT_THROW(FromTranslationQuaternion(p, Eigen::Quaterniond(NAN, 0, 0, 0), "q"),
               std::invalid_argument);
  EXPECT_THROW(FromTranslationQuaternion(Eigen::Vector3d(INFINITY, 0, 0),
                                         Eigen::Quaterniond::Identity(), "p"),
               std::invalid_argument);
}

TEST(PoseTest, DistancesOfKnownPoses) {
  Eigen::Isometry3d A = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d B = Eigen::Isometry3d::Identity();
  B.translation() = Eigen::Vector3d(0.3, 0.4, 0.0);
  B.linear() = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  EXPECT_NEAR(TranslationDistance(A, B), 0.5, 1e-15);
  EXPECT_NEAR(RotationAngle(A, B), 0.7, 1e-12);
  EXPECT_NEAR(RotationAngle(B, A), 0.7, 1e-12);
  const PoseError error = ComputePoseError(B, A);
  EXPECT_NEAR(error.translation_m, 0.5, 1e-15);
  EXPECT_NEAR(error.rotation_rad, 0.7, 1e-12);
  // Near 0 and near pi the angle stays accurate.
  B.linear() = Eigen::AngleAxisd(1e-7, Eigen::Vector3d::UnitX()).toRotationMatrix();
  EXPECT_NEAR(RotationAngle(A, B), 1e-7, 1e-15);
  B.linear() = Eigen::AngleAxisd(kPi - 1e-7, Eigen::Vector3d::UnitY()).toRotationMatrix();
  EXPECT_NEAR(RotationAngle(A, B), kPi - 1e-7, 1e-9);
  B.linear() = Eigen::AngleAxisd(kPi, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  EXPECT_NEAR(RotationAngle(A, B), kPi, 1e-12);
}

TEST(PoseTest, RotationAngleIsLeftInvariant) {
  std::mt19937 rng(3);
  for (int i = 0; i < 50; ++i) {
    const Eigen::Isometry3d A = RandomPose(&rng);
    const Eigen::Isometry3d B = RandomPose(&rng);
    const Eigen::Isometry3d C = RandomPose(&rng);
    EXPECT_NEAR(RotationAngle(A, B), RotationAngle(C * A, C * B), 1e-9);
    EXPECT_NEAR(RotationAngle(A, A), 0.0, 1e-7);
  }
}

TEST(PoseTest, InterpolationEndsMidpointAndConstantSpeed) {
  std::mt19937 rng(5);
  for (int i = 0; i < 50; ++i) {
    const Eigen::Isometry3d A = RandomPose(&rng);
    const Eigen::Isometry3d B = RandomPose(&rng);
    EXPECT_TRUE(Interpolate(A, B, 0.0).isApprox(A, 1e-9));
    EXPECT_TRUE(Interpolate(A, B, 1.0).isApprox(B, 1e-9));
    const double total = RotationAngle(A, B);
    for (double t : {0.1, 0.25, 0.5, 0.9}) {
      const Eigen::Isometry3d M = Interpolate(A, B, t);
      EXPECT_TRUE(IsValidPose(M, 1e-9));
      EXPECT_NEAR(RotationAngle(A, M), t * total, 1e-7);
      EXPECT_NEAR(RotationAngle(M, B), (1 - t) * total, 1e-7);
      EXPECT_TRUE(M.translation().isApprox(
          A.translation() + t * (B.translation() - A.translation()), 1e-12));
    }
  }
  EXPECT_THROW(Interpolate(Eigen::Isometry3d::Identity(), Eigen::Isometry3d::Identity(), NAN),
               std::invalid_argument);
}

TEST(PoseTest, InterpolationTakesTheShorterArc) {
  Eigen::Isometry3d A = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d B = Eigen::Isometry3d::Identity();
  B.linear() = Eigen::AngleAxisd(1.5 * kPi, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  // 270 degrees one way is 90 the other: the midpoint is -45 degrees.
  const Eigen::Isometry3d M = Interpolate(A, B, 0.5);
  EXPECT_NEAR(RotationAngle(A, M), kPi / 4, 1e-12);
  EXPECT_TRUE((M * Eigen::Vector3d::UnitX())
                  .isApprox(Eigen::Vector3d(std::cos(-kPi / 4), std::sin(-kPi / 4), 0), 1e-12));
}

}  // namespace
}  // namespace picking::geometry
