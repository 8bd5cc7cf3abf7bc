#include "services/robot/core/sim_backend.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <functional>
#include <mutex>

#include "libs/errors/errors.h"

namespace picking::robot {
namespace {

// An in-process world: an obstacle box the tool flange must not enter, a horizontal
// surface (stiffness 2000 N/m) the TCP can press on, and a record of every placement.
class FakeArm final : public SimulatedArm {
 public:
  explicit FakeArm(const ur10::Ur10Kinematics& kin) : kin_(kin) {
    q_ << 0.2, -1.6, 1.8, -1.8, -1.57, 0.3;
  }

  JointVector ReadJoints() override {
    std::lock_guard<std::mutex> lock(mutex_);
    if (unreachable_) throw UnavailableError("connection refused");
    return q_;
  }
  ArmPlacement PlaceArm(const JointVector& q) override {
    std::function<void(std::size_t)> hook;
    std::size_t count = 0;
    ArmPlacement placement;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (unreachable_) throw UnavailableError("connection refused");
      q_ = q;
      placements_.push_back(q);
      const Eigen::Vector3d p = kin_.ForwardKinematics(q).translation();
      if (has_obstacle_ && (p.array() >= obstacle_min_.array()).all() &&
          (p.array() <= obstacle_max_.array()).all()) {
        placement.in_collision = true;
        placement.collision_detail = "wrist_3_link hit the obstacle";
        ++collisions_;
      }
      if (p.z() < surface_z_) {
        placement.in_collision = true;
        placement.collision_detail = "suction cup touches the surface";
      }
      hook = hook_;
      count = placements_.size();
    }
    if (hook) hook(count);
    return placement;
  }
  ContactProbe Probe(const Eigen::Isometry3d& X_BaseTool, const Eigen::Vector3d& direction_tcp,
                     double max_distance_m) override {
    std::lock_guard<std::mutex> lock(mutex_);
    ++probes_;
    ContactProbe probe;
    const Eigen::Vector3d axis = X_BaseTool.linear() * direction_tcp;
    const double height = X_BaseTool.translation().z() - surface_z_;
    if (axis.z() < -1e-9 && height >= 0.0 && height / -axis.z() <= max_distance_m) {
      probe.contact = true;
      probe.distance_m = height / -axis.z();
      probe.stiffness_n_per_m = 2000.0;
      probe.what = "surface";
    }
    return probe;
  }

  void SetObstacle(const Eigen::Vector3d& min, const Eigen::Vector3d& max) {
    std::lock_guard<std::mutex> lock(mutex_);
    has_obstacle_ = true;
    obstacle_min_ = min;
    obstacle_max_ = max;
  }
  void ClearObstacle() {
    std::lock_guard<std::mutex> lock(mutex_);
    has_obstacle_ = false;
  }
  void set_surface_z(double z) {
    std::lock_guard<std::mutex> lock(mutex_);
    surface_z_ = z;
  }
  void set_unreachable(bool v) {
    std::lock_guard<std::mutex> lock(mutex_);
    unreachable_ = v;
  }
  void set_hook(std::function<void(std::size_t)> hook) {
    std::lock_guard<std::mutex> lock(mutex_);
    hook_ = std::move(hook);
  }
  JointVector q() {
    std::lock_guard<std::mutex> lock(mutex_);
    return q_;
  }
  std::vector<JointVector> placements() {
    std::lock_guard<std::mutex> lock(mutex_);
    return placements_;
  }
  int probes() {
    std::lock_guard<std::mutex> lock(mutex_);
    return probes_;
  }

 private:
  ur10::Ur10Kinematics kin_;
  std::mutex mutex_;
  JointVector q_;
  std::vector<JointVector> placements_;
  bool has_obstacle_ = false;
  Eigen::Vector3d obstacle_min_, obstacle_max_;
  double surface_z_ = -10.0;
  bool unreachable_ = false;
  int collisions_ = 0;
  int probes_ = 0;
  std::function<void(std::size_t)> hook_;
};

class SimBackendTest : public ::testing::Test {
 protected:
  SimBackendTest()
      : model_(ur10::Ur10Model::Load(std::string(PICKING_DATA_DIR) + "/ur10")),
        kin_(model_),
        checker_(kin_, SafetyLimits::FromModel(model_,
                                               {"cell", {-1.5, -1.5, -0.5}, {1.5, 1.5, 1.6}}, 0.5)),
        arm_(std::make_shared<FakeArm>(kin_)) {
    SimBackendOptions options;
    options.time_scale = 1e4;  // fast; pacing is not what these tests check
    options.command_rate_hz = 50.0;
    backend_ = std::make_unique<SimBackend>(arm_, checker_, options);
  }

