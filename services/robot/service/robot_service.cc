#include "services/robot/service/robot_service.h"

#include <grpcpp/server_context.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <limits>
#include <mutex>
#include <sstream>
#include <thread>

#include "libs/apc/catalogue.h"
#include "libs/errors/errors.h"
#include "libs/proto_convert/proto_convert.h"
#include "libs/runtime/status.h"
#include "libs/world/cell_config.h"
#include "services/robot/core/sim_backend.h"
#include "services/robot/core/ur_backend.h"
#include "services/robot/service/sim_arm_client.h"

namespace picking::robot {
namespace {

namespace pb = ::picking::robot::v1;
namespace pc = ::picking::proto_convert;

JointVector ToJointVector(const std::array<double, 6>& q) {
  JointVector v;
  for (int i = 0; i < 6; ++i) v[i] = q[i];
  return v;
}

// The `backend` setting as the contract names it; the setting is checked when the backend is
// connected ("sim" or "ur").
pb::RobotBackend BackendToProto(const std::string& name) {
  if (name == "sim") return pb::ROBOT_BACKEND_SIM;
  if (name == "ur") return pb::ROBOT_BACKEND_UR;
  return pb::ROBOT_BACKEND_UNSPECIFIED;
}

std::string Num(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}

// Smallest speed / acceleration fraction of MotionOptions and smallest guarded-move speed.
// Slower motions take hours and millions of samples; planning them wedged the server.
constexpr double kMinFraction = 1e-3;
constexpr double kMinGuardedSpeed_m_s = 1e-3;
// Longest ProtectiveStop reason kept: every refused motion quotes it.
constexpr std::size_t kMaxReasonBytes = 256;

// A fraction of MotionOptions: 0 means the default, otherwise [kMinFraction, 1].
double Fraction(double value, double default_value, const char* field) {
  if (value == 0.0) return default_value;
  if (!std::isfinite(value) || value < kMinFraction || value > 1.0) {
    throw std::invalid_argument(std::string("options.") + field + " must be in [" +
                                Num(kMinFraction) + ", 1] (or 0 for the default), got " +
                                Num(value));
  }
  return value;
}

// Joint positions of a repeated field: exactly 6 finite values.
JointVector JointsOf(const google::protobuf::RepeatedField<double>& values,
                     const std::string& field) {
  if (values.size() != ur10::kNumJoints) {
    throw std::invalid_argument(field + " needs 6 values, got " + std::to_string(values.size()));
  }
  JointVector q;
  for (int i = 0; i < ur10::kNumJoints; ++i) {
    if (!std::isfinite(values[i])) {
      throw std::invalid_argument(field + "[" + std::to_string(i) + "] is not finite");
    }
    q[i] = values[i];
  }
  return q;
}

// Largest TCP speed between consecutive samples, m/s.
double PeakToolSpeed(const JointTrajectory& trajectory, const SafetyChecker& checker) {
  double peak = 0.0;
  const auto& p = trajectory.points;
  Eigen::Vector3d previous = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < p.size(); ++i) {
    const Eigen::Vector3d tcp =
        (checker.kinematics().ForwardKinematics(p[i].q_rad) * checker.X_ToolTcp()).translation();
    if (i > 0) peak = std::max(peak, (tcp - previous).norm() / (p[i].time_s - p[i - 1].time_s));
    previous = tcp;
  }
  return peak;
}

// The joint positions of a trajectory's waypoints, after `q_start_rad` if given.
std::vector<JointVector> PathOf(const JointTrajectory& trajectory,
                                const JointVector* q_start_rad = nullptr) {
  std::vector<JointVector> path;
  path.reserve(trajectory.points.size() + 1);
  if (q_start_rad) path.push_back(*q_start_rad);
  for (const TrajectoryPoint& p : trajectory.points) path.push_back(p.q_rad);
  return path;
}

// Stops the arm when the call's deadline passes, the client cancels or the server shuts
// down while a motion runs.
class MotionWatch final {
 public:
  MotionWatch(grpc::ServerContext* context, RobotBackend* backend)
      : context_(context), backend_(backend) {
    thread_ = std::thread([this] { Run(); });
  }
  ~MotionWatch() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      done_ = true;
    }
    wake_.notify_all();
    thread_.join();
  }
  MotionWatch(const MotionWatch&) = delete;
  MotionWatch& operator=(const MotionWatch&) = delete;

  bool deadline_passed() const { return deadline_passed_; }
  bool cancelled() const { return cancelled_; }
  bool shutting_down() const { return shutting_down_; }

 private:
  void Run() {
    std::unique_lock<std::mutex> lock(mutex_);
    while (!done_) {
      // Poll fast for the first stop; afterwards only repeat it now and then, since a real
      // controller gets a script per Stop.
      wake_.wait_for(lock, std::chrono::milliseconds(stopping() ? 100 : 10));
      if (done_) return;
      if (!stopping()) {
        if (std::chrono::system_clock::now() >= context_->deadline()) {
          deadline_passed_ = true;
        } else if (context_->IsCancelled()) {
          cancelled_ = true;
        } else if (runtime::ShuttingDown()) {
          shutting_down_ = true;
        } else {
          continue;
        }
      }
      // Repeated until the motion returns: a stop that lands before the backend has begun
      // the motion would otherwise be lost and the motion run on unobserved.
      lock.unlock();
      backend_->Stop();
      lock.lock();
    }
  }
  bool stopping() const { return deadline_passed_ || cancelled_ || shutting_down_; }

  grpc::ServerContext* context_;
  RobotBackend* backend_;
  std::mutex mutex_;
  std::condition_variable wake_;
  bool done_ = false;
  std::atomic<bool> deadline_passed_{false};
  std::atomic<bool> cancelled_{false};
  std::atomic<bool> shutting_down_{false};
  std::thread thread_;
};

