#include "services/robot/core/trajectory.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <utility>
#include <vector>

namespace picking::robot {
namespace {

void ValidateLimits(const JointVector& v, const JointVector& a, double rate_hz, const char* where) {
  for (int j = 0; j < ur10::kNumJoints; ++j) {
    if (!std::isfinite(v[j]) || v[j] <= 0.0) {
      throw std::invalid_argument(std::string(where) + ": max velocity of joint " +
                                  ur10::kJointNames[j] + " must be finite and > 0");
    }
    if (!std::isfinite(a[j]) || a[j] <= 0.0) {
      throw std::invalid_argument(std::string(where) + ": max acceleration of joint " +
                                  ur10::kJointNames[j] + " must be finite and > 0");
    }
  }
  if (!std::isfinite(rate_hz) || rate_hz <= 0.0) {
    throw std::invalid_argument(std::string(where) + ": sample rate must be finite and > 0");
  }
}

// Why a profile of `duration_s` sampled at `rate_hz` is refused, or "" if it is not.
std::string DurationProblem(double duration_s, double rate_hz, double max_duration_s,
                            std::size_t max_samples) {
  std::ostringstream os;
  if (!(duration_s <= max_duration_s)) {
    os << "the motion would take " << duration_s << " s, more than the " << max_duration_s
       << " s limit (raise the speed or acceleration)";
  } else if (!(duration_s * rate_hz < static_cast<double>(max_samples))) {
    os << "the motion would need " << duration_s * rate_hz << " samples, more than the "
       << max_samples << " limit";
  }
  return os.str();
}

// Sample times k / rate in [0, duration] plus the exact end.
std::vector<double> SampleTimes(double duration_s, double rate_hz) {
  std::vector<double> times;
  const double dt = 1.0 / rate_hz;
  for (long k = 0;; ++k) {
    const double t = k * dt;
    if (t >= duration_s - 1e-9 * dt) break;
    times.push_back(t);
  }
  times.push_back(duration_s);
  return times;
}

// Central finite differences of positions into velocities and accelerations (zero at the
// ends, where the profiles start and stop at rest).
void FillDerivatives(JointTrajectory* trajectory) {
  auto& p = trajectory->points;
  for (std::size_t i = 0; i < p.size(); ++i) {
    p[i].qd_rad_s.setZero();
    p[i].qdd_rad_s2.setZero();
    if (i == 0 || i + 1 == p.size()) continue;
    const double h0 = p[i].time_s - p[i - 1].time_s;
    const double h1 = p[i + 1].time_s - p[i].time_s;
    const JointVector v0 = (p[i].q_rad - p[i - 1].q_rad) / h0;
    const JointVector v1 = (p[i + 1].q_rad - p[i].q_rad) / h1;
    p[i].qd_rad_s = (v0 * h1 + v1 * h0) / (h0 + h1);
    p[i].qdd_rad_s2 = 2.0 * (v1 - v0) / (h0 + h1);
  }
}

Eigen::Isometry3d Interpolate(const Eigen::Isometry3d& X0, const Eigen::Isometry3d& X1, double u) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = (1.0 - u) * X0.translation() + u * X1.translation();
  const Eigen::Quaterniond q0(X0.linear());
  const Eigen::Quaterniond q1(X1.linear());
  X.linear() = q0.slerp(u, q1).toRotationMatrix();
  return X;
}

}  // namespace

TrapezoidProfile::TrapezoidProfile(double v_max, double a_max) {
  if (!(v_max > 0.0) || !(a_max > 0.0) || !std::isfinite(v_max) || !std::isfinite(a_max)) {
    throw std::invalid_argument("TrapezoidProfile: speed and acceleration must be finite, > 0");
  }
  a_ = a_max;
  if (v_max * v_max / a_max >= 1.0) {  // never reaches v_max: triangle
    t_acc_ = std::sqrt(1.0 / a_max);
    v_ = a_max * t_acc_;
    duration_s_ = 2.0 * t_acc_;
  } else {
    v_ = v_max;
    t_acc_ = v_max / a_max;
    duration_s_ = t_acc_ + 1.0 / v_max;
  }
}

void TrapezoidProfile::Evaluate(double t, double* s, double* sd, double* sdd) const {
  t = std::clamp(t, 0.0, duration_s_);
  if (t < t_acc_) {
    *s = 0.5 * a_ * t * t;
    *sd = a_ * t;
    *sdd = a_;
  } else if (t <= duration_s_ - t_acc_) {
    *s = 0.5 * a_ * t_acc_ * t_acc_ + v_ * (t - t_acc_);
    *sd = v_;
    *sdd = 0.0;
  } else {
    const double tr = duration_s_ - t;
    *s = 1.0 - 0.5 * a_ * tr * tr;
    *sd = a_ * tr;
    *sdd = -a_;
  }
  if (t >= duration_s_) {
    *s = 1.0;
    *sd = 0.0;
  }
}

