#include "services/robot/core/sim_backend.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "libs/errors/errors.h"

namespace picking::robot {
namespace {

// Collisions this close before the probed contact point count as the expected touch.
constexpr double kContactSlackM = 1e-3;

// Reports a trajectory's progress once per waypoint reached (and once at the start).
class ProgressReporter {
 public:
  void Update(const JointTrajectory& trajectory, double tau, const RobotState& state,
              const std::function<void(const TrajectoryProgress&)>& progress) {
    const auto& p = trajectory.points;
    if (p.empty()) return;
    const auto after = std::upper_bound(
        p.begin(), p.end(), tau, [](double v, const TrajectoryPoint& pt) { return v < pt.time_s; });
    const std::size_t index = static_cast<std::size_t>(after - p.begin()) - 1;
    if (index <= reached_ && reported_) return;
    reached_ = index;
    reported_ = true;
    const double duration = trajectory.duration_s();
    TrajectoryProgress info;
    info.waypoint_index = index;
    info.time_s = p[index].time_s;
    info.fraction = duration > 0.0 ? p[index].time_s / duration : 1.0;
    info.state = state;
    progress(info);
  }

 private:
  std::size_t reached_ = 0;
  bool reported_ = false;
};

void RequirePositive(double value, const char* field) {
  if (!std::isfinite(value) || value <= 0.0) {
    throw std::invalid_argument(std::string("SimBackendOptions: ") + field +
                                " must be finite and > 0");
  }
}

// Empty when the world's TCP pose agrees with ours within 1e-6 m and 1e-6 rad, else why not.
std::string TcpDisagreement(const Eigen::Isometry3d& X_BaseTcp_ours,
                            const Eigen::Isometry3d& X_BaseTcp_world) {
  constexpr double kToleranceM = 1e-6, kToleranceRad = 1e-6;
  const double distance_m = (X_BaseTcp_world.translation() - X_BaseTcp_ours.translation()).norm();
  const double angle_rad =
      Eigen::AngleAxisd(X_BaseTcp_ours.linear().transpose() * X_BaseTcp_world.linear()).angle();
  if (distance_m <= kToleranceM && angle_rad <= kToleranceRad) return {};
  auto position = [](const Eigen::Isometry3d& X) {
    std::ostringstream os;
    os << "(" << X.translation().x() << ", " << X.translation().y() << ", " << X.translation().z()
       << ")";
    return os.str();
  };
  std::ostringstream os;
  os << "the simulator puts the tool centre point at " << position(X_BaseTcp_world)
     << ", the robot's cell description at " << position(X_BaseTcp_ours) << " (" << distance_m
     << " m, " << angle_rad
     << " rad apart): the simulator and the robot must load the same cell description "
        "(setting 'cell')";
  return os.str();
}

}  // namespace

void SimBackendOptions::Validate() const {
  RequirePositive(time_scale, "time_scale");
  RequirePositive(command_rate_hz, "command_rate_hz");
  RequirePositive(planning_rate_hz, "planning_rate_hz");
  RequirePositive(stop_acceleration_rad_s2, "stop_acceleration_rad_s2");
  if (!std::isfinite(start_tolerance_rad) || start_tolerance_rad < 0.0) {
    throw std::invalid_argument("SimBackendOptions: start_tolerance_rad must be finite and >= 0");
  }
  if (!std::isfinite(link_check_period_s) || link_check_period_s < 0.0) {
    throw std::invalid_argument("SimBackendOptions: link_check_period_s must be finite and >= 0");
  }
  if (!now) throw std::invalid_argument("SimBackendOptions: now (the clock) is empty");
}

void SampleTrajectory(const JointTrajectory& trajectory, double t_s, JointVector* q_rad,
                      JointVector* qd_rad_s) {
  const auto& p = trajectory.points;
  if (p.size() == 1 || t_s <= p.front().time_s) {
    *q_rad = p.front().q_rad;
    qd_rad_s->setZero();
    return;
  }
  if (t_s >= p.back().time_s) {
    *q_rad = p.back().q_rad;
    qd_rad_s->setZero();
    return;
  }
  const auto next = std::upper_bound(
      p.begin(), p.end(), t_s, [](double t, const TrajectoryPoint& pt) { return t < pt.time_s; });
  const TrajectoryPoint& b = *next;
  const TrajectoryPoint& a = *(next - 1);
  const double h = b.time_s - a.time_s;
  const double u = (t_s - a.time_s) / h;
  *q_rad = (1.0 - u) * a.q_rad + u * b.q_rad;
  *qd_rad_s = (b.q_rad - a.q_rad) / h;
}

namespace {

MotionCheckOptions CheckOptionsOf(const SimBackendOptions& options) {
  options.Validate();
  MotionCheckOptions check;
  check.start_tolerance_rad = options.start_tolerance_rad;
  check.planning_rate_hz = options.planning_rate_hz;
  return check;
}

}  // namespace

SimBackend::SimBackend(std::shared_ptr<SimulatedArm> arm, const SafetyChecker& checker,
                       const SimBackendOptions& options)
    : CheckedBackend(CheckOptionsOf(options)),
      arm_(std::move(arm)),
      base_checker_(checker),
      checker_(checker),
      options_(options) {
  if (!arm_) throw std::invalid_argument("SimBackend: the simulated arm is null");
}

const SafetyChecker& SimBackend::CheckerForMotion() {
  RefreshTool();
  return checker_;
}

RobotState SimBackend::StateLocked() const {
  RobotState s;
  s.q_rad = q_;
  s.qd_rad_s = qd_;
  s.X_BaseTool = checker_.kinematics().ForwardKinematics(q_);
  s.wrench_base = wrench_;
  s.status = status_;
  s.timestamp_s = time_s_;
  s.gripper_head_angle_rad = checker_.head_angle_rad();
  return s;
}

void SimBackend::RefreshTool() {
  double angle = 0.0;
  try {
    std::lock_guard<std::mutex> arm(arm_mutex_);
    angle = arm_->ReadHeadAngle();
  } catch (const std::exception&) {
    return;  // BeginMotion reports the world as unreachable
  }
  SafetyChecker tool = base_checker_.WithHeadAngle(angle);
  std::lock_guard<std::mutex> lock(mutex_);
  checker_ = std::move(tool);
}

double SimBackend::GripperHeadAngle() {
  std::lock_guard<std::mutex> arm(arm_mutex_);
  return arm_->ReadHeadAngle();
}

void SimBackend::SyncLocked() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (synced_) return;
  }
  JointVector q;
  try {
    q = arm_->ReadJoints();
  } catch (const UnavailableError&) {
    throw;
  } catch (const std::exception& e) {
    // Without the arm's joints the backend cannot serve anything.
    throw UnavailableError(std::string("cannot read the simulated arm: ") + e.what());
  }
  if (!q.allFinite()) throw UnavailableError("simulator reported non-finite arm joints");
  std::lock_guard<std::mutex> lock(mutex_);
  q_ = q;
  qd_.setZero();
  wrench_.setZero();
  synced_ = true;
  MarkContactLocked();
  if (status_ == RobotStatus::kUnknown) status_ = RobotStatus::kReady;
}