class RobotServiceImpl final : public pb::RobotService::Service {
 public:
  RobotServiceImpl(std::shared_ptr<RobotBackend> backend, const SafetyChecker& checker,
                   std::shared_ptr<const CollisionGuard> guard, const RobotServiceOptions& options)
      : backend_(std::move(backend)),
        checker_(checker),
        guard_(std::move(guard)),
        options_(options) {
    if (!backend_) throw std::invalid_argument("RobotService: null backend");
    if (!guard_) throw std::invalid_argument("RobotService: null collision guard");
    options_.Validate();
  }

  grpc::Status GetState(grpc::ServerContext*, const pb::GetStateRequest*,
                        pb::GetStateResponse* response) override {
    return runtime::Guard([&] {
      *response = StateToProto(CurrentState());
      return grpc::Status::OK;
    });
  }

  grpc::Status StreamState(grpc::ServerContext* context, const pb::StreamStateRequest* request,
                           grpc::ServerWriter<pb::StreamStateResponse>* writer) override {
    return runtime::Guard([&] {
      double rate_hz = request->rate_hz();
      if (rate_hz == 0.0) rate_hz = 10.0;
      if (!std::isfinite(rate_hz) || rate_hz <= 0.0 || rate_hz > 500.0) {
        return runtime::InvalidArgument("rate_hz must be in (0, 500] (or 0 for 10), got " +
                                        Num(rate_hz));
      }
      const auto period = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
          std::chrono::duration<double>(1.0 / rate_hz));
      auto next = std::chrono::steady_clock::now();
      while (true) {
        if (context->IsCancelled()) return grpc::Status(grpc::StatusCode::CANCELLED, "cancelled");
        pb::StreamStateResponse sample;
        *sample.mutable_state() = StateToProto(CurrentState());
        if (!writer->Write(sample)) return grpc::Status::OK;
        next += period;
        // Wait in short slices so a cancel or a shutdown ends the stream promptly.
        while (std::chrono::steady_clock::now() < next) {
          const auto slice = std::min<std::chrono::steady_clock::duration>(
              next - std::chrono::steady_clock::now(), std::chrono::milliseconds(50));
          if (runtime::WaitForShutdown(
                  std::chrono::duration_cast<std::chrono::milliseconds>(slice) +
                  std::chrono::milliseconds(slice < std::chrono::milliseconds(1) ? 1 : 0))) {
            return runtime::Unavailable("the robot server is shutting down");
          }
          if (context->IsCancelled()) {
            return grpc::Status(grpc::StatusCode::CANCELLED, "cancelled");
          }
        }
      }
    });
  }

  grpc::Status GetLimits(grpc::ServerContext*, const pb::GetLimitsRequest*,
                         pb::GetLimitsResponse* response) override {
    const SafetyLimits& limits = checker_.limits();
    for (int j = 0; j < ur10::kNumJoints; ++j) {
      auto* joint = response->add_joints();
      joint->set_name(ur10::kJointNames[j]);
      joint->set_min_position_rad(limits.min_position_rad[j]);
      joint->set_max_position_rad(limits.max_position_rad[j]);
      joint->set_max_velocity_rad_s(limits.max_velocity_rad_s[j]);
      joint->set_max_acceleration_rad_s2(limits.max_acceleration_rad_s2[j]);
    }
    response->set_max_tcp_speed_m_s(limits.max_tool_speed_m_s);
    *response->mutable_workspace()->mutable_min() = pc::VectorToProto(limits.workspace.min_m);
    *response->mutable_workspace()->mutable_max() = pc::VectorToProto(limits.workspace.max_m);
    for (const Box& zone : limits.forbidden_zones) {
      auto* box = response->add_forbidden_zones();
      *box->mutable_min() = pc::VectorToProto(zone.min_m);
      *box->mutable_max() = pc::VectorToProto(zone.max_m);
    }
    response->set_max_contact_force_n(options_.max_contact_force_n);
    return grpc::Status::OK;
  }

  grpc::Status MoveJoints(grpc::ServerContext* context, const pb::MoveJointsRequest* request,
                          pb::MoveJointsResponse* response) override {
    return runtime::Guard([&] {
      const JointVector target = ToJointVector(pc::JointsFromProto(request->target(), "target"));
      const double speed_fraction = Fraction(request->options().speed_fraction(),
                                             options_.default_speed_fraction, "speed_fraction");
      const double acceleration_fraction =
          Fraction(request->options().acceleration_fraction(),
                   options_.default_acceleration_fraction, "acceleration_fraction");
      const MotionSlot slot(this);
      const RobotState start = ReadyState();
      const ToolChecks tool = ToolNow();
      const SafetyChecker& checker = tool.checker;
      if (const SafetyCheck check = checker.CheckJointTarget(target); !check) {
        return runtime::InvalidArgument("target: " + check.reason);
      }
      const SafetyLimits& limits = checker.limits();
      double speed = speed_fraction * limits.max_velocity_rad_s.minCoeff();
      const double acceleration = acceleration_fraction * limits.max_acceleration_rad_s2.minCoeff();
      // The controller moves every joint synchronously on a trapezoid (UR movej); that path is
      // checked sample by sample, slowed down where the TCP would exceed its speed limit.
      JointTrajectory path;
      for (int attempt = 0; attempt < 10; ++attempt) {
        TimeParametrizationOptions profile;
        profile.max_velocity_rad_s = JointVector::Constant(speed);
        profile.max_acceleration_rad_s2 = JointVector::Constant(acceleration);
        path = TimeParametrizePath({start.q_rad, target}, profile);
        const double peak = PeakToolSpeed(path, checker);
        if (peak <= limits.max_tool_speed_m_s) break;
        speed *= 0.95 * limits.max_tool_speed_m_s / peak;
      }
      if (const SafetyCheck check = checker.CheckTrajectory(path, 1e-6); !check) {
        return runtime::InvalidArgument("path to the target: " + check.reason);
      }
      // The controller's path is the straight line in joint space.
      if (const SafetyCheck check = tool.guard->CheckJointMotion(start.q_rad, target); !check) {
        return runtime::InvalidArgument("path to the target: " + check.reason);
      }
      MotionResult result;
      grpc::Status status;
      {
        MotionWatch watch(context, backend_.get());
        result = backend_->MoveJoints(target, speed, acceleration);
        status = StatusOf(result, watch);
      }
      if (!status.ok()) return status;
      *response->mutable_final_state() = StateToProto(result.final_state);
      response->set_duration_s(std::max(0.0, result.final_state.timestamp_s - start.timestamp_s));
      return grpc::Status::OK;
    });
  }

  grpc::Status MoveLinear(grpc::ServerContext* context, const pb::MoveLinearRequest* request,
                          pb::MoveLinearResponse* response) override {
    return runtime::Guard([&] {
      const Eigen::Isometry3d X_BaseTcp_goal =
          pc::PoseFromProto(request->x_base_tcp_target(), "X_base_tcp_target");
      const double speed_fraction = Fraction(request->options().speed_fraction(),
                                             options_.default_speed_fraction, "speed_fraction");
      const double acceleration_fraction =
          Fraction(request->options().acceleration_fraction(),
                   options_.default_acceleration_fraction, "acceleration_fraction");
      const MotionSlot slot(this);
      const RobotState start = ReadyState();
      const ToolChecks tool = ToolNow();
      const SafetyChecker& checker = tool.checker;
      const SafetyLimits& limits = checker.limits();
      const double tool_speed = speed_fraction * limits.max_tool_speed_m_s;
      if (const SafetyCheck check =
              checker.CheckLinearMove(start.q_rad, X_BaseTcp_goal, tool_speed);
          !check) {
        return runtime::InvalidArgument("X_base_tcp_target: " + check.reason);
      }
      LinearMoveOptions options;
      options.X_ToolTcp = checker.X_ToolTcp();
      options.max_tool_speed_m_s = tool_speed;
      options.max_tool_acceleration_m_s2 =
          acceleration_fraction * options_.max_tcp_acceleration_m_s2;
      options.max_velocity_rad_s = limits.max_velocity_rad_s;
      options.max_acceleration_rad_s2 = limits.max_acceleration_rad_s2;
      const LinearMoveResult plan =
          PlanLinearMove(checker.kinematics(), start.q_rad, X_BaseTcp_goal, options);
      if (!plan.ok) return runtime::InvalidArgument("linear move: " + plan.reason);
      if (const SafetyCheck check = checker.CheckTrajectory(plan.trajectory, 1e-6); !check) {
        return runtime::InvalidArgument("linear move: " + check.reason);
      }
      if (const SafetyCheck check = tool.guard->CheckPath(PathOf(plan.trajectory)); !check) {
        return runtime::InvalidArgument("linear move: " + check.reason);
      }
      MotionResult result;
      grpc::Status status;
      {
        MotionWatch watch(context, backend_.get());
        result = backend_->ExecuteTrajectory(plan.trajectory, {});
        status = StatusOf(result, watch);
      }
      if (!status.ok()) return status;
      *response->mutable_final_state() = StateToProto(result.final_state);
      response->set_duration_s(std::max(0.0, result.final_state.timestamp_s - start.timestamp_s));
      return grpc::Status::OK;
    });
  }

  grpc::Status ExecuteTrajectory(
      grpc::ServerContext* context, const pb::ExecuteTrajectoryRequest* request,
      grpc::ServerWriter<pb::ExecuteTrajectoryResponse>* writer) override {
    return runtime::Guard([&] {
      const JointTrajectory trajectory = TrajectoryFromProto(request->trajectory());
      double tolerance = request->start_tolerance_rad();
      if (tolerance == 0.0) tolerance = options_.max_start_tolerance_rad;
      if (!std::isfinite(tolerance) || tolerance < 0.0 ||
          tolerance > options_.max_start_tolerance_rad) {
        return runtime::InvalidArgument("start_tolerance_rad must be in (0, " +
                                        Num(options_.max_start_tolerance_rad) + "], got " +
                                        Num(tolerance));
      }
      const MotionSlot slot(this);
      const RobotState start = ReadyState();
      const ToolChecks tool = ToolNow();
      if (const SafetyCheck check = tool.checker.CheckTrajectory(trajectory, 1e-6); !check) {
        return runtime::InvalidArgument("trajectory: " + check.reason);
      }
      const double start_error =
          (trajectory.points.front().q_rad - start.q_rad).cwiseAbs().maxCoeff();
      if (start_error > tolerance) {
        return runtime::InvalidArgument("trajectory: the first point is " + Num(start_error) +
                                        " rad from the current joint positions (tolerance " +
                                        Num(tolerance) + " rad)");
      }
      // Both backends move along the polyline of the waypoints, from where the arm is.
      if (const SafetyCheck check = tool.guard->CheckPath(PathOf(trajectory, &start.q_rad));
          !check) {
        return runtime::InvalidArgument("trajectory: " + check.reason);
      }
      auto report = [&](const TrajectoryProgress& progress) {
        pb::ExecuteTrajectoryResponse message;
        message.set_time_from_start_s(progress.time_s);
        message.set_fraction_done(std::clamp(progress.fraction, 0.0, 1.0));
        *message.mutable_joints() = JointStateToProto(progress.state);
        writer->Write(message);  // a client gone is noticed by the watch
      };
      MotionResult result;
      grpc::Status status;
      {
        MotionWatch watch(context, backend_.get());
        result = backend_->ExecuteTrajectory(trajectory, report);
        status = StatusOf(result, watch);
      }
      if (!status.ok()) return status;
      pb::ExecuteTrajectoryResponse last;
      last.set_time_from_start_s(trajectory.duration_s());
      last.set_fraction_done(1.0);
      *last.mutable_joints() = JointStateToProto(result.final_state);
      last.set_done(true);
      writer->Write(last);
      return grpc::Status::OK;
    });
  }

  grpc::Status GuardedMove(grpc::ServerContext* context, const pb::GuardedMoveRequest* request,
                           pb::GuardedMoveResponse* response) override {
    return runtime::Guard([&] {
      const Eigen::Vector3d direction = pc::VectorFromProto(request->direction(), "direction");
      if (std::abs(direction.norm() - 1.0) > 1e-3) {
        return runtime::InvalidArgument("direction must be a unit vector, its norm is " +
                                        Num(direction.norm()));
      }
      const double distance = request->max_distance_m();
      if (!std::isfinite(distance) || distance <= 0.0 || distance > 0.5) {
        return runtime::InvalidArgument("max_distance_m must be in (0, 0.5], got " + Num(distance));
      }
      const double force = request->force_threshold_n();
      if (!std::isfinite(force) || force <= 0.0 || force > options_.max_contact_force_n) {
        return runtime::InvalidArgument("force_threshold_n must be in (0, " +
                                        Num(options_.max_contact_force_n) + "], got " + Num(force));
      }
      double speed = request->speed_m_s();
      if (speed == 0.0) speed = 0.05;
      const double max_speed = std::min(0.25, checker_.limits().max_tool_speed_m_s);
      if (!std::isfinite(speed) || speed < kMinGuardedSpeed_m_s || speed > max_speed) {
        return runtime::InvalidArgument("speed_m_s must be in [" + Num(kMinGuardedSpeed_m_s) +
                                        ", " + Num(max_speed) + "] (or 0 for 0.05), got " +
                                        Num(speed));
      }
      const MotionSlot slot(this);
      const RobotState start = ReadyState();
      const ToolChecks tool = ToolNow();
      const SafetyChecker& checker = tool.checker;
      const Eigen::Isometry3d X_BaseTcp = start.X_BaseTool * checker.X_ToolTcp();
      const Eigen::Vector3d direction_tcp =
          request->in_tool_frame()
              ? direction.normalized()
              : Eigen::Vector3d(X_BaseTcp.linear().transpose() * direction.normalized());
      const Eigen::Vector3d axis_base = X_BaseTcp.linear() * direction_tcp;
      Eigen::Isometry3d X_goal = X_BaseTcp;
      X_goal.translation() += axis_base * distance;
      if (const SafetyCheck check = checker.CheckLinearMove(start.q_rad, X_goal, speed); !check) {
        return runtime::InvalidArgument("guarded move over the full distance: " + check.reason);
      }
      if (const SafetyCheck check =
              CheckGuardedPath(tool, start.q_rad, X_BaseTcp, axis_base, distance);
          !check) {
        return runtime::InvalidArgument("guarded move: " + check.reason);
      }
      GuardedMoveRequest move;
      move.direction_tcp = direction_tcp;
      move.max_distance_m = distance;
      move.speed_m_s = speed;
      move.acceleration_m_s2 = options_.guarded_acceleration_m_s2;
      move.force_threshold_n = force;
      MotionResult result;
      grpc::Status status;
      {
        MotionWatch watch(context, backend_.get());
        result = backend_->GuardedMove(move);
        status = StatusOf(result, watch);
      }
      if (!status.ok()) return status;
      const Eigen::Vector3d p_end =
          (result.final_state.X_BaseTool * checker.X_ToolTcp()).translation();
      response->set_contact(result.outcome == MotionOutcome::kContact);
      response->set_distance_travelled_m((p_end - X_BaseTcp.translation()).dot(axis_base));
      response->set_contact_force_n(
          std::max(0.0, -result.final_state.wrench_base.head<3>().dot(axis_base)));
      *response->mutable_final_state() = StateToProto(result.final_state);
      return grpc::Status::OK;
    });
  }

  grpc::Status Stop(grpc::ServerContext*, const pb::StopRequest*, pb::StopResponse*) override {
    return runtime::Guard([&] {
      backend_->Stop();
      return grpc::Status::OK;
    });
  }

  grpc::Status ProtectiveStop(grpc::ServerContext*, const pb::ProtectiveStopRequest* request,
                              pb::ProtectiveStopResponse*) override {
    return runtime::Guard([&] {
      {
        std::lock_guard<std::mutex> lock(mutex_);
        latched_ = true;
        // Stored cut: every refused motion quotes it until the reset.
        detail_ = request->reason().empty()
                      ? "protective stop requested"
                      : "protective stop requested: " +
                            runtime::CutMessage(request->reason(), kMaxReasonBytes);
      }
      backend_->ProtectiveStop();
      // A controller applies the stop asynchronously: answer once it reports it.
      WaitForStatus([](RobotStatus s) { return s == RobotStatus::kProtectiveStop; });
      return grpc::Status::OK;
    });
  }

  grpc::Status ResetProtectiveStop(grpc::ServerContext*, const pb::ResetProtectiveStopRequest*,
                                   pb::ResetProtectiveStopResponse*) override {
    return runtime::Guard([&] {
      std::string reason;
      if (!backend_->ResetProtectiveStop(&reason)) {
        return runtime::FailedPrecondition("protective stop not cleared: " + reason);
      }
      WaitForStatus([](RobotStatus s) { return s != RobotStatus::kProtectiveStop; });
      std::lock_guard<std::mutex> lock(mutex_);
      latched_ = false;
      detail_.clear();
      return grpc::Status::OK;
    });
  }

 private:
  // Moves are exclusive: a second one is refused rather than queued. While a slot is held
  // the arm counts as moving, also after a stop while the backend still winds the motion
  // down: a client that sees IDLE may start the next motion.
  class MotionSlot {
   public:
    explicit MotionSlot(RobotServiceImpl* robot)
        : lock_(robot->motion_mutex_, std::try_to_lock), running_(&robot->motion_running_) {
      if (!lock_.owns_lock()) throw PreconditionError("another motion is running");
      running_->store(true);
    }
    ~MotionSlot() { running_->store(false); }
    MotionSlot(const MotionSlot&) = delete;
    MotionSlot& operator=(const MotionSlot&) = delete;

   private:
    std::unique_lock<std::mutex> lock_;
    std::atomic<bool>* running_;
  };

  // The backend's state, MOVING while a motion call is in progress.
  RobotState CurrentState() {
    RobotState state = backend_->GetState();
    if (state.status == RobotStatus::kReady && motion_running_.load()) {
      state.status = RobotStatus::kMoving;
    }
    return state;
  }

  // A guarded move's swept path: the arm and the gripper tube along the straight tcp line up
  // to where the cup would meet a static surface (board, tote, table, floor, pedestal), or
  // the full distance. The cup's touch is the contact the move is meant to find: the force
  // threshold stops it there, so the travel beyond is the contact's, not a collision's.
  // The checks of one motion, with the gripper's head where the robot's world has it now.
  struct ToolChecks {
    SafetyChecker checker;
    std::shared_ptr<const CollisionGuard> guard;
  };
  ToolChecks ToolNow() const {
    const double head_rad = backend_->GripperHeadAngle();
    try {
      return {checker_.WithHeadAngle(head_rad), guard_->ForHeadAngle(head_rad)};
    } catch (const std::invalid_argument& e) {
      throw PreconditionError(std::string("the gripper's head does not match the cell: ") +
                              e.what());
    }
  }

  SafetyCheck CheckGuardedPath(const ToolChecks& tool, const JointVector& q_start_rad,
                               const Eigen::Isometry3d& X_BaseTcp, const Eigen::Vector3d& axis_Base,
                               double distance_m) const {
    const double travel_m =
        tool.guard->CupTravelToStaticContact(X_BaseTcp.translation(), axis_Base, distance_m);
    if (travel_m <= 1e-9) return tool.guard->CheckPath({q_start_rad});
    Eigen::Isometry3d X_BaseTcp_contact = X_BaseTcp;
    X_BaseTcp_contact.translation() += axis_Base * travel_m;
    LinearMoveOptions options;
    options.X_ToolTcp = tool.checker.X_ToolTcp();
    const LinearMoveResult line = SampleLinearPath(tool.checker.kinematics(), q_start_rad,
                                                   X_BaseTcp_contact, options, 0.005, 0.02);
    if (!line.ok) return SafetyCheck::Fail(line.reason);
    return tool.guard->CheckPath(PathOf(line.trajectory));
  }

  // Polls the backend's state until `done` holds, at most kStatusWait.
  void WaitForStatus(const std::function<bool(RobotStatus)>& done) {
    constexpr auto kStatusWait = std::chrono::seconds(2);
    const auto deadline = std::chrono::steady_clock::now() + kStatusWait;
    while (!done(backend_->GetState().status) && std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
  }

  // The current state if the arm may move now. @throws PreconditionError / UnavailableError.
  RobotState ReadyState() {
    const RobotState state = backend_->GetState();
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (latched_) {
        throw PreconditionError("protective stop active (" + detail_ +
                                "); call ResetProtectiveStop first");
      }
    }
    switch (state.status) {
      case RobotStatus::kReady:
        return state;
      case RobotStatus::kUnknown:
        throw UnavailableError("no state received from the robot yet");
      case RobotStatus::kProtectiveStop:
        throw PreconditionError("protective stop active; call ResetProtectiveStop first");
      default:
        throw PreconditionError(std::string("the robot cannot move now: ") +
                                RobotStatusName(state.status));
    }
  }

  grpc::Status StatusOf(const MotionResult& result, const MotionWatch& watch) {
    switch (result.outcome) {
      case MotionOutcome::kCompleted:
      case MotionOutcome::kContact:
        return grpc::Status::OK;
      case MotionOutcome::kRejected:
        if (result.message.rfind("robot is not ready", 0) == 0) {
          return runtime::FailedPrecondition(result.message);
        }
        if (result.message.rfind("no robot state", 0) == 0) {
          return runtime::Unavailable(result.message);
        }
        return runtime::InvalidArgument(result.message);
      case MotionOutcome::kStopped:
        if (watch.deadline_passed()) {
          return grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED,
                              "the motion did not finish within the call's deadline; the arm "
                              "is stopped");
        }
        if (watch.cancelled()) {
          return grpc::Status(grpc::StatusCode::CANCELLED, "cancelled; the arm is stopped");
        }
        if (watch.shutting_down()) {
          return runtime::Unavailable("the robot server is shutting down; the arm is stopped");
        }
        return grpc::Status(grpc::StatusCode::ABORTED, "motion stopped by Stop");
      case MotionOutcome::kProtectiveStop: {
        std::lock_guard<std::mutex> lock(mutex_);
        if (!latched_) detail_ = result.message;
        latched_ = true;
        return grpc::Status(grpc::StatusCode::ABORTED, "motion interrupted: " + detail_);
      }
      case MotionOutcome::kFailed:
        if (result.message.find("timed out") != std::string::npos) {
          return grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED, result.message);
        }
        return runtime::Unavailable(result.message);
    }
    return grpc::Status(grpc::StatusCode::INTERNAL, "unknown motion outcome");
  }

  pb::GetStateResponse StateToProto(const RobotState& state) {
    pb::GetStateResponse out;
    *out.mutable_joints() = JointStateToProto(state);
    *out.mutable_x_base_tool() = pc::PoseToProto(state.X_BaseTool);
    *out.mutable_x_base_tcp() =
        pc::PoseToProto(state.X_BaseTool * checker_.X_ToolTcpAt(state.gripper_head_angle_rad));
    *out.mutable_tcp_wrench()->mutable_force_n() = pc::VectorToProto(state.wrench_base.head<3>());
    *out.mutable_tcp_wrench()->mutable_torque_nm() = pc::VectorToProto(state.wrench_base.tail<3>());
    out.set_backend(BackendToProto(options_.backend_name));
    out.set_stamp_unix_ns(std::chrono::duration_cast<std::chrono::nanoseconds>(
                              std::chrono::system_clock::now().time_since_epoch())
                              .count());
    bool latched = false;
    std::string detail;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      latched = latched_;
      detail = detail_;
    }
    switch (state.status) {
      case RobotStatus::kReady:
        out.set_status(pb::ROBOT_STATUS_IDLE);
        break;
      case RobotStatus::kMoving:
        out.set_status(pb::ROBOT_STATUS_MOVING);
        break;
      case RobotStatus::kProtectiveStop:
        out.set_status(pb::ROBOT_STATUS_PROTECTIVE_STOP);
        if (detail.empty()) detail = "protective stop";
        break;
      case RobotStatus::kEmergencyStop:
      case RobotStatus::kFault:
        out.set_status(pb::ROBOT_STATUS_PROTECTIVE_STOP);
        detail = RobotStatusName(state.status);
        break;
      case RobotStatus::kPoweredOff:
        out.set_status(pb::ROBOT_STATUS_POWERED_OFF);
        break;
      case RobotStatus::kUnknown:
        out.set_status(pb::ROBOT_STATUS_DISCONNECTED);
        break;
    }
    // The service's latch wins over a controller state that has not caught up yet.
    if (latched && state.status != RobotStatus::kEmergencyStop &&
        state.status != RobotStatus::kFault) {
      out.set_status(pb::ROBOT_STATUS_PROTECTIVE_STOP);
    }
    if (out.status() == pb::ROBOT_STATUS_PROTECTIVE_STOP) out.set_status_detail(detail);
    return out;
  }

  static common::v1::JointState JointStateToProto(const RobotState& state) {
    common::v1::JointState out;
    for (int j = 0; j < ur10::kNumJoints; ++j) {
      out.add_positions_rad(state.q_rad[j]);
      out.add_velocities_rad_s(state.qd_rad_s[j]);
    }
    return out;
  }

  static JointTrajectory TrajectoryFromProto(const common::v1::JointTrajectory& in) {
    constexpr int kMaxPoints = 1'000'000;
    if (in.points_size() == 0) throw std::invalid_argument("trajectory has no points");
    if (in.points_size() > kMaxPoints) {
      throw std::invalid_argument("trajectory has more than " + std::to_string(kMaxPoints) +
                                  " points");
    }
    JointTrajectory out;
    out.points.reserve(in.points_size());
    for (int i = 0; i < in.points_size(); ++i) {
      const auto& p = in.points(i);
      const std::string field = "trajectory.points[" + std::to_string(i) + "]";
      TrajectoryPoint point;
      point.time_s = p.time_from_start_s();
      if (!std::isfinite(point.time_s)) {
        throw std::invalid_argument(field + ".time_from_start_s is not finite");
      }
      point.q_rad = JointsOf(p.positions_rad(), field + ".positions_rad");
      if (p.velocities_rad_s_size() > 0) {
        point.qd_rad_s = JointsOf(p.velocities_rad_s(), field + ".velocities_rad_s");
      }
      if (p.accelerations_rad_s2_size() > 0) {
        point.qdd_rad_s2 = JointsOf(p.accelerations_rad_s2(), field + ".accelerations_rad_s2");
      }
      out.points.push_back(point);
    }
    if (std::abs(out.points.front().time_s) > 1e-9) {
      throw std::invalid_argument("trajectory.points[0].time_from_start_s must be 0, got " +
                                  Num(out.points.front().time_s));
    }
    if (!(out.duration_s() <= kMaxTrajectoryDuration_s)) {
      throw std::invalid_argument("trajectory lasts " + Num(out.duration_s()) +
                                  " s, more than the " + Num(kMaxTrajectoryDuration_s) +
                                  " s limit");
    }
    return out;
  }

  std::shared_ptr<RobotBackend> backend_;
  SafetyChecker checker_;
  std::shared_ptr<const CollisionGuard> guard_;
  RobotServiceOptions options_;
  std::mutex motion_mutex_;
  std::atomic<bool> motion_running_{false};  // A MotionSlot is held.
  std::mutex mutex_;
  bool latched_ = false;  // protective stop requested or seen, until reset
  std::string detail_;
};

