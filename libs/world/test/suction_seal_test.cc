#include "libs/world/suction_seal.h"

#include <gtest/gtest.h>

#include <cmath>

#include "libs/world/mesh_utils.h"

namespace picking::world {
namespace {

// A cup above `X_BaseObject`'s origin looking down (-z in base), its lip `gap_m` above z = top.
Eigen::Isometry3d CupAbove(double top_z_m, double gap_m, double tilt_rad = 0.0) {
  Eigen::Isometry3d X_BaseTcp = Eigen::Isometry3d::Identity();
  X_BaseTcp.linear() = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix() *
                       Eigen::AngleAxisd(tilt_rad, Eigen::Vector3d::UnitY()).toRotationMatrix();
  X_BaseTcp.translation() = Eigen::Vector3d(0.0, 0.0, top_z_m + gap_m);
  return X_BaseTcp;
}

SealMeasure SealOn(const TriangleMesh& mesh, const Eigen::Isometry3d& X_BaseTcp) {
  RayScene scene;
  scene.Add(1, mesh, Eigen::Isometry3d::Identity());
  scene.Commit();
  return MeasureSeal(scene, X_BaseTcp, SealOptions{});
}

TEST(MeasureSealTest, AFlatFaceUnderTheWholeLipSeals) {
  const SealMeasure m = SealOn(MakeBox({0.10, 0.10, 0.05}), CupAbove(0.025, 0.002));
  EXPECT_TRUE(m.sealed) << m.reason;
  EXPECT_EQ(m.object_id, 1);
  EXPECT_NEAR(m.flatness_m, 0.0, 1e-6);
  EXPECT_NEAR(m.angle_rad, 0.0, 1e-6);
}

TEST(MeasureSealTest, ALipTooFarAboveTheFaceDoesNotTouchIt) {
  const SealMeasure m = SealOn(MakeBox({0.10, 0.10, 0.05}), CupAbove(0.025, 0.006));
  EXPECT_FALSE(m.sealed);
  EXPECT_EQ(m.reason, "the lip does not touch the surface");
}

// The lip (1.5 cm radius) on a baseball (3.7 cm): the rim stands 3.2 mm off the plane of
// its hits, more than the 2 mm a lip conforms to.
TEST(MeasureSealTest, ABallsCurveIsNotFlatEnough) {
  // Turned so that no pole of the mesh lies under the cup's centre ray.
  const TriangleMesh ball =
      Transformed(MakeSphere(0.037, 48, 96),
                  Eigen::Isometry3d(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitX())));
  const SealMeasure m = SealOn(ball, CupAbove(0.037, -0.002));
  EXPECT_FALSE(m.sealed);
  EXPECT_EQ(m.reason, "surface under the lip is not flat enough");
  EXPECT_GT(m.flatness_m, 0.002);
}

TEST(MeasureSealTest, AFaceNarrowerThanTheLipLeavesALipPointOverNothing) {
  const SealMeasure m = SealOn(MakeBox({0.10, 0.02, 0.05}), CupAbove(0.025, 0.002));
  EXPECT_FALSE(m.sealed);
  EXPECT_EQ(m.reason, "a lip point meets no surface");
}

TEST(MeasureSealTest, AFaceTiltedPastTheToleranceIsRefused) {
  // The lip pressed 2 mm into the face at its centre: its high side stands 2.4 mm off it.
  const SealMeasure straight = SealOn(MakeBox({0.10, 0.10, 0.05}), CupAbove(0.025, -0.002, 0.3));
  EXPECT_TRUE(straight.sealed) << straight.reason;
  EXPECT_NEAR(straight.angle_rad, 0.3, 1e-6);
  const SealMeasure tilted = SealOn(MakeBox({0.10, 0.10, 0.05}), CupAbove(0.025, -0.002, 0.45));
  EXPECT_FALSE(tilted.sealed);
  EXPECT_EQ(tilted.reason, "surface is tilted too far from the cup axis");
}

TEST(MeasureSealTest, ALipAcrossTwoObjectsDoesNotSeal) {
  RayScene scene;
  Eigen::Isometry3d X_left = Eigen::Isometry3d::Identity(), X_right = X_left;
  X_left.translation().x() = -0.025;
  X_right.translation().x() = 0.025;
  scene.Add(1, MakeBox({0.05, 0.10, 0.05}), X_left);
  scene.Add(2, MakeBox({0.05, 0.10, 0.05}), X_right);
  scene.Commit();
  const SealMeasure m = MeasureSeal(scene, CupAbove(0.025, 0.002), SealOptions{});
  EXPECT_FALSE(m.sealed);
  EXPECT_EQ(m.reason, "the lip spans more than one object");
}

TEST(MeasureSealTest, BadOptionsAreRefused) {
  RayScene scene;
  scene.Add(1, MakeBox({0.1, 0.1, 0.1}), Eigen::Isometry3d::Identity());
  scene.Commit();
  SealOptions options;
  options.rim_samples = 2;
  EXPECT_THROW(MeasureSeal(scene, CupAbove(0.05, 0.0), options), std::invalid_argument);
  options = SealOptions{};
  options.cup_radius_m = 0.0;
  EXPECT_THROW(MeasureSeal(scene, CupAbove(0.05, 0.0), options), std::invalid_argument);
  EXPECT_THROW(ValidateSealOptions(options), std::invalid_argument);
  EXPECT_NO_THROW(ValidateSealOptions(SealOptions{}));
}

}  // namespace
}  // namespace picking::world