bool SimBackend::LinkCheckDueLocked() const {
  return options_.now() - last_contact_ >=
         std::chrono::duration<double>(options_.link_check_period_s);
}

void SimBackend::CheckLinkLocked() {
  bool synced = false;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (synced_ && !LinkCheckDueLocked()) return;
    synced = synced_;
  }
  // Not synced: read where the arm is, not only whether the world answers.
  if (!synced) {
    SyncLocked();
    return;
  }
  try {
    arm_->CheckReachable();
  } catch (const std::exception& e) {
    std::lock_guard<std::mutex> lock(mutex_);
    synced_ = false;  // the world may come back restarted: read the arm again then
    if (dynamic_cast<const UnavailableError*>(&e)) throw;
    throw UnavailableError(std::string("cannot read the simulated arm: ") + e.what());
  }
  std::lock_guard<std::mutex> lock(mutex_);
  MarkContactLocked();
}

RobotState SimBackend::GetState() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (synced_ && !LinkCheckDueLocked()) return StateLocked();
  }
  std::unique_lock<std::mutex> arm(arm_mutex_, std::try_to_lock);
  if (!arm.owns_lock()) {
    // A world call is under way (a motion streams the arm): its outcome tells whether the
    // world answers, so report the commanded state rather than queue behind it.
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (synced_) return StateLocked();
    }
    arm.lock();
  }
  CheckLinkLocked();
  std::lock_guard<std::mutex> lock(mutex_);
  return StateLocked();
}