// "x, y, z" of a 3-vector setting.
Eigen::Vector3d Vector3Setting(const runtime::Config& config, const std::string& key,
                               const Eigen::Vector3d& default_value) {
  const std::vector<double> v =
      config.GetDoubles(key, {default_value.x(), default_value.y(), default_value.z()});
  if (v.size() != 3) {
    throw std::invalid_argument("setting '" + key + "' needs 3 values, got " +
                                std::to_string(v.size()));
  }
  return Eigen::Vector3d(v[0], v[1], v[2]);
}

std::vector<std::string> SplitNames(const std::string& text) {
  std::vector<std::string> names;
  std::string current;
  auto flush = [&] {
    const auto b = current.find_first_not_of(" \t[]");
    const auto e = current.find_last_not_of(" \t[]");
    if (b != std::string::npos) names.push_back(current.substr(b, e - b + 1));
    current.clear();
  };
  for (char c : text) {
    if (c == ',') {
      flush();
    } else {
      current += c;
    }
  }
  flush();
  return names;
}

// Default forbidden zones of the cell in data/cell/default_cell.yaml (base frame): the
// pedestal under the robot and the shelf's solid base below the lowest bins.
struct ZoneDefault {
  const char* name;
  Eigen::Vector3d min_m, max_m;
};
const std::vector<ZoneDefault>& DefaultZones() {
  static const std::vector<ZoneDefault> kZones = {
      {"pedestal", {-0.25, -0.25, -0.70}, {0.25, 0.25, -0.05}},
      {"shelf_base", {0.80, -0.50, -0.70}, {1.70, 0.50, 0.07}},
  };
  return kZones;
}

