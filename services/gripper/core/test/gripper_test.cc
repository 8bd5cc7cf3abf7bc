#include "services/gripper/core/gripper.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <memory>
#include <stdexcept>

#include "libs/errors/errors.h"
#include "services/gripper/core/testing/fake_clock.h"

namespace picking::gripper {
namespace {

using testing::FakeClock;

// A pump whose vacuum rises exponentially (time constant tau_s) toward sealed_kpa when an
// item is under the cup, or open_kpa without one, on the fake clock's time.
class FakeBackend final : public GripperBackend {
 public:
  struct Calls {
    int set_vacuum = 0;
    int read = 0;
    int set_joint_mode = 0;
    JointMode last_mode = JointMode::kUnactuated;
    double last_angle_rad = 0.0;
  };

  FakeBackend(std::shared_ptr<FakeClock> clock, std::shared_ptr<Calls> calls)
      : clock_(std::move(clock)), calls_(std::move(calls)) {}

  bool item = true;
  double sealed_kpa = 30.0;
  double open_kpa = 4.0;
  double tau_s = 0.1;
  bool unavailable = false;

  std::string name() const override { return "fake"; }
  void SetVacuum(bool on) override {
    if (unavailable) throw UnavailableError("fake pump unplugged");
    ++calls_->set_vacuum;
    on_ = on;
    on_since_ = clock_->Now();
  }
  GripperReading Read() override {
    if (unavailable) throw UnavailableError("fake pump unplugged");
    ++calls_->read;
    GripperReading r;
    r.vacuum_on = on_;
    if (on_) {
      const double t = std::chrono::duration<double>(clock_->Now() - on_since_).count();
      r.vacuum_kpa = (item ? sealed_kpa : open_kpa) * (1.0 - std::exp(-t / tau_s));
    }
    r.joint_mode = calls_->last_mode;
    r.joint_angle_rad = calls_->last_angle_rad;
    r.gravity_head_m_s2 = Eigen::Vector3d(0, 0, kGravity_m_s2);
    return r;
  }
  void SetJointMode(JointMode mode, double angle_rad) override {
    ++calls_->set_joint_mode;
    calls_->last_mode = mode;
    calls_->last_angle_rad = angle_rad;
  }

 private:
  std::shared_ptr<FakeClock> clock_;
  std::shared_ptr<Calls> calls_;
  bool on_ = false;
  FakeClock::time_point on_since_{};
};

class GripperTest : public ::testing::Test {
 protected:
  std::unique_ptr<Gripper> Make(GripperKind kind, bool item = true) {
    auto backend = std::make_unique<FakeBackend>(clock_, calls_);
    backend->item = item;
    backend_ = backend.get();
    GripperOptions options;
    options.kind = kind;
    return std::make_unique<Gripper>(std::move(backend), options, clock_);
  }

