#include "services/gripper/core/keep_vertical.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace picking::gripper {

Eigen::Vector3d GravityInHead(const Eigen::Vector3d& g_tool, double q_rad) {
  const double c = std::cos(q_rad);
  const double s = std::sin(q_rad);
  // R_x(-q) * g_tool.
  return Eigen::Vector3d(g_tool.x(), c * g_tool.y() + s * g_tool.z(),
                         -s * g_tool.y() + c * g_tool.z());
}

double HeadTilt(const Eigen::Vector3d& g_head) { return std::atan2(g_head.y(), g_head.z()); }

double VerticalJointAngle(const Eigen::Vector3d& g_tool) {
  if (!g_tool.allFinite()) throw std::invalid_argument("gravity must be finite");
  if (std::hypot(g_tool.y(), g_tool.z()) < 1e-9) {
    throw std::invalid_argument(
        "gravity is along the joint axis: no joint angle makes the head vertical");
  }
  return -std::atan2(g_tool.y(), g_tool.z());
}

KeepVerticalController::KeepVerticalController(const KeepVerticalOptions& options)
    : options_(options) {
  const auto bad = [](const std::string& what) {
    throw std::invalid_argument("keep-vertical controller: " + what);
  };
  if (!(options.gain > 0.0 && options.gain <= 1.0)) bad("gain must be in (0, 1]");
  if (!std::isfinite(options.min_angle_rad) || !std::isfinite(options.max_angle_rad) ||
      !(options.min_angle_rad < options.max_angle_rad)) {
    bad("need finite min_angle_rad < max_angle_rad");
  }
  if (!(options.max_rate_rad_s > 0.0) || !std::isfinite(options.max_rate_rad_s)) {
    bad("max_rate_rad_s must be > 0");
  }
  if (!(options.deadband_rad >= 0.0) || !std::isfinite(options.deadband_rad)) {
    bad("deadband_rad must be >= 0");
  }
  if (!(options.min_plane_gravity_m_s2 >= 0.0) || !std::isfinite(options.min_plane_gravity_m_s2)) {
    bad("min_plane_gravity_m_s2 must be >= 0");
  }
}

KeepVerticalStep KeepVerticalController::Step(const Eigen::Vector3d& g_head, double q_measured_rad,
                                              double dt_s) {
  if (!g_head.allFinite() || !std::isfinite(q_measured_rad) || !std::isfinite(dt_s) ||
      !(dt_s > 0.0)) {
    throw std::invalid_argument("keep-vertical step: inputs must be finite and dt_s > 0");
  }
  const double previous = previous_command_rad_.value_or(
      std::clamp(q_measured_rad, options_.min_angle_rad, options_.max_angle_rad));
  KeepVerticalStep step;
  step.command_rad = previous;
  if (std::hypot(g_head.y(), g_head.z()) < options_.min_plane_gravity_m_s2) {
    step.observable = false;
    previous_command_rad_ = step.command_rad;
    return step;
  }
  step.tilt_rad = HeadTilt(g_head);
  double target = previous;
  if (std::abs(step.tilt_rad) > options_.deadband_rad) {
    target = q_measured_rad - options_.gain * step.tilt_rad;
  }
  const double max_delta = options_.max_rate_rad_s * dt_s;
  double command = std::clamp(target, previous - max_delta, previous + max_delta);
  command = std::clamp(command, options_.min_angle_rad, options_.max_angle_rad);
  step.saturated = command != target;
  step.command_rad = command;
  previous_command_rad_ = command;
  return step;
}

}  // namespace picking::gripper