// The swept-path check over the static cell of the cell description the planner and the
// simulator load, with the planner's gripper tube and padding.
std::shared_ptr<const CollisionGuard> BuildCollisionGuard(const ur10::Ur10Kinematics& kinematics,
                                                          const world::CellConfig& cell_config) {
  const planner::GripperGeometry gripper = planner::GripperGeometry::FromCell(cell_config.gripper);
  world::CellModel cell;
  try {
    cell = world::LoadCellModel(cell_config);
  } catch (const std::runtime_error& e) {
    throw std::invalid_argument(std::string("setting 'cell': ") + e.what());
  }
  return std::make_shared<const CollisionGuard>(kinematics, cell, gripper);
}

}  // namespace

void RobotServiceOptions::Validate() const {
  auto positive = [](double v, const char* field) {
    if (!std::isfinite(v) || v <= 0.0) {
      throw std::invalid_argument(std::string(field) + " must be finite and > 0");
    }
  };
  auto fraction = [](double v, const char* field) {
    if (!std::isfinite(v) || v <= 0.0 || v > 1.0) {
      throw std::invalid_argument(std::string(field) + " must be in (0, 1]");
    }
  };
  fraction(default_speed_fraction, "motion.default_speed_fraction");
  fraction(default_acceleration_fraction, "motion.default_acceleration_fraction");
  positive(max_tcp_acceleration_m_s2, "safety.max_tcp_acceleration_m_s2");
  positive(max_contact_force_n, "safety.max_contact_force_n");
  positive(guarded_acceleration_m_s2, "guarded.acceleration_m_s2");
  positive(max_start_tolerance_rad, "max_start_tolerance_rad");
}

