#include "services/robot/core/urscript.h"

#include <gtest/gtest.h>

#include <cmath>

namespace picking::robot::urscript {
namespace {

TEST(UrScriptTest, MoveJ) {
  JointVector q;
  q << 0.0, -1.5707963267948966, 1.5, -3.14159265, 0.25, -0.0000001;
  EXPECT_EQ(MoveJ(q, 1.4, 1.05),
            "movej([0.000000, -1.570796, 1.500000, -3.141593, 0.250000, 0.000000], "
            "a=1.400000, v=1.050000, t=0.000000, r=0.000000)");
  EXPECT_EQ(MoveJ(JointVector::Zero(), 1.0, 0.5, 2.0, 0.01),
            "movej([0.000000, 0.000000, 0.000000, 0.000000, 0.000000, 0.000000], "
            "a=1.000000, v=0.500000, t=2.000000, r=0.010000)");
}

TEST(UrScriptTest, MoveLUsesRotationVector) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(0.4, -0.2, 0.3);
  X.linear() = Eigen::AngleAxisd(3.14159265358979 / 2, Eigen::Vector3d::UnitY()).toRotationMatrix();
  EXPECT_EQ(MoveL(X, 1.2, 0.25),
            "movel(p[0.400000, -0.200000, 0.300000, 0.000000, 1.570796, 0.000000], "
            "a=1.200000, v=0.250000, t=0.000000, r=0.000000)");
}

TEST(UrScriptTest, SpeedStopServo) {
  JointVector qd = JointVector::Zero();
  qd[0] = 0.1;
  EXPECT_EQ(SpeedJ(qd, 0.5, 1.0),
            "speedj([0.100000, 0.000000, 0.000000, 0.000000, 0.000000, 0.000000], a=0.500000, "
            "t=1.000000)");
  Eigen::Matrix<double, 6, 1> twist = Eigen::Matrix<double, 6, 1>::Zero();
  twist[2] = -0.02;
  EXPECT_EQ(SpeedL(twist, 0.5, 3.0),
            "speedl([0.000000, 0.000000, -0.020000, 0.000000, 0.000000, 0.000000], a=0.500000, "
            "t=3.000000)");
  EXPECT_EQ(StopJ(2.0), "stopj(2.000000)");
  EXPECT_EQ(StopL(1.5), "stopl(1.500000)");
  EXPECT_EQ(ServoJ(JointVector::Constant(0.5), 0.008, 0.1, 300),
            "servoj([0.500000, 0.500000, 0.500000, 0.500000, 0.500000, 0.500000], 0, 0, "
            "0.008000, 0.100000, 300.000000)");
}

TEST(UrScriptTest, RejectsBadArguments) {
  EXPECT_THROW(MoveJ(JointVector::Constant(std::nan("")), 1, 1), std::invalid_argument);
  EXPECT_THROW(MoveJ(JointVector::Zero(), -1, 1), std::invalid_argument);
  EXPECT_THROW(MoveJ(JointVector::Zero(), 1, 0), std::invalid_argument);
  EXPECT_THROW(MoveJ(JointVector::Zero(), 1, 1, -1), std::invalid_argument);
  EXPECT_THROW(StopJ(std::nan("")), std::invalid_argument);
  EXPECT_THROW(ServoJ(JointVector::Zero(), 0.008, 0.5), std::invalid_argument);
  EXPECT_THROW(ServoJ(JointVector::Zero(), 0.008, 0.1, 50), std::invalid_argument);
}

TEST(UrScriptTest, Program) {
  EXPECT_EQ(Program("picking_move", {"stopj(1.000000)", "textmsg(\"x\")"}),
            "def picking_move():\n  stopj(1.000000)\n  textmsg(\"x\")\nend\n");
  EXPECT_THROW(Program("1bad", {}), std::invalid_argument);
  EXPECT_THROW(Program("ok", {"a\nb"}), std::invalid_argument);
}

}  // namespace
}  // namespace picking::robot::urscript
