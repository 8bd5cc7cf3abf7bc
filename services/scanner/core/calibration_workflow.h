#pragma once

#include <Eigen/Geometry>

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "services/scanner/core/calibration.h"
#include "services/scanner/core/calibration_io.h"
#include "services/scanner/core/calibration_shelf.h"
#include "services/scanner/core/calibration_store.h"
#include "services/scanner/core/capture_store.h"
#include "services/scanner/core/patterns.h"
#include "services/scanner/core/projector_backend.h"
#include "services/scanner/core/scan_pipeline.h"

namespace picking::scanner {

/// The scan pipeline of a calibration state, or null when the camera, the projector or
/// X_CameraProjector is missing.
/// @throws std::invalid_argument when the values cannot be used (invalid intrinsics, a
///   projector size the Gray code cannot cover).
std::shared_ptr<ScanPipeline> MakeScanPipeline(const CalibrationState& state);

/// The pattern sequence of the projector the scanner drives: the size of the projector device
/// when there is one (`projector` not null), else that of the state's projector intrinsics.
/// @throws picking::PreconditionError when neither is known.
PatternSequence ProjectorPatterns(const ProjectorBackend* projector,
                                  const CalibrationState& current);

/// The top face of a Kiva pod in the shelf frame (x to the shelf's right, y toward its back,
/// z up): 0.87 m square, 1.9 m above the floor.
ShelfTopModel KivaPodTop();

/// A view a calibration left out, and why ("chessboard not found", "no robot pose ...").
struct SkippedView {
  std::string name;
  std::string reason;
};

/// Lists the views of one calibration in `layout` (image directories only; a session is
/// always one folder per view). A workflow calls it once, after the calibration state has
/// passed the kind's checks, so that a state that cannot be calibrated is reported before a
/// source that cannot be read.
using ViewSource = std::function<std::vector<StoredView>(ViewLayout layout)>;

/// A ViewSource of views listed beforehand.
ViewSource FixedViews(std::vector<StoredView> views);

/// Settings of the calibration workflows; the defaults are the scanner's.
struct CalibrationWorkflowOptions {
  /// Fewest usable views of camera, projector and hand-eye calibration (>= 3, the least
  /// OpenCV's calibrations take). A shelf pose needs one scan.
  int min_views = 3;
  /// Gray-code decoding of projector calibration and shelf scans, grey levels in [0, 255]: a
  /// pixel decodes when white - black >= min_contrast and every bit's
  /// |pattern - inverse| >= min_bit_contrast.
  int min_contrast = 20;
  int min_bit_contrast = 1;
  /// Depth range of the points of a shelf scan, metres (0 < min < max).
  double min_depth_m = 0.1;
  double max_depth_m = 3.0;
  /// The shelf whose pose ShelfPose finds.
  ShelfTopModel shelf_top = KivaPodTop();
  /// Told of each view a calibration leaves out, with the calibration's name ("projector
  /// calibration"), e.g. to log it; may be empty.
  std::function<void(const std::string& calibration, const SkippedView& view)> on_view_skipped;

  /// Throws std::invalid_argument naming the first bad field.
  void Validate() const;
};

/// What one calibration found: the new calibration state (neither current nor stored yet),
/// the files that record it, and its quality figures.
struct CalibrationRun {
  /// The current state with the calibrated values replaced and marked calibrated.
  CalibrationState state;
  /// Files to write, in this order: intrinsics first, then the pose (SaveCalibrationRun).
  std::vector<std::pair<CalibrationKind, IntrinsicsFile>> intrinsics_files;
  std::optional<std::pair<CalibrationKind, PoseFile>> pose_file;

  int views_used = 0;
  std::vector<SkippedView> skipped;  ///< Views left out, in view order.
  /// Camera: reprojection RMS; projector: cv::stereoCalibrate's RMS; hand-eye: RMS of the
  /// board poses' reprojection over the views; pixels. 0 for a shelf pose.
  double rms_reprojection_error_px = 0.0;
  /// Camera and hand-eye: each used view's reprojection RMS, pixels.
  std::vector<double> per_view_error_px;
  /// Projector: reprojection RMS of the projector as an inverse camera, pixels.
  double projector_rms_px = 0.0;
  /// Hand-eye: spread of the board position in the base frame over the views; shelf pose:
  /// RMS of the rigid fit over the top corners; metres.
  double residual_translation_m = 0.0;
  /// Hand-eye: spread of the board orientation in the base frame; shelf pose: angle between
  /// the measured top face's normal and the fitted shelf's z axis; radians.
  double residual_rotation_rad = 0.0;
};

/// Writes the files of `run` to `store` (each with its history copy) and sets the pose in
/// run->state to the value as stored (a quaternion), so that a restarted scanner has the same
/// values. Returns the path of the run's main file: its pose file, else its last intrinsics
/// file.
/// @throws std::runtime_error when a file cannot be written, std::invalid_argument when
///   `run` has no file.
std::string SaveCalibrationRun(const CalibrationStore& store, CalibrationRun* run);

/// The scanner's calibrations from stored views, one method per kind. Each checks that
/// `current` can be calibrated, lists the views of `source`, leaves out the views it cannot
/// use (options().on_view_skipped), calibrates, and checks that the new state can scan. It
/// changes nothing: the caller stores the run (SaveCalibrationRun) and makes it current.
///
/// Errors: picking::PreconditionError when the state lacks what the kind needs, when too few
/// views are usable (naming the skipped views and why) or when the views do not determine
/// the result (e.g. wrist motions about one axis); whatever `source` throws;
/// std::invalid_argument for unusable input (images of different sizes, a result that cannot
/// scan); CameraError when an image cannot be read.
class CalibrationWorkflow final {
 public:
  /// @throws std::invalid_argument when `options` are out of range.
  explicit CalibrationWorkflow(CalibrationWorkflowOptions options);

  const CalibrationWorkflowOptions& options() const { return options_; }

  /// Camera intrinsics from the white image of each view that shows `board`.
  CalibrationRun Camera(const ViewSource& source, const ChessboardSpec& board,
                        const CalibrationState& current) const;

  /// Camera and projector intrinsics and X_CameraProjector (Moreno & Taubin) from views of
  /// `board` under the full Gray-code sequence of the projector: the `projector` device's
  /// size when not null, else the current projector intrinsics' size.
  CalibrationRun Projector(const ViewSource& source, const ChessboardSpec& board,
                           const CalibrationState& current,
                           const ProjectorBackend* projector) const;

  /// X_ToolCamera from the white images of `board` (posed with the current camera
  /// intrinsics) paired with each view's X_BaseTool.
  CalibrationRun HandEye(const ViewSource& source, const ChessboardSpec& board,
                         const CalibrationState& current) const;

  /// X_BaseShelf from views of the shelf's top front edge with their X_BaseTool, each
  /// decoded by `pipeline` (the scan pipeline of `current`) and moved to the base frame with
  /// the current X_ToolCamera.
  CalibrationRun ShelfPose(const ViewSource& source, const CalibrationState& current,
                           ScanPipeline& pipeline) const;

 private:
  CalibrationWorkflowOptions options_;
};

}  // namespace picking::scanner
