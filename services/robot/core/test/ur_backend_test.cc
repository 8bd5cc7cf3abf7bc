#include "services/robot/core/ur_backend.h"

#include <gtest/gtest.h>

#include <atomic>
#include <thread>

#include "services/robot/core/test/fake_ur_controller.h"

namespace picking::robot {
namespace {

class UrBackendTest : public ::testing::Test {
 protected:
  UrBackendTest()
      : model_(ur10::Ur10Model::Load(std::string(PICKING_DATA_DIR) + "/ur10")),
        kin_(model_),
        checker_(kin_, SafetyLimits::FromModel(model_,
                                               {"cell", {-1.5, -1.5, -0.5}, {1.5, 1.5, 1.6}}, 0.5)),
        fake_(kin_) {
    UrBackendOptions options;
    options.rtde_port = fake_.rtde_port();
    options.script_port = fake_.script_port();
    options.dashboard_port = fake_.dashboard_port();
    options.rtde_frequency_hz = 500.0;
    backend_ = UrBackend::Connect(options, checker_);
    EXPECT_TRUE(backend_->WaitForState(0.0, std::chrono::seconds(5)));
  }
  void PowerOn() { backend_->PowerOnAndReleaseBrakes(std::chrono::seconds(5)); }

  ur10::Ur10Model model_;
  ur10::Ur10Kinematics kin_;
  SafetyChecker checker_;
  testing::FakeUrController fake_;
  std::unique_ptr<UrBackend> backend_;
};

TEST_F(UrBackendTest, StateFromRtde) {
  const RobotState s = backend_->GetState();
  EXPECT_EQ(s.status, RobotStatus::kPoweredOff);
  EXPECT_NEAR(s.q_rad[0], 0.2, 1e-12);
  EXPECT_TRUE(s.X_BaseTool.isApprox(kin_.ForwardKinematics(s.q_rad)));
  EXPECT_GT(s.timestamp_s, 0.0);
}

TEST_F(UrBackendTest, MoveRejectedWhilePoweredOff) {
  const MotionResult r = backend_->MoveJoints(fake_.q(), 0.5, 1.0);
  EXPECT_EQ(r.outcome, MotionOutcome::kRejected);
  EXPECT_NE(r.message.find("POWERED_OFF"), std::string::npos) << r.message;
  EXPECT_TRUE(fake_.script_lines().empty());
}

TEST_F(UrBackendTest, MoveJointsReachesTarget) {
  PowerOn();
  EXPECT_EQ(fake_.dashboard_commands(), (std::vector<std::string>{"power on", "brake release"}));
  JointVector target = fake_.q();
  target[0] += 0.2;
  target[3] -= 0.1;
  const MotionResult r = backend_->MoveJoints(target, 1.0, 2.0);
  ASSERT_EQ(r.outcome, MotionOutcome::kCompleted) << r.message;
  EXPECT_LT((r.final_state.q_rad - target).cwiseAbs().maxCoeff(), 1e-3);
  ASSERT_EQ(fake_.script_lines().size(), 1u);
  EXPECT_EQ(fake_.script_lines()[0].rfind("movej([0.400000, -1.600000", 0), 0u)
      << fake_.script_lines()[0];
}

TEST_F(UrBackendTest, UnsafeTargetsAreRejectedBeforeSending) {
  PowerOn();
  JointVector target = fake_.q();
  target[2] = 3.5;  // beyond the elbow limit
  MotionResult r = backend_->MoveJoints(target, 0.5, 1.0);
  EXPECT_EQ(r.outcome, MotionOutcome::kRejected);
  EXPECT_NE(r.message.find("elbow_joint"), std::string::npos) << r.message;
  target = fake_.q();
  target[1] = std::nan("");
  EXPECT_EQ(backend_->MoveJoints(target, 0.5, 1.0).outcome, MotionOutcome::kRejected);
  EXPECT_EQ(backend_->MoveJoints(fake_.q(), 50.0, 1.0).outcome, MotionOutcome::kRejected);
  EXPECT_TRUE(fake_.script_lines().empty());
}

TEST_F(UrBackendTest, ExecuteTrajectoryReportsProgress) {
  PowerOn();
  const JointVector q0 = fake_.q();
  JointVector q1 = q0;
  q1[0] += 0.3;
  q1[4] += 0.2;
  TimeParametrizationOptions options;
  options.max_velocity_rad_s = model_.max_velocity_rad_s() * 0.2;  // TCP below 0.5 m/s
  options.max_acceleration_rad_s2 = model_.max_acceleration_rad_s2();
  const JointTrajectory trajectory = TimeParametrizePath({q0, q1}, options);
  std::vector<TrajectoryProgress> progress;
  const MotionResult r = backend_->ExecuteTrajectory(
      trajectory, [&](const TrajectoryProgress& p) { progress.push_back(p); });
  ASSERT_EQ(r.outcome, MotionOutcome::kCompleted) << r.message;
  ASSERT_FALSE(progress.empty());
  for (std::size_t i = 1; i < progress.size(); ++i) {
    EXPECT_GT(progress[i].waypoint_index, progress[i - 1].waypoint_index);
  }
  EXPECT_EQ(progress.back().waypoint_index, trajectory.points.size() - 1);
  EXPECT_DOUBLE_EQ(progress.back().fraction, 1.0);
  const auto lines = fake_.script_lines();
  EXPECT_EQ(lines.front(), "def picking_trajectory():");
  EXPECT_EQ(lines.back(), "end");
  EXPECT_EQ(lines.size(), trajectory.points.size() - 1 + 3);  // servoj lines + stopj + def/end
}

TEST_F(UrBackendTest, TrajectoryNotStartingAtRobotIsRejected) {
  PowerOn();
  JointVector q0 = fake_.q();
  q0[0] += 0.1;
  JointVector q1 = q0;
  q1[0] += 0.1;
  const JointTrajectory t = TimeParametrizePath({q0, q1}, {});
  const MotionResult r = backend_->ExecuteTrajectory(t, {});
  EXPECT_EQ(r.outcome, MotionOutcome::kRejected);
  EXPECT_NE(r.message.find("away from the current"), std::string::npos) << r.message;
}

TEST_F(UrBackendTest, GuardedMoveStopsOnContact) {
  PowerOn();
  const Eigen::Isometry3d X = kin_.ForwardKinematics(fake_.q());
  // Move along the tool z axis; place the surface 3 cm ahead if the axis points down.
  const Eigen::Vector3d axis = X.linear().col(2);
  ASSERT_LT(axis.z(), -0.5) << "start pose must point the tool down";
  fake_.set_surface_z(X.translation().z() - 0.03);
  GuardedMoveRequest request;
  request.max_distance_m = 0.1;
  request.speed_m_s = 0.05;
  request.force_threshold_n = 10.0;
  const MotionResult r = backend_->GuardedMove(request);
  ASSERT_EQ(r.outcome, MotionOutcome::kContact) << r.message;
  const double travelled = (r.final_state.X_BaseTool.translation() - X.translation()).dot(axis);
  EXPECT_GT(travelled, 0.025);
  EXPECT_LT(travelled, 0.05);
}

TEST_F(UrBackendTest, GuardedMoveWithoutContactCompletes) {
  PowerOn();
  GuardedMoveRequest request;
  request.max_distance_m = 0.04;
  request.speed_m_s = 0.05;
  const MotionResult r = backend_->GuardedMove(request);
  EXPECT_EQ(r.outcome, MotionOutcome::kCompleted) << r.message;
  request.force_threshold_n = -1.0;
  EXPECT_EQ(backend_->GuardedMove(request).outcome, MotionOutcome::kRejected);
  request.force_threshold_n = 10.0;
  request.direction_tcp = Eigen::Vector3d(0.0, 0.0, 2.0);  // not a unit vector
  const MotionResult bad = backend_->GuardedMove(request);
  EXPECT_EQ(bad.outcome, MotionOutcome::kRejected);
  EXPECT_NE(bad.message.find("unit vector"), std::string::npos) << bad.message;
}

TEST_F(UrBackendTest, GuardedMoveFollowsTheRequestedToolDirection) {
  PowerOn();
  const Eigen::Isometry3d X = kin_.ForwardKinematics(fake_.q());
  GuardedMoveRequest request;
  request.direction_tcp = Eigen::Vector3d::UnitX();
  request.max_distance_m = 0.03;
  request.speed_m_s = 0.05;
  const MotionResult r = backend_->GuardedMove(request);
  ASSERT_EQ(r.outcome, MotionOutcome::kCompleted) << r.message;
  const Eigen::Vector3d moved = r.final_state.X_BaseTool.translation() - X.translation();
  // Along the tool's x axis, not its z axis.
  EXPECT_GT(moved.dot(X.linear().col(0)), 0.02);
  EXPECT_LT(std::abs(moved.dot(X.linear().col(2))), 0.005);
}

TEST_F(UrBackendTest, ProtectiveStopInterruptsAndResets) {
  PowerOn();
  std::string reason;
  EXPECT_FALSE(backend_->ResetProtectiveStop(&reason));
  EXPECT_NE(reason.find("Cannot unlock"), std::string::npos) << reason;
  JointVector target = fake_.q();
  target[0] += 1.0;
  std::atomic<bool> triggered{false};
  std::thread stopper([&] {
    // Trigger once the robot is seen moving.
    while (backend_->GetState().status != RobotStatus::kMoving) {
      backend_->WaitForState(backend_->GetState().timestamp_s, std::chrono::seconds(1));
    }
    backend_->ProtectiveStop();
    triggered = true;
  });
  const MotionResult r = backend_->MoveJoints(target, 0.3, 1.0);
  stopper.join();
  EXPECT_TRUE(triggered);
  EXPECT_EQ(r.outcome, MotionOutcome::kProtectiveStop) << r.message;
  EXPECT_EQ(backend_->MoveJoints(target, 0.3, 1.0).outcome, MotionOutcome::kRejected);
  EXPECT_TRUE(backend_->ResetProtectiveStop(&reason)) << reason;
  backend_->WaitForState(backend_->GetState().timestamp_s, std::chrono::seconds(1));
  backend_->WaitForState(backend_->GetState().timestamp_s, std::chrono::seconds(1));
  EXPECT_EQ(backend_->GetState().status, RobotStatus::kReady);
}

TEST_F(UrBackendTest, StopFromAnotherThread) {
  PowerOn();
  JointVector target = fake_.q();
  target[0] += 1.0;
  std::thread stopper([&] {
    while (backend_->GetState().status != RobotStatus::kMoving) {
      backend_->WaitForState(backend_->GetState().timestamp_s, std::chrono::seconds(1));
    }
    backend_->Stop();
  });
  const MotionResult r = backend_->MoveJoints(target, 0.3, 1.0);
  stopper.join();
  EXPECT_EQ(r.outcome, MotionOutcome::kStopped) << r.message;
  EXPECT_GT((r.final_state.q_rad - target).cwiseAbs().maxCoeff(), 0.1);
  EXPECT_EQ(fake_.script_lines().back(), "stopj(3.000000)");
}

}  // namespace
}  // namespace picking::robot
