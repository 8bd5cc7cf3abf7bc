#include "services/robot/core/checked_backend.h"

#include <cmath>
#include <stdexcept>

namespace picking::robot {

CheckedBackend::CheckedBackend(const MotionCheckOptions& options) : options_(options) {
  if (!(options_.start_tolerance_rad > 0.0) || !std::isfinite(options_.start_tolerance_rad)) {
    throw std::invalid_argument("start_tolerance_rad must be positive and finite");
  }
  if (!(options_.planning_rate_hz > 0.0) || !std::isfinite(options_.planning_rate_hz)) {
    throw std::invalid_argument("planning_rate_hz must be positive and finite");
  }
}

MotionResult CheckedBackend::MoveJoints(const JointVector& q_target_rad, double speed_rad_s,
                                        double acceleration_rad_s2) {
  std::lock_guard<std::mutex> motion(motion_mutex_);
  const SafetyChecker& checker = CheckerForMotion();
  if (const SafetyCheck check =
          checker.CheckJointMove(q_target_rad, speed_rad_s, acceleration_rad_s2);
      !check) {
    return Reject(check.reason);
  }
  MotionResult begin = BeginMotion();
  if (begin.outcome != MotionOutcome::kCompleted) return begin;
  // The whole joint line from where the arm is, as a controller interpolates it: every
  // sample inside the workspace and outside the forbidden zones, not only the target.
  TimeParametrizationOptions timing;
  timing.max_velocity_rad_s = JointVector::Constant(speed_rad_s);
  timing.max_acceleration_rad_s2 = JointVector::Constant(acceleration_rad_s2);
  timing.sample_rate_hz = options_.planning_rate_hz;
  const JointTrajectory line = TimeParametrizePath({begin.final_state.q_rad, q_target_rad}, timing);
  if (const SafetyCheck check = checker.CheckTrajectory(line, 1e-6); !check) {
    return Reject("joint move: " + check.reason);
  }
  return RunJointMove(begin, q_target_rad, speed_rad_s, acceleration_rad_s2, line);
}

MotionResult CheckedBackend::ExecuteTrajectory(
    const JointTrajectory& trajectory,
    const std::function<void(const TrajectoryProgress&)>& progress) {
  std::lock_guard<std::mutex> motion(motion_mutex_);
  if (const SafetyCheck check = CheckerForMotion().CheckTrajectory(trajectory); !check) {
    return Reject(check.reason);
  }
  MotionResult begin = BeginMotion();
  if (begin.outcome != MotionOutcome::kCompleted) return begin;
  const double start_error =
      (trajectory.points.front().q_rad - begin.final_state.q_rad).cwiseAbs().maxCoeff();
  if (start_error > options_.start_tolerance_rad) {
    return Reject("trajectory starts " + std::to_string(start_error) +
                  " rad away from the current joint positions");
  }
  return RunTrajectory(begin, trajectory, progress);
}

MotionResult CheckedBackend::GuardedMove(const GuardedMoveRequest& request) {
  std::lock_guard<std::mutex> motion(motion_mutex_);
  const SafetyChecker& checker = CheckerForMotion();
  if (const SafetyCheck check = checker.CheckGuardedMove(request); !check) {
    return Reject(check.reason);
  }
  MotionResult begin = BeginMotion();
  if (begin.outcome != MotionOutcome::kCompleted) return begin;
  GuardedMovePlan plan;
  plan.direction_tcp =
      request.direction_tcp.normalized() * (request.max_distance_m > 0.0 ? 1.0 : -1.0);
  plan.X_BaseTool = begin.final_state.X_BaseTool;
  plan.X_BaseTcp = plan.X_BaseTool * checker.X_ToolTcp();
  plan.axis_base = plan.X_BaseTcp.linear() * plan.direction_tcp;
  plan.distance_m = std::abs(request.max_distance_m);
  plan.X_BaseTcp_goal = plan.X_BaseTcp;
  plan.X_BaseTcp_goal.translation() += plan.axis_base * plan.distance_m;
  if (const SafetyCheck check =
          checker.CheckLinearMove(begin.final_state.q_rad, plan.X_BaseTcp_goal, request.speed_m_s);
      !check) {
    return Reject("guarded move: " + check.reason);
  }
  return RunGuardedMove(begin, request, plan);
}

}  // namespace picking::robot
