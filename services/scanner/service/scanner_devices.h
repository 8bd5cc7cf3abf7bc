#pragma once

#include <memory>

#include "libs/runtime/channel.h"
#include "services/scanner/core/camera_backend.h"
#include "services/scanner/core/projector_backend.h"
#include "services/scanner/core/sim_backends.h"
#include "services/scanner/service/scanner_settings.h"
#include "services/scanner/service/sim_clients.h"

namespace picking::scanner {

/// The devices a scanner drives: the simulated sensor pair, or a real or replayed camera
/// with a real projector or none; and the robot service that gives the pose of a view without
/// one.
struct ScannerDevices {
  std::shared_ptr<SimulatorClient> simulator;  ///< camera=sim only.
  std::shared_ptr<SimSensorLink> link;         ///< camera=sim only.
  std::unique_ptr<CameraBackend> camera;
  std::unique_ptr<ProjectorBackend> projector;  ///< Null with projector=none.
  std::shared_ptr<RobotPoseClient> robot;       ///< Null without robot.address.
};

/// The simulated sensor's true geometry: the nominal files of `dir`.
/// @throws std::invalid_argument naming sensor.nominal_dir when a file cannot be read.
SimSensorModel LoadSimModel(const std::string& dir);

/// Opens the devices `settings` name (validated settings); the simulator and the robot
/// service are called over channels from `channels`.
/// @throws std::invalid_argument for sim.* or robot.* values the clients refuse or nominal
///   files that cannot be read, std::runtime_error naming the camera or projector when a
///   device cannot be opened.
ScannerDevices OpenScannerDevices(const ScannerSettings& settings,
                                  const runtime::ChannelFactory& channels);

}  // namespace picking::scanner
