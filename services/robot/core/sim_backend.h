#pragma once

#include <Eigen/Geometry>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "services/robot/core/checked_backend.h"
#include "services/robot/core/robot_backend.h"
#include "services/robot/core/safety.h"

namespace picking::robot {

/// Result of putting the simulated arm at joint positions.
struct ArmPlacement {
  /// True if the arm or gripper intersects the cell at these joints.
  bool in_collision = false;
  /// Which link hit what (empty without a collision).
  std::string collision_detail;
  /// The world's tool centre point (the suction cup) at these joints, when it reports one:
  /// SimBackend checks it against its own X_BaseTool * X_ToolTcp.
  std::optional<Eigen::Isometry3d> X_BaseTcp;
};

/// Where the suction cup touches along a straight tool motion.
struct ContactProbe {
  bool contact = false;
  /// Travel along the direction until first touch, m (valid with `contact`).
  double distance_m = 0.0;
  /// Spring constant of the touched surface, N/m (> 0 with `contact`).
  double stiffness_n_per_m = 0.0;
  /// What is touched, for messages (item name or surface).
  std::string what;
};

/// The simulated world as the SimBackend sees it (the simulator service over gRPC in
/// production, an in-process model in tests). Calls may block; they are made from one
/// thread at a time.
class SimulatedArm {
 public:
  virtual ~SimulatedArm() = default;
  /// The arm's joint positions now. @throws UnavailableError if the world is unreachable,
  /// std::runtime_error for other failures.
  virtual JointVector ReadJoints() = 0;
  /// Asks whether the world answers, changing nothing (the link check of an idle arm).
  /// @throws as ReadJoints. Default: ReadJoints.
  virtual void CheckReachable() { ReadJoints(); }
  /// Puts the arm at `q_rad`. @throws as ReadJoints.
  virtual ArmPlacement PlaceArm(const JointVector& q_rad) = 0;
  /// The gripper's head on its servo joint now, radians (0: straight, or no joint).
  /// @throws as ReadJoints. Default: 0.
  virtual double ReadHeadAngle() { return 0.0; }
  /// Probes a straight motion of the TCP from the flange pose `X_BaseTool` along
  /// `direction_tcp` (unit, TCP frame) over at most `max_distance_m`. @throws as ReadJoints.
  virtual ContactProbe Probe(const Eigen::Isometry3d& X_BaseTool,
                             const Eigen::Vector3d& direction_tcp, double max_distance_m) = 0;
};

/// Options of SimBackend.
struct SimBackendOptions {
  /// Simulated seconds per wall-clock second (> 0): 10 runs motions ten times faster than
  /// real time.
  double time_scale = 1.0;
  /// Joint positions sent to the simulated arm per simulated second (> 0).
  double command_rate_hz = 50.0;
  /// Sample rate of the trajectories planned for MoveJoints and GuardedMove, Hz (> 0).
  double planning_rate_hz = 125.0;
  /// Joint deceleration of Stop(), rad/s^2 (> 0).
  double stop_acceleration_rad_s2 = 3.0;
  /// Largest distance (rad, max over joints) between a trajectory's first point and the arm.
  double start_tolerance_rad = 0.01;
  /// GetState asks the world again when its last answer is older than this, wall-clock s
  /// (>= 0; 0: at every call): a world that went away is reported (UnavailableError) within
  /// this bound plus one call's timeout, instead of the last commanded state.
  double link_check_period_s = 0.5;
  /// The wall clock of the link check (injectable for tests).
  std::function<std::chrono::steady_clock::time_point()> now = std::chrono::steady_clock::now;
  /// @throws std::invalid_argument naming the bad field.
  void Validate() const;
};

/// RobotBackend of a simulated arm. Motions are time-parametrised (TimeParametrizePath for
/// joint moves, PlanLinearMove for guarded moves) and streamed to the SimulatedArm by
/// sampling the trajectory at options.command_rate_hz of simulated time, paced in real time
/// divided by options.time_scale. A collision reported by the arm is a protective stop: the
/// arm goes back to the last collision-free sample, the status latches kProtectiveStop and
/// the motion ends with kProtectiveStop naming what hit. A guarded move probes the contact
/// along its direction first, then travels to the contact plus the press needed to reach the
/// force threshold (force = stiffness * press, capped by the maximum distance); touching
/// beyond the contact point is expected and not a collision. A world that places the tool
/// centre point elsewhere than the checker's X_ToolTcp (more than 1e-6 m or 1e-6 rad apart:
/// the simulator and the robot loaded different cell descriptions) fails the motion at its
/// first sample with kFailed naming both poses. The state (joints, wrench,
/// status) is the commanded one, read from the world once at first use and again after the
/// world was unreachable. The link is watched: GetState reads the world's joints whenever its
/// last answer is older than options.link_check_period_s, so a world that stopped answering
/// makes GetState throw UnavailableError (naming it) rather than report a stale state.
class SimBackend final : public CheckedBackend {
 public:
  /// @throws std::invalid_argument for a null arm or bad options.
  SimBackend(std::shared_ptr<SimulatedArm> arm, const SafetyChecker& checker,
             const SimBackendOptions& options);

