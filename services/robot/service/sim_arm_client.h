#pragma once

#include <memory>
#include <string>

#include "libs/runtime/channel.h"
#include "picking/simulator/v1/simulator.grpc.pb.h"
#include "services/robot/core/sim_backend.h"

namespace picking::robot {

/// Options of SimulatorArmClient.
struct SimulatorArmClientOptions {
  /// Deadline of each simulator call, s (> 0).
  double timeout_s = 2.0;
  /// Where the arm is put when the simulator knows no arm joints yet (e.g. no layout
  /// loaded), rad. Default: facing the shelf (+x), tool pointing down, flange about 0.43 m in
  /// front of the base and 0.59 m above it.
  JointVector initial_joints_rad =
      (JointVector() << 3.14159265358979, -2.0, 2.0, -1.5707963267949, -1.5707963267949, 0.0)
          .finished();
};

/// SimulatedArm served by picking-simulator (picking.simulator.v1): ReadJoints is
/// GetGroundTruth's arm joints, PlaceArm is SetArmJoints (with its X_base_tcp, the cup the
/// simulator placed), Probe is ProbeContact from the flange pose. An
/// unreachable simulator or a call past its deadline throws UnavailableError naming the
/// address; any other refusal throws std::runtime_error with the simulator's message.
class SimulatorArmClient final : public SimulatedArm {
 public:
  /// Over a channel from `channels` (plaintext or TLS) to `address`; connects lazily.
  /// @throws std::invalid_argument for an address that is not HOST:PORT or bad options.
  static std::shared_ptr<SimulatorArmClient> Connect(
      const std::string& address, const SimulatorArmClientOptions& options,
      const runtime::ChannelFactory& channels = runtime::ChannelFactory());
  SimulatorArmClient(std::unique_ptr<simulator::v1::SimulatorService::StubInterface> stub,
                     std::string address, const SimulatorArmClientOptions& options);

  JointVector ReadJoints() override;
  /// GetGroundTruth answered, with or without an arm (FAILED_PRECONDITION: no layout yet).
  void CheckReachable() override;
  ArmPlacement PlaceArm(const JointVector& q_rad) override;
  /// GetGroundTruth's gripper_head_angle_rad (0 before a layout is loaded).
  double ReadHeadAngle() override;
  ContactProbe Probe(const Eigen::Isometry3d& X_BaseTool, const Eigen::Vector3d& direction_tcp,
                     double max_distance_m) override;

 private:
  std::unique_ptr<simulator::v1::SimulatorService::StubInterface> stub_;
  std::string address_;
  SimulatorArmClientOptions options_;
};

}  // namespace picking::robot
