#pragma once

#include <memory>
#include <string>

#include "libs/runtime/config.h"
#include "libs/runtime/server.h"
#include "picking/robot/v1/robot.grpc.pb.h"
#include "services/robot/core/collision_guard.h"
#include "services/robot/core/robot_backend.h"
#include "services/robot/core/safety.h"

namespace picking::robot {

/// Settings of the RobotService adapter beyond the SafetyLimits.
struct RobotServiceOptions {
  /// The `backend` setting, "sim" or "ur" (GetStateResponse.backend: ROBOT_BACKEND_SIM or
  /// ROBOT_BACKEND_UR).
  std::string backend_name = "sim";
  /// Fractions used when a request leaves MotionOptions at 0, in (0, 1].
  double default_speed_fraction = 0.5;
  double default_acceleration_fraction = 0.5;
  /// TCP acceleration limit of linear moves (scaled by acceleration_fraction), m/s^2 (> 0).
  double max_tcp_acceleration_m_s2 = 1.0;
  /// Largest force threshold a guarded move may ask for, N (> 0).
  double max_contact_force_n = 50.0;
  /// TCP acceleration of guarded moves, m/s^2 (> 0).
  double guarded_acceleration_m_s2 = 0.5;
  /// Largest start_tolerance_rad an ExecuteTrajectory request may ask for, rad (> 0).
  double max_start_tolerance_rad = 0.01;
  /// @throws std::invalid_argument naming the bad field.
  void Validate() const;
};

/// The picking.robot.v1.RobotService over any RobotBackend. Every motion is checked against
/// `checker` (joint, speed and acceleration limits, workspace box, forbidden zones, TCP
/// speed) and its swept path against `guard` (the static cell and self-collision) from the
/// current state before the backend is asked to move; a refused request (INVALID_ARGUMENT
/// naming the limit, or the links and what they hit) changes nothing. A guarded move's path
/// is checked up to where the suction cup would meet a static surface (the contact it is
/// meant to find). Moves are exclusive; a call past its deadline or cancelled by the client
/// stops the arm. @throws std::invalid_argument for a null backend or guard, bad options.
std::shared_ptr<v1::RobotService::Service> MakeRobotService(
    std::shared_ptr<RobotBackend> backend, const SafetyChecker& checker,
    std::shared_ptr<const CollisionGuard> guard, const RobotServiceOptions& options);

/// Builds the robot server's services from its settings (see docs/services.md): the backend
/// (`backend` = sim | ur), the UR10 model from `data_dir`, the tool centre point and gripper
/// tube (the cell description `cell`), the safety limits and the collision guard over the
/// cell description's static cell. @throws
/// std::invalid_argument for bad settings or cell description, std::runtime_error when the UR
/// controller cannot be reached.
runtime::ServiceSet BuildRobotServices(const runtime::Config& config);

}  // namespace picking::robot
