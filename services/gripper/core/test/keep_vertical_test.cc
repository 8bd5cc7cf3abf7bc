#include "services/gripper/core/keep_vertical.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>

#include "services/gripper/core/gripper_types.h"

namespace picking::gripper {
namespace {

constexpr double kPi = 3.14159265358979323846;

// Gravity in the tool frame for a tool tilted by `phi` about its x axis and `psi` about y.
Eigen::Vector3d ToolGravity(double phi, double psi = 0.0) {
  return kGravity_m_s2 * Eigen::Vector3d(-std::sin(psi), std::cos(psi) * std::sin(phi),
                                         std::cos(psi) * std::cos(phi));
}

TEST(KeepVerticalGeometryTest, VerticalAngleZeroesTheTiltForRandomToolOrientations) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> angle(-kPi, kPi);
  for (int i = 0; i < 1000; ++i) {
    const Eigen::Vector3d g_tool = ToolGravity(angle(rng), angle(rng) / 3.0);
    const double q = VerticalJointAngle(g_tool);
    const Eigen::Vector3d g_head = GravityInHead(g_tool, q);
    EXPECT_NEAR(HeadTilt(g_head), 0.0, 1e-12);
    EXPECT_NEAR(g_head.y(), 0.0, 1e-12);
    EXPECT_GT(g_head.z(), 0.0);  // Suction axis along gravity, not against it.
    EXPECT_NEAR(g_head.norm(), kGravity_m_s2, 1e-12);  // A rotation keeps the magnitude.
  }
}

TEST(KeepVerticalGeometryTest, TiltGrowsWithTheJointAngle) {
  // Tool tilted by phi about x: at joint angle q the head is tilted by phi + q.
  for (double phi : {-1.0, -0.3, 0.0, 0.4, 1.2}) {
    for (double q : {-1.2, -0.5, 0.0, 0.3, 1.0}) {
      EXPECT_NEAR(HeadTilt(GravityInHead(ToolGravity(phi), q)), phi + q, 1e-12);
    }
  }
  EXPECT_NEAR(VerticalJointAngle(ToolGravity(0.4)), -0.4, 1e-12);
}

TEST(KeepVerticalGeometryTest, GravityAlongTheJointAxisHasNoVerticalAngle) {
  EXPECT_THROW(VerticalJointAngle(Eigen::Vector3d(kGravity_m_s2, 0, 0)), std::invalid_argument);
  EXPECT_THROW(VerticalJointAngle(Eigen::Vector3d(std::nan(""), 0, 1)), std::invalid_argument);
}

// A simulated head: a servo that moves toward its command at a limited rate, an
// accelerometer with seeded Gaussian noise, and a tool whose tilt changes over time.
struct SimulatedHead {
  double q_rad = 0.0;
  double servo_rate_rad_s = 5.0;
  std::mt19937 rng{42};
  std::normal_distribution<double> noise{0.0, 0.05};  // m/s^2 per axis.

