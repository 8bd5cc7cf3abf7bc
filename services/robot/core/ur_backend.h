#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include "services/robot/core/byte_stream.h"
#include "services/robot/core/checked_backend.h"
#include "services/robot/core/dashboard.h"
#include "services/robot/core/robot_backend.h"
#include "services/robot/core/rtde.h"
#include "services/robot/core/safety.h"

namespace picking::robot {

/// Options of UrBackend.
struct UrBackendOptions {
  std::string host = "127.0.0.1";
  std::uint16_t rtde_port = rtde::kPort;
  /// Secondary interface (URScript programs and commands).
  std::uint16_t script_port = 30002;
  std::uint16_t dashboard_port = DashboardClient::kPort;
  /// RTDE output rate, Hz (125 on CB3, up to 500 on e-Series).
  double rtde_frequency_hz = 125.0;
  std::chrono::milliseconds connect_timeout{3000};
  /// A motion is "at the target" within this joint distance (rad) and speed (rad/s).
  double joint_tolerance_rad = 1e-3;
  double still_speed_rad_s = 1e-3;
  /// Decelerations of Stop(): joint (rad/s^2) and tool (m/s^2).
  double stop_acceleration_rad_s2 = 3.0;
  double stop_acceleration_m_s2 = 2.0;
  /// servoj look-ahead time (s) and gain used by ExecuteTrajectory.
  double servo_lookahead_s = 0.1;
  double servo_gain = 300.0;
  /// Extra time allowed beyond a motion's planned duration before it fails, s.
  double motion_timeout_margin_s = 5.0;
};

/// RobotBackend of a real Universal Robots arm: state from RTDE (actual_q, actual_qd,
/// actual_TCP_force, robot_mode, safety_mode, timestamp; X_BaseTool by the model's forward
/// kinematics of actual_q), motion by URScript over the secondary interface, power, brakes
/// and protective-stop reset by the dashboard server.
class UrBackend final : public CheckedBackend {
 public:
  /// Connects the three interfaces, negotiates RTDE protocol 2, sets up the output recipe
  /// and starts it. @throws StreamError / std::runtime_error naming what failed.
  static std::unique_ptr<UrBackend> Connect(const UrBackendOptions& options,
                                            const SafetyChecker& checker);

  /// Takes connected interfaces (tests can pass any streams).
  UrBackend(std::unique_ptr<rtde::RtdeClient> rtde, std::unique_ptr<ByteStream> script,
            std::unique_ptr<DashboardClient> dashboard, const SafetyChecker& checker,
            const UrBackendOptions& options);
  ~UrBackend() override;

  /// The RTDE output variables requested by Connect.
  static const std::vector<std::string>& OutputVariables();

  /// "power on" then "brake release" on the dashboard; waits until robot_mode is RUNNING.
  /// @throws std::runtime_error with the controller's reply or on timeout.
  void PowerOnAndReleaseBrakes(std::chrono::milliseconds timeout);

  RobotState GetState() override;
  void Stop() override;
  void ProtectiveStop() override;
  bool ResetProtectiveStop(std::string* reason) override;

  /// Waits until an RTDE state with timestamp > `after_s` arrived; false on timeout.
  bool WaitForState(double after_s, std::chrono::milliseconds timeout);

 private:
  void ReadLoop();
  void SendScript(const std::string& text);
  // Waits until `done(state)`; returns the outcome (kCompleted when done).
  MotionResult Wait(const std::function<bool(const RobotState&)>& done, double timeout_s,
                    const std::function<void(const RobotState&)>& on_state = {});
  // The safety layer's hooks (CheckedBackend).
  const SafetyChecker& CheckerForMotion() override { return checker_; }
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

  std::unique_ptr<rtde::RtdeClient> rtde_;
  std::unique_ptr<ByteStream> script_;
  std::unique_ptr<DashboardClient> dashboard_;
  SafetyChecker checker_;
  ur10::Ur10Kinematics kinematics_;
  UrBackendOptions options_;

  std::mutex mutex_;
  std::condition_variable state_changed_;
  RobotState state_;
  bool have_state_ = false;
  bool connection_lost_ = false;
  std::string connection_error_;
  std::atomic<bool> stop_requested_{false};
  std::atomic<bool> closing_{false};
  std::mutex script_mutex_;
  std::mutex dashboard_mutex_;
  std::thread reader_;
};

}  // namespace picking::robot
