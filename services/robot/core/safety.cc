#include "services/robot/core/safety.h"

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace picking::robot {
namespace {

std::string Vec(const Eigen::Vector3d& p) {
  std::ostringstream os;
  os << "(" << p.x() << ", " << p.y() << ", " << p.z() << ")";
  return os.str();
}

void ValidateBox(const Box& box, const std::string& what) {
  if (!box.min_m.allFinite() || !box.max_m.allFinite()) {
    throw std::invalid_argument("SafetyLimits: " + what + " '" + box.name + "' is not finite");
  }
  if (!(box.min_m.array() < box.max_m.array()).all()) {
    throw std::invalid_argument("SafetyLimits: " + what + " '" + box.name +
                                "' needs min < max on every axis");
  }
}

}  // namespace

SafetyLimits SafetyLimits::FromModel(const ur10::Ur10Model& model, const Box& workspace,
                                     double max_tool_speed_m_s) {
  SafetyLimits limits;
  limits.min_position_rad = model.min_position_rad();
  limits.max_position_rad = model.max_position_rad();
  limits.max_velocity_rad_s = model.max_velocity_rad_s();
  limits.max_acceleration_rad_s2 = model.max_acceleration_rad_s2();
  limits.workspace = workspace;
  limits.max_tool_speed_m_s = max_tool_speed_m_s;
  limits.Validate();
  return limits;
}

void SafetyLimits::Validate() const {
  for (int j = 0; j < ur10::kNumJoints; ++j) {
    const std::string joint = std::string("SafetyLimits: joint ") + ur10::kJointNames[j];
    if (!std::isfinite(min_position_rad[j]) || !std::isfinite(max_position_rad[j]) ||
        !(min_position_rad[j] < max_position_rad[j])) {
      throw std::invalid_argument(joint + ": position limits must be finite with min < max");
    }
    if (!std::isfinite(max_velocity_rad_s[j]) || max_velocity_rad_s[j] <= 0.0) {
      throw std::invalid_argument(joint + ": max_velocity_rad_s must be finite and > 0");
    }
    if (!std::isfinite(max_acceleration_rad_s2[j]) || max_acceleration_rad_s2[j] <= 0.0) {
      throw std::invalid_argument(joint + ": max_acceleration_rad_s2 must be finite and > 0");
    }
  }
  ValidateBox(workspace, "workspace");
  for (const Box& zone : forbidden_zones) ValidateBox(zone, "forbidden zone");
  if (!std::isfinite(max_tool_speed_m_s) || max_tool_speed_m_s <= 0.0) {
    throw std::invalid_argument("SafetyLimits: max_tool_speed_m_s must be finite and > 0");
  }
}

SafetyChecker::SafetyChecker(const ur10::Ur10Kinematics& kinematics, SafetyLimits limits,
                             const world::GripperConfig& gripper)
    : SafetyChecker(kinematics, std::move(limits), gripper.X_ToolTcp) {
  gripper_ = gripper;
}

SafetyChecker SafetyChecker::WithHeadAngle(double head_angle_rad) const {
  if (const std::string problem =
          world::HeadAngleProblem(head_angle_rad, gripper_.max_head_angle_rad);
      !problem.empty()) {
    throw std::invalid_argument("the gripper's head angle " + problem);
  }
  SafetyChecker bent = *this;
  bent.head_angle_rad_ = head_angle_rad;
  bent.X_ToolTcp_ = gripper_.X_ToolTcpAt(head_angle_rad);
  return bent;
}

SafetyChecker::SafetyChecker(const ur10::Ur10Kinematics& kinematics, SafetyLimits limits,
                             const Eigen::Isometry3d& X_ToolTcp)
    : kinematics_(kinematics), limits_(std::move(limits)), X_ToolTcp_(X_ToolTcp) {
  gripper_.X_ToolTcp = X_ToolTcp;
  limits_.Validate();
  if (!X_ToolTcp_.matrix().allFinite()) {
    throw std::invalid_argument("SafetyChecker: X_ToolTcp is not finite");
  }
  // IK inside CheckLinearMove must respect the (possibly tighter) safety position limits.
  ur10::Ur10Model model = kinematics.model();
  auto joint_limits = model.limits();
  for (int j = 0; j < ur10::kNumJoints; ++j) {
    joint_limits[j].min_position_rad = limits_.min_position_rad[j];
    joint_limits[j].max_position_rad = limits_.max_position_rad[j];
  }
  model.set_limits(joint_limits);
  kinematics_ = ur10::Ur10Kinematics(model);
}

SafetyCheck SafetyChecker::CheckTcp(const Eigen::Vector3d& p_BaseTcp,
                                    const std::string& where) const {
  if (!limits_.workspace.Contains(p_BaseTcp)) {
    return SafetyCheck::Fail(where + ": tool centre point " + Vec(p_BaseTcp) +
                             " m is outside the workspace box " + Vec(limits_.workspace.min_m) +
                             " - " + Vec(limits_.workspace.max_m));
  }
  for (const Box& zone : limits_.forbidden_zones) {
    if (zone.Contains(p_BaseTcp)) {
      return SafetyCheck::Fail(where + ": tool centre point " + Vec(p_BaseTcp) +
                               " m is inside the forbidden zone '" + zone.name + "'");
    }
  }
  return SafetyCheck::Ok();
}

SafetyCheck SafetyChecker::CheckJointMove(const JointVector& q_target_rad, double speed_rad_s,
                                          double acceleration_rad_s2) const {
  const double max_speed = limits_.max_velocity_rad_s.minCoeff();
  if (!std::isfinite(speed_rad_s) || speed_rad_s <= 0.0 || speed_rad_s > max_speed) {
    return SafetyCheck::Fail("joint speed must be in (0, " + std::to_string(max_speed) + "] rad/s");
  }
  const double max_acceleration = limits_.max_acceleration_rad_s2.minCoeff();
  if (!std::isfinite(acceleration_rad_s2) || acceleration_rad_s2 <= 0.0 ||
      acceleration_rad_s2 > max_acceleration) {
    return SafetyCheck::Fail("joint acceleration must be in (0, " +
                             std::to_string(max_acceleration) + "] rad/s^2");
  }
  return CheckJointTarget(q_target_rad);
}

SafetyCheck SafetyChecker::CheckGuardedMove(const GuardedMoveRequest& request) const {
  if (!request.direction_tcp.allFinite() || std::abs(request.direction_tcp.norm() - 1.0) > 1e-3) {
    return SafetyCheck::Fail("guarded move direction must be a finite unit vector");
  }
  if (!std::isfinite(request.max_distance_m) || request.max_distance_m == 0.0 ||
      !std::isfinite(request.speed_m_s) || request.speed_m_s <= 0.0 ||
      !std::isfinite(request.acceleration_m_s2) || request.acceleration_m_s2 <= 0.0 ||
      !std::isfinite(request.force_threshold_n) || request.force_threshold_n <= 0.0) {
    return SafetyCheck::Fail(
        "guarded move needs a finite non-zero distance and positive speed, "
        "acceleration and force threshold");
  }
  return SafetyCheck::Ok();
}

SafetyCheck SafetyChecker::CheckJointTarget(const JointVector& q_rad) const {
  for (int j = 0; j < ur10::kNumJoints; ++j) {
    std::ostringstream os;
    if (!std::isfinite(q_rad[j])) {
      os << "joint " << ur10::kJointNames[j] << " target is not finite";
      return SafetyCheck::Fail(os.str());
    }
    if (q_rad[j] < limits_.min_position_rad[j] || q_rad[j] > limits_.max_position_rad[j]) {
      os << "joint " << ur10::kJointNames[j] << " target " << q_rad[j]
         << " rad is outside its position limits [" << limits_.min_position_rad[j] << ", "
         << limits_.max_position_rad[j] << "] rad";
      return SafetyCheck::Fail(os.str());
    }
  }
  const Eigen::Vector3d p = (kinematics_.ForwardKinematics(q_rad) * X_ToolTcp_).translation();
  return CheckTcp(p, "joint target");
}

SafetyCheck SafetyChecker::CheckLinearMove(const JointVector& q_start_rad,
                                           const Eigen::Isometry3d& X_BaseTcp_goal,
                                           double tool_speed_m_s, double step_m) const {
  if (!X_BaseTcp_goal.matrix().allFinite()) return SafetyCheck::Fail("goal pose is not finite");
  if (!std::isfinite(tool_speed_m_s) || tool_speed_m_s < 0.0) {
    return SafetyCheck::Fail("requested tool speed is not finite or negative");
  }
  if (tool_speed_m_s > limits_.max_tool_speed_m_s) {
    std::ostringstream os;
    os << "requested tool speed " << tool_speed_m_s << " m/s exceeds the limit "
       << limits_.max_tool_speed_m_s << " m/s";
    return SafetyCheck::Fail(os.str());
  }
  if (const SafetyCheck start = CheckJointTarget(q_start_rad); !start) {
    return SafetyCheck::Fail("start: " + start.reason);
  }
  LinearMoveOptions options;
  options.X_ToolTcp = X_ToolTcp_;
  const LinearMoveResult path =
      SampleLinearPath(kinematics_, q_start_rad, X_BaseTcp_goal, options, step_m, 0.02);
  if (!path.ok) return SafetyCheck::Fail("linear move: " + path.reason);
  const auto& points = path.trajectory.points;
  for (std::size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3d p =
        (kinematics_.ForwardKinematics(points[i].q_rad) * X_ToolTcp_).translation();
    const SafetyCheck tcp = CheckTcp(
        p, "linear move sample " + std::to_string(i) + " of " + std::to_string(points.size() - 1));
    if (!tcp) return tcp;
  }
  return SafetyCheck::Ok();
}

SafetyCheck SafetyChecker::CheckTrajectory(const JointTrajectory& trajectory,
                                           double tolerance) const {
  const auto& p = trajectory.points;
  if (p.empty()) return SafetyCheck::Fail("trajectory has no waypoints");
  Eigen::Vector3d previous_tcp = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < p.size(); ++i) {
    const std::string where = "waypoint " + std::to_string(i);
    std::ostringstream os;
    if (!std::isfinite(p[i].time_s)) return SafetyCheck::Fail(where + ": time is not finite");
    if (!p[i].qd_rad_s.allFinite() || !p[i].qdd_rad_s2.allFinite()) {
      return SafetyCheck::Fail(where + ": velocity or acceleration is not finite");
    }
    // Declared velocities and accelerations are what a backend may command, so they obey
    // the same limits as the ones implied by the positions.
    for (int j = 0; j < ur10::kNumJoints; ++j) {
      if (std::abs(p[i].qd_rad_s[j]) > limits_.max_velocity_rad_s[j] * (1.0 + tolerance)) {
        os << where << ": joint " << ur10::kJointNames[j] << " declared velocity "
           << std::abs(p[i].qd_rad_s[j]) << " rad/s exceeds the limit "
           << limits_.max_velocity_rad_s[j] << " rad/s";
        return SafetyCheck::Fail(os.str());
      }
      if (std::abs(p[i].qdd_rad_s2[j]) > limits_.max_acceleration_rad_s2[j] * (1.0 + tolerance)) {
        os << where << ": joint " << ur10::kJointNames[j] << " declared acceleration "
           << std::abs(p[i].qdd_rad_s2[j]) << " rad/s^2 exceeds the limit "
           << limits_.max_acceleration_rad_s2[j] << " rad/s^2";
        return SafetyCheck::Fail(os.str());
      }
    }
    if (i == 0 && p[i].time_s < 0.0) return SafetyCheck::Fail(where + ": negative time");
    if (i > 0 && !(p[i].time_s > p[i - 1].time_s)) {
      os << where << ": time " << p[i].time_s << " s does not increase (previous "
         << p[i - 1].time_s << " s)";
      return SafetyCheck::Fail(os.str());
    }
    if (const SafetyCheck target = CheckJointTarget(p[i].q_rad); !target) {
      return SafetyCheck::Fail(where + ": " + target.reason);
    }
    const Eigen::Vector3d tcp =
        (kinematics_.ForwardKinematics(p[i].q_rad) * X_ToolTcp_).translation();
    if (i == 0) {
      previous_tcp = tcp;
      continue;
    }
    const double h = p[i].time_s - p[i - 1].time_s;
    const JointVector v = (p[i].q_rad - p[i - 1].q_rad) / h;
    // The robot is at rest before the first and after the last waypoint.
    if (i == 1 || i + 1 == p.size()) {
      const JointVector a_end = 2.0 * v / h;
      for (int j = 0; j < ur10::kNumJoints; ++j) {
        if (std::abs(a_end[j]) > limits_.max_acceleration_rad_s2[j] * (1.0 + tolerance)) {
          os << (i == 1 ? "start" : "end") << " (segment " << i - 1 << "-" << i << "): joint "
             << ur10::kJointNames[j] << " acceleration from/to rest " << std::abs(a_end[j])
             << " rad/s^2 exceeds the limit " << limits_.max_acceleration_rad_s2[j] << " rad/s^2";
          return SafetyCheck::Fail(os.str());
        }
      }
    }
    for (int j = 0; j < ur10::kNumJoints; ++j) {
      if (std::abs(v[j]) > limits_.max_velocity_rad_s[j] * (1.0 + tolerance)) {
        os << "segment " << i - 1 << "-" << i << ": joint " << ur10::kJointNames[j] << " speed "
           << std::abs(v[j]) << " rad/s exceeds the limit " << limits_.max_velocity_rad_s[j]
           << " rad/s";
        return SafetyCheck::Fail(os.str());
      }
    }
    const double tool_speed = (tcp - previous_tcp).norm() / h;
    if (tool_speed > limits_.max_tool_speed_m_s * (1.0 + tolerance)) {
      os << "segment " << i - 1 << "-" << i << ": tool speed " << tool_speed
         << " m/s exceeds the limit " << limits_.max_tool_speed_m_s << " m/s";
      return SafetyCheck::Fail(os.str());
    }
    previous_tcp = tcp;
    if (i + 1 < p.size()) {
      const double h1 = p[i + 1].time_s - p[i].time_s;
      if (!(h1 > 0.0)) continue;  // reported as non-increasing time at the next waypoint
      const JointVector v1 = (p[i + 1].q_rad - p[i].q_rad) / h1;
      const JointVector a = 2.0 * (v1 - v) / (h + h1);
      for (int j = 0; j < ur10::kNumJoints; ++j) {
        if (std::abs(a[j]) > limits_.max_acceleration_rad_s2[j] * (1.0 + tolerance)) {
          os << where << ": joint " << ur10::kJointNames[j] << " acceleration " << std::abs(a[j])
             << " rad/s^2 exceeds the limit " << limits_.max_acceleration_rad_s2[j] << " rad/s^2";
          return SafetyCheck::Fail(os.str());
        }
      }
    }
  }
  return SafetyCheck::Ok();
}

}  // namespace picking::robot
