#pragma once

#include <Eigen/Geometry>

#include <functional>
#include <mutex>
#include <string>

#include "services/robot/core/robot_backend.h"
#include "services/robot/core/safety.h"
#include "services/robot/core/trajectory.h"

namespace picking::robot {

/// Options of the safety layer (CheckedBackend).
struct MotionCheckOptions {
  /// Largest distance (rad, max over joints) between a trajectory's first point and the arm.
  double start_tolerance_rad = 0.01;
  /// Sample rate of the joint line a MoveJoints is checked along, Hz (> 0).
  double planning_rate_hz = 125.0;
};

/// A guarded move as the safety layer checked it: where the tcp starts and where the full
/// distance would take it.
struct GuardedMovePlan {
  Eigen::Vector3d direction_tcp = Eigen::Vector3d::UnitZ();  ///< Unit, the sign of the distance.
  Eigen::Vector3d axis_base = Eigen::Vector3d::UnitZ();      ///< direction_tcp in base.
  double distance_m = 0.0;                                   ///< >= 0.
  Eigen::Isometry3d X_BaseTool = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d X_BaseTcp = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d X_BaseTcp_goal = Eigen::Isometry3d::Identity();
};

/// The safety layer every backend sits behind. Each motion call, one at a time, is checked
/// against the backend's SafetyChecker (limits, workspace, forbidden zones), then the arm is
/// asked whether it may move (BeginMotion), then checked against where the arm is: a joint
/// move along its whole joint line, a trajectory's start within start_tolerance_rad, a
/// guarded move's straight line from the tcp. Only then does the backend move (Run*). A
/// motion refused on the way is kRejected with the reason and nothing moves.
class CheckedBackend : public RobotBackend {
 public:
  MotionResult MoveJoints(const JointVector& q_target_rad, double speed_rad_s,
                          double acceleration_rad_s2) final;
  MotionResult ExecuteTrajectory(
      const JointTrajectory& trajectory,
      const std::function<void(const TrajectoryProgress&)>& progress) final;
  MotionResult GuardedMove(const GuardedMoveRequest& request) final;

 protected:
  /// @throws std::invalid_argument for a non-positive or non-finite option.
  explicit CheckedBackend(const MotionCheckOptions& options);

  /// The checker for the motion about to start (a simulated gripper's head is read first).
  virtual const SafetyChecker& CheckerForMotion() = 0;
  /// A refusal: kRejected with `why` and the current state.
  virtual MotionResult Reject(const std::string& why) = 0;
  /// Synchronises with the arm and checks it is ready; kCompleted (with the arm's state) when
  /// it may move.
  virtual MotionResult BeginMotion() = 0;
  /// The moves themselves, checked; `begin` is BeginMotion's result.
  virtual MotionResult RunJointMove(const MotionResult& begin, const JointVector& q_target_rad,
                                    double speed_rad_s, double acceleration_rad_s2,
                                    const JointTrajectory& line) = 0;
  virtual MotionResult RunTrajectory(
      const MotionResult& begin, const JointTrajectory& trajectory,
      const std::function<void(const TrajectoryProgress&)>& progress) = 0;
  virtual MotionResult RunGuardedMove(const MotionResult& begin, const GuardedMoveRequest& request,
                                      const GuardedMovePlan& plan) = 0;

 private:
  MotionCheckOptions options_;
  std::mutex motion_mutex_;  // one motion at a time
};

}  // namespace picking::robot
