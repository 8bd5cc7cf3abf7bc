#pragma once

#include <Eigen/Geometry>

#include <functional>
#include <string>

#include "services/robot/core/trajectory.h"

namespace picking::robot {

/// What the arm is doing, as far as motion is concerned.
enum class RobotStatus {
  kUnknown = 0,     ///< no state received yet
  kPoweredOff,      ///< power off or brakes engaged
  kReady,           ///< powered, brakes released, not moving
  kMoving,          ///< executing a motion
  kProtectiveStop,  ///< stopped by the safety system; ResetProtectiveStop to continue
  kEmergencyStop,   ///< emergency stop pressed; needs the operator
  kFault,           ///< fault or safety violation; needs the operator
};
const char* RobotStatusName(RobotStatus status);

/// Measured state of the arm.
struct RobotState {
  JointVector q_rad = JointVector::Zero();
  JointVector qd_rad_s = JointVector::Zero();
  /// Pose of the tool flange (or the controller's TCP) in the robot base frame.
  Eigen::Isometry3d X_BaseTool = Eigen::Isometry3d::Identity();
  /// Wrench at the TCP in the base frame: force (N) then torque (Nm).
  Eigen::Matrix<double, 6, 1> wrench_base = Eigen::Matrix<double, 6, 1>::Zero();
  RobotStatus status = RobotStatus::kUnknown;
  /// Controller time of the sample, s.
  double timestamp_s = 0.0;
  /// The gripper's head on its servo joint as last reported, radians (0: straight).
  double gripper_head_angle_rad = 0.0;
};

/// How a motion ended.
enum class MotionOutcome {
  kCompleted,       ///< reached the target
  kContact,         ///< guarded move: the force threshold was reached
  kRejected,        ///< refused before moving (safety check, bad input, robot not ready)
  kStopped,         ///< Stop() was called
  kProtectiveStop,  ///< the robot entered a protective stop
  kFailed,          ///< connection lost, timeout or another error
};
const char* MotionOutcomeName(MotionOutcome outcome);

struct MotionResult {
  MotionOutcome outcome = MotionOutcome::kFailed;
  std::string message;
  /// State when the motion ended.
  RobotState final_state;
  bool ok() const {
    return outcome == MotionOutcome::kCompleted || outcome == MotionOutcome::kContact;
  }
};

/// Progress of a trajectory: index of the waypoint reached, its time, fraction in [0, 1].
struct TrajectoryProgress {
  std::size_t waypoint_index = 0;
  double time_s = 0.0;
  double fraction = 0.0;
  RobotState state;
};

/// A guarded move along a direction fixed in the tool centre point frame (by default the tool
/// z axis, the suction cup's approach direction).
struct GuardedMoveRequest {
  /// Unit direction of travel in the TCP frame at the start of the move.
  Eigen::Vector3d direction_tcp = Eigen::Vector3d::UnitZ();
  /// Signed distance along `direction_tcp` (m, e.g. +0.15 to descend onto an object).
  double max_distance_m = 0.1;
  double speed_m_s = 0.02;
  double acceleration_m_s2 = 0.5;
  /// Stop when the force component opposing the motion reaches this value, N (> 0).
  double force_threshold_n = 10.0;
};

/// The robot arm as the robot service sees it: a simulator or a real UR behind the same
/// interface. Motion calls block until the motion ends; Stop and ProtectiveStop may be called
/// from another thread while a motion call blocks. Implementations check motions against
/// their SafetyChecker before moving and report kRejected with the reason.
class RobotBackend {
 public:
  virtual ~RobotBackend() = default;
  /// The latest measured state.
  virtual RobotState GetState() = 0;
  /// Joint-space move to `q_target_rad` with the given peak joint speed and acceleration.
  virtual MotionResult MoveJoints(const JointVector& q_target_rad, double speed_rad_s,
                                  double acceleration_rad_s2) = 0;
  /// Executes a time-parametrised trajectory, calling `progress` (if set) as waypoints are
  /// reached, from the calling thread.
  virtual MotionResult ExecuteTrajectory(
      const JointTrajectory& trajectory,
      const std::function<void(const TrajectoryProgress&)>& progress) = 0;
  /// Moves the TCP along request.direction_tcp until the force threshold or the distance is
  /// reached (kContact or kCompleted). The final state's wrench_base holds the measured
  /// contact force.
  virtual MotionResult GuardedMove(const GuardedMoveRequest& request) = 0;
  /// Decelerates the current motion to rest; the blocked motion call returns kStopped.
  virtual void Stop() = 0;
  /// Stops immediately as the safety system would and latches kProtectiveStop.
  virtual void ProtectiveStop() = 0;
  /// Clears a protective stop. @returns false with `reason` if it cannot be cleared.
  virtual bool ResetProtectiveStop(std::string* reason) = 0;
  /// The gripper's head on its servo joint, radians, as the robot's world says now: motions
  /// are checked and their tcp computed with it. 0 for a gripper without a joint; the UR
  /// backend has no link to the gripper and answers 0. @throws UnavailableError.
  virtual double GripperHeadAngle() { return 0.0; }
};

}  // namespace picking::robot