  ur10::Ur10Model model_;
  ur10::Ur10Kinematics kin_;
  SafetyChecker checker_;
  std::shared_ptr<FakeArm> arm_;
  std::unique_ptr<SimBackend> backend_;
};

TEST_F(SimBackendTest, StateIsReadFromTheWorld) {
  const RobotState s = backend_->GetState();
  EXPECT_EQ(s.status, RobotStatus::kReady);
  EXPECT_TRUE(s.q_rad.isApprox(arm_->q()));
  EXPECT_TRUE(s.X_BaseTool.isApprox(kin_.ForwardKinematics(s.q_rad)));
}

TEST_F(SimBackendTest, MoveJointsStreamsTheInterpolatedTrajectory) {
  JointVector target = arm_->q();
  target[0] += 0.4;
  target[3] -= 0.2;
  const MotionResult r = backend_->MoveJoints(target, 0.5, 1.0);
  ASSERT_EQ(r.outcome, MotionOutcome::kCompleted) << r.message;
  EXPECT_LT((r.final_state.q_rad - target).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_EQ(r.final_state.status, RobotStatus::kReady);
  const auto placements = arm_->placements();
  // Trapezoid over 0.4 rad at 0.5 rad/s, 1 rad/s^2: 1.3 s, sampled at 50 Hz.
  EXPECT_NEAR(static_cast<double>(placements.size()), 1.3 * 50.0, 1.5);
  JointVector previous = placements.front();
  for (const JointVector& q : placements) {
    EXPECT_LE((q - previous).cwiseAbs().maxCoeff(), 0.5 / 50.0 + 1e-9);
    previous = q;
  }
  EXPECT_TRUE(arm_->q().isApprox(target));
}

TEST_F(SimBackendTest, UnsafeTargetsAreRejectedWithoutPlacingTheArm) {
  JointVector target = arm_->q();
  target[2] = 3.5;
  MotionResult r = backend_->MoveJoints(target, 0.5, 1.0);
  EXPECT_EQ(r.outcome, MotionOutcome::kRejected);
  EXPECT_NE(r.message.find("elbow_joint"), std::string::npos) << r.message;
  target = arm_->q();
  target[1] = std::nan("");
  EXPECT_EQ(backend_->MoveJoints(target, 0.5, 1.0).outcome, MotionOutcome::kRejected);
  EXPECT_EQ(backend_->MoveJoints(arm_->q(), 50.0, 1.0).outcome, MotionOutcome::kRejected);
  EXPECT_TRUE(arm_->placements().empty());
}

TEST_F(SimBackendTest, CollisionIsAProtectiveStopNamingWhatHit) {
  const JointVector start = arm_->q();
  JointVector target = start;
  target[0] += 0.6;
  // An obstacle around the flange's position halfway along the move.
  JointVector mid = start;
  mid[0] += 0.3;
  const Eigen::Vector3d p_mid = kin_.ForwardKinematics(mid).translation();
  arm_->SetObstacle(p_mid - Eigen::Vector3d::Constant(0.03),
                    p_mid + Eigen::Vector3d::Constant(0.03));
  const MotionResult r = backend_->MoveJoints(target, 0.5, 1.0);
  ASSERT_EQ(r.outcome, MotionOutcome::kProtectiveStop) << r.message;
  EXPECT_NE(r.message.find("wrist_3_link hit the obstacle"), std::string::npos) << r.message;
  EXPECT_EQ(backend_->GetState().status, RobotStatus::kProtectiveStop);
  // The arm rests at the last collision-free sample, short of the obstacle.
  const Eigen::Vector3d p = kin_.ForwardKinematics(arm_->q()).translation();
  EXPECT_GT((p - p_mid).cwiseAbs().maxCoeff(), 0.03);
  EXPECT_TRUE(backend_->GetState().q_rad.isApprox(arm_->q()));

  // Moves are refused until the stop is reset.
  const std::size_t placed = arm_->placements().size();
  const MotionResult refused = backend_->MoveJoints(start, 0.5, 1.0);
  EXPECT_EQ(refused.outcome, MotionOutcome::kRejected);
  EXPECT_NE(refused.message.find("PROTECTIVE_STOP"), std::string::npos) << refused.message;
  std::string reason;
  EXPECT_TRUE(backend_->ResetProtectiveStop(&reason)) << reason;
  EXPECT_EQ(backend_->GetState().status, RobotStatus::kReady);
  EXPECT_GT(arm_->placements().size(), placed);  // the reset checked the pose
  const MotionResult back = backend_->MoveJoints(start, 0.5, 1.0);
  EXPECT_EQ(back.outcome, MotionOutcome::kCompleted) << back.message;
}

TEST_F(SimBackendTest, ResetIsRefusedWhileTheArmIsInCollision) {
  std::string reason;
  EXPECT_FALSE(backend_->ResetProtectiveStop(&reason));
  EXPECT_NE(reason.find("not in a protective stop"), std::string::npos) << reason;
  backend_->ProtectiveStop();
  const Eigen::Vector3d p = kin_.ForwardKinematics(arm_->q()).translation();
  arm_->SetObstacle(p - Eigen::Vector3d::Constant(0.01), p + Eigen::Vector3d::Constant(0.01));
  EXPECT_FALSE(backend_->ResetProtectiveStop(&reason));
  EXPECT_NE(reason.find("still in collision: wrist_3_link"), std::string::npos) << reason;
  EXPECT_EQ(backend_->GetState().status, RobotStatus::kProtectiveStop);
  arm_->ClearObstacle();
  EXPECT_TRUE(backend_->ResetProtectiveStop(&reason)) << reason;
}

TEST_F(SimBackendTest, StopDeceleratesToRestShortOfTheTarget) {
  JointVector target = arm_->q();
  target[0] += 1.0;
  arm_->set_hook([this](std::size_t n) {
    if (n == 40) backend_->Stop();
  });
  const MotionResult r = backend_->MoveJoints(target, 0.5, 1.0);
  ASSERT_EQ(r.outcome, MotionOutcome::kStopped) << r.message;
  EXPECT_GT((r.final_state.q_rad - target).cwiseAbs().maxCoeff(), 0.1);
  EXPECT_EQ(r.final_state.qd_rad_s.norm(), 0.0);
  // Braking from 0.5 rad/s at 3 rad/s^2 takes 1/6 s: about 9 more samples at 50 Hz.
  const auto placements = arm_->placements();
  EXPECT_GE(placements.size(), 40u + 8u);
  EXPECT_LE(placements.size(), 40u + 10u);
  // Joint steps shrink while braking.
  const std::size_t n = placements.size();
  EXPECT_LT((placements[n - 1] - placements[n - 2]).norm(),
            (placements[41] - placements[40]).norm());
  EXPECT_EQ(backend_->GetState().status, RobotStatus::kReady);
}

TEST_F(SimBackendTest, ProtectiveStopFromAnotherThreadLatches) {
  JointVector target = arm_->q();
  target[0] += 1.0;
  arm_->set_hook([this](std::size_t n) {
    if (n == 10) backend_->ProtectiveStop();
  });
  const MotionResult r = backend_->MoveJoints(target, 0.5, 1.0);
  EXPECT_EQ(r.outcome, MotionOutcome::kProtectiveStop) << r.message;
  EXPECT_EQ(arm_->placements().size(), 10u);  // stops at once
  EXPECT_EQ(backend_->GetState().status, RobotStatus::kProtectiveStop);
  EXPECT_EQ(backend_->MoveJoints(target, 0.5, 1.0).outcome, MotionOutcome::kRejected);
  arm_->set_hook({});
  std::string reason;
  EXPECT_TRUE(backend_->ResetProtectiveStop(&reason)) << reason;
  EXPECT_EQ(backend_->MoveJoints(target, 0.5, 1.0).outcome, MotionOutcome::kCompleted);
}

TEST_F(SimBackendTest, ExecuteTrajectoryReportsIncreasingProgress) {
  const JointVector q0 = arm_->q();
  JointVector q1 = q0;
  q1[0] += 0.3;
  q1[4] += 0.2;
  TimeParametrizationOptions options;
  options.max_velocity_rad_s = model_.max_velocity_rad_s() * 0.2;
  options.max_acceleration_rad_s2 = model_.max_acceleration_rad_s2();
  const JointTrajectory trajectory = TimeParametrizePath({q0, q1}, options);
  std::vector<TrajectoryProgress> progress;
  const MotionResult r = backend_->ExecuteTrajectory(
      trajectory, [&](const TrajectoryProgress& p) { progress.push_back(p); });
  ASSERT_EQ(r.outcome, MotionOutcome::kCompleted) << r.message;
  ASSERT_GE(progress.size(), 2u);
  for (std::size_t i = 1; i < progress.size(); ++i) {
    EXPECT_GT(progress[i].waypoint_index, progress[i - 1].waypoint_index);
    EXPECT_GT(progress[i].fraction, progress[i - 1].fraction);
  }
  EXPECT_EQ(progress.back().waypoint_index, trajectory.points.size() - 1);
  EXPECT_DOUBLE_EQ(progress.back().fraction, 1.0);
  EXPECT_TRUE(r.final_state.q_rad.isApprox(q1));
}

TEST_F(SimBackendTest, TrajectoryNotStartingAtTheArmIsRejected) {
  JointVector q0 = arm_->q();
  q0[0] += 0.1;
  JointVector q1 = q0;
  q1[0] += 0.1;
  const MotionResult r = backend_->ExecuteTrajectory(TimeParametrizePath({q0, q1}, {}), {});
  EXPECT_EQ(r.outcome, MotionOutcome::kRejected);
  EXPECT_NE(r.message.find("away from the current"), std::string::npos) << r.message;
  EXPECT_TRUE(arm_->placements().empty());
}

TEST_F(SimBackendTest, GuardedMovePressesUntilTheForceThreshold) {
  const Eigen::Isometry3d X = kin_.ForwardKinematics(arm_->q());
  ASSERT_LT(X.linear().col(2).z(), -0.99) << "start pose must point the tool down";
  arm_->set_surface_z(X.translation().z() - 0.03);
  GuardedMoveRequest request;
  request.max_distance_m = 0.1;
  request.speed_m_s = 0.05;
  request.force_threshold_n = 10.0;
  const MotionResult r = backend_->GuardedMove(request);
  ASSERT_EQ(r.outcome, MotionOutcome::kContact) << r.message;
  EXPECT_EQ(arm_->probes(), 1);
  // First touch after 3 cm of height (the axis is slightly tilted), then 10 N / 2000 N/m =
  // 5 mm of press.
  const Eigen::Vector3d axis = X.linear().col(2);
  const double travelled = (r.final_state.X_BaseTool.translation() - X.translation()).dot(axis);
  EXPECT_NEAR(travelled, 0.03 / -axis.z() + 0.005, 1e-9);
  EXPECT_NEAR(-r.final_state.wrench_base.head<3>().dot(axis), 10.0, 1e-3);
  EXPECT_NE(r.message.find("contact with surface"), std::string::npos) << r.message;
  EXPECT_EQ(backend_->GetState().status, RobotStatus::kReady);
}

TEST_F(SimBackendTest, GuardedMoveWithoutEnoughTravelReportsNoContact) {
  const Eigen::Isometry3d X = kin_.ForwardKinematics(arm_->q());
  // Touches after 38 mm of 40 mm: 2 mm of press give 4 N, below the 10 N threshold.
  arm_->set_surface_z(X.translation().z() - 0.038);
  GuardedMoveRequest request;
  request.max_distance_m = 0.04;
  request.speed_m_s = 0.05;
  request.force_threshold_n = 10.0;
  const MotionResult r = backend_->GuardedMove(request);
  ASSERT_EQ(r.outcome, MotionOutcome::kCompleted) << r.message;
  const Eigen::Vector3d axis = X.linear().col(2);
  const double press_m = 0.04 - 0.038 / -axis.z();
  EXPECT_NEAR(-r.final_state.wrench_base.head<3>().dot(axis), 2000.0 * press_m, 1e-6);
  EXPECT_LT(2000.0 * press_m, 10.0);
}

TEST_F(SimBackendTest, GuardedMoveAlongAnotherToolDirection) {
  // Along -z of the tool (upward here): no surface that way, full distance, no force.
  const Eigen::Isometry3d X = kin_.ForwardKinematics(arm_->q());
  arm_->set_surface_z(X.translation().z() - 0.03);
  GuardedMoveRequest request;
  request.direction_tcp = -Eigen::Vector3d::UnitZ();
  request.max_distance_m = 0.05;
  const MotionResult r = backend_->GuardedMove(request);
  ASSERT_EQ(r.outcome, MotionOutcome::kCompleted) << r.message;
  EXPECT_NEAR((r.final_state.X_BaseTool.translation() - X.translation()).norm(), 0.05, 1e-9);
  EXPECT_GT(r.final_state.X_BaseTool.translation().z() - X.translation().z(), 0.049);
  EXPECT_EQ(r.final_state.wrench_base.norm(), 0.0);
  request.direction_tcp = Eigen::Vector3d(0.0, 0.0, 2.0);
  EXPECT_EQ(backend_->GuardedMove(request).outcome, MotionOutcome::kRejected);
}

TEST_F(SimBackendTest, UnreachableWorldFailsAndIsReadAgainLater) {
  arm_->set_unreachable(true);
  EXPECT_THROW(backend_->GetState(), UnavailableError);
  JointVector target = arm_->q();
  target[0] += 0.1;
  const MotionResult r = backend_->MoveJoints(target, 0.5, 1.0);
  EXPECT_EQ(r.outcome, MotionOutcome::kFailed);
  EXPECT_NE(r.message.find("simulator unreachable"), std::string::npos) << r.message;
  arm_->set_unreachable(false);
  EXPECT_EQ(backend_->MoveJoints(target, 0.5, 1.0).outcome, MotionOutcome::kCompleted);
}

TEST_F(SimBackendTest, GetStateReportsAWorldThatStoppedAnswering) {
  std::chrono::steady_clock::time_point now{};
  SimBackendOptions options;
  options.time_scale = 1e4;
  options.link_check_period_s = 0.5;
  options.now = [&now] { return now; };
  SimBackend backend(arm_, checker_, options);
  ASSERT_EQ(backend.GetState().status, RobotStatus::kReady);
  arm_->set_unreachable(true);
  // Within the period the world's last answer stands.
  now += std::chrono::milliseconds(400);
  EXPECT_EQ(backend.GetState().status, RobotStatus::kReady);
  // After it the world is asked, and its silence reported rather than the stale state.
  now += std::chrono::milliseconds(200);
  try {
    backend.GetState();
    ADD_FAILURE() << "GetState answered while the world was unreachable";
  } catch (const UnavailableError& e) {
    EXPECT_NE(std::string(e.what()).find("connection refused"), std::string::npos) << e.what();
  }
  // And at every call until it answers again; then the arm is read again.
  EXPECT_THROW(backend.GetState(), UnavailableError);
  arm_->set_unreachable(false);
  const RobotState back = backend.GetState();
  EXPECT_EQ(back.status, RobotStatus::kReady);
  EXPECT_TRUE(back.q_rad.isApprox(arm_->q()));
}

TEST_F(SimBackendTest, AMotionKeepsTheLinkFreshWithoutExtraReads) {
  std::chrono::steady_clock::time_point now{};
  SimBackendOptions options;
  options.time_scale = 1e4;
  options.link_check_period_s = 0.5;
  options.now = [&now] { return now; };
  SimBackend backend(arm_, checker_, options);
  ASSERT_EQ(backend.GetState().status, RobotStatus::kReady);
  now += std::chrono::seconds(1);
  JointVector target = arm_->q();
  target[0] += 0.1;
  ASSERT_EQ(backend.MoveJoints(target, 0.5, 1.0).outcome, MotionOutcome::kCompleted);
  // The motion's placements were the world's answers: no check is due.
  arm_->set_unreachable(true);
  EXPECT_EQ(backend.GetState().status, RobotStatus::kReady);
  now += std::chrono::seconds(1);
  EXPECT_THROW(backend.GetState(), UnavailableError);
}

TEST(SampleTrajectoryTest, InterpolatesAndClamps) {
  JointTrajectory t;
  TrajectoryPoint a, b;
  b.time_s = 2.0;
  b.q_rad = JointVector::Constant(1.0);
  t.points = {a, b};
  JointVector q, qd;
  SampleTrajectory(t, 0.5, &q, &qd);
  EXPECT_TRUE(q.isApprox(JointVector::Constant(0.25)));
  EXPECT_TRUE(qd.isApprox(JointVector::Constant(0.5)));
  SampleTrajectory(t, 3.0, &q, &qd);
  EXPECT_TRUE(q.isApprox(JointVector::Constant(1.0)));
  EXPECT_EQ(qd.norm(), 0.0);
  SampleTrajectory(t, -1.0, &q, &qd);
  EXPECT_EQ(q.norm(), 0.0);
}

TEST(SimBackendOptionsTest, Validates) {
  SimBackendOptions options;
  options.time_scale = 0.0;
  EXPECT_THROW(options.Validate(), std::invalid_argument);
  options = {};
  options.command_rate_hz = std::nan("");
  EXPECT_THROW(options.Validate(), std::invalid_argument);
  options = {};
  options.link_check_period_s = -1.0;
  EXPECT_THROW(options.Validate(), std::invalid_argument);
  options = {};
  options.now = nullptr;
  EXPECT_THROW(options.Validate(), std::invalid_argument);
}

}  // namespace
}  // namespace picking::robot
