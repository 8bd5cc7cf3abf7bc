#include "services/robot/core/ur_backend.h"

#include <cmath>
#include <sstream>
#include <stdexcept>

#include "services/robot/core/urscript.h"

namespace picking::robot {
namespace {

// RTDE robot_mode and safety_mode values (RTDE guide).
constexpr std::int32_t kRobotModeRunning = 7;
constexpr std::int32_t kSafetyNormal = 1;
constexpr std::int32_t kSafetyReduced = 2;
constexpr std::int32_t kSafetyProtectiveStop = 3;
constexpr std::int32_t kSafetySystemEmergencyStop = 6;
constexpr std::int32_t kSafetyRobotEmergencyStop = 7;

JointVector ToJoints(const std::array<double, 6>& v) {
  JointVector q;
  for (int i = 0; i < 6; ++i) q[i] = v[i];
  return q;
}

}  // namespace

const char* RobotStatusName(RobotStatus status) {
  switch (status) {
    case RobotStatus::kUnknown:
      return "UNKNOWN";
    case RobotStatus::kPoweredOff:
      return "POWERED_OFF";
    case RobotStatus::kReady:
      return "READY";
    case RobotStatus::kMoving:
      return "MOVING";
    case RobotStatus::kProtectiveStop:
      return "PROTECTIVE_STOP";
    case RobotStatus::kEmergencyStop:
      return "EMERGENCY_STOP";
    case RobotStatus::kFault:
      return "FAULT";
  }
  return "?";
}

const char* MotionOutcomeName(MotionOutcome outcome) {
  switch (outcome) {
    case MotionOutcome::kCompleted:
      return "COMPLETED";
    case MotionOutcome::kContact:
      return "CONTACT";
    case MotionOutcome::kRejected:
      return "REJECTED";
    case MotionOutcome::kStopped:
      return "STOPPED";
    case MotionOutcome::kProtectiveStop:
      return "PROTECTIVE_STOP";
    case MotionOutcome::kFailed:
      return "FAILED";
  }
  return "?";
}

const std::vector<std::string>& UrBackend::OutputVariables() {
  static const std::vector<std::string> kNames = {"timestamp",        "actual_q",   "actual_qd",
                                                  "actual_TCP_force", "robot_mode", "safety_mode"};
  return kNames;
}

std::unique_ptr<UrBackend> UrBackend::Connect(const UrBackendOptions& options,
                                              const SafetyChecker& checker) {
  auto rtde = std::make_unique<rtde::RtdeClient>(
      TcpStream::Connect(options.host, options.rtde_port, options.connect_timeout),
      options.connect_timeout);
  if (!rtde->NegotiateProtocolVersion(rtde::kProtocolVersion)) {
    throw std::runtime_error("RTDE at " + options.host + ": protocol version 2 refused");
  }
  rtde->SetupOutputs(options.rtde_frequency_hz, OutputVariables());
  rtde->Start();
  auto script = TcpStream::Connect(options.host, options.script_port, options.connect_timeout);
  auto dashboard = std::make_unique<DashboardClient>(
      TcpStream::Connect(options.host, options.dashboard_port, options.connect_timeout),
      options.connect_timeout);
  return std::make_unique<UrBackend>(std::move(rtde), std::move(script), std::move(dashboard),
                                     checker, options);
}

UrBackend::UrBackend(std::unique_ptr<rtde::RtdeClient> rtde, std::unique_ptr<ByteStream> script,
                     std::unique_ptr<DashboardClient> dashboard, const SafetyChecker& checker,
                     const UrBackendOptions& options)
    : CheckedBackend(MotionCheckOptions{}),
      rtde_(std::move(rtde)),
      script_(std::move(script)),
      dashboard_(std::move(dashboard)),
      checker_(checker),
      kinematics_(checker.kinematics()),
      options_(options) {
  if (!rtde_ || !script_ || !dashboard_) {
    throw std::invalid_argument("UrBackend: every interface must be connected");
  }
  const auto& recipe = rtde_->output_recipe();
  for (const auto& name : OutputVariables()) recipe.IndexOf(name);  // throws if missing
  reader_ = std::thread([this] { ReadLoop(); });
}

UrBackend::~UrBackend() {
  closing_ = true;
  rtde_->Close();
  script_->Close();
  if (reader_.joinable()) reader_.join();
}

void UrBackend::ReadLoop() {
  const rtde::Recipe& recipe = rtde_->output_recipe();
  const std::size_t i_time = recipe.IndexOf("timestamp");
  const std::size_t i_q = recipe.IndexOf("actual_q");
  const std::size_t i_qd = recipe.IndexOf("actual_qd");
  const std::size_t i_force = recipe.IndexOf("actual_TCP_force");
  const std::size_t i_robot = recipe.IndexOf("robot_mode");
  const std::size_t i_safety = recipe.IndexOf("safety_mode");
  while (!closing_) {
    RobotState s;
    try {
      const rtde::DataPackage data = rtde_->Receive(std::chrono::milliseconds(1000));
      s.timestamp_s = std::get<double>(data.values.at(i_time));
      s.q_rad = ToJoints(std::get<std::array<double, 6>>(data.values.at(i_q)));
      s.qd_rad_s = ToJoints(std::get<std::array<double, 6>>(data.values.at(i_qd)));
      const auto force = std::get<std::array<double, 6>>(data.values.at(i_force));
      for (int k = 0; k < 6; ++k) s.wrench_base[k] = force[k];
      const std::int32_t robot_mode = std::get<std::int32_t>(data.values.at(i_robot));
      const std::int32_t safety_mode = std::get<std::int32_t>(data.values.at(i_safety));
      s.X_BaseTool = kinematics_.ForwardKinematics(s.q_rad);
      if (safety_mode == kSafetyProtectiveStop) {
        s.status = RobotStatus::kProtectiveStop;
      } else if (safety_mode == kSafetySystemEmergencyStop ||
                 safety_mode == kSafetyRobotEmergencyStop) {
        s.status = RobotStatus::kEmergencyStop;
      } else if (safety_mode != kSafetyNormal && safety_mode != kSafetyReduced) {
        s.status = RobotStatus::kFault;
      } else if (robot_mode != kRobotModeRunning) {
        s.status = RobotStatus::kPoweredOff;
      } else if (s.qd_rad_s.cwiseAbs().maxCoeff() > options_.still_speed_rad_s) {
        s.status = RobotStatus::kMoving;
      } else {
        s.status = RobotStatus::kReady;
      }
    } catch (const std::exception& e) {
      std::lock_guard<std::mutex> lock(mutex_);
      connection_lost_ = true;
      connection_error_ = e.what();
      state_changed_.notify_all();
      return;
    }
    std::lock_guard<std::mutex> lock(mutex_);
    state_ = s;
    have_state_ = true;
    state_changed_.notify_all();
  }
}

RobotState UrBackend::GetState() {
  std::lock_guard<std::mutex> lock(mutex_);
  return state_;
}

bool UrBackend::WaitForState(double after_s, std::chrono::milliseconds timeout) {
  std::unique_lock<std::mutex> lock(mutex_);
  return state_changed_.wait_for(lock, timeout, [&] {
    return connection_lost_ || (have_state_ && state_.timestamp_s > after_s);
  }) && !connection_lost_;
}

void UrBackend::SendScript(const std::string& text) {
  std::lock_guard<std::mutex> lock(script_mutex_);
  script_->WriteAll(text.back() == '\n' ? text : text + "\n");
}

void UrBackend::PowerOnAndReleaseBrakes(std::chrono::milliseconds timeout) {
  {
    std::lock_guard<std::mutex> lock(dashboard_mutex_);
    dashboard_->PowerOn();
    dashboard_->BrakeRelease();
  }
  std::unique_lock<std::mutex> lock(mutex_);
  const bool running = state_changed_.wait_for(lock, timeout, [&] {
    return connection_lost_ || (have_state_ && (state_.status == RobotStatus::kReady ||
                                                state_.status == RobotStatus::kMoving));
  });
  if (!running || connection_lost_) {
    throw std::runtime_error("UR: robot did not reach RUNNING after power on / brake release");
  }
}

MotionResult UrBackend::Reject(const std::string& why) {
  MotionResult r;
  r.outcome = MotionOutcome::kRejected;
  r.message = why;
  r.final_state = GetState();
  return r;
}

MotionResult UrBackend::BeginMotion() {
  std::lock_guard<std::mutex> lock(mutex_);
  MotionResult r;
  r.final_state = state_;
  if (connection_lost_) {
    r.outcome = MotionOutcome::kFailed;
    r.message = "RTDE connection lost: " + connection_error_;
  } else if (!have_state_) {
    r.outcome = MotionOutcome::kRejected;
    r.message = "no robot state received yet";
  } else if (state_.status != RobotStatus::kReady) {
    r.outcome = MotionOutcome::kRejected;
    r.message = std::string("robot is not ready: ") + RobotStatusName(state_.status);
  } else {
    r.outcome = MotionOutcome::kCompleted;
  }
  stop_requested_ = false;
  return r;
}

MotionResult UrBackend::Wait(const std::function<bool(const RobotState&)>& done, double timeout_s,
                             const std::function<void(const RobotState&)>& on_state) {
  const auto deadline = std::chrono::steady_clock::now() +
                        std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                            std::chrono::duration<double>(timeout_s));
  double last_time = -1.0;
  bool stopping = false;
  MotionResult r;
  std::unique_lock<std::mutex> lock(mutex_);
  while (true) {
    if (!state_changed_.wait_until(lock, deadline, [&] {
          return connection_lost_ || state_.timestamp_s > last_time ||
                 (stop_requested_ && !stopping);
        })) {
      r.outcome = MotionOutcome::kFailed;
      r.message = "motion timed out";
      r.final_state = state_;
      return r;
    }
    r.final_state = state_;
    if (connection_lost_) {
      r.outcome = MotionOutcome::kFailed;
      r.message = "RTDE connection lost: " + connection_error_;
      return r;
    }
    last_time = state_.timestamp_s;
    if (state_.status == RobotStatus::kProtectiveStop ||
        state_.status == RobotStatus::kEmergencyStop || state_.status == RobotStatus::kFault) {
      r.outcome = state_.status == RobotStatus::kProtectiveStop ? MotionOutcome::kProtectiveStop
                                                                : MotionOutcome::kFailed;
      r.message = std::string("robot entered ") + RobotStatusName(state_.status);
      return r;
    }
    if (stop_requested_) {
      stopping = true;  // from now on only new states wake this loop
      if (state_.qd_rad_s.cwiseAbs().maxCoeff() <= options_.still_speed_rad_s &&
          state_.timestamp_s > 0.0) {
        r.outcome = MotionOutcome::kStopped;
        r.message = "stopped on request";
        return r;
      }
      continue;
    }
    const RobotState s = state_;
    lock.unlock();
    if (on_state) on_state(s);
    const bool finished = done(s);
    lock.lock();
    if (finished) {
      r.outcome = MotionOutcome::kCompleted;
      r.final_state = s;
      return r;
    }
  }
}