MotionResult SimBackend::Reject(const std::string& why) {
  MotionResult r;
  r.outcome = MotionOutcome::kRejected;
  r.message = why;
  std::lock_guard<std::mutex> lock(mutex_);
  r.final_state = StateLocked();
  return r;
}

MotionResult SimBackend::BeginMotion() {
  MotionResult r;
  try {
    std::lock_guard<std::mutex> arm(arm_mutex_);
    SyncLocked();
  } catch (const std::exception& e) {
    r.outcome = MotionOutcome::kFailed;
    r.message = std::string("simulator unreachable: ") + e.what();
    return r;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  r.final_state = StateLocked();
  if (status_ != RobotStatus::kReady) {
    r.outcome = MotionOutcome::kRejected;
    r.message = std::string("robot is not ready: ") + RobotStatusName(status_);
    return r;
  }
  stop_requested_ = false;
  r.outcome = MotionOutcome::kCompleted;
  return r;
}

Eigen::Matrix<double, 6, 1> SimBackend::ContactWrench(const JointVector& q, const ContactZone& zone,
                                                      double* penetration_m) const {
  // Contact model of guarded moves: travel past the first touch presses the spring.
  Eigen::Matrix<double, 6, 1> wrench = Eigen::Matrix<double, 6, 1>::Zero();
  *penetration_m = -std::numeric_limits<double>::infinity();
  if (!zone.enabled) return wrench;
  const Eigen::Vector3d p_tcp =
      (checker_.kinematics().ForwardKinematics(q) * checker_.X_ToolTcp()).translation();
  *penetration_m = (p_tcp - zone.p_start_base).dot(zone.axis_base) - zone.contact_distance_m;
  if (*penetration_m > 0.0) {
    wrench.head<3>() = -zone.axis_base * zone.stiffness_n_per_m * *penetration_m;
  }
  return wrench;
}

MotionResult SimBackend::StopBeforeCollision(const JointVector& last_free,
                                             const std::string& detail) {
  try {
    std::lock_guard<std::mutex> arm(arm_mutex_);
    arm_->PlaceArm(last_free);
  } catch (const std::exception&) {
    // Reported as the protective stop below; the next call reads the arm again.
  }
  std::lock_guard<std::mutex> lock(mutex_);
  q_ = last_free;
  qd_.setZero();
  wrench_.setZero();
  status_ = RobotStatus::kProtectiveStop;
  protective_requested_ = true;
  MotionResult r;
  r.outcome = MotionOutcome::kProtectiveStop;
  r.message =
      "protective stop: collision: " + (detail.empty() ? std::string("unnamed contact") : detail);
  r.final_state = StateLocked();
  return r;
}

namespace {

// The trajectory's own clock while the arm follows it: in step with the simulated time until a
// stop is asked for, then slowing linearly to rest within the time the fastest joint needs at
// the stop deceleration, so the arm decelerates along its path.
class TrajectoryClock {
 public:
  TrajectoryClock(const JointTrajectory& trajectory, double stop_acceleration_rad_s2)
      : trajectory_(trajectory),
        duration_s_(trajectory.duration_s()),
        stop_acceleration_rad_s2_(stop_acceleration_rad_s2) {}

  bool stopping() const { return stopping_; }
  // The arm ended before the trajectory did: it was stopped on request.
  bool stopped_early() const { return stopping_ && tau_s_ < duration_s_; }

  // Starts the deceleration at simulated time `t_s`.
  void BeginStop(double t_s) {
    stopping_ = true;
    stop_t0_s_ = t_s;
    stop_tau0_s_ = tau_s_;
    JointVector q, qd;
    SampleTrajectory(trajectory_, tau_s_, &q, &qd);
    stop_duration_s_ = qd.cwiseAbs().maxCoeff() / stop_acceleration_rad_s2_;
  }

  struct Step {
    double tau_s = 0.0;  // trajectory time
    double rate = 1.0;   // d(tau)/dt
    bool finished = false;
  };
  // The trajectory time at simulated time `t_s`.
  Step Advance(double t_s) {
    Step step;
    if (stopping_) {
      const double s = std::min(t_s - stop_t0_s_, stop_duration_s_);
      tau_s_ =
          stop_duration_s_ > 0.0 ? stop_tau0_s_ + s - 0.5 * s * s / stop_duration_s_ : stop_tau0_s_;
      step.rate = stop_duration_s_ > 0.0 ? 1.0 - s / stop_duration_s_ : 0.0;
      step.finished = s >= stop_duration_s_;
    } else {
      tau_s_ = t_s;
    }
    if (tau_s_ >= duration_s_) {
      tau_s_ = duration_s_;
      step.finished = true;
    }
    step.tau_s = tau_s_;
    return step;
  }

 private:
  const JointTrajectory& trajectory_;
  const double duration_s_;
  const double stop_acceleration_rad_s2_;
  double tau_s_ = 0.0;
  bool stopping_ = false;
  double stop_t0_s_ = 0.0, stop_tau0_s_ = 0.0, stop_duration_s_ = 0.0;
};

}  // namespace

MotionResult SimBackend::FinishMotion(MotionOutcome outcome, const std::string& message,
                                      RobotStatus status) {
  MotionResult r;
  r.outcome = outcome;
  r.message = message;
  std::lock_guard<std::mutex> lock(mutex_);
  qd_.setZero();
  if (status_ != RobotStatus::kProtectiveStop) status_ = status;
  r.final_state = StateLocked();
  return r;
}

std::optional<MotionResult> SimBackend::PlaceArmAt(const JointVector& q, const ContactZone& zone,
                                                   double penetration_m,
                                                   const JointVector& last_free) {
  ArmPlacement placement;
  try {
    std::lock_guard<std::mutex> arm(arm_mutex_);
    placement = arm_->PlaceArm(q);
    std::lock_guard<std::mutex> lock(mutex_);
    MarkContactLocked();
  } catch (const UnavailableError& e) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      synced_ = false;  // where the arm is must be read again
    }
    return FinishMotion(MotionOutcome::kFailed, std::string("simulator unreachable: ") + e.what(),
                        RobotStatus::kUnknown);
  } catch (const std::exception& e) {
    return FinishMotion(MotionOutcome::kFailed,
                        std::string("simulator refused the arm motion: ") + e.what(),
                        RobotStatus::kReady);
  }
  if (placement.X_BaseTcp) {
    const std::string disagreement = TcpDisagreement(
        checker_.kinematics().ForwardKinematics(q) * checker_.X_ToolTcp(), *placement.X_BaseTcp);
    if (!disagreement.empty()) {
      try {
        std::lock_guard<std::mutex> arm(arm_mutex_);
        arm_->PlaceArm(last_free);
      } catch (const std::exception&) {
        // The motion fails anyway; the next call reads the arm again.
      }
      return FinishMotion(MotionOutcome::kFailed, disagreement, RobotStatus::kReady);
    }
  }
  if (placement.in_collision && !(zone.enabled && penetration_m > -kContactSlackM)) {
    return StopBeforeCollision(last_free, placement.collision_detail);
  }
  return std::nullopt;
}

