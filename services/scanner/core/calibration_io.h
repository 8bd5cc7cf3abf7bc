#pragma once

#include <Eigen/Geometry>

#include <string>

#include "services/scanner/core/calibration.h"

namespace picking::scanner {

/// Version of the calibration file format written by the Save functions. Load rejects any
/// other version.
inline constexpr int kCalibrationFormatVersion = 1;

/// What a calibration file holds; the "kind" field of the file.
enum class CalibrationKind {
  kCameraIntrinsics,           ///< "camera_intrinsics"
  kProjectorIntrinsics,        ///< "projector_intrinsics"
  kCameraProjectorExtrinsics,  ///< "camera_projector_extrinsics": X_CameraProjector
  kHandEye,                    ///< "hand_eye": X_ToolCamera
  kShelfPose,                  ///< "shelf_pose": X_BaseShelf
};

/// The "kind" string of `kind`.
std::string CalibrationKindName(CalibrationKind kind);

/// Facts about how a calibration was obtained, stored beside its values.
struct CalibrationInfo {
  std::string timestamp_utc;  ///< ISO 8601, e.g. "2016-07-01T12:00:00Z"; empty = now on Save.
  double error = 0.0;         ///< Quality figure: reprojection RMS (px) or residual (m).
  std::string error_unit = "px";
};

struct IntrinsicsFile {
  CameraIntrinsics intrinsics;
  CalibrationInfo info;
};

/// A rigid transform X_ParentChild, e.g. X_ToolCamera for kHandEye.
struct PoseFile {
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  CalibrationInfo info;
};

/// JSON layout (format_version 1):
///   {"format_version": 1, "kind": "camera_intrinsics", "timestamp_utc": "...",
///    "error": 0.21, "error_unit": "px",
///    "values": {"width": 1280, "height": 1024, "fx": .., "fy": .., "cx": .., "cy": ..,
///               "distortion": [k1, k2, p1, p2, k3]}}
/// and for poses
///    "values": {"parent_frame": "tool", "child_frame": "camera",
///               "translation_m": [x, y, z], "rotation_xyzw": [qx, qy, qz, qw]}.
///
/// Save writes a temporary file beside `path` and renames it over `path`, so an existing
/// file is replaced only by a complete new one. Throws std::runtime_error naming the file
/// when it cannot be written, std::invalid_argument when the values are invalid (then
/// nothing is written).
void SaveIntrinsics(const std::string& path, CalibrationKind kind, const IntrinsicsFile& file);
void SavePose(const std::string& path, CalibrationKind kind, const PoseFile& file);

/// Loads a file written by SaveIntrinsics / SavePose. Throws std::runtime_error naming the
/// file and the field when the file is missing or unparsable, has another format_version or
/// kind, or a field is missing, of the wrong type or out of range.
IntrinsicsFile LoadIntrinsics(const std::string& path, CalibrationKind kind);
PoseFile LoadPose(const std::string& path, CalibrationKind kind);

}  // namespace picking::scanner
