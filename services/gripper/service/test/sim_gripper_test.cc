// The simulator backend against a fake SimulatorService served in-process.
#include "services/gripper/service/sim_gripper.h"

#include <gtest/gtest.h>

#include <cmath>
#include <memory>

#include "libs/errors/errors.h"
#include "services/gripper/core/gripper.h"
#include "services/gripper/core/keep_vertical.h"
#include "services/gripper/core/testing/fake_clock.h"
#include "services/gripper/service/test/fake_simulator.h"

namespace picking::gripper {
namespace {

using testing::FakeClock;
using testing::FakeSimulator;
using testing::TiltedDownTool;

constexpr double kPi = 3.14159265358979323846;

class SimGripperTest : public ::testing::Test {
 protected:
  std::unique_ptr<Gripper> MakeGripper(GripperKind kind) {
    SimGripperOptions options;
    options.kind = kind;
    auto backend = SimGripper::Connect(sim_.address(), options);
    backend_ = backend.get();
    GripperOptions gripper_options;
    gripper_options.kind = kind;
    return std::make_unique<Gripper>(std::move(backend), gripper_options, clock_);
  }

  FakeSimulator sim_;
  std::shared_ptr<FakeClock> clock_ = std::make_shared<FakeClock>();
  SimGripper* backend_ = nullptr;
};

TEST_F(SimGripperTest, VacuumOnAnItemSealsAtTheSimulatorsLevel) {
  sim_.SetItemUnderCup("crayola_64_ct");
  sim_.SetReportedKpa(28.0, 2.0);
  auto gripper = MakeGripper(GripperKind::kTote);
  const GripperState state = gripper->SetVacuum(true, 1.0);
  EXPECT_TRUE(sim_.suction_on());
  EXPECT_TRUE(state.item_attached);
  EXPECT_DOUBLE_EQ(state.reading.vacuum_kpa, 28.0);
  EXPECT_EQ(state.backend, "sim");
  EXPECT_EQ(clock_->sleeps(), 0);  // Sealed at the first reading.

  const GripperState off = gripper->SetVacuum(false);
  EXPECT_FALSE(sim_.suction_on());
  EXPECT_FALSE(off.item_attached);
  EXPECT_DOUBLE_EQ(off.reading.vacuum_kpa, 0.0);
}

TEST_F(SimGripperTest, ModelledLevelsWhenTheSimulatorReportsNone) {
  auto gripper = MakeGripper(GripperKind::kTote);
  // Nothing under the cup: the open level, never a seal.
  EXPECT_THROW(gripper->SetVacuum(true, 0.3), TimeoutError);
  EXPECT_DOUBLE_EQ(gripper->State().reading.vacuum_kpa, SimGripperOptions().open_kpa);
  gripper->SetVacuum(false);
  sim_.SetItemUnderCup("expo_dry_erase_board_eraser");
  const GripperState state = gripper->SetVacuum(true, 0.3);
  EXPECT_TRUE(state.item_attached);
  EXPECT_DOUBLE_EQ(state.reading.vacuum_kpa, SimGripperOptions().sealed_kpa);
}

TEST_F(SimGripperTest, ALostItemOpensTheCup) {
  sim_.SetItemUnderCup("crayola_64_ct");
  auto gripper = MakeGripper(GripperKind::kTote);
  EXPECT_TRUE(gripper->SetVacuum(true, 0.5).item_attached);
  sim_.DropAttachedItem();
  const GripperState state = gripper->State();
  EXPECT_FALSE(state.item_attached);
  EXPECT_TRUE(state.reading.vacuum_on);
  EXPECT_LE(state.reading.vacuum_kpa, SimGripperOptions().open_kpa);
}

TEST_F(SimGripperTest, KeepVerticalFollowsTheToolPose) {
  auto gripper = MakeGripper(GripperKind::kTote);
  sim_.SetToolPose(TiltedDownTool(0.4));
  GripperState state = gripper->SetJointMode(JointMode::kKeepVertical);
  EXPECT_EQ(state.reading.joint_mode, JointMode::kKeepVertical);
  EXPECT_NEAR(state.reading.joint_angle_rad, -0.4, 1e-9);
  EXPECT_NEAR(state.reading.gravity_head_m_s2.y(), 0.0, 1e-9);
  EXPECT_NEAR(state.reading.gravity_head_m_s2.z(), kGravity_m_s2, 1e-9);
  sim_.SetToolPose(TiltedDownTool(-1.1));
  state = gripper->State();
  EXPECT_NEAR(state.reading.joint_angle_rad, 1.1, 1e-9);
  EXPECT_NEAR(HeadTilt(state.reading.gravity_head_m_s2), 0.0, 1e-9);
  // Beyond the servo's reach the angle stops at the limit.
  sim_.SetToolPose(TiltedDownTool(2.0));
  EXPECT_NEAR(gripper->State().reading.joint_angle_rad, -kPi / 2, 1e-12);
}

TEST_F(SimGripperTest, FixedAndUnactuatedModes) {
  auto gripper = MakeGripper(GripperKind::kTote);
  sim_.SetToolPose(TiltedDownTool(0.3));
  GripperState state = gripper->SetJointMode(JointMode::kFixed, 0.7);
  EXPECT_DOUBLE_EQ(state.reading.joint_angle_rad, 0.7);
  EXPECT_NEAR(HeadTilt(state.reading.gravity_head_m_s2), 1.0, 1e-9);  // 0.3 + 0.7.
  EXPECT_DOUBLE_EQ(sim_.head_angle_rad(), 0.7);  // the simulated head turned with the servo

  state = gripper->SetJointMode(JointMode::kUnactuated);
  EXPECT_NEAR(state.reading.joint_angle_rad, -0.3, 1e-9);  // Hangs along gravity.
  sim_.SetItemUnderCup("crayola_64_ct");
  gripper->SetVacuum(true);
  sim_.SetToolPose(TiltedDownTool(-0.5));
  state = gripper->State();
  EXPECT_NEAR(state.reading.joint_angle_rad, -0.3, 1e-9);  // Locked by the vacuum.
  EXPECT_NEAR(HeadTilt(state.reading.gravity_head_m_s2), -0.8, 1e-9);
  gripper->SetVacuum(false);
  EXPECT_NEAR(gripper->State().reading.joint_angle_rad, 0.5, 1e-9);  // Free again.
}

// The simulated head follows the servo; a turn the simulator refuses (the head would hit
// the cell, or the cell's gripper has no such range) fails and keeps the mode.
TEST_F(SimGripperTest, TheSimulatedHeadFollowsTheServo) {
  auto gripper = MakeGripper(GripperKind::kTote);
  sim_.SetToolPose(TiltedDownTool(0.0));
  gripper->SetJointMode(JointMode::kFixed, 1.2);
  EXPECT_DOUBLE_EQ(sim_.head_angle_rad(), 1.2);
  const int turns = sim_.head_calls();
  gripper->State();  // a fixed head is not turned again
  EXPECT_EQ(sim_.head_calls(), turns);
  sim_.BlockHead(true);
  EXPECT_THROW(backend_->SetJointMode(JointMode::kFixed, 0.4), PreconditionError);
  EXPECT_DOUBLE_EQ(sim_.head_angle_rad(), 1.2);
  EXPECT_EQ(gripper->State().reading.joint_mode, JointMode::kFixed);
  EXPECT_DOUBLE_EQ(gripper->State().reading.joint_angle_rad, 1.2);
  sim_.BlockHead(false);
  gripper->SetJointMode(JointMode::kFixed, 0.0);
  EXPECT_DOUBLE_EQ(sim_.head_angle_rad(), 0.0);
}

TEST_F(SimGripperTest, ShelfGripperHasNoJoint) {
  auto gripper = MakeGripper(GripperKind::kShelf);
  sim_.SetToolPose(TiltedDownTool(0.3));
  EXPECT_THROW(backend_->SetJointMode(JointMode::kFixed, 0.1), PreconditionError);
  const GripperState state = gripper->State();
  EXPECT_DOUBLE_EQ(state.reading.joint_angle_rad, 0.0);
  EXPECT_NEAR(state.reading.gravity_head_m_s2.y(), kGravity_m_s2 * std::sin(0.3), 1e-9);
}

TEST_F(SimGripperTest, SimulatorRefusalsBecomePreconditionErrors) {
  sim_.SetNoLayout(true);
  auto gripper = MakeGripper(GripperKind::kTote);
  EXPECT_THROW(gripper->SetVacuum(true), PreconditionError);
  EXPECT_THROW(gripper->State(), PreconditionError);
}

TEST(SimGripperUnreachableTest, EveryCallIsUnavailableAndNothingIsContactedAtConstruction) {
  std::string address;
  {
    FakeSimulator gone;
    address = gone.address();
  }
  SimGripperOptions options;
  options.timeout_s = 2.0;
  auto backend = SimGripper::Connect(address, options);  // Lazy: does not fail here.
  try {
    backend->Read();
    FAIL() << "expected UnavailableError";
  } catch (const UnavailableError& e) {
    EXPECT_NE(std::string(e.what()).find(address), std::string::npos) << e.what();
  }
  EXPECT_THROW(backend->SetVacuum(true), UnavailableError);
  EXPECT_THROW(SimGripper::Connect("no-port", options), std::invalid_argument);
  options.timeout_s = 0.0;
  EXPECT_THROW(SimGripper::Connect(address, options), std::invalid_argument);
}

}  // namespace
}  // namespace picking::gripper