MotionResult UrBackend::RunJointMove(const MotionResult& begin, const JointVector& q_target_rad,
                                     double speed_rad_s, double acceleration_rad_s2,
                                     const JointTrajectory&) {
  // The controller interpolates the joints synchronously: rest-to-rest over the largest
  // joint distance.
  const double distance = (q_target_rad - begin.final_state.q_rad).cwiseAbs().maxCoeff();
  const double planned_s = TrapezoidProfile(speed_rad_s / std::max(distance, 1e-9),
                                            acceleration_rad_s2 / std::max(distance, 1e-9))
                               .duration_s();
  try {
    SendScript(urscript::MoveJ(q_target_rad, acceleration_rad_s2, speed_rad_s));
  } catch (const std::exception& e) {
    MotionResult r = begin;
    r.outcome = MotionOutcome::kFailed;
    r.message = std::string("sending movej: ") + e.what();
    return r;
  }
  return Wait(
      [&](const RobotState& s) {
        return (s.q_rad - q_target_rad).cwiseAbs().maxCoeff() <= options_.joint_tolerance_rad &&
               s.qd_rad_s.cwiseAbs().maxCoeff() <= options_.still_speed_rad_s;
      },
      planned_s + options_.motion_timeout_margin_s);
}

MotionResult UrBackend::RunTrajectory(
    const MotionResult& begin, const JointTrajectory& trajectory,
    const std::function<void(const TrajectoryProgress&)>& progress) {
  const auto& p = trajectory.points;
  std::vector<std::string> lines;
  for (std::size_t i = 1; i < p.size(); ++i) {
    lines.push_back(urscript::ServoJ(p[i].q_rad, p[i].time_s - p[i - 1].time_s,
                                     options_.servo_lookahead_s, options_.servo_gain));
  }
  lines.push_back(urscript::StopJ(options_.stop_acceleration_rad_s2));
  try {
    SendScript(urscript::Program("picking_trajectory", lines));
  } catch (const std::exception& e) {
    MotionResult r = begin;
    r.outcome = MotionOutcome::kFailed;
    r.message = std::string("sending trajectory program: ") + e.what();
    return r;
  }
  // Progress: the nearest waypoint in a window ahead of the last one reached.
  std::size_t reached = 0;
  auto on_state = [&](const RobotState& s) {
    std::size_t best = reached;
    double best_distance = (p[reached].q_rad - s.q_rad).cwiseAbs().maxCoeff();
    for (std::size_t i = reached + 1; i < std::min(p.size(), reached + 64); ++i) {
      const double d = (p[i].q_rad - s.q_rad).cwiseAbs().maxCoeff();
      if (d < best_distance) {
        best = i;
        best_distance = d;
      }
    }
    if (best > reached) {
      reached = best;
      if (progress) {
        TrajectoryProgress info;
        info.waypoint_index = reached;
        info.time_s = p[reached].time_s;
        info.fraction =
            trajectory.duration_s() > 0.0 ? p[reached].time_s / trajectory.duration_s() : 1.0;
        info.state = s;
        progress(info);
      }
    }
  };
  const JointVector q_end = p.back().q_rad;
  return Wait(
      [&](const RobotState& s) {
        return reached + 1 == p.size() &&
               (s.q_rad - q_end).cwiseAbs().maxCoeff() <= options_.joint_tolerance_rad &&
               s.qd_rad_s.cwiseAbs().maxCoeff() <= options_.still_speed_rad_s;
      },
      trajectory.duration_s() + options_.motion_timeout_margin_s, on_state);
}

