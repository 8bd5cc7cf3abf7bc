#pragma once

#include <string>

#include "libs/runtime/config.h"
#include "services/scanner/core/calibration.h"
#include "services/scanner/core/calibration_shelf.h"
#include "services/scanner/core/calibration_workflow.h"
#include "services/scanner/core/camera_backend.h"
#include "services/scanner/service/sim_clients.h"

namespace picking::scanner {

/// Server-wide defaults of a scan (decode.*, scan.* and camera.* settings); a request's
/// non-zero values override the decoding ones.
struct ScanSettings {
  int min_contrast = 20;  ///< decode.min_contrast: white - black, grey levels.
  /// decode.min_bit_contrast: |pattern - inverse| of every bit, grey levels. 1 rather than a
  /// larger margin: a pixel on a stripe edge has |pattern - inverse| near 0 in its finest
  /// bits, and the sub-pixel refinement places such pixels correctly, so a larger threshold
  /// only removes good points (bin_E at 1 m in simulation: 72.9 % of the bin's visible
  /// surface covered with 1, 53.6 % with 5, median depth error 0.075 mm either way).
  int min_bit_contrast = 1;
  /// decode.refine_rows: sub-pixel refinement of the projector rows as well as the columns.
  /// With the projector beside the camera depth comes from the column; the rows add ~0.01 mm
  /// of median depth accuracy (bin_E at 1 m: 0.085 -> 0.075 mm) for twice the refinement time.
  bool refine_rows = false;
  double max_residual_m = 0.001;  ///< decode.max_residual_m: triangulation residual.
  /// decode.reference_distance_m: where max_residual_m is converted to projector pixels.
  double reference_distance_m = 1.0;
  double min_depth_m = 0.1;      ///< scan.min_depth_m
  double max_depth_m = 3.0;      ///< scan.max_depth_m
  int normals_step = 2;          ///< scan.normals_step, pixels.
  double exposure_us = 8000.0;   ///< camera.exposure_us
  double frame_timeout_s = 2.0;  ///< camera.frame_timeout_s: wait beyond the exposure.
  /// camera.dropped_frame_retries: software trigger, takes of a frame that came incomplete.
  int dropped_frame_retries = 2;
  /// camera.trigger: how frames are started: by the projector's trigger output (hardware), by
  /// the scanner (software), or by the camera's own clock (free run).
  TriggerMode trigger_mode = TriggerMode::kHardware;
  std::string trigger_line = "Line0";  ///< camera.trigger_line: GenICam line of the trigger.

  /// Reads the keys; camera.trigger defaults to free_run with projector=none, else hardware.
  /// @throws std::invalid_argument for a value of the wrong type or an unknown trigger.
  static ScanSettings FromConfig(const runtime::Config& config, const std::string& projector);
  /// @throws std::invalid_argument naming the first setting out of range.
  void Validate() const;
};

/// The sensor: which camera and projector, how to reach their devices, and the robot service
/// that gives the pose of a view without one.
struct SensorSettings {
  std::string camera = "sim";                   ///< camera: sim, aravis or replay.
  std::string projector = "sim";                ///< projector: sim, dlpc350 or none.
  std::string sim_address = "127.0.0.1:50051";  ///< sim.address of picking-simulator.
  long long sim_seed = 1;                       ///< sim.seed of the simulated camera's noise.
  SimRenderSettings sim_render;                 ///< sim.* rendering.
  std::string aravis_device;                    ///< aravis.device; empty: the first camera.
  std::string replay_dir;                       ///< replay.dir: the frames camera=replay plays.
  std::string dlpc350_device = "/dev/hidraw0";  ///< dlpc350.device
  std::string robot_address;                    ///< robot.address; empty: no robot service.
  double robot_timeout_s = 2.0;                 ///< robot.timeout_s

  /// Reads every key whichever sensor is chosen, so that one file serves them all. The
  /// projector defaults to sim with camera=sim, dlpc350 with aravis, none otherwise.
  /// @throws std::invalid_argument for a value of the wrong type.
  static SensorSettings FromConfig(const runtime::Config& config);
  /// @throws std::invalid_argument for an unknown camera or projector, a pair that does not
  ///   go together (sim with a real device) or camera=replay without replay.dir.
  void Validate() const;
};

/// The scanner server's settings (docs/services.md, `picking-scanner --help`).
struct ScannerSettings {
  SensorSettings sensor;
  ScanSettings scan;
  ChessboardSpec board;  ///< board.*: the calibration target unless a request names one.
  ShelfTopModel shelf_top = KivaPodTop();  ///< shelf.top_corners_m
  std::string calibration_dir;             ///< calibration.dir; default <data>/scanner.
  std::string nominal_dir;  ///< sensor.nominal_dir; default <data>/scanner/sim_sensor.

  /// Where CaptureCalibrationView stores its sessions: <calibration_dir>/sessions.
  std::string sessions_dir() const;

  /// Reads and validates every setting.
  /// @throws std::invalid_argument naming the first bad setting.
  static ScannerSettings FromConfig(const runtime::Config& config);
  /// @throws std::invalid_argument naming the first bad setting.
  void Validate() const;
};

}  // namespace picking::scanner
