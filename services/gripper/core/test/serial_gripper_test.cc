// End-to-end tests of the serial backend over a pseudo-terminal pair, against the fake
// micro controller on the master side.
#include "services/gripper/core/serial_gripper.h"

#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <string>

#include "libs/errors/errors.h"
#include "services/gripper/core/gripper.h"
#include "services/gripper/core/testing/fake_clock.h"
#include "services/gripper/core/testing/fake_micro_controller.h"

namespace picking::gripper {
namespace {

using testing::FakeClock;
using testing::FakeMicroController;
using testing::FakeMicroControllerOptions;

constexpr double kPi = 3.14159265358979323846;

Eigen::Vector3d ToolGravity(double phi) {
  return kGravity_m_s2 * Eigen::Vector3d(0.0, std::sin(phi), std::cos(phi));
}

class SerialGripperTest : public ::testing::Test {
 protected:
  explicit SerialGripperTest(FakeMicroControllerOptions options = {}) : fake_(options) {
    serial::SerialLinkOptions link_options;
    link_options.reply_timeout_s = 0.1;
    link_options.max_attempts = 3;
    const std::string device = fake_.device_path();
    auto link = std::make_unique<serial::SerialLink>(
        [device] { return serial::OpenSerialPort(device, 115200); }, device, link_options);
    link_ = link.get();
    auto backend = std::make_unique<SerialGripper>(std::move(link));
    backend_ = backend.get();
    GripperOptions gripper_options;
    gripper_options.kind = GripperKind::kTote;
    gripper_ = std::make_unique<Gripper>(std::move(backend), gripper_options, clock_);
  }