JointTrajectory TimeParametrizePath(const std::vector<JointVector>& path_rad,
                                    const TimeParametrizationOptions& options) {
  ValidateLimits(options.max_velocity_rad_s, options.max_acceleration_rad_s2,
                 options.sample_rate_hz, "TimeParametrizePath");
  if (path_rad.empty()) throw std::invalid_argument("TimeParametrizePath: empty path");
  for (std::size_t i = 0; i < path_rad.size(); ++i) {
    if (!path_rad[i].allFinite()) {
      throw std::invalid_argument("TimeParametrizePath: waypoint " + std::to_string(i) +
                                  " is not finite");
    }
  }
  // Corners: drop repeated waypoints and merge collinear same-direction segments.
  std::vector<JointVector> corners = {path_rad.front()};
  for (std::size_t i = 1; i < path_rad.size(); ++i) {
    if ((path_rad[i] - corners.back()).cwiseAbs().maxCoeff() < 1e-12) continue;
    if (corners.size() >= 2) {
      const JointVector d0 = (corners.back() - corners[corners.size() - 2]).normalized();
      const JointVector d1 = (path_rad[i] - corners.back()).normalized();
      if (d0.dot(d1) > 1.0 - 1e-12) {
        corners.back() = path_rad[i];
        continue;
      }
    }
    corners.push_back(path_rad[i]);
  }

  struct Segment {
    JointVector start, delta;
    double t0;
    TrapezoidProfile profile;
  };
  std::vector<Segment> segments;
  double t = 0.0;
  for (std::size_t i = 1; i < corners.size(); ++i) {
    const JointVector delta = corners[i] - corners[i - 1];
    double v = std::numeric_limits<double>::infinity();
    double a = std::numeric_limits<double>::infinity();
    for (int j = 0; j < ur10::kNumJoints; ++j) {
      if (delta[j] == 0.0) continue;
      v = std::min(v, options.max_velocity_rad_s[j] / std::abs(delta[j]));
      a = std::min(a, options.max_acceleration_rad_s2[j] / std::abs(delta[j]));
    }
    segments.push_back({corners[i - 1], delta, t, TrapezoidProfile(v, a)});
    t += segments.back().profile.duration_s();
  }

  if (const std::string why =
          DurationProblem(t, options.sample_rate_hz, options.max_duration_s, options.max_samples);
      !why.empty()) {
    throw std::invalid_argument("TimeParametrizePath: " + why);
  }
  JointTrajectory trajectory;
  if (segments.empty()) {
    trajectory.points.push_back({0.0, corners.front(), JointVector::Zero(), JointVector::Zero()});
    return trajectory;
  }
  std::size_t k = 0;
  for (double time : SampleTimes(t, options.sample_rate_hz)) {
    while (k + 1 < segments.size() && time >= segments[k].t0 + segments[k].profile.duration_s()) {
      ++k;
    }
    const Segment& seg = segments[k];
    double s, sd, sdd;
    seg.profile.Evaluate(time - seg.t0, &s, &sd, &sdd);
    TrajectoryPoint p;
    p.time_s = time;
    p.q_rad = seg.start + s * seg.delta;
    p.qd_rad_s = sd * seg.delta;
    p.qdd_rad_s2 = sdd * seg.delta;
    trajectory.points.push_back(p);
  }
  trajectory.points.back().q_rad = corners.back();
  trajectory.points.back().qd_rad_s.setZero();
  return trajectory;
}

