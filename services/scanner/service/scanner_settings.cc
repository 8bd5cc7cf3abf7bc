#include "services/scanner/service/scanner_settings.h"

#include <filesystem>
#include <stdexcept>
#include <vector>

#include "libs/apc/catalogue.h"
#include "services/scanner/service/scanner_service.h"

namespace picking::scanner {
namespace {

namespace fs = std::filesystem;

SimRenderSettings SimRenderSettingsFrom(const runtime::Config& config) {
  SimRenderSettings render;
  render.timeout_s = config.GetDouble("sim.timeout_s", render.timeout_s);
  render.ambient = config.GetDouble("sim.ambient", render.ambient);
  render.noise_sigma = config.GetDouble("sim.noise_sigma", render.noise_sigma);
  render.gamma = config.GetDouble("sim.gamma", render.gamma);
  render.electrons_per_dn = config.GetDouble("sim.electrons_per_dn", render.electrons_per_dn);
  render.projector_blur_sigma_px =
      config.GetDouble("sim.projector_blur_sigma_px", render.projector_blur_sigma_px);
  return render;
}

TriggerMode TriggerModeFrom(const std::string& trigger) {
  if (trigger == "hardware") return TriggerMode::kHardware;
  if (trigger == "software") return TriggerMode::kSoftware;
  if (trigger == "free_run") return TriggerMode::kFreeRun;
  throw std::invalid_argument(
      "setting 'camera.trigger' must be hardware, software or free_run, got '" + trigger + "'");
}

std::vector<double> CornersOf(const ShelfTopModel& m) {
  std::vector<double> v;
  for (const Eigen::Vector3d& p :
       {m.p_ShelfFrontLeft, m.p_ShelfFrontRight, m.p_ShelfBackRight, m.p_ShelfBackLeft}) {
    v.insert(v.end(), {p.x(), p.y(), p.z()});
  }
  return v;
}

ShelfTopModel ShelfTopFrom(const std::vector<double>& v) {
  if (v.size() != 12) {
    throw std::invalid_argument("setting 'shelf.top_corners_m' needs 12 numbers (4 corners)");
  }
  return {Eigen::Vector3d(v[0], v[1], v[2]), Eigen::Vector3d(v[3], v[4], v[5]),
          Eigen::Vector3d(v[6], v[7], v[8]), Eigen::Vector3d(v[9], v[10], v[11])};
}

}  // namespace

std::vector<std::string> ScannerSettingsHelp() {
  return {
      "camera=sim|aravis|replay (default sim)",
      "projector=sim|dlpc350|none (default: sim with camera=sim, none with replay, dlpc350 "
      "with aravis)",
      "sim.address=HOST:PORT of picking-simulator (default 127.0.0.1:50051)",
      "sim.timeout_s, sim.ambient, sim.noise_sigma, sim.gamma, sim.electrons_per_dn, "
      "sim.projector_blur_sigma_px, sim.seed: simulated rendering",
      "robot.address=HOST:PORT of picking-robot for poses of views without one (default none)",
      "robot.timeout_s=2",
      "aravis.device=ID (default: first camera; a GigE Vision camera also by its IP address)",
      "replay.dir=FOLDER of PNG or PGM frames, played in name order (camera=replay)",
      "dlpc350.device=/dev/hidrawN (projector=dlpc350)",
      "calibration.dir=FOLDER of the current calibration files (default <data>/scanner)",
      "sensor.nominal_dir=FOLDER of the nominal (simulated) sensor (default "
      "<data>/scanner/sim_sensor)",
      "decode.min_contrast=20, decode.min_bit_contrast=1, decode.max_residual_m=0.001, "
      "decode.reference_distance_m=1, decode.refine_rows=false (sub-pixel rows too)",
      "scan.min_depth_m=0.1, scan.max_depth_m=3, scan.normals_step=2",
      "camera.exposure_us=8000, camera.frame_timeout_s=2 (wait for a frame beyond its exposure)",
      "camera.dropped_frame_retries=2 (software trigger: take an incomplete frame again)",
      "camera.trigger=hardware|software|free_run (default: hardware with a projector, free_run "
      "with projector=none), camera.trigger_line=Line0 (GenICam line of the projector's "
      "trigger output)",
      "board.inner_corners_cols=9, board.inner_corners_rows=6, board.square_size_m=0.025",
      "shelf.top_corners_m=12 numbers (shelf frame top corners)",
  };
}

ScanSettings ScanSettings::FromConfig(const runtime::Config& config, const std::string& projector) {
  ScanSettings d;
  d.min_contrast = static_cast<int>(config.GetInt("decode.min_contrast", d.min_contrast));
  d.min_bit_contrast =
      static_cast<int>(config.GetInt("decode.min_bit_contrast", d.min_bit_contrast));
  d.refine_rows = config.GetBool("decode.refine_rows", d.refine_rows);
  d.max_residual_m = config.GetDouble("decode.max_residual_m", d.max_residual_m);
  d.reference_distance_m = config.GetDouble("decode.reference_distance_m", d.reference_distance_m);
  d.min_depth_m = config.GetDouble("scan.min_depth_m", d.min_depth_m);
  d.max_depth_m = config.GetDouble("scan.max_depth_m", d.max_depth_m);
  d.normals_step = static_cast<int>(config.GetInt("scan.normals_step", d.normals_step));
  d.exposure_us = config.GetDouble("camera.exposure_us", d.exposure_us);
  d.frame_timeout_s = config.GetDouble("camera.frame_timeout_s", d.frame_timeout_s);
  d.dropped_frame_retries =
      static_cast<int>(config.GetInt("camera.dropped_frame_retries", d.dropped_frame_retries));
  // Without a projector nothing pulses the trigger line: the camera runs on its own clock.
  d.trigger_mode = TriggerModeFrom(
      config.GetString("camera.trigger", projector == "none" ? "free_run" : "hardware"));
  d.trigger_line = config.GetString("camera.trigger_line", d.trigger_line);
  return d;
}

void ScanSettings::Validate() const {
  if (dropped_frame_retries < 0) {
    throw std::invalid_argument("setting 'camera.dropped_frame_retries' must be >= 0, got " +
                                std::to_string(dropped_frame_retries));
  }
  if (trigger_line.empty()) throw std::invalid_argument("setting 'camera.trigger_line' is empty");
  if (!(exposure_us > 0)) throw std::invalid_argument("setting 'camera.exposure_us' must be > 0");
  if (!(frame_timeout_s > 0)) {
    throw std::invalid_argument("setting 'camera.frame_timeout_s' must be > 0");
  }
  if (min_contrast < 0 || min_contrast > 255) {
    throw std::invalid_argument("setting 'decode.min_contrast' must be in [0, 255]");
  }
  if (min_bit_contrast < 0 || min_bit_contrast > 255) {
    throw std::invalid_argument("setting 'decode.min_bit_contrast' must be in [0, 255]");
  }
  if (!(max_residual_m > 0)) {
    throw std::invalid_argument("setting 'decode.max_residual_m' must be > 0");
  }
  if (!(reference_distance_m > 0)) {
    throw std::invalid_argument("setting 'decode.reference_distance_m' must be > 0");
  }
  if (!(min_depth_m > 0 && max_depth_m > min_depth_m)) {
    throw std::invalid_argument(
        "settings 'scan.min_depth_m' / 'scan.max_depth_m': need 0 < min < max");
  }
  if (normals_step < 1) throw std::invalid_argument("setting 'scan.normals_step' must be >= 1");
}

SensorSettings SensorSettings::FromConfig(const runtime::Config& config) {
  SensorSettings s;
  s.camera = config.GetString("camera", s.camera);
  const std::string default_projector = s.camera == "sim"      ? "sim"
                                        : s.camera == "aravis" ? "dlpc350"
                                                               : "none";
  s.projector = config.GetString("projector", default_projector);
  s.sim_address = config.GetString("sim.address", s.sim_address);
  s.sim_seed = config.GetInt("sim.seed", s.sim_seed);
  s.sim_render = SimRenderSettingsFrom(config);
  s.aravis_device = config.GetString("aravis.device", s.aravis_device);
  s.replay_dir = config.GetString("replay.dir", s.replay_dir);
  s.dlpc350_device = config.GetString("dlpc350.device", s.dlpc350_device);
  s.robot_address = config.GetString("robot.address", s.robot_address);
  s.robot_timeout_s = config.GetDouble("robot.timeout_s", s.robot_timeout_s);
  return s;
}

// The sim.* and robot.* values are checked by their clients (SimulatorClient,
// RobotPoseClient) when the devices are opened: the sim.* ones only matter with camera=sim.
void SensorSettings::Validate() const {
  if ((camera == "sim") != (projector == "sim")) {
    throw std::invalid_argument(camera == "sim"
                                    ? "setting 'projector': camera=sim needs projector=sim"
                                    : "setting 'projector': projector=sim needs camera=sim");
  }
  if (camera == "sim") return;
  if (camera == "replay" && replay_dir.empty()) {
    throw std::invalid_argument("setting 'replay.dir' is required with camera=replay");
  }
  if (camera != "replay" && camera != "aravis") {
    throw std::invalid_argument("setting 'camera' must be sim, aravis or replay, got '" + camera +
                                "'");
  }
  if (projector != "dlpc350" && projector != "none") {
    throw std::invalid_argument("setting 'projector' must be sim, dlpc350 or none, got '" +
                                projector + "'");
  }
}

std::string ScannerSettings::sessions_dir() const {
  return (fs::path(calibration_dir) / "sessions").string();
}

ScannerSettings ScannerSettings::FromConfig(const runtime::Config& config) {
  const std::string data_dir = apc::DefaultDataDir();
  ScannerSettings s;
  s.sensor = SensorSettings::FromConfig(config);
  s.calibration_dir =
      config.GetString("calibration.dir", (fs::path(data_dir) / "scanner").string());
  s.nominal_dir = config.GetString("sensor.nominal_dir",
                                   (fs::path(data_dir) / "scanner" / "sim_sensor").string());
  s.scan = ScanSettings::FromConfig(config, s.sensor.projector);
  s.board.inner_corners_x =
      static_cast<int>(config.GetInt("board.inner_corners_cols", s.board.inner_corners_x));
  s.board.inner_corners_y =
      static_cast<int>(config.GetInt("board.inner_corners_rows", s.board.inner_corners_y));
  s.board.square_size_m = config.GetDouble("board.square_size_m", s.board.square_size_m);
  s.shelf_top = ShelfTopFrom(config.GetDoubles("shelf.top_corners_m", CornersOf(s.shelf_top)));
  s.Validate();
  return s;
}

void ScannerSettings::Validate() const {
  scan.Validate();
  board.Validate();
  shelf_top.Validate();
  sensor.Validate();
  if (calibration_dir.empty()) throw std::invalid_argument("setting 'calibration.dir' is empty");
}

}  // namespace picking::scanner