  /// @throws UnavailableError if the world cannot be read (first use, after it was
  /// unreachable, or at a due link check).
  RobotState GetState() override;
  void Stop() override;
  void ProtectiveStop() override;
  /// @throws UnavailableError if the world cannot be asked whether the arm is still in
  /// collision.
  bool ResetProtectiveStop(std::string* reason) override;
  /// The world's head angle, read now.
  double GripperHeadAngle() override;

 private:
  // Reads the gripper's head angle from the world and checks the motion that follows with
  // it (checker_ from base_checker_); keeps the last angle when the world does not answer
  // (the motion then fails to synchronise).
  void RefreshTool();
  // Reads the joints from the world if not done yet. Caller holds arm_mutex_.
  void SyncLocked();
  // Asks the world whether it still answers (SyncLocked if not synced). Caller holds
  // arm_mutex_. @throws UnavailableError naming the world, which must then be read again.
  void CheckLinkLocked();
  // A world call answered now. Caller holds mutex_.
  void MarkContactLocked() { last_contact_ = options_.now(); }
  // True when the world has not answered for link_check_period_s. Caller holds mutex_.
  bool LinkCheckDueLocked() const;
  // CheckedBackend's hooks. The checker is the one at the head's angle read from the world;
  // BeginMotion synchronises and checks the arm is ready.
  const SafetyChecker& CheckerForMotion() override;
  MotionResult Reject(const std::string& why) override;
  MotionResult BeginMotion() override;
  MotionResult RunJointMove(const MotionResult& begin, const JointVector& q_target_rad,
                            double speed_rad_s, double acceleration_rad_s2,
                            const JointTrajectory& line) override;
  MotionResult RunTrajectory(
      const MotionResult& begin, const JointTrajectory& trajectory,
      const std::function<void(const TrajectoryProgress&)>& progress) override;
  MotionResult RunGuardedMove(const MotionResult& begin, const GuardedMoveRequest& request,
                              const GuardedMovePlan& plan) override;
  // Streams `trajectory`; collisions closer than `contact_distance_m` along `axis_base`
  // from `p_start_tcp` are protective stops, beyond it expected contact (guarded moves).
  struct ContactZone {
    bool enabled = false;
    Eigen::Vector3d p_start_base = Eigen::Vector3d::Zero();
    Eigen::Vector3d axis_base = Eigen::Vector3d::UnitZ();
    double contact_distance_m = 0.0;
    double stiffness_n_per_m = 0.0;
  };
  MotionResult Run(const JointTrajectory& trajectory,
                   const std::function<void(const TrajectoryProgress&)>& progress,
                   const ContactZone& zone);
  // Ends the motion: the arm at rest with `status` (unless a protective stop holds it).
  MotionResult FinishMotion(MotionOutcome outcome, const std::string& message, RobotStatus status);
  // Places the simulated arm at `q`; the motion's end when it cannot (the world unreachable
  // or refusing, its tcp not where ours is, a collision outside the contact zone).
  std::optional<MotionResult> PlaceArmAt(const JointVector& q, const ContactZone& zone,
                                         double penetration_m, const JointVector& last_free);
  // The guarded move's spring: the force on the tcp at `q` (zero before the first touch), and
  // how far past the touch the tcp is in `penetration_m` (-inf outside a contact zone).
  Eigen::Matrix<double, 6, 1> ContactWrench(const JointVector& q, const ContactZone& zone,
                                            double* penetration_m) const;
  // The safety system stops the arm before a hit: back to `last_free`, protective stop.
  MotionResult StopBeforeCollision(const JointVector& last_free, const std::string& detail);
  RobotState StateLocked() const;

  std::shared_ptr<SimulatedArm> arm_;
  const SafetyChecker base_checker_;  // the gripper's head straight
  // At the head's angle; written by the motion thread under mutex_, read by it freely and
  // by others under mutex_.
  SafetyChecker checker_;
  SimBackendOptions options_;

  std::mutex arm_mutex_;  // one world call at a time
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  bool synced_ = false;
  JointVector q_ = JointVector::Zero();
  JointVector qd_ = JointVector::Zero();
  Eigen::Matrix<double, 6, 1> wrench_ = Eigen::Matrix<double, 6, 1>::Zero();
  RobotStatus status_ = RobotStatus::kUnknown;
  bool stop_requested_ = false;
  bool protective_requested_ = false;
  double time_s_ = 0.0;                                   // simulated time of the commanded state
  std::chrono::steady_clock::time_point last_contact_{};  // last answer of the world
};

/// Joint positions and velocities of `trajectory` at time `t_s` (clamped into its range),
/// linearly interpolated between waypoints. @pre the trajectory is not empty.
void SampleTrajectory(const JointTrajectory& trajectory, double t_s, JointVector* q_rad,
                      JointVector* qd_rad_s);

}  // namespace picking::robot
