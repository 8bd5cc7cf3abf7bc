#pragma once

#include <Eigen/Geometry>

#include <cstddef>
#include <string>
#include <vector>

#include "libs/ur10/kinematics.h"

namespace picking::robot {

using ur10::JointVector;

/// Longest motion the planners produce, s. A slower motion (a tiny speed or acceleration)
/// is refused: at 125 Hz a day-long motion is millions of samples held in memory, and a
/// motion nobody waits for ties up the arm.
constexpr double kMaxTrajectoryDuration_s = 600.0;
/// Most samples a planned trajectory may have (600 s at 1 kHz).
constexpr std::size_t kMaxTrajectorySamples = 600'000;

/// One sample of a joint trajectory. Time from the trajectory start in s, positions in rad,
/// velocities in rad/s, accelerations in rad/s^2.
struct TrajectoryPoint {
  double time_s = 0.0;
  JointVector q_rad = JointVector::Zero();
  JointVector qd_rad_s = JointVector::Zero();
  JointVector qdd_rad_s2 = JointVector::Zero();
};

/// A time-parametrised joint trajectory, samples in increasing time starting at 0.
struct JointTrajectory {
  std::vector<TrajectoryPoint> points;
  double duration_s() const { return points.empty() ? 0.0 : points.back().time_s; }
};

/// Options of TimeParametrizePath.
struct TimeParametrizationOptions {
  /// Per-joint speed limits, rad/s (> 0).
  JointVector max_velocity_rad_s = JointVector::Constant(1.0);
  /// Per-joint acceleration limits, rad/s^2 (> 0).
  JointVector max_acceleration_rad_s2 = JointVector::Constant(1.0);
  /// Output sample rate, Hz (> 0). 125 Hz is the CB3 controller's servo rate.
  double sample_rate_hz = 125.0;
  /// Longest accepted profile, s, and most samples; a path needing more is refused.
  double max_duration_s = kMaxTrajectoryDuration_s;
  std::size_t max_samples = kMaxTrajectorySamples;
};

/// Time-optimal rest-to-rest parametrisation of a piecewise-linear joint path.
///
/// Following the polyline exactly, the robot must stop at every corner (a direction change
/// at non-zero speed needs infinite acceleration), so the time-optimal profile is, per
/// maximal straight stretch, a trapezoid (or triangle) in the path parameter whose peak speed
/// and acceleration are limited by the joint with the tightest limit relative to its
/// displacement. Collinear consecutive segments are merged and repeated waypoints dropped.
/// Samples are at k / sample_rate_hz plus the exact end point.
/// @throws std::invalid_argument for an empty path, non-finite values or bad limits, and
/// when the profile lasts longer than options.max_duration_s or needs more than
/// options.max_samples samples (checked before any sample is made).
JointTrajectory TimeParametrizePath(const std::vector<JointVector>& path_rad,
                                    const TimeParametrizationOptions& options);

/// Options of PlanLinearMove.
struct LinearMoveOptions {
  /// Pose of the tool centre point in the flange frame (the gripper's TCP offset).
  Eigen::Isometry3d X_ToolTcp = Eigen::Isometry3d::Identity();
  /// TCP speed and acceleration along the line, m/s and m/s^2 (> 0).
  double max_tool_speed_m_s = 0.25;
  double max_tool_acceleration_m_s2 = 0.5;
  /// Rotation speed and acceleration about the interpolation axis, rad/s and rad/s^2 (> 0).
  double max_tool_angular_speed_rad_s = 1.0;
  double max_tool_angular_acceleration_rad_s2 = 2.0;
  /// Joint limits for the resulting trajectory (e.g. from the model or the safety limits).
  JointVector max_velocity_rad_s = JointVector::Constant(1.0);
  JointVector max_acceleration_rad_s2 = JointVector::Constant(1.0);
  /// Output sample rate, Hz.
  double sample_rate_hz = 125.0;
  /// Largest joint change allowed between two consecutive samples, rad. A bigger jump means
  /// the path passes (near) a singularity or needs a branch change.
  double max_joint_step_rad = 0.2;
  /// Longest accepted motion, s, and most samples; a slower line is refused.
  double max_duration_s = kMaxTrajectoryDuration_s;
  std::size_t max_samples = kMaxTrajectorySamples;
};

/// Result of PlanLinearMove / SampleLinearPath.
struct LinearMoveResult {
  bool ok = false;
  /// Why the move is impossible (names the sample and its path fraction).
  std::string reason;
  /// The trajectory (PlanLinearMove) or the samples with times 0 (SampleLinearPath).
  JointTrajectory trajectory;
  /// The IK branch kept along the whole path (the start configuration's).
  ur10::Branch branch;
};

/// Samples the straight TCP line from FK(q_start) to X_BaseTcp_goal (orientation by slerp)
/// every `max_step_m` / `max_step_rad`, solving IK at each sample on the start's branch with
/// the previous sample as seed (seed continuity). Fails if a sample is unreachable on that
/// branch or a joint jumps more than options.max_joint_step_rad. Times are 0.
LinearMoveResult SampleLinearPath(const ur10::Ur10Kinematics& kinematics,
                                  const JointVector& q_start_rad,
                                  const Eigen::Isometry3d& X_BaseTcp_goal,
                                  const LinearMoveOptions& options, double max_step_m = 0.005,
                                  double max_step_rad = 0.02);

/// A time-parametrised straight TCP line: a trapezoidal profile along the line within the
/// tool speed/acceleration limits, IK at every sample (seed continuity, start branch), then
/// uniformly slowed down until the finite-difference joint speeds and accelerations are
/// within the joint limits. Not ok (with the reason) when the motion would last longer than
/// options.max_duration_s or need more than options.max_samples samples.
LinearMoveResult PlanLinearMove(const ur10::Ur10Kinematics& kinematics,
                                const JointVector& q_start_rad,
                                const Eigen::Isometry3d& X_BaseTcp_goal,
                                const LinearMoveOptions& options);

/// Position, speed and acceleration of a rest-to-rest trapezoidal profile covering a unit
/// distance with peak speed `v_max` and acceleration `a_max` (> 0), at time t.
struct TrapezoidProfile {
  TrapezoidProfile(double v_max, double a_max);
  double duration_s() const { return duration_s_; }
  /// s(t) in [0, 1], s'(t), s''(t); t clamped into [0, duration].
  void Evaluate(double t, double* s, double* sd, double* sdd) const;

 private:
  double v_ = 0.0;
  double a_ = 0.0;
  double t_acc_ = 0.0;
  double duration_s_ = 0.0;
};

}  // namespace picking::robot
