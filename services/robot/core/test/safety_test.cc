#include "services/robot/core/safety.h"

#include <gtest/gtest.h>

#include <cmath>

namespace picking::robot {
namespace {

class SafetyTest : public ::testing::Test {
 protected:
  SafetyTest()
      : model_(ur10::Ur10Model::Load(std::string(PICKING_DATA_DIR) + "/ur10")), kin_(model_) {
    limits_ = SafetyLimits::FromModel(model_, {"cell", {-1.4, -1.4, -0.2}, {1.4, 1.4, 1.6}}, 0.5);
    q_ << 0.2, -1.6, 1.8, -1.8, -1.57, 0.3;
  }
  SafetyChecker Checker() const { return SafetyChecker(kin_, limits_); }
  Eigen::Vector3d Tcp(const JointVector& q) const {
    return kin_.ForwardKinematics(q).translation();
  }

  ur10::Ur10Model model_;
  ur10::Ur10Kinematics kin_;
  SafetyLimits limits_;
  JointVector q_;
};

TEST_F(SafetyTest, AcceptsValidTarget) { EXPECT_TRUE(Checker().CheckJointTarget(q_).ok); }

TEST_F(SafetyTest, RefusesNanAndNamesJoint) {
  JointVector q = q_;
  q[3] = std::nan("");
  const SafetyCheck c = Checker().CheckJointTarget(q);
  EXPECT_FALSE(c.ok);
  EXPECT_NE(c.reason.find("wrist_1"), std::string::npos) << c.reason;
  EXPECT_NE(c.reason.find("not finite"), std::string::npos) << c.reason;
}

TEST_F(SafetyTest, RefusesJointOutsideLimits) {
  JointVector q = q_;
  q[2] = 3.3;
  const SafetyCheck c = Checker().CheckJointTarget(q);
  EXPECT_FALSE(c.ok);
  EXPECT_NE(c.reason.find("elbow_joint"), std::string::npos) << c.reason;
}

TEST_F(SafetyTest, RefusesTcpOutsideWorkspaceAndInForbiddenZone) {
  limits_.workspace.max_m.z() = Tcp(q_).z() - 0.01;
  SafetyCheck c = Checker().CheckJointTarget(q_);
  EXPECT_FALSE(c.ok);
  EXPECT_NE(c.reason.find("outside the workspace"), std::string::npos) << c.reason;
  limits_.workspace.max_m.z() = 1.6;
  const Eigen::Vector3d p = Tcp(q_);
  limits_.forbidden_zones.push_back(
      {"shelf", p - Eigen::Vector3d::Constant(0.05), p + Eigen::Vector3d::Constant(0.05)});
  c = Checker().CheckJointTarget(q_);
  EXPECT_FALSE(c.ok);
  EXPECT_NE(c.reason.find("shelf"), std::string::npos) << c.reason;
}

TEST_F(SafetyTest, InvalidLimitsThrow) {
  limits_.max_velocity_rad_s[1] = -1;
  EXPECT_THROW(Checker(), std::invalid_argument);
  limits_ = SafetyLimits{};
  limits_.workspace.max_m.x() = limits_.workspace.min_m.x();
  EXPECT_THROW(Checker(), std::invalid_argument);
  limits_ = SafetyLimits{};
  limits_.forbidden_zones.push_back(
      {"bad", Eigen::Vector3d::Zero(), Eigen::Vector3d::Constant(std::nan(""))});
  EXPECT_THROW(Checker(), std::invalid_argument);
}

TEST_F(SafetyTest, LinearMoveInsideWorkspace) {
  Eigen::Isometry3d goal = kin_.ForwardKinematics(q_);
  goal.translation().z() -= 0.2;
  const SafetyCheck c = Checker().CheckLinearMove(q_, goal, 0.2);
  EXPECT_TRUE(c.ok) << c.reason;
}

TEST_F(SafetyTest, LinearMoveCrossingForbiddenZoneIsRefusedAtASample) {
  Eigen::Isometry3d goal = kin_.ForwardKinematics(q_);
  const Eigen::Vector3d start = goal.translation();
  goal.translation().z() -= 0.3;
  // A thin slab between start and goal: both ends are outside it.
  limits_.forbidden_zones.push_back(
      {"tote_wall", Eigen::Vector3d(start.x() - 0.1, start.y() - 0.1, start.z() - 0.16),
       Eigen::Vector3d(start.x() + 0.1, start.y() + 0.1, start.z() - 0.14)});
  EXPECT_TRUE(Checker().CheckJointTarget(q_).ok);
  const SafetyCheck c = Checker().CheckLinearMove(q_, goal, 0.1);
  EXPECT_FALSE(c.ok);
  EXPECT_NE(c.reason.find("linear move sample"), std::string::npos) << c.reason;
  EXPECT_NE(c.reason.find("tote_wall"), std::string::npos) << c.reason;
}

TEST_F(SafetyTest, LinearMoveTooFastOrUnreachable) {
  Eigen::Isometry3d goal = kin_.ForwardKinematics(q_);
  goal.translation().z() -= 0.1;
  EXPECT_NE(Checker().CheckLinearMove(q_, goal, 0.9).reason.find("tool speed"), std::string::npos);
  goal.translation() = Eigen::Vector3d(1.35, 0.0, 1.5);
  const SafetyCheck c = Checker().CheckLinearMove(q_, goal, 0.1);
  EXPECT_FALSE(c.ok);
  goal.translation().x() = std::nan("");
  EXPECT_FALSE(Checker().CheckLinearMove(q_, goal, 0.1).ok);
}

JointTrajectory Trajectory(const JointVector& q0, const JointVector& q1,
                           const SafetyLimits& limits) {
  TimeParametrizationOptions options;
  options.max_velocity_rad_s = limits.max_velocity_rad_s * 0.5;
  options.max_acceleration_rad_s2 = limits.max_acceleration_rad_s2;
  return TimeParametrizePath({q0, q1}, options);
}

TEST_F(SafetyTest, TrajectoryChecks) {
  limits_.max_tool_speed_m_s = 2.0;
  JointVector q1 = q_;
  q1[0] += 0.3;
  JointTrajectory t = Trajectory(q_, q1, limits_);
  SafetyCheck c = Checker().CheckTrajectory(t);
  ASSERT_TRUE(c.ok) << c.reason;

  JointTrajectory fast = t;  // compressed in time: too fast
  for (auto& p : fast.points) p.time_s *= 0.3;
  c = Checker().CheckTrajectory(fast);
  EXPECT_FALSE(c.ok);
  EXPECT_NE(c.reason.find("shoulder_pan"), std::string::npos) << c.reason;

  JointTrajectory backwards = t;
  backwards.points[5].time_s = backwards.points[4].time_s;
  c = Checker().CheckTrajectory(backwards);
  EXPECT_FALSE(c.ok);
  EXPECT_NE(c.reason.find("waypoint 5"), std::string::npos) << c.reason;

  JointTrajectory nan = t;
  nan.points[7].q_rad[4] = std::nan("");
  c = Checker().CheckTrajectory(nan);
  EXPECT_NE(c.reason.find("waypoint 7"), std::string::npos) << c.reason;
  EXPECT_NE(c.reason.find("wrist_2"), std::string::npos) << c.reason;

  JointTrajectory jerk = t;  // a step in the middle
  jerk.points[10].q_rad[1] += 0.01;
  c = Checker().CheckTrajectory(jerk);
  EXPECT_FALSE(c.ok);
  EXPECT_NE(c.reason.find("shoulder_lift"), std::string::npos) << c.reason;

  EXPECT_FALSE(Checker().CheckTrajectory(JointTrajectory{}).ok);
}

// A trajectory whose positions move slowly but whose declared velocity is 100 rad/s was
// accepted: a backend that streams the declared velocities would have commanded it.
TEST_F(SafetyTest, TrajectoryDeclaredVelocityAndAccelerationLimits) {
  limits_.max_tool_speed_m_s = 2.0;
  JointVector q1 = q_;
  q1[0] += 0.3;
  const JointTrajectory t = Trajectory(q_, q1, limits_);
  ASSERT_TRUE(Checker().CheckTrajectory(t).ok);

  JointTrajectory fast = t;
  fast.points[3].qd_rad_s[2] = 100.0;
  SafetyCheck c = Checker().CheckTrajectory(fast);
  EXPECT_FALSE(c.ok);
  EXPECT_NE(c.reason.find("waypoint 3"), std::string::npos) << c.reason;
  EXPECT_NE(c.reason.find("elbow_joint declared velocity 100"), std::string::npos) << c.reason;

  JointTrajectory hard = t;
  hard.points[4].qdd_rad_s2[5] = -1e4;
  c = Checker().CheckTrajectory(hard);
  EXPECT_FALSE(c.ok);
  EXPECT_NE(c.reason.find("wrist_3 declared acceleration"), std::string::npos) << c.reason;
}

TEST_F(SafetyTest, TrajectoryToolSpeedLimit) {
  JointVector q1 = q_;
  q1[0] += 0.5;  // base rotation: the TCP moves at about r * 1 rad/s
  JointTrajectory t = Trajectory(q_, q1, limits_);
  limits_.max_tool_speed_m_s = 0.2;
  const SafetyCheck c = Checker().CheckTrajectory(t);
  EXPECT_FALSE(c.ok);
  EXPECT_NE(c.reason.find("tool speed"), std::string::npos) << c.reason;
}

}  // namespace
}  // namespace picking::robot