std::shared_ptr<v1::RobotService::Service> MakeRobotService(
    std::shared_ptr<RobotBackend> backend, const SafetyChecker& checker,
    std::shared_ptr<const CollisionGuard> guard, const RobotServiceOptions& options) {
  return std::make_shared<RobotServiceImpl>(std::move(backend), checker, std::move(guard), options);
}

namespace {

world::CellConfig CellConfigFrom(const runtime::Config& config, const std::string& data_dir) {
  const std::string cell_path = config.GetPath("cell", world::DefaultCellConfigPath(data_dir));
  try {
    return world::ReadCellConfig(cell_path);
  } catch (const world::CellConfigError& e) {
    throw std::invalid_argument(std::string("setting 'cell': ") + e.what());
  }
}

// The forbidden zones the settings name: the built-in ones by name, others from their
// safety.zone.<name>.min_m / .max_m settings (which may also move a built-in one).
std::vector<Box> ForbiddenZonesFrom(const runtime::Config& config) {
  std::string default_zone_names;
  for (const ZoneDefault& zone : DefaultZones()) {
    default_zone_names += (default_zone_names.empty() ? "" : ",") + std::string(zone.name);
  }
  std::vector<Box> zones;
  for (const std::string& name :
       SplitNames(config.GetString("safety.forbidden_zones", default_zone_names))) {
    Eigen::Vector3d min_m = Eigen::Vector3d::Constant(std::nan(""));
    Eigen::Vector3d max_m = min_m;
    for (const ZoneDefault& zone : DefaultZones()) {
      if (name == zone.name) min_m = zone.min_m, max_m = zone.max_m;
    }
    const std::string prefix = "safety.zone." + name;
    if (!min_m.allFinite() && (!config.Has(prefix + ".min_m") || !config.Has(prefix + ".max_m"))) {
      throw std::invalid_argument("forbidden zone '" + name + "' needs settings '" + prefix +
                                  ".min_m' and '" + prefix + ".max_m'");
    }
    zones.push_back({name,
                     Vector3Setting(config, prefix + ".min_m",
                                    min_m.allFinite() ? min_m : Eigen::Vector3d::Zero()),
                     Vector3Setting(config, prefix + ".max_m",
                                    max_m.allFinite() ? max_m : Eigen::Vector3d::Zero())});
  }
  return zones;
}

// Joint, speed and workspace limits: the model's joint limits, the workspace box and the
// forbidden zones.
SafetyLimits SafetyLimitsFrom(const runtime::Config& config, const ur10::Ur10Model& model) {
  Box workspace;
  workspace.name = "workspace";
  workspace.min_m =
      Vector3Setting(config, "safety.workspace_min_m", Eigen::Vector3d(-1.2, -1.4, -0.68));
  workspace.max_m =
      Vector3Setting(config, "safety.workspace_max_m", Eigen::Vector3d(1.3, 1.4, 1.5));
  SafetyLimits limits =
      SafetyLimits::FromModel(model, workspace, config.GetDouble("safety.max_tcp_speed_m_s", 0.5));
  limits.forbidden_zones = ForbiddenZonesFrom(config);
  const double joint_speed_scale = config.GetDouble("safety.joint_speed_scale", 1.0);
  if (!std::isfinite(joint_speed_scale) || joint_speed_scale <= 0.0 || joint_speed_scale > 1.0) {
    throw std::invalid_argument("setting 'safety.joint_speed_scale' must be in (0, 1]");
  }
  limits.max_velocity_rad_s *= joint_speed_scale;
  limits.Validate();
  return limits;
}

RobotServiceOptions RobotServiceOptionsFrom(const runtime::Config& config) {
  RobotServiceOptions options;
  options.default_speed_fraction =
      config.GetDouble("motion.default_speed_fraction", options.default_speed_fraction);
  options.default_acceleration_fraction = config.GetDouble("motion.default_acceleration_fraction",
                                                           options.default_acceleration_fraction);
  options.max_tcp_acceleration_m_s2 =
      config.GetDouble("safety.max_tcp_acceleration_m_s2", options.max_tcp_acceleration_m_s2);
  options.max_contact_force_n =
      config.GetDouble("safety.max_contact_force_n", options.max_contact_force_n);
  options.guarded_acceleration_m_s2 =
      config.GetDouble("guarded.acceleration_m_s2", options.guarded_acceleration_m_s2);
  options.backend_name = config.GetString("backend", "sim");
  return options;
}

// The sim backend's settings (sim.*), read whichever backend is chosen.
struct SimSettings {
  std::string address;
  SimBackendOptions backend;
  SimulatorArmClientOptions arm;
};

SimSettings SimSettingsFrom(const runtime::Config& config) {
  SimSettings sim;
  sim.address = config.GetString("sim.address", "127.0.0.1:50051");
  sim.backend.time_scale = config.GetDouble("sim.time_scale", sim.backend.time_scale);
  sim.backend.command_rate_hz = config.GetDouble("sim.rate_hz", sim.backend.command_rate_hz);
  sim.backend.stop_acceleration_rad_s2 =
      config.GetDouble("sim.stop_acceleration_rad_s2", sim.backend.stop_acceleration_rad_s2);
  sim.backend.link_check_period_s =
      config.GetDouble("sim.link_check_period_s", sim.backend.link_check_period_s);
  sim.arm.timeout_s = config.GetDouble("sim.timeout_s", sim.arm.timeout_s);
  const std::vector<double> initial =
      config.GetDoubles("sim.initial_joints_rad",
                        std::vector<double>(sim.arm.initial_joints_rad.data(),
                                            sim.arm.initial_joints_rad.data() + ur10::kNumJoints));
  if (initial.size() != ur10::kNumJoints) {
    throw std::invalid_argument("setting 'sim.initial_joints_rad' needs 6 values");
  }
  for (int j = 0; j < ur10::kNumJoints; ++j) sim.arm.initial_joints_rad[j] = initial[j];
  return sim;
}

// The ur backend's settings (ur.*), read whichever backend is chosen.
struct UrSettings {
  UrBackendOptions backend;
  bool power_on = false;
};

UrSettings UrSettingsFrom(const runtime::Config& config) {
  UrSettings ur;
  UrBackendOptions& o = ur.backend;
  o.host = config.GetString("ur.host", o.host);
  auto port = [&](const std::string& key, std::uint16_t default_value) {
    const long long value = config.GetInt(key, default_value);
    if (value < 1 || value > 65535) {
      throw std::invalid_argument("setting '" + key + "' must be a port in [1, 65535]");
    }
    return static_cast<std::uint16_t>(value);
  };
  o.rtde_port = port("ur.rtde_port", o.rtde_port);
  o.script_port = port("ur.script_port", o.script_port);
  o.dashboard_port = port("ur.dashboard_port", o.dashboard_port);
  o.rtde_frequency_hz = config.GetDouble("ur.rtde_frequency_hz", o.rtde_frequency_hz);
  const double connect_timeout_s = config.GetDouble("ur.connect_timeout_s", 3.0);
  if (!std::isfinite(connect_timeout_s) || connect_timeout_s <= 0.0) {
    throw std::invalid_argument("setting 'ur.connect_timeout_s' must be > 0");
  }
  o.connect_timeout = std::chrono::milliseconds(static_cast<long long>(connect_timeout_s * 1000.0));
  ur.power_on = config.GetBool("ur.power_on", false);
  if (!std::isfinite(o.rtde_frequency_hz) || o.rtde_frequency_hz <= 0.0 ||
      o.rtde_frequency_hz > 500.0) {
    throw std::invalid_argument("setting 'ur.rtde_frequency_hz' must be in (0, 500]");
  }
  return ur;
}

std::shared_ptr<RobotBackend> ConnectBackend(const std::string& name, const SimSettings& sim,
                                             const UrSettings& ur, const SafetyChecker& checker,
                                             const runtime::ChannelFactory& sim_channels) {
  if (name == "sim") {
    return std::make_shared<SimBackend>(
        SimulatorArmClient::Connect(sim.address, sim.arm, sim_channels), checker, sim.backend);
  }
  if (name == "ur") {
    std::shared_ptr<UrBackend> backend;
    try {
      backend = UrBackend::Connect(ur.backend, checker);
    } catch (const std::exception& e) {
      throw std::runtime_error("UR controller at " + ur.backend.host + " unreachable: " + e.what());
    }
    if (ur.power_on) backend->PowerOnAndReleaseBrakes(std::chrono::seconds(30));
    return backend;
  }
  throw std::invalid_argument("setting 'backend' must be 'sim' or 'ur', got '" + name + "'");
}

}  // namespace