LinearMoveResult SampleLinearPath(const ur10::Ur10Kinematics& kinematics,
                                  const JointVector& q_start_rad,
                                  const Eigen::Isometry3d& X_BaseTcp_goal,
                                  const LinearMoveOptions& options, double max_step_m,
                                  double max_step_rad) {
  LinearMoveResult result;
  if (!q_start_rad.allFinite()) {
    result.reason = "start joint vector is not finite";
    return result;
  }
  if (const std::string out = kinematics.model().PositionLimitViolation(q_start_rad);
      !out.empty()) {
    result.reason = "start joints: " + out;
    return result;
  }
  if (!X_BaseTcp_goal.matrix().allFinite() || !options.X_ToolTcp.matrix().allFinite()) {
    result.reason = "goal pose or TCP offset is not finite";
    return result;
  }
  if (!(max_step_m > 0.0) || !(max_step_rad > 0.0)) {
    result.reason = "sampling steps must be > 0";
    return result;
  }
  const Eigen::Isometry3d X_TcpTool = options.X_ToolTcp.inverse();
  const Eigen::Isometry3d X_BaseTcp_start =
      kinematics.ForwardKinematics(q_start_rad) * options.X_ToolTcp;
  const double distance_m = (X_BaseTcp_goal.translation() - X_BaseTcp_start.translation()).norm();
  const double angle_rad =
      Eigen::AngleAxisd(X_BaseTcp_start.linear().transpose() * X_BaseTcp_goal.linear()).angle();
  const int n = std::max({1, static_cast<int>(std::ceil(distance_m / max_step_m)),
                          static_cast<int>(std::ceil(angle_rad / max_step_rad))});
  result.branch = kinematics.BranchOf(q_start_rad);
  JointVector previous = q_start_rad;
  result.trajectory.points.push_back({0.0, q_start_rad, JointVector::Zero(), JointVector::Zero()});
  for (int i = 1; i <= n; ++i) {
    const double u = static_cast<double>(i) / n;
    const Eigen::Isometry3d X_BaseTool =
        Interpolate(X_BaseTcp_start, X_BaseTcp_goal, u) * X_TcpTool;
    std::string why;
    const auto sol = kinematics.NearestSolution(X_BaseTool, previous, result.branch, &why);
    std::ostringstream os;
    if (!sol) {
      os << "sample " << i << " of " << n << " (fraction " << u << ") is not reachable on branch "
         << result.branch.ToString() << ": " << why;
      result.reason = os.str();
      return result;
    }
    const JointVector step = (sol->q_rad - previous).cwiseAbs();
    int joint;
    if (step.maxCoeff(&joint) > options.max_joint_step_rad) {
      os << "sample " << i << " of " << n << " (fraction " << u << "): joint "
         << ur10::kJointNames[joint] << " jumps " << step[joint] << " rad (more than "
         << options.max_joint_step_rad << " rad), the line passes near a singularity";
      result.reason = os.str();
      return result;
    }
    previous = sol->q_rad;
    result.trajectory.points.push_back({0.0, sol->q_rad, JointVector::Zero(), JointVector::Zero()});
  }
  result.ok = true;
  return result;
}

namespace {

// Limits on the path parameter u in [0, 1] of a straight tool line: the tool's speed and
// acceleration limits over its length and turn, and the joints' limits over their dq/du
// along the densely sampled path. Infinite for a zero-length move.
void PathParameterLimits(const std::vector<TrajectoryPoint>& samples, double distance_m,
                         double angle_rad, const LinearMoveOptions& options, double* u_speed,
                         double* u_accel) {
  *u_speed = std::numeric_limits<double>::infinity();
  *u_accel = std::numeric_limits<double>::infinity();
  if (distance_m > 0.0) {
    *u_speed = std::min(*u_speed, options.max_tool_speed_m_s / distance_m);
    *u_accel = std::min(*u_accel, options.max_tool_acceleration_m_s2 / distance_m);
  }
  if (angle_rad > 0.0) {
    *u_speed = std::min(*u_speed, options.max_tool_angular_speed_rad_s / angle_rad);
    *u_accel = std::min(*u_accel, options.max_tool_angular_acceleration_rad_s2 / angle_rad);
  }
  const double du = 1.0 / static_cast<double>(samples.size() - 1);
  for (std::size_t i = 1; i < samples.size(); ++i) {
    const JointVector dq_du = (samples[i].q_rad - samples[i - 1].q_rad).cwiseAbs() / du;
    for (int j = 0; j < ur10::kNumJoints; ++j) {
      if (dq_du[j] <= 0.0) continue;
      *u_speed = std::min(*u_speed, options.max_velocity_rad_s[j] / dq_du[j]);
      *u_accel = std::min(*u_accel, options.max_acceleration_rad_s2[j] / dq_du[j]);
    }
  }
}

// Largest finite-difference joint speed and acceleration of `trajectory` relative to the
// joint limits (1 = at the limit).
std::pair<double, double> LimitRatios(const JointTrajectory& trajectory,
                                      const LinearMoveOptions& options) {
  double ratio_v = 0.0, ratio_a = 0.0;
  const auto& p = trajectory.points;
  for (std::size_t i = 1; i < p.size(); ++i) {
    const double h = p[i].time_s - p[i - 1].time_s;
    const JointVector v = (p[i].q_rad - p[i - 1].q_rad) / h;
    ratio_v =
        std::max(ratio_v, (v.cwiseAbs().cwiseQuotient(options.max_velocity_rad_s)).maxCoeff());
    if (i + 1 < p.size()) {
      ratio_a = std::max(
          ratio_a,
          p[i].qdd_rad_s2.cwiseAbs().cwiseQuotient(options.max_acceleration_rad_s2).maxCoeff());
    }
  }
  return {ratio_v, ratio_a};
}

}  // namespace