  FakeMicroController fake_;
  std::shared_ptr<FakeClock> clock_ = std::make_shared<FakeClock>();
  serial::SerialLink* link_ = nullptr;
  SerialGripper* backend_ = nullptr;
  std::unique_ptr<Gripper> gripper_;
};

TEST_F(SerialGripperTest, VacuumReachesASealOverTheLine) {
  const GripperState state = gripper_->SetVacuum(true, 2.0);
  EXPECT_TRUE(fake_.relay_on());
  EXPECT_TRUE(state.item_attached);
  EXPECT_TRUE(state.reading.vacuum_on);
  EXPECT_GE(state.reading.vacuum_kpa, 15.0);
  EXPECT_EQ(state.backend, "serial");
  EXPECT_EQ(fake_.commands().front(), "V1");

  const GripperState off = gripper_->SetVacuum(false);
  EXPECT_FALSE(fake_.relay_on());
  EXPECT_FALSE(off.item_attached);
  const auto stats = backend_->stats();
  EXPECT_EQ(stats.retries, 0u);
  EXPECT_EQ(stats.garbled_lines, 0u);
}

TEST_F(SerialGripperTest, AGripperThatNeverReachesVacuumTimesOut) {
  fake_.SetItemUnderCup(false);
  EXPECT_THROW(gripper_->SetVacuum(true, 0.5), TimeoutError);
  EXPECT_NEAR(clock_->elapsed_s(), 0.5, 1e-9);
  EXPECT_TRUE(fake_.relay_on());  // The pump stays as commanded.
  const GripperState state = gripper_->State();
  EXPECT_NEAR(state.reading.vacuum_kpa, 4.0, 0.01);
  EXPECT_FALSE(state.item_attached);
}

TEST_F(SerialGripperTest, GarbledAndTruncatedRepliesAreDiscardedAndTheCommandRetried) {
  fake_.GarbleNextReplies(1);
  EXPECT_NO_THROW(backend_->SetVacuum(true));
  auto stats = backend_->stats();
  EXPECT_EQ(stats.garbled_lines, 1u);
  EXPECT_EQ(stats.timeouts, 1u);
  EXPECT_EQ(stats.retries, 1u);
  EXPECT_EQ(stats.stale_replies, 0u);

  // Half a line glued to the retry's reply: the whole reply after the last '$' is used.
  fake_.TruncateNextReplies(1);
  const GripperReading reading = backend_->Read();
  EXPECT_TRUE(reading.vacuum_on);
  stats = backend_->stats();
  EXPECT_EQ(stats.garbled_lines, 2u);
  EXPECT_EQ(stats.retries, 2u);
}

TEST_F(SerialGripperTest, NoiseAndStaleRepliesBeforeAReplyAreSkipped) {
  fake_.SendRaw("noise\n\r\n" + std::string(300, '#') + "\n" +
                serial::EncodeLine(serial::OkBody(9999)) + "$OK 1");
  EXPECT_NO_THROW(backend_->SetVacuum(true));
  const auto stats = backend_->stats();
  EXPECT_EQ(stats.overlong_lines, 1u);
  EXPECT_EQ(stats.stale_replies, 1u);
  // "noise" and the fragment "$OK 1" glued to the real reply's line.
  EXPECT_EQ(stats.garbled_lines, 2u);
  EXPECT_EQ(stats.retries, 0u);
}

TEST_F(SerialGripperTest, ALostReplyIsRecoveredByRetryingTheSameSequenceNumber) {
  fake_.DropNextReplies(1);
  backend_->SetJointMode(JointMode::kFixed, 0.5);
  EXPECT_EQ(fake_.mode(), JointMode::kFixed);
  EXPECT_NEAR(fake_.fixed_target_rad(), 0.5, 1e-4);
  const auto stats = backend_->stats();
  EXPECT_EQ(stats.timeouts, 1u);
  EXPECT_EQ(stats.retries, 1u);
  const auto commands = fake_.commands();
  ASSERT_EQ(commands.size(), 3u);  // S twice (the lost reply), then M F.
  EXPECT_EQ(commands[0], "S 28.65");
  EXPECT_EQ(commands[1], "S 28.65");
  EXPECT_EQ(commands[2], "M F");
}

TEST_F(SerialGripperTest, ASilentControllerIsUnavailableUntilItAnswersAgain) {
  fake_.SetSilent(true);
  try {
    backend_->Read();
    FAIL() << "expected UnavailableError";
  } catch (const UnavailableError& e) {
    EXPECT_NE(std::string(e.what()).find("did not answer 'Q' (3 attempts"), std::string::npos)
        << e.what();
  }
  EXPECT_EQ(backend_->stats().timeouts, 3u);
  fake_.SetSilent(false);
  EXPECT_NO_THROW(backend_->Read());
}

TEST_F(SerialGripperTest, ControllerErrorsMapToErrorKinds) {
  EXPECT_THROW(link_->Transact("S 120.00"), std::invalid_argument);
  EXPECT_THROW(link_->Transact("M X"), std::invalid_argument);
  EXPECT_THROW(link_->Transact("Z"), UnavailableError);
  EXPECT_EQ(fake_.mode(), JointMode::kUnactuated);  // Nothing changed.
}

TEST_F(SerialGripperTest, FixedModeMovesTheServoToTheAngle) {
  GripperState state = gripper_->SetJointMode(JointMode::kFixed, -0.6);
  for (int i = 0; i < 5; ++i) state = gripper_->State();
  EXPECT_EQ(state.reading.joint_mode, JointMode::kFixed);
  EXPECT_NEAR(state.reading.joint_angle_rad, -0.6, 1e-3);
}

TEST_F(SerialGripperTest, KeepVerticalModeLevelsTheHeadAsTheToolTilts) {
  gripper_->SetVacuum(true);  // The limp joint is locked by vacuum; only the servo moves it.
  fake_.SetToolGravity(ToolGravity(0.5));
  GripperState state = gripper_->SetJointMode(JointMode::kKeepVertical);
  for (int i = 0; i < 10; ++i) state = gripper_->State();
  EXPECT_EQ(state.reading.joint_mode, JointMode::kKeepVertical);
  EXPECT_NEAR(state.reading.joint_angle_rad, -0.5, 0.01);
  EXPECT_NEAR(HeadTilt(state.reading.gravity_head_m_s2), 0.0, 0.01);
  fake_.SetToolGravity(ToolGravity(-0.8));
  for (int i = 0; i < 10; ++i) state = gripper_->State();
  EXPECT_NEAR(state.reading.joint_angle_rad, 0.8, 0.01);
  EXPECT_NEAR(state.reading.gravity_head_m_s2.y(), 0.0, 0.1);
}

TEST_F(SerialGripperTest, UnactuatedHeadHangsFreelyUntilVacuumLocksTheJoint) {
  fake_.SetToolGravity(ToolGravity(0.3));
  GripperState state = gripper_->SetJointMode(JointMode::kUnactuated);
  for (int i = 0; i < 3; ++i) state = gripper_->State();
  EXPECT_NEAR(state.reading.joint_angle_rad, -0.3, 1e-3);  // Hangs along gravity.
  gripper_->SetVacuum(true);
  fake_.SetToolGravity(ToolGravity(-0.2));
  for (int i = 0; i < 3; ++i) state = gripper_->State();
  EXPECT_NEAR(state.reading.joint_angle_rad, -0.3, 1e-3);  // Locked by the sealed joint.
  EXPECT_EQ(state.reading.joint_mode, JointMode::kUnactuated);
}

class ShelfSerialGripperTest : public SerialGripperTest {
 protected:
  static FakeMicroControllerOptions NoServo() {
    FakeMicroControllerOptions options;
    options.has_servo = false;
    return options;
  }
  ShelfSerialGripperTest() : SerialGripperTest(NoServo()) {}
};

TEST_F(ShelfSerialGripperTest, AControllerWithoutServoRefusesJointCommands) {
  EXPECT_THROW(backend_->SetJointMode(JointMode::kKeepVertical, 0.0), PreconditionError);
  EXPECT_NO_THROW(backend_->SetVacuum(true));
}

TEST(SerialPortTest, RejectsUnknownRatesAndMissingDevices) {
  EXPECT_THROW(serial::OpenSerialPort("/dev/null", 12345), std::invalid_argument);
  EXPECT_THROW(serial::OpenSerialPort("/nonexistent/ttyUSB9", 115200), UnavailableError);
  EXPECT_THROW(serial::OpenSerialPort("/dev/null", 115200), UnavailableError);  // No tty.
}

}  // namespace
}  // namespace picking::gripper