runtime::ServiceSet BuildRobotServices(const runtime::Config& config) {
  // The UR10 model, and the gripper's tool centre point from the cell description.
  const std::string data_dir = config.GetString("data_dir", apc::DefaultDataDir());
  ur10::Ur10ModelOptions model_options;
  model_options.max_acceleration_rad_s2 =
      config.GetDouble("ur10.max_acceleration_rad_s2", model_options.max_acceleration_rad_s2);
  const ur10::Ur10Model model = ur10::Ur10Model::Load(data_dir + "/ur10", model_options);
  const world::CellConfig cell_config = CellConfigFrom(config, data_dir);
  const ur10::Ur10Kinematics kinematics(model);
  const SafetyChecker checker(kinematics, SafetyLimitsFrom(config, model), cell_config.gripper);
  const std::shared_ptr<const CollisionGuard> guard = BuildCollisionGuard(kinematics, cell_config);
  const RobotServiceOptions options = RobotServiceOptionsFrom(config);

  // Both backends' settings are read whichever is chosen, so one file can hold both.
  const runtime::ChannelFactory sim_channels = runtime::ChannelFactory::FromConfig(config);
  const SimSettings sim = SimSettingsFrom(config);
  const UrSettings ur = UrSettingsFrom(config);
  const std::shared_ptr<RobotBackend> backend =
      ConnectBackend(options.backend_name, sim, ur, checker, sim_channels);

  runtime::ServiceSet set;
  set.Add(MakeRobotService(backend, checker, guard, options),
          v1::RobotService::service_full_name());
  set.on_shutdown = [backend] { backend->Stop(); };
  return set;
}

}  // namespace picking::robot