LinearMoveResult PlanLinearMove(const ur10::Ur10Kinematics& kinematics,
                                const JointVector& q_start_rad,
                                const Eigen::Isometry3d& X_BaseTcp_goal,
                                const LinearMoveOptions& options) {
  ValidateLimits(options.max_velocity_rad_s, options.max_acceleration_rad_s2,
                 options.sample_rate_hz, "PlanLinearMove");
  for (double v :
       {options.max_tool_speed_m_s, options.max_tool_acceleration_m_s2,
        options.max_tool_angular_speed_rad_s, options.max_tool_angular_acceleration_rad_s2}) {
    if (!std::isfinite(v) || v <= 0.0) {
      throw std::invalid_argument("PlanLinearMove: tool speed/acceleration limits must be > 0");
    }
  }
  LinearMoveResult dense = SampleLinearPath(kinematics, q_start_rad, X_BaseTcp_goal, options);
  if (!dense.ok) return dense;
  const auto& samples = dense.trajectory.points;
  if (samples.size() < 2) return dense;

  const Eigen::Isometry3d X_TcpTool = options.X_ToolTcp.inverse();
  const Eigen::Isometry3d X_BaseTcp_start =
      kinematics.ForwardKinematics(q_start_rad) * options.X_ToolTcp;
  const double distance_m = (X_BaseTcp_goal.translation() - X_BaseTcp_start.translation()).norm();
  const double angle_rad =
      Eigen::AngleAxisd(X_BaseTcp_start.linear().transpose() * X_BaseTcp_goal.linear()).angle();

  double u_speed = 0.0, u_accel = 0.0;
  PathParameterLimits(samples, distance_m, angle_rad, options, &u_speed, &u_accel);
  if (!std::isfinite(u_speed) || !std::isfinite(u_accel)) {  // zero-length move
    dense.trajectory.points.resize(1);
    return dense;
  }

  LinearMoveResult result;
  result.branch = dense.branch;
  for (int attempt = 0; attempt < 40; ++attempt) {
    const TrapezoidProfile profile(u_speed, u_accel);
    if (std::string why = DurationProblem(profile.duration_s(), options.sample_rate_hz,
                                          options.max_duration_s, options.max_samples);
        !why.empty()) {
      result.reason = std::move(why);
      return result;
    }
    JointTrajectory trajectory;
    JointVector previous = q_start_rad;
    bool failed = false;
    for (double t : SampleTimes(profile.duration_s(), options.sample_rate_hz)) {
      double u, ud, udd;
      profile.Evaluate(t, &u, &ud, &udd);
      const Eigen::Isometry3d X_BaseTool =
          Interpolate(X_BaseTcp_start, X_BaseTcp_goal, u) * X_TcpTool;
      std::string why;
      const auto sol = kinematics.NearestSolution(X_BaseTool, previous, result.branch, &why);
      if (!sol || (sol->q_rad - previous).cwiseAbs().maxCoeff() > options.max_joint_step_rad) {
        // The dense sampling succeeded, so this only happens through rounding at a boundary.
        std::ostringstream os;
        os << "time sample at " << t << " s (fraction " << u << ") lost the IK branch "
           << result.branch.ToString() << (why.empty() ? "" : ": " + why);
        result.reason = os.str();
        failed = true;
        break;
      }
      previous = sol->q_rad;
      trajectory.points.push_back({t, sol->q_rad, JointVector::Zero(), JointVector::Zero()});
    }
    if (failed) return result;
    FillDerivatives(&trajectory);
    const auto [ratio_v, ratio_a] = LimitRatios(trajectory, options);
    if (ratio_v <= 1.0 && ratio_a <= 1.0) {
      result.ok = true;
      result.trajectory = std::move(trajectory);
      return result;
    }
    // Uniform time scaling by k divides speeds by k and accelerations by k^2.
    const double k = std::max({ratio_v, std::sqrt(ratio_a), 1.0}) * 1.02;
    u_speed /= k;
    u_accel /= k * k;
  }
  result.reason = "could not slow the line down to within the joint limits";
  return result;
}

}  // namespace picking::robot