  Eigen::Vector3d Accelerometer(const Eigen::Vector3d& g_tool) {
    return GravityInHead(g_tool, q_rad) + Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
  }
  void Drive(double command_rad, double dt_s) {
    const double max_step = servo_rate_rad_s * dt_s;
    q_rad += std::clamp(command_rad - q_rad, -max_step, max_step);
  }
};

TEST(KeepVerticalControllerTest, HoldsASimulatedHeadVerticalWhileTheToolTilts) {
  KeepVerticalController controller;
  SimulatedHead head;
  const double dt = 0.01;
  double previous_command = 0.0;
  double worst_settled_tilt = 0.0;
  // Tool tilt profile: steps and a slow sweep, all within the servo's reach.
  auto tool_tilt = [](int step) {
    if (step < 200) return 0.6;
    if (step < 400) return -0.9;
    return -0.9 + 0.002 * (step - 400);  // 0.2 rad/s sweep up to +0.7.
  };
  for (int step = 0; step < 1200; ++step) {
    const Eigen::Vector3d g_tool = ToolGravity(tool_tilt(step), 0.1);
    const KeepVerticalStep out = controller.Step(head.Accelerometer(g_tool), head.q_rad, dt);
    ASSERT_TRUE(out.observable);
    ASSERT_LE(std::abs(out.command_rad), kPi / 2 + 1e-12);
    if (step > 0) {
      ASSERT_LE(std::abs(out.command_rad - previous_command),
                controller.options().max_rate_rad_s * dt + 1e-12);
    }
    previous_command = out.command_rad;
    head.Drive(out.command_rad, dt);
    // Settled: 100 steps (1 s) after each step change, and throughout the slow sweep.
    if ((step >= 100 && step < 200) || (step >= 300 && step < 400) || step >= 500) {
      const double true_tilt = HeadTilt(GravityInHead(g_tool, head.q_rad));
      worst_settled_tilt = std::max(worst_settled_tilt, std::abs(true_tilt));
    }
  }
  EXPECT_LT(worst_settled_tilt, 0.03) << "the head strayed from vertical by more than 1.7 deg";
  EXPECT_NEAR(head.q_rad, -0.7, 0.03);
}

TEST(KeepVerticalControllerTest, SaturatesAtTheServoRangeWhenVerticalIsOutOfReach) {
  KeepVerticalOptions options;
  options.gain = 1.0;
  options.max_rate_rad_s = 100.0;
  KeepVerticalController controller(options);
  const Eigen::Vector3d g_tool = ToolGravity(2.0);  // Needs q = -2.0, beyond -pi/2.
  double q = 0.0;
  KeepVerticalStep out;
  for (int i = 0; i < 10; ++i) {
    out = controller.Step(GravityInHead(g_tool, q), q, 0.01);
    q = out.command_rad;
  }
  EXPECT_DOUBLE_EQ(q, -kPi / 2);
  EXPECT_TRUE(out.saturated);
}

TEST(KeepVerticalControllerTest, FullGainWithoutRateLimitCorrectsInOneStep) {
  KeepVerticalOptions options;
  options.gain = 1.0;
  options.max_rate_rad_s = 1000.0;
  KeepVerticalController controller(options);
  const Eigen::Vector3d g_tool = ToolGravity(0.3);
  const KeepVerticalStep out = controller.Step(GravityInHead(g_tool, 0.1), 0.1, 0.01);
  EXPECT_NEAR(out.tilt_rad, 0.4, 1e-12);
  EXPECT_NEAR(out.command_rad, -0.3, 1e-12);
  EXPECT_FALSE(out.saturated);
}

TEST(KeepVerticalControllerTest, HoldsWhenTiltIsUnobservableOrInsideTheDeadband) {
  KeepVerticalController controller;
  // Gravity along the joint axis: nothing to correct, the command stays.
  KeepVerticalStep out = controller.Step(Eigen::Vector3d(kGravity_m_s2, 0.1, 0.1), 0.2, 0.01);
  EXPECT_FALSE(out.observable);
  EXPECT_DOUBLE_EQ(out.command_rad, 0.2);
  // A tilt inside the deadband does not move the servo.
  out = controller.Step(GravityInHead(ToolGravity(-0.2 + 0.002), 0.2), 0.2, 0.01);
  EXPECT_TRUE(out.observable);
  EXPECT_DOUBLE_EQ(out.command_rad, 0.2);
}

TEST(KeepVerticalControllerTest, RejectsBadOptionsAndInputs) {
  KeepVerticalOptions options;
  options.gain = 0.0;
  EXPECT_THROW(KeepVerticalController{options}, std::invalid_argument);
  options = KeepVerticalOptions();
  options.gain = 1.5;
  EXPECT_THROW(KeepVerticalController{options}, std::invalid_argument);
  options = KeepVerticalOptions();
  options.min_angle_rad = 1.0;
  options.max_angle_rad = -1.0;
  EXPECT_THROW(KeepVerticalController{options}, std::invalid_argument);
  options = KeepVerticalOptions();
  options.max_rate_rad_s = 0.0;
  EXPECT_THROW(KeepVerticalController{options}, std::invalid_argument);

  KeepVerticalController controller;
  EXPECT_THROW(controller.Step(Eigen::Vector3d(0, 0, std::nan("")), 0.0, 0.01),
               std::invalid_argument);
  EXPECT_THROW(controller.Step(Eigen::Vector3d(0, 0, 9.8), 0.0, 0.0), std::invalid_argument);
}

}  // namespace
}  // namespace picking::gripper
