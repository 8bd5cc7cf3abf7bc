#pragma once

#include <Eigen/Core>

#include <string>
#include <string_view>

/// Value types shared by the gripper's core library, its backends and its service adapter.
namespace picking::gripper {

/// The two grippers of the cell (see docs/gripper-serial-protocol.md and the paper's gripper
/// figure): the shelf gripper is a suction cup on a fixed tube; the tote gripper's head hangs
/// on an extra servo joint.
enum class GripperKind { kShelf, kTote };

/// Modes of the tote gripper's servo joint.
enum class JointMode {
  kUnactuated,    ///< The servo is limp: the head swings freely (it hangs under gravity).
  kFixed,         ///< The servo holds a commanded angle.
  kKeepVertical,  ///< The servo keeps the head's suction axis along gravity.
};

/// "shelf" / "tote"; throws std::invalid_argument naming `field` for anything else.
GripperKind GripperKindFromName(std::string_view name, std::string_view field);
std::string_view GripperKindName(GripperKind kind);
std::string_view JointModeName(JointMode mode);

/// Standard gravity, m/s^2.
constexpr double kGravity_m_s2 = 9.80665;

/// What a backend measures, without any interpretation.
///
/// Frames: `tool` is the UR10 tool flange frame of the suction tube (+z along the tube,
/// out of the flange, the approach direction); `head` is the suction head, rotated about the
/// tool's x axis by the servo joint angle (head = tool at angle 0).
struct GripperReading {
  bool vacuum_on = false;   ///< The pump (relay) is commanded on.
  double vacuum_kpa = 0.0;  ///< Gauge vacuum, kPa (0 = atmosphere, positive = suction).
  JointMode joint_mode = JointMode::kUnactuated;
  double joint_angle_rad = 0.0;  ///< Measured servo angle, radians (0 = head along the tool).
  /// Gravity measured by the head's accelerometer, head frame, m/s^2 (the negated specific
  /// force: a vertical head pointing down reads (0, 0, +9.81)).
  Eigen::Vector3d gravity_head_m_s2 = Eigen::Vector3d::Zero();
};

/// The gripper's state as served: the reading plus the seal decision.
struct GripperState {
  GripperKind kind = GripperKind::kShelf;
  std::string backend;  ///< "sim" or "serial".
  GripperReading reading;
  bool item_attached = false;  ///< The vacuum is above the seal threshold (with hysteresis).
};

}  // namespace picking::gripper