MotionResult UrBackend::RunGuardedMove(const MotionResult& begin, const GuardedMoveRequest& request,
                                       const GuardedMovePlan& plan) {
  const Eigen::Isometry3d& X_BaseTcp = plan.X_BaseTcp;
  const Eigen::Vector3d& axis = plan.axis_base;
  const double distance = plan.distance_m;
  const Eigen::Vector3d p_start = X_BaseTcp.translation();
  const double braking_m =
      request.speed_m_s * request.speed_m_s / (2.0 * request.acceleration_m_s2);
  Eigen::Matrix<double, 6, 1> twist = Eigen::Matrix<double, 6, 1>::Zero();
  twist.head<3>() = axis * request.speed_m_s;
  const double planned_s =
      distance / request.speed_m_s + request.speed_m_s / request.acceleration_m_s2;
  try {
    SendScript(urscript::SpeedL(twist, request.acceleration_m_s2, planned_s));
  } catch (const std::exception& e) {
    MotionResult r = begin;
    r.outcome = MotionOutcome::kFailed;
    r.message = std::string("sending speedl: ") + e.what();
    return r;
  }
  const double t0 = begin.final_state.timestamp_s;
  bool contact = false;
  bool stop_sent = false;
  double travelled = 0.0;
  double force = 0.0;
  MotionResult result = Wait(
      [&](const RobotState& s) {
        const Eigen::Vector3d p = (s.X_BaseTool * checker_.X_ToolTcp()).translation();
        travelled = (p - p_start).dot(axis);
        force = -s.wrench_base.head<3>().dot(axis);  // reaction opposing the motion
        if (!stop_sent &&
            (force >= request.force_threshold_n || travelled >= distance - braking_m)) {
          contact = force >= request.force_threshold_n;
          stop_sent = true;
          SendScript(urscript::StopL(options_.stop_acceleration_m_s2));
          return false;
        }
        const bool still = s.qd_rad_s.cwiseAbs().maxCoeff() <= options_.still_speed_rad_s;
        // speedl ends by itself after planned_s: done without contact once at rest.
        return still && (stop_sent || s.timestamp_s - t0 > planned_s);
      },
      planned_s + options_.motion_timeout_margin_s);
  if (result.outcome == MotionOutcome::kCompleted) {
    std::ostringstream os;
    os << (contact ? "contact" : "no contact") << " after " << travelled << " m, force " << force
       << " N";
    result.outcome = contact ? MotionOutcome::kContact : MotionOutcome::kCompleted;
    result.message = os.str();
  }
  return result;
}

void UrBackend::Stop() {
  stop_requested_ = true;
  try {
    SendScript(urscript::StopJ(options_.stop_acceleration_rad_s2));
  } catch (const std::exception&) {
    // The connection loss is reported by the blocked motion call.
  }
  std::lock_guard<std::mutex> lock(mutex_);
  state_changed_.notify_all();
}

void UrBackend::ProtectiveStop() {
  try {
    SendScript("protective_stop()");
  } catch (const std::exception&) {
  }
}

bool UrBackend::ResetProtectiveStop(std::string* reason) {
  try {
    std::lock_guard<std::mutex> lock(dashboard_mutex_);
    dashboard_->UnlockProtectiveStop();
    return true;
  } catch (const std::exception& e) {
    if (reason) *reason = e.what();
    return false;
  }
}

}  // namespace picking::robot