  std::shared_ptr<FakeClock> clock_ = std::make_shared<FakeClock>();
  std::shared_ptr<FakeBackend::Calls> calls_ = std::make_shared<FakeBackend::Calls>();
  FakeBackend* backend_ = nullptr;
};

TEST_F(GripperTest, WaitForSealReturnsOnceTheVacuumCrossesTheThreshold) {
  auto gripper = Make(GripperKind::kTote);
  const GripperState state = gripper->SetVacuum(true, 2.0);
  EXPECT_TRUE(state.item_attached);
  EXPECT_TRUE(state.reading.vacuum_on);
  EXPECT_GE(state.reading.vacuum_kpa, 15.0);
  // 30 * (1 - exp(-t / 0.1)) reaches 15 kPa at t = 0.1 ln 2 = 69 ms: the wait ends at the
  // first 20 ms poll after that.
  EXPECT_NEAR(clock_->elapsed_s(), 0.08, 1e-9);
  EXPECT_EQ(state.backend, "fake");
  EXPECT_EQ(state.kind, GripperKind::kTote);
}

TEST_F(GripperTest, AGripperThatNeverReachesVacuumTimesOutWithThePumpStillOn) {
  auto gripper = Make(GripperKind::kTote, /*item=*/false);
  try {
    gripper->SetVacuum(true, 0.5);
    FAIL() << "expected TimeoutError";
  } catch (const TimeoutError& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find("15.0 kPa"), std::string::npos) << message;
    EXPECT_NE(message.find("last reading 4.0 kPa"), std::string::npos) << message;
  }
  EXPECT_NEAR(clock_->elapsed_s(), 0.5, 1e-9);  // Waited exactly the timeout.
  const GripperState state = gripper->State();
  EXPECT_TRUE(state.reading.vacuum_on);
  EXPECT_FALSE(state.item_attached);
}

TEST_F(GripperTest, ACancelledWaitEndsBeforeItsTimeout) {
  auto gripper = Make(GripperKind::kTote, /*item=*/false);
  int asked = 0;
  EXPECT_THROW(gripper->SetVacuum(true, 5.0, [&] { return ++asked == 3; }), UnavailableError);
  EXPECT_EQ(asked, 3);
  EXPECT_NEAR(clock_->elapsed_s(), 0.04, 1e-9);  // Two polls, then cancelled.
  EXPECT_TRUE(gripper->State().reading.vacuum_on);
}

TEST_F(GripperTest, NoWaitReturnsAtOnceAndVacuumOffDetaches) {
  auto gripper = Make(GripperKind::kTote);
  GripperState state = gripper->SetVacuum(true);
  EXPECT_FALSE(state.item_attached);  // No time has passed: no vacuum yet.
  EXPECT_EQ(clock_->sleeps(), 0);
  clock_->SleepFor(std::chrono::seconds(1));
  EXPECT_TRUE(gripper->State().item_attached);
  state = gripper->SetVacuum(false, 3.0);  // The wait applies to switching on only.
  EXPECT_FALSE(state.item_attached);
  EXPECT_FALSE(state.reading.vacuum_on);
}

TEST_F(GripperTest, RejectsBadWaitsWithoutTouchingThePump) {
  auto gripper = Make(GripperKind::kTote);
  EXPECT_THROW(gripper->SetVacuum(true, std::nan("")), std::invalid_argument);
  EXPECT_THROW(gripper->SetVacuum(true, -0.1), std::invalid_argument);
  EXPECT_THROW(gripper->SetVacuum(true, 10.5), std::invalid_argument);
  EXPECT_THROW(gripper->SetVacuum(true, std::numeric_limits<double>::infinity()),
               std::invalid_argument);
  EXPECT_EQ(calls_->set_vacuum, 0);
}

TEST_F(GripperTest, ShelfGripperHasNoJoint) {
  auto gripper = Make(GripperKind::kShelf);
  EXPECT_THROW(gripper->SetJointMode(JointMode::kKeepVertical), PreconditionError);
  EXPECT_THROW(gripper->SetJointMode(JointMode::kFixed, 0.2), PreconditionError);
  EXPECT_EQ(calls_->set_joint_mode, 0);
  const GripperState state = gripper->State();
  EXPECT_EQ(state.kind, GripperKind::kShelf);
  EXPECT_EQ(state.reading.joint_angle_rad, 0.0);
}

TEST_F(GripperTest, ToteGripperValidatesJointAngles) {
  auto gripper = Make(GripperKind::kTote);
  EXPECT_THROW(gripper->SetJointMode(JointMode::kFixed, std::nan("")), std::invalid_argument);
  EXPECT_THROW(gripper->SetJointMode(JointMode::kKeepVertical, std::nan("")),
               std::invalid_argument);
  EXPECT_THROW(gripper->SetJointMode(JointMode::kFixed, 1.6), std::invalid_argument);
  EXPECT_THROW(gripper->SetJointMode(JointMode::kFixed, -1.6), std::invalid_argument);
  EXPECT_EQ(calls_->set_joint_mode, 0);

  GripperState state = gripper->SetJointMode(JointMode::kFixed, -0.75);
  EXPECT_EQ(calls_->last_mode, JointMode::kFixed);
  EXPECT_DOUBLE_EQ(calls_->last_angle_rad, -0.75);
  EXPECT_EQ(state.reading.joint_mode, JointMode::kFixed);
  // The angle is irrelevant outside fixed mode, so a large one is accepted and not sent.
  state = gripper->SetJointMode(JointMode::kKeepVertical, 3.0);
  EXPECT_EQ(calls_->last_mode, JointMode::kKeepVertical);
  EXPECT_DOUBLE_EQ(calls_->last_angle_rad, 0.0);
  gripper->SetJointMode(JointMode::kUnactuated);
  EXPECT_EQ(calls_->last_mode, JointMode::kUnactuated);
  EXPECT_EQ(calls_->set_joint_mode, 3);
}

TEST_F(GripperTest, BackendErrorsPassThrough) {
  auto gripper = Make(GripperKind::kTote);
  backend_->unavailable = true;
  EXPECT_THROW(gripper->SetVacuum(true, 1.0), UnavailableError);
  EXPECT_THROW(gripper->State(), UnavailableError);
}

TEST(GripperOptionsTest, RejectsBadOptions) {
  auto clock = std::make_shared<FakeClock>();
  auto calls = std::make_shared<FakeBackend::Calls>();
  GripperOptions options;
  options.poll_interval_s = 0.0;
  EXPECT_THROW(Gripper(std::make_unique<FakeBackend>(clock, calls), options, clock),
               std::invalid_argument);
  options = GripperOptions();
  options.seal = SealOptions{5.0, 8.0};
  EXPECT_THROW(Gripper(std::make_unique<FakeBackend>(clock, calls), options, clock),
               std::invalid_argument);
  EXPECT_THROW(Gripper(nullptr, GripperOptions(), clock), std::invalid_argument);
}

}  // namespace
}  // namespace picking::gripper
