#pragma once

#include <memory>
#include <string>
#include <vector>

#include "libs/runtime/config.h"
#include "libs/runtime/server.h"
#include "picking/scanner/v1/scanner.grpc.pb.h"

namespace picking::scanner {

/// The settings the scanner server reads, for --help (see docs/services.md).
std::vector<std::string> ScannerSettingsHelp();

/// Builds the scanner server's services from its settings (see docs/services.md).
///
/// Calibrate reads its views from a session (CaptureCalibrationView) or an image_directory
/// on the scanner host:
/// - CAMERA: image_directory holds one chessboard image per view (.png, .jpg, .bmp, .pgm);
///   a session uses the white image of each view.
/// - PROJECTOR, HAND_EYE, SHELF_POSE: one subfolder per view (a session's `view_NNN`, or any
///   names in an image_directory, taken in name order). A view folder holds the view's
///   captures in sequence order when its image files are sorted by name (white, black, then
///   each column bit and its inverse from the most significant, then the row bits likewise:
///   2 + 2 * (ceil(log2 width) + ceil(log2 height)) images for the projector's size, 44 for
///   912 x 1140), and, for HAND_EYE and SHELF_POSE, `X_base_tool.txt`: the flange pose in
///   the robot base frame at capture time as one line "x y z qx qy qz qw" (metres, unit
///   quaternion). PROJECTOR needs the chessboard in the white image; HAND_EYE uses only
///   the white image and the current camera intrinsics; SHELF_POSE decodes each view with
///   the current scanner calibration and hand-eye calibration.
/// Views that cannot be used (no board, no pose, wrong image count) are skipped and named in
/// the FAILED_PRECONDITION error when fewer than 3 (PROJECTOR, HAND_EYE) or none (SHELF_POSE)
/// remain. A failed calibration changes nothing, neither the current values nor the files.
/// At start the server loads the files of calibration.dir and refuses to start (exit 2,
/// naming the file and field) when one cannot be read or has another format_version.
/// @throws std::invalid_argument for bad settings (unknown backend, missing replay folder,
///   malformed calibration file or one of another format version), std::runtime_error when
///   a device cannot be opened.
runtime::ServiceSet BuildScannerServices(const runtime::Config& config);

}  // namespace picking::scanner
