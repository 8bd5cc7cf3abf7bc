#pragma once

#include <memory>
#include <mutex>
#include <string>

#include "libs/runtime/channel.h"
#include "picking/simulator/v1/simulator.grpc.pb.h"
#include "services/gripper/core/gripper_backend.h"

namespace picking::gripper {

/// Settings of the simulator backend.
struct SimGripperOptions {
  /// Which gripper is simulated; the shelf gripper has no joint (angle 0, the
  /// accelerometer reads the tool frame's gravity).
  GripperKind kind = GripperKind::kTote;
  /// Deadline of each call to the simulator, seconds (> 0).
  double timeout_s = 2.0;
  /// Vacuum levels reported when the simulator's SetSuction answer carries none
  /// (vacuum_kpa = 0): a sealed cup and an open cup, kPa.
  double sealed_kpa = 25.0;
  double open_kpa = 3.0;
  /// Servo range, radians: keep-vertical angles are clamped to [-max, +max].
  double max_joint_angle_rad = 1.5707963267948966;
};

/// The gripper in the simulated cell (picking.simulator.v1.SimulatorService):
///  - vacuum: SetSuction; the level is the simulator's, or the modelled sealed/open level;
///    a seal whose item the ground truth no longer shows attached reads as open;
///  - joint: kinematic. The tool orientation comes from GetGroundTruth.X_base_tool (the
///    UR10 flange, +z along the tube) with gravity along -z of base. Keep-vertical
///    sets the angle that makes the head vertical (clamped to the servo range); fixed holds
///    its angle; unactuated hangs vertically while the vacuum is off and stays where it was
///    once the vacuum seals the joint's play. The simulator's head (SetGripperHead) is
///    turned to the angle when the mode is set (a refusal, e.g. the head would hit the
///    cell, fails the call and keeps the old mode) and, for the modes that follow gravity,
///    whenever the gripper is read.
/// An unreachable simulator makes each call throw UnavailableError; construction never
/// contacts it. Thread safe.
class SimGripper final : public GripperBackend {
 public:
  /// Throws std::invalid_argument for a null stub or bad options.
  SimGripper(std::unique_ptr<simulator::v1::SimulatorService::StubInterface> stub,
             std::string address, const SimGripperOptions& options = {});

  /// Over a channel from `channels` (plaintext or TLS) to `address` (HOST:PORT); connects
  /// lazily.
  static std::unique_ptr<SimGripper> Connect(
      const std::string& address, const SimGripperOptions& options = {},
      const runtime::ChannelFactory& channels = runtime::ChannelFactory());

  std::string name() const override { return "sim"; }
  void SetVacuum(bool on) override;
  GripperReading Read() override;
  void SetJointMode(JointMode mode, double angle_rad) override;

 private:
  // Gravity in the tool frame from the simulator's ground truth.
  Eigen::Vector3d ToolGravity(simulator::v1::GetGroundTruthResponse* truth);
  double JointAngleLocked(const Eigen::Vector3d& g_tool);
  double HangingAngle(const Eigen::Vector3d& g_tool) const;
  // Turns the simulator's head to `angle_rad` unless it is there (`world_angle_rad`); a
  // refusal throws when `required`, else leaves the head as it was.
  void PushHeadLocked(double angle_rad, double world_angle_rad, bool required);

  std::unique_ptr<simulator::v1::SimulatorService::StubInterface> stub_;
  const std::string address_;
  const SimGripperOptions options_;

  std::mutex mutex_;
  bool vacuum_on_ = false;
  double vacuum_kpa_ = 0.0;
  bool sealed_on_item_ = false;  // SetSuction attached an item.
  // The servo holds the head straight until told otherwise: a limp head would swing into
  // whatever the planner took to be clear.
  JointMode mode_ = JointMode::kFixed;
  double fixed_angle_rad_ = 0.0;
  double angle_rad_ = 0.0;  // Last angle reported (held when the tilt is unobservable).
};

}  // namespace picking::gripper
