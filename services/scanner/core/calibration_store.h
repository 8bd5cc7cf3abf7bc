#pragma once

#include <Eigen/Geometry>

#include <optional>
#include <string>

#include "services/scanner/core/calibration.h"
#include "services/scanner/core/calibration_io.h"

namespace picking::scanner {

/// The calibrations a scanner uses, and whether each was calibrated or is a nominal value.
struct CalibrationState {
  std::optional<CameraIntrinsics> camera;
  std::optional<CameraIntrinsics> projector;
  std::optional<Eigen::Isometry3d> X_CameraProjector;
  std::optional<Eigen::Isometry3d> X_ToolCamera;
  std::optional<Eigen::Isometry3d> X_BaseShelf;
  bool camera_calibrated = false;
  bool projector_calibrated = false;  ///< Projector intrinsics and X_CameraProjector.
  bool hand_eye_calibrated = false;
  bool shelf_calibrated = false;
};

/// Calibration files of one folder: `camera_intrinsics.json`, `projector_intrinsics.json`,
/// `camera_projector.json`, `hand_eye.json`, `shelf_pose.json` (calibration_io.h format).
/// Each Save also keeps a time-stamped copy in `history/`.
class CalibrationStore final {
 public:
  /// @param dir folder of the current calibration files (created on the first save).
  /// @param nominal_dir folder of nominal files used for kinds `dir` lacks; may be empty.
  CalibrationStore(std::string dir, std::string nominal_dir);

  const std::string& dir() const { return dir_; }

  /// Loads every kind: from `dir` if present (calibrated), else from `nominal_dir`.
  /// @throws std::runtime_error naming the file when a present file is malformed.
  CalibrationState Load() const;

  /// Path of the file of `kind` in `dir`.
  std::string PathOf(CalibrationKind kind) const;

  /// Writes one file atomically (and its history copy) and returns its path.
  std::string SaveIntrinsics(CalibrationKind kind, const IntrinsicsFile& file) const;
  std::string SavePose(CalibrationKind kind, const PoseFile& file) const;

 private:
  std::string dir_;
  std::string nominal_dir_;
};

}  // namespace picking::scanner