MotionResult SimBackend::Run(const JointTrajectory& trajectory,
                             const std::function<void(const TrajectoryProgress&)>& progress,
                             const ContactZone& zone) {
  using Clock = std::chrono::steady_clock;
  const double dt = 1.0 / options_.command_rate_hz;
  const Clock::time_point wall_start = Clock::now();
  auto wall_at = [&](double t_sim) {
    return wall_start + std::chrono::duration_cast<Clock::duration>(
                            std::chrono::duration<double>(t_sim / options_.time_scale));
  };

  JointVector last_free;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    last_free = q_;
    status_ = RobotStatus::kMoving;
    wrench_.setZero();
  }
  double t = 0.0;  // simulated time of the last sample sent
  TrajectoryClock clock(trajectory, options_.stop_acceleration_rad_s2);
  ProgressReporter reporter;
  while (true) {
    const double t_next = t + dt;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      wake_.wait_until(lock, wall_at(t_next), [&] {
        return protective_requested_ || (stop_requested_ && !clock.stopping());
      });
      if (protective_requested_) {
        lock.unlock();
        return FinishMotion(MotionOutcome::kProtectiveStop, "protective stop", RobotStatus::kReady);
      }
      if (stop_requested_ && !clock.stopping()) {
        clock.BeginStop(t);
        continue;
      }
    }
    t = t_next;
    const TrajectoryClock::Step step = clock.Advance(t);
    JointVector q, qd;
    SampleTrajectory(trajectory, step.tau_s, &q, &qd);
    qd *= step.rate;
    if (step.finished) qd.setZero();

    double penetration_m = 0.0;
    const Eigen::Matrix<double, 6, 1> wrench = ContactWrench(q, zone, &penetration_m);
    if (std::optional<MotionResult> ended = PlaceArmAt(q, zone, penetration_m, last_free)) {
      return *ended;
    }
    last_free = q;
    RobotState state;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      q_ = q;
      qd_ = qd;
      wrench_ = wrench;
      time_s_ += dt;
      state = StateLocked();
    }
    if (progress) reporter.Update(trajectory, step.tau_s, state, progress);
    if (step.finished) {
      if (clock.stopped_early()) {
        return FinishMotion(MotionOutcome::kStopped, "stopped on request", RobotStatus::kReady);
      }
      return FinishMotion(MotionOutcome::kCompleted, "", RobotStatus::kReady);
    }
  }
}

