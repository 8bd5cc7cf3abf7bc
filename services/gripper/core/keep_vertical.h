#pragma once

#include <Eigen/Core>

#include <optional>

/// Keeping the tote gripper's suction head vertical with its servo joint.
///
/// Geometry (see GripperReading for the frames): the servo turns the head about the tool's
/// x axis by the joint angle q, so gravity in the head frame is g_head = R_x(-q) * g_tool.
/// The head is vertical when its suction axis +z_head points along gravity, i.e. when the
/// head's tilt atan2(g_head.y, g_head.z) is zero. A tilt about the joint axis can be
/// corrected; a tilt about the head's y axis (g_head.x) cannot, with one joint.
namespace picking::gripper {

/// Gravity in the head frame at joint angle `q_rad`, from gravity in the tool frame.
Eigen::Vector3d GravityInHead(const Eigen::Vector3d& g_tool, double q_rad);

/// The head's tilt about the joint axis, radians in (-pi, pi]: the angle from +z_head to the
/// projection of gravity on the head's y-z plane, positive about +x_head.
/// Rotating the joint by -tilt makes the head vertical.
double HeadTilt(const Eigen::Vector3d& g_head);

/// The joint angle that makes the head exactly vertical for gravity `g_tool` (tool frame),
/// radians in (-pi, pi]; not clamped to a servo range. Throws std::invalid_argument when
/// gravity has no component across the joint axis (|(g_y, g_z)| < 1e-9): every angle is
/// then equally vertical.
double VerticalJointAngle(const Eigen::Vector3d& g_tool);

/// Settings of the keep-vertical controller.
struct KeepVerticalOptions {
  /// Proportional gain on the measured tilt per step, in (0, 1]: 1 corrects the whole tilt
  /// in one step; smaller gains filter accelerometer noise.
  double gain = 0.5;
  /// Servo angle limits, radians (min < max).
  double min_angle_rad = -1.5707963267948966;
  double max_angle_rad = 1.5707963267948966;
  /// Largest change of the command per second, rad/s (> 0).
  double max_rate_rad_s = 4.0;
  /// Tilts smaller than this are not corrected, so noise does not make the servo hunt, rad.
  double deadband_rad = 0.005;
  /// Below this magnitude of gravity across the joint axis (the head's y-z plane), m/s^2,
  /// the tilt is not observable (the joint axis is near vertical) and the command is held.
  double min_plane_gravity_m_s2 = 2.0;
};

/// One step's output.
struct KeepVerticalStep {
  double command_rad = 0.0;  ///< Servo angle to command.
  double tilt_rad = 0.0;     ///< Measured tilt of the head (0 when not observable).
  bool observable = true;    ///< False when the command was held for lack of signal.
  bool saturated = false;    ///< The command hit the angle or rate limit.
};

/// A proportional controller on the measured tilt, clamped to the servo range and rate:
///   command = clamp(q_measured - gain * tilt, range, previous command +- max_rate * dt).
/// The reference control law of the micro controller's keep-vertical mode.
class KeepVerticalController final {
 public:
  /// Throws std::invalid_argument for options outside their documented ranges.
  explicit KeepVerticalController(const KeepVerticalOptions& options = {});

  /// One control step. `g_head` is the accelerometer's gravity (head frame, m/s^2),
  /// `q_measured_rad` the servo's present angle, `dt_s` > 0 the time since the last step.
  /// Throws std::invalid_argument for non-finite inputs or dt_s <= 0.
  KeepVerticalStep Step(const Eigen::Vector3d& g_head, double q_measured_rad, double dt_s);

  /// Forgets the previous command (the next step's rate limit starts from q_measured).
  void Reset() { previous_command_rad_.reset(); }

  const KeepVerticalOptions& options() const { return options_; }

 private:
  KeepVerticalOptions options_;
  std::optional<double> previous_command_rad_;
};

}  // namespace picking::gripper
