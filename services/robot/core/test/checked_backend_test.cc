// The safety layer every backend sits behind (CheckedBackend): what it refuses before the
// backend moves, the same for the simulated arm and the real one.
#include "services/robot/core/checked_backend.h"

#include <gtest/gtest.h>

#include <string>

namespace picking::robot {
namespace {

// A backend whose arm stands at `q` and records what it was asked to run.
class RecordingBackend final : public CheckedBackend {
 public:
  RecordingBackend(const SafetyChecker& checker, const JointVector& q)
      : CheckedBackend(MotionCheckOptions{}), checker_(checker), q_(q) {}
  RobotState GetState() override {
    RobotState s;
    s.q_rad = q_;
    s.X_BaseTool = checker_.kinematics().ForwardKinematics(q_);
    s.status = RobotStatus::kReady;
    return s;
  }
  void Stop() override {}
  void ProtectiveStop() override {}
  bool ResetProtectiveStop(std::string*) override { return true; }
  int runs = 0;

 protected:
  const SafetyChecker& CheckerForMotion() override { return checker_; }
  MotionResult Reject(const std::string& why) override {
    return {MotionOutcome::kRejected, why, GetState()};
  }
  MotionResult BeginMotion() override { return {MotionOutcome::kCompleted, "", GetState()}; }
  MotionResult RunJointMove(const MotionResult& begin, const JointVector&, double, double,
                            const JointTrajectory&) override {
    return Ran(begin);
  }
  MotionResult RunTrajectory(const MotionResult& begin, const JointTrajectory&,
                             const std::function<void(const TrajectoryProgress&)>&) override {
    return Ran(begin);
  }
  MotionResult RunGuardedMove(const MotionResult& begin, const GuardedMoveRequest&,
                              const GuardedMovePlan&) override {
    return Ran(begin);
  }

 private:
  MotionResult Ran(const MotionResult& begin) {
    ++runs;
    return begin;
  }
  const SafetyChecker& checker_;
  JointVector q_;
};

class CheckedBackendTest : public ::testing::Test {
 protected:
  CheckedBackendTest()
      : model_(ur10::Ur10Model::Load(std::string(PICKING_DATA_DIR) + "/ur10")), kin_(model_) {
    q0_ << 0.0, -1.2, 1.4, -1.7, -1.57, 0.0;
    q1_ = q0_;
    q1_[0] += 2.0;  // the base turns: the tcp sweeps an arc around the robot
  }
  // The model's limits, a workspace around the robot and, with `zone_at_middle`, a
  // forbidden box around where the tcp passes half-way through the turn.
  SafetyChecker Checker(bool zone_at_middle) const {
    SafetyLimits limits =
        SafetyLimits::FromModel(model_, {"cell", {-2.0, -2.0, -1.0}, {2.0, 2.0, 2.0}}, 0.5);
    if (zone_at_middle) {
      JointVector q_mid = q0_;
      q_mid[0] += 1.0;
      const Eigen::Vector3d p = kin_.ForwardKinematics(q_mid).translation();
      limits.forbidden_zones.push_back(
          {"post", p - Eigen::Vector3d::Constant(0.1), p + Eigen::Vector3d::Constant(0.1)});
    }
    return SafetyChecker(kin_, limits);
  }

  ur10::Ur10Model model_;
  ur10::Ur10Kinematics kin_;
  JointVector q0_, q1_;
};

TEST_F(CheckedBackendTest, AJointMoveIsCheckedAlongItsWholeLineNotOnlyAtItsTarget) {
  const SafetyChecker free = Checker(false);
  RecordingBackend backend_free(free, q0_);
  EXPECT_EQ(backend_free.MoveJoints(q1_, 0.5, 1.0).outcome, MotionOutcome::kCompleted);
  EXPECT_EQ(backend_free.runs, 1);
  // The start and the target are clear of the post; the line between them is not.
  const SafetyChecker post = Checker(true);
  ASSERT_TRUE(post.CheckJointTarget(q1_)) << post.CheckJointTarget(q1_).reason;
  RecordingBackend backend(post, q0_);
  const MotionResult r = backend.MoveJoints(q1_, 0.5, 1.0);
  EXPECT_EQ(r.outcome, MotionOutcome::kRejected);
  EXPECT_NE(r.message.find("post"), std::string::npos) << r.message;
  EXPECT_EQ(backend.runs, 0);
}

TEST_F(CheckedBackendTest, ATrajectoryMustStartWhereTheArmIs) {
  const SafetyChecker checker = Checker(false);
  RecordingBackend backend(checker, q0_);
  JointTrajectory trajectory;
  JointVector away = q0_;
  away[1] += 0.05;
  for (const double t : {0.0, 2.0}) {
    TrajectoryPoint point;
    point.time_s = t;
    point.q_rad = away;
    trajectory.points.push_back(point);
  }
  const MotionResult r = backend.ExecuteTrajectory(trajectory, {});
  EXPECT_EQ(r.outcome, MotionOutcome::kRejected);
  EXPECT_NE(r.message.find("away from the current joint positions"), std::string::npos);
  EXPECT_EQ(backend.runs, 0);
}

TEST_F(CheckedBackendTest, AGuardedMoveIsCheckedAlongItsLine) {
  const SafetyChecker checker = Checker(false);
  RecordingBackend backend(checker, q0_);
  GuardedMoveRequest request;
  request.max_distance_m = 0.05;
  EXPECT_EQ(backend.GuardedMove(request).outcome, MotionOutcome::kCompleted);
  request.max_distance_m = 5.0;  // out of the workspace
  const MotionResult r = backend.GuardedMove(request);
  EXPECT_EQ(r.outcome, MotionOutcome::kRejected);
  EXPECT_NE(r.message.find("guarded move"), std::string::npos) << r.message;
  EXPECT_EQ(backend.runs, 1);
}

}  // namespace
}  // namespace picking::robot