MotionResult SimBackend::RunJointMove(const MotionResult&, const JointVector&, double, double,
                                      const JointTrajectory& line) {
  return Run(line, {}, ContactZone());
}

MotionResult SimBackend::RunTrajectory(
    const MotionResult&, const JointTrajectory& trajectory,
    const std::function<void(const TrajectoryProgress&)>& progress) {
  return Run(trajectory, progress, ContactZone());
}

MotionResult SimBackend::RunGuardedMove(const MotionResult& begin,
                                        const GuardedMoveRequest& request,
                                        const GuardedMovePlan& plan) {
  const JointVector q0 = begin.final_state.q_rad;
  const Eigen::Isometry3d& X_BaseTool = plan.X_BaseTool;
  const Eigen::Isometry3d& X_BaseTcp = plan.X_BaseTcp;
  const Eigen::Vector3d& direction_tcp = plan.direction_tcp;
  const Eigen::Vector3d& axis = plan.axis_base;
  const double distance = plan.distance_m;
  ContactProbe probe;
  try {
    std::lock_guard<std::mutex> arm(arm_mutex_);
    probe = arm_->Probe(X_BaseTool, direction_tcp, distance);
  } catch (const std::exception& e) {
    if (dynamic_cast<const UnavailableError*>(&e)) {
      std::lock_guard<std::mutex> lock(mutex_);
      synced_ = false;  // where the arm is must be read again
    }
    MotionResult r = begin;
    r.outcome = MotionOutcome::kFailed;
    r.message = std::string("simulator unreachable: contact probe: ") + e.what();
    return r;
  }
  ContactZone zone;
  double travel = distance;
  if (probe.contact && std::isfinite(probe.distance_m) && probe.distance_m < distance) {
    const double contact_at = std::max(0.0, probe.distance_m);
    // A rigid surface (no stiffness reported) meets any threshold at first touch.
    const double press =
        probe.stiffness_n_per_m > 0.0 ? request.force_threshold_n / probe.stiffness_n_per_m : 0.0;
    travel = std::min(distance, contact_at + press);
    zone.enabled = true;
    zone.p_start_base = X_BaseTcp.translation();
    zone.axis_base = axis;
    zone.contact_distance_m = contact_at;
    zone.stiffness_n_per_m = probe.stiffness_n_per_m;
  }

  MotionResult result;
  if (travel > 1e-9) {
    LinearMoveOptions options;
    options.X_ToolTcp = checker_.X_ToolTcp();
    options.max_tool_speed_m_s = request.speed_m_s;
    options.max_tool_acceleration_m_s2 = request.acceleration_m_s2;
    options.max_velocity_rad_s = checker_.limits().max_velocity_rad_s;
    options.max_acceleration_rad_s2 = checker_.limits().max_acceleration_rad_s2;
    options.sample_rate_hz = options_.planning_rate_hz;
    Eigen::Isometry3d X_stop = X_BaseTcp;
    X_stop.translation() += axis * travel;
    const LinearMoveResult plan = PlanLinearMove(checker_.kinematics(), q0, X_stop, options);
    if (!plan.ok) return Reject("guarded move: " + plan.reason);
    result = Run(plan.trajectory, {}, zone);
  } else {
    result = begin;
    result.outcome = MotionOutcome::kCompleted;
  }
  if (result.outcome != MotionOutcome::kCompleted) return result;

  double force_n = 0.0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (zone.enabled && probe.stiffness_n_per_m <= 0.0 && travel >= zone.contact_distance_m) {
      wrench_.head<3>() = -axis * request.force_threshold_n;
    }
    force_n = -wrench_.head<3>().dot(axis);
    result.final_state = StateLocked();
  }
  const Eigen::Vector3d p_end =
      (result.final_state.X_BaseTool * checker_.X_ToolTcp()).translation();
  const double travelled = (p_end - X_BaseTcp.translation()).dot(axis);
  const bool contact = force_n >= request.force_threshold_n * (1.0 - 1e-6);
  std::ostringstream os;
  os << (contact ? "contact with " + probe.what : std::string("no contact")) << " after "
     << travelled << " m, force " << force_n << " N";
  result.outcome = contact ? MotionOutcome::kContact : MotionOutcome::kCompleted;
  result.message = os.str();
  return result;
}

void SimBackend::Stop() {
  std::lock_guard<std::mutex> lock(mutex_);
  stop_requested_ = true;
  wake_.notify_all();
}

void SimBackend::ProtectiveStop() {
  std::lock_guard<std::mutex> lock(mutex_);
  protective_requested_ = true;
  status_ = RobotStatus::kProtectiveStop;
  qd_.setZero();
  wake_.notify_all();
}

bool SimBackend::ResetProtectiveStop(std::string* reason) {
  std::lock_guard<std::mutex> arm(arm_mutex_);
  SyncLocked();
  JointVector q;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (status_ != RobotStatus::kProtectiveStop) {
      if (reason) *reason = "the robot is not in a protective stop";
      return false;
    }
    q = q_;
  }
  ArmPlacement placement;
  try {
    placement = arm_->PlaceArm(q);
  } catch (const UnavailableError&) {
    throw;
  } catch (const std::exception& e) {
    throw UnavailableError(std::string("cannot check the simulated arm for collisions: ") +
                           e.what());
  }
  if (placement.in_collision) {
    if (reason) *reason = "the arm is still in collision: " + placement.collision_detail;
    return false;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  protective_requested_ = false;
  status_ = RobotStatus::kReady;
  return true;
}

}  // namespace picking::robot
