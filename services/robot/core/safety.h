#pragma once

#include <Eigen/Geometry>

#include <string>
#include <vector>

#include "libs/ur10/kinematics.h"
#include "libs/world/cell_config.h"
#include "services/robot/core/robot_backend.h"
#include "services/robot/core/trajectory.h"

namespace picking::robot {

/// An axis-aligned box in the robot base frame, metres.
struct Box {
  std::string name;
  Eigen::Vector3d min_m = Eigen::Vector3d::Zero();
  Eigen::Vector3d max_m = Eigen::Vector3d::Zero();
  bool Contains(const Eigen::Vector3d& p_Base) const {
    return (p_Base.array() >= min_m.array()).all() && (p_Base.array() <= max_m.array()).all();
  }
};

/// Limits every motion must respect. All in the robot base frame, SI units.
struct SafetyLimits {
  JointVector min_position_rad = JointVector::Constant(-6.283185307179586);
  JointVector max_position_rad = JointVector::Constant(6.283185307179586);
  JointVector max_velocity_rad_s = JointVector::Constant(1.0);
  JointVector max_acceleration_rad_s2 = JointVector::Constant(1.0);
  /// The tool centre point must stay inside this box.
  Box workspace{"workspace", Eigen::Vector3d::Constant(-1.5), Eigen::Vector3d::Constant(1.5)};
  /// The tool centre point must never enter any of these boxes.
  std::vector<Box> forbidden_zones;
  /// Largest TCP linear speed, m/s.
  double max_tool_speed_m_s = 0.5;

  /// Joint limits of the model, the given workspace and tool speed.
  static SafetyLimits FromModel(const ur10::Ur10Model& model, const Box& workspace,
                                double max_tool_speed_m_s);
  /// @throws std::invalid_argument naming the field: non-finite values, min >= max,
  /// non-positive speeds/accelerations, an empty workspace box or forbidden zone.
  void Validate() const;
};

/// Outcome of a safety check: ok, or the reason naming the joint, waypoint or limit.
struct SafetyCheck {
  bool ok = true;
  std::string reason;
  static SafetyCheck Ok() { return {}; }
  static SafetyCheck Fail(std::string why) { return {false, std::move(why)}; }
  explicit operator bool() const { return ok; }
};

/// Validates joint targets, straight TCP moves and trajectories against SafetyLimits.
/// NaN or infinity anywhere is refused. Thread-safe (const).
class SafetyChecker final {
 public:
  /// @param X_ToolTcp pose of the tool centre point in the flange frame.
  /// @throws std::invalid_argument if `limits` are invalid (see SafetyLimits::Validate).
  SafetyChecker(const ur10::Ur10Kinematics& kinematics, SafetyLimits limits,
                const Eigen::Isometry3d& X_ToolTcp = Eigen::Isometry3d::Identity());
  /// With the cell's gripper: its tcp with the head straight, and its head on a servo joint
  /// (world::GripperConfig) for WithHeadAngle.
  SafetyChecker(const ur10::Ur10Kinematics& kinematics, SafetyLimits limits,
                const world::GripperConfig& gripper);

  /// The same checks with the gripper's head at `head_angle_rad` (the tcp moves with the
  /// head). Throws std::invalid_argument outside the servo's range (any angle but 0 for a
  /// gripper without a joint).
  SafetyChecker WithHeadAngle(double head_angle_rad) const;
  double head_angle_rad() const { return head_angle_rad_; }
  /// The tcp with the head at `head_angle_rad` (not checked against the servo's range).
  Eigen::Isometry3d X_ToolTcpAt(double head_angle_rad) const {
    return gripper_.X_ToolTcpAt(head_angle_rad);
  }

  const SafetyLimits& limits() const { return limits_; }
  /// The kinematics (with the safety position limits applied to IK).
  const ur10::Ur10Kinematics& kinematics() const { return kinematics_; }
  const Eigen::Isometry3d& X_ToolTcp() const { return X_ToolTcp_; }

  /// Joint positions within limits, TCP inside the workspace and outside every forbidden zone.
  SafetyCheck CheckJointTarget(const JointVector& q_rad) const;

  /// A joint move (UR movej): speed in (0, slowest joint's limit] rad/s, acceleration in
  /// (0, smallest joint limit] rad/s^2, and the target as CheckJointTarget.
  SafetyCheck CheckJointMove(const JointVector& q_target_rad, double speed_rad_s,
                             double acceleration_rad_s2) const;

  /// A guarded move's parameters: a finite unit direction, a finite non-zero distance and
  /// positive speed, acceleration and force threshold.
  SafetyCheck CheckGuardedMove(const GuardedMoveRequest& request) const;

  /// A straight TCP line from FK(q_start) to X_BaseTcp_goal: every intermediate pose (sampled
  /// every `step_m` / 0.02 rad) reachable on the start's IK branch without a joint jump, and
  /// every sampled TCP position inside the workspace and outside the forbidden zones; the
  /// requested TCP speed (if > 0) within max_tool_speed_m_s.
  SafetyCheck CheckLinearMove(const JointVector& q_start_rad,
                              const Eigen::Isometry3d& X_BaseTcp_goal, double tool_speed_m_s = 0.0,
                              double step_m = 0.005) const;

  /// Every waypoint as CheckJointTarget, time finite, starting >= 0 and strictly increasing,
  /// finite-difference joint speeds and accelerations and TCP speed within the limits
  /// (relative slack `tolerance` for the rounding of sampled profiles). The robot is taken to
  /// be at rest before the first and after the last waypoint.
  SafetyCheck CheckTrajectory(const JointTrajectory& trajectory, double tolerance = 1e-6) const;

 private:
  SafetyCheck CheckTcp(const Eigen::Vector3d& p_BaseTcp, const std::string& where) const;

  ur10::Ur10Kinematics kinematics_;
  SafetyLimits limits_;
  Eigen::Isometry3d X_ToolTcp_;
  world::GripperConfig gripper_;  // X_ToolTcp with the head straight
  double head_angle_rad_ = 0.0;
};

}  // namespace picking::robot
