#include "services/scanner/service/scanner_devices.h"

#include <stdexcept>
#include <string>

#include "services/scanner/core/aravis_camera.h"
#include "services/scanner/core/calibration_io.h"
#include "services/scanner/core/dlpc350.h"
#include "services/scanner/core/replay_camera.h"

namespace picking::scanner {
namespace {

ScannerDevices SimDevices(const SensorSettings& sensor, const std::string& nominal_dir,
                          const runtime::ChannelFactory& channels) {
  ScannerDevices devices;
  devices.simulator =
      std::make_shared<SimulatorClient>(sensor.sim_address, sensor.sim_render, channels);
  devices.link = std::make_shared<SimSensorLink>(
      [simulator = devices.simulator] { return simulator->ToolPose(); });
  SimSensorModel model = LoadSimModel(nominal_dir);
  const auto pw = static_cast<std::uint32_t>(model.projector.width());
  const auto ph = static_cast<std::uint32_t>(model.projector.height());
  devices.camera = std::make_unique<SimCamera>(devices.link, devices.simulator, std::move(model),
                                               static_cast<std::uint64_t>(sensor.sim_seed));
  devices.projector = std::make_unique<SimProjector>(devices.link, pw, ph);
  return devices;
}

// The camera and projector kinds were checked by SensorSettings::Validate.
ScannerDevices HardwareDevices(const SensorSettings& sensor) {
  ScannerDevices devices;
  try {
    if (sensor.camera == "replay") {
      devices.camera = std::make_unique<ReplayCamera>(sensor.replay_dir);
    } else {
      devices.camera = std::make_unique<AravisCamera>(sensor.aravis_device);
    }
    if (sensor.projector == "dlpc350") {
      devices.projector = std::make_unique<Dlpc350Projector>(
          std::make_unique<dlpc350::HidrawTransport>(sensor.dlpc350_device));
    }
  } catch (const CameraError& e) {
    throw std::runtime_error(std::string("camera: ") + e.what());
  } catch (const ProjectorError& e) {
    throw std::runtime_error(std::string("projector: ") + e.what());
  }
  return devices;
}

}  // namespace

SimSensorModel LoadSimModel(const std::string& dir) {
  const std::string base = dir + "/";
  try {
    SimSensorModel model{
        LoadIntrinsics(base + "camera_intrinsics.json", CalibrationKind::kCameraIntrinsics)
            .intrinsics.ToPinholeCamera(),
        LoadIntrinsics(base + "projector_intrinsics.json", CalibrationKind::kProjectorIntrinsics)
            .intrinsics.ToPinholeCamera()};
    model.X_CameraProjector =
        LoadPose(base + "camera_projector.json", CalibrationKind::kCameraProjectorExtrinsics).pose;
    model.X_ToolCamera = LoadPose(base + "hand_eye.json", CalibrationKind::kHandEye).pose;
    return model;
  } catch (const std::runtime_error& e) {
    throw std::invalid_argument(std::string("setting 'sensor.nominal_dir': ") + e.what());
  }
}

ScannerDevices OpenScannerDevices(const ScannerSettings& settings,
                                  const runtime::ChannelFactory& channels) {
  const SensorSettings& sensor = settings.sensor;
  ScannerDevices devices = sensor.camera == "sim"
                               ? SimDevices(sensor, settings.nominal_dir, channels)
                               : HardwareDevices(sensor);
  if (!sensor.robot_address.empty()) {
    devices.robot =
        std::make_shared<RobotPoseClient>(sensor.robot_address, sensor.robot_timeout_s, channels);
  }
  return devices;
}

}  // namespace picking::scanner
