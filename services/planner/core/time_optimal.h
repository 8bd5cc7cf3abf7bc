#pragma once

#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "libs/ur10/ur10_model.h"

namespace picking::planner {

using ur10::JointVector;

/// Options of TimeParametrizeTimeOptimal. Every limit applies per joint, in the order of a
/// JointVector.
struct TimeOptimalOptions {
  /// Joint speed limits, rad/s (finite, > 0).
  JointVector max_velocity_rad_s = JointVector::Constant(1.0);
  /// Joint acceleration limits, rad/s^2 (finite, > 0).
  JointVector max_acceleration_rad_s2 = JointVector::Constant(1.0);
  /// Largest distance (Euclidean norm in joint space, rad) between a corner waypoint and the
  /// circular blend that replaces the corner (finite, >= 0). 0 follows the waypoint polyline
  /// exactly: the robot stops at every corner.
  double max_deviation_rad = 0.01;
  /// Output sample period, s (finite, in [1e-6, 1]). 0.008 s is the CB3 controller's 125 Hz.
  double sample_period_s = 0.008;
  /// Time step of the phase-plane integration on blends, s (finite, in [1e-6, 0.1]). Straight
  /// segments are integrated in closed form; on a blend a step also never exceeds 2 % of its
  /// radius. Smaller steps bring the result closer to the time optimum, at a cost in speed:
  /// 0.001 s takes twice as long on paths of many blends for trajectories 0.1 % shorter.
  double integration_step_s = 0.004;
  /// Optional speed bound on a point the arm carries (the tool centre point; m/s):
  /// point_speed_rate(q, dq_ds) is that point's speed per unit joint-space path speed at q,
  /// moving along the unit tangent dq_ds (|J(q) dq_ds| for the point's Jacobian J). Each line
  /// and blend of the path has its joint speed limits lowered just enough that the point
  /// stays within max_point_speed at samples point_speed_step_rad apart, so the motion slows
  /// only where the point moves fast, not as a whole. Empty: no bound.
  std::function<double(const JointVector& q, const JointVector& dq_ds)> point_speed_rate;
  double max_point_speed = std::numeric_limits<double>::infinity();
  double point_speed_step_rad = 0.02;
};

/// One sample of a time-parametrised joint trajectory. Time from the trajectory start in s,
/// positions in rad, velocities in rad/s, accelerations in rad/s^2.
struct TrajectorySample {
  double time_s = 0.0;
  JointVector q_rad = JointVector::Zero();
  JointVector qd_rad_s = JointVector::Zero();
  JointVector qdd_rad_s2 = JointVector::Zero();
};

/// Result of TimeParametrizeTimeOptimal.
struct TimeOptimalResult {
  /// Always true: invalid input throws instead (kept so that callers can treat every timing
  /// law alike).
  bool ok = true;
  /// Empty when ok.
  std::string reason;
  /// Samples at t = k * sample_period_s from t = 0, plus one at exactly duration_s (a regular
  /// sample closer than 1 % of a period to the end is left out). The first sample is the first
  /// waypoint at rest, the last is exactly the last waypoint at rest. qd and qdd are those of
  /// the continuous trajectory at the sample time (qdd right after t = 0 at the first sample,
  /// right before the end at the last one).
  std::vector<TrajectorySample> samples;
  /// Duration of the trajectory, s (0 for a single waypoint).
  double duration_s = 0.0;
  /// Corners passed on a circular blend, and corners where the trajectory comes to rest.
  int num_blends = 0;
  int num_stops = 0;
  /// Largest distance of a blend from its corner waypoint, rad (<= max_deviation_rad). Every
  /// sample lies on the blended path, so this also bounds the distance of every sample from
  /// the waypoint polyline (see MaxDistanceFromPolyline to measure it).
  double max_blend_deviation_rad = 0.0;
  /// Switching points of the phase-plane solution (each starts a backward integration).
  int num_switching_points = 0;
  /// Pieces of constant path acceleration of the phase-plane solution.
  int num_phase_plane_intervals = 0;
};

/// Time-optimal trajectory through joint-space waypoints within joint speed and acceleration
/// limits: Kunz & Stilman, "Time-Optimal Trajectory Generation for Path Following with
/// Bounded Acceleration and Velocity" (RSS 2012), in the structure of their reference
/// implementation.
///
/// 1. Path: straight segments between the waypoints, each corner replaced by a circular blend
///    tangent to both segments that stays within max_deviation_rad of the corner and uses at
///    most half of each adjacent segment. Exact repeats of a waypoint are dropped, waypoints
///    inside a straight stretch (direction change below 1e-11) merged. A corner is a stop (the path
///    is split into rest-to-rest pieces there) when max_deviation_rad is 0, when the blend radius
///    would be below 1e-4 rad (a near reversal), or when passing the blend would be slower than
///    stopping at the corner.
/// 2. Phase plane (path position s, path speed s_dot): the acceleration and velocity limit
///    curves, switching points (segment junctions, minima of the acceleration limit curve on
///    blends, and the points where the velocity limit curve can be followed again), forward
///    integration at the largest path acceleration and backward integration at the largest
///    deceleration from each switching point, spliced at their intersection; the limit
///    curves, switching points and their heights are located by bisection. Straight segments
///    are integrated in closed form. A switching point whose backward curve meets a limit
///    curve before the forward profile is lowered (bisection) until it does not.
/// 3. Sampling at sample_period_s.
///
/// Every step of constant path acceleration is checked against the limits at both of its
/// ends, on a blend with a margin that bounds the change of the joint speed and acceleration
/// inside the step, so the continuous trajectory (and therefore every finite difference of
/// the samples) is within the limits, not just the sampled values. Blends are planned 1e-6
/// (relative) inside the limits. The result is never slower (up to rounding) than stopping at
/// every corner as robot::TimeParametrizePath does: if blending is, every corner is stopped at
/// instead (the result then has num_blends == 0).
///
/// @throws std::invalid_argument for no waypoints, a non-finite waypoint or option, a limit
/// <= 0, a negative max_deviation_rad, a period or step outside its range (the message names
/// the value), or a trajectory that would need more than 2e7 samples.
/// @throws std::logic_error if the phase-plane solution breaks its own invariants (a bug).
TimeOptimalResult TimeParametrizeTimeOptimal(const std::vector<JointVector>& waypoints_rad,
                                             const TimeOptimalOptions& options);

/// Largest distance (Euclidean norm in joint space, rad) of a sample from the polyline through
/// `waypoints_rad`: for each sample the distance to the nearest polyline segment. O(samples x
/// waypoints); meant for validation. 0 if either list is empty.
double MaxDistanceFromPolyline(const std::vector<TrajectorySample>& samples,
                               const std::vector<JointVector>& waypoints_rad);

/// The polyline segment each sample lies on: the index j of the segment from waypoint j to
/// j + 1 within `tolerance_rad` (Euclidean, joint space), or -1 for a sample off the polyline
/// (in a blend). The samples run forward along the polyline, so each is looked for on the
/// segment of the last sample found and the few after it; a sample not found there counts as
/// off, which only ever asks for more checking.
std::vector<int> PolylineSegmentOfSamples(const std::vector<TrajectorySample>& samples,
                                          const std::vector<JointVector>& waypoints_rad,
                                          double tolerance_rad);

}  // namespace picking::planner
