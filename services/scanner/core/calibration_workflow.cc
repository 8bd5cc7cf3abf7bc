#include "services/scanner/core/calibration_workflow.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "libs/errors/errors.h"
#include "services/scanner/core/merge.h"

namespace picking::scanner {
namespace {

// The calibrations' names, as their messages and skipped-view reports start.
constexpr const char* kCameraCalibration = "camera calibration";
constexpr const char* kProjectorCalibration = "projector calibration";
constexpr const char* kHandEyeCalibration = "hand-eye calibration";
constexpr const char* kShelfCalibration = "shelf pose calibration";

constexpr const char* kNoRobotPose = "no robot pose (X_base_tool.txt)";

// Records a view the calibration leaves out and tells the options' observer.
void Skip(const CalibrationWorkflowOptions& options, const char* calibration,
          const std::string& view, const std::string& reason, CalibrationRun* run) {
  run->skipped.push_back({view, reason});
  if (options.on_view_skipped) options.on_view_skipped(calibration, run->skipped.back());
}

// " (view_001: reason; view_004: reason)" for an error message, at most `limit` views;
// nothing when no view was skipped.
std::string SkippedSuffix(const std::vector<SkippedView>& skipped, std::size_t limit = 6) {
  if (skipped.empty()) return {};
  std::string out;
  for (std::size_t i = 0; i < skipped.size() && i < limit; ++i) {
    out += (i ? "; " : "") + skipped[i].name + ": " + skipped[i].reason;
  }
  if (skipped.size() > limit) out += "; and " + std::to_string(skipped.size() - limit) + " more";
  return " (" + out + ")";
}

std::string BoardText(const ChessboardSpec& board) {
  return std::to_string(board.inner_corners_x) + " x " + std::to_string(board.inner_corners_y);
}

// The white images of the views that show `board`.
std::vector<ChessboardView> BoardViews(const CalibrationWorkflowOptions& options,
                                       const std::vector<StoredView>& views,
                                       const ChessboardSpec& board, CalibrationRun* run) {
  std::vector<ChessboardView> out;
  for (const auto& v : views) {
    GrayImage image = LoadWhiteImage(v);
    std::vector<Eigen::Vector2d> corners_px;
    if (!DetectChessboard(image, board, &corners_px)) {
      Skip(options, kCameraCalibration, v.name, "chessboard not found", run);
      continue;
    }
    out.push_back({v.name, std::move(image)});
  }
  return out;
}

ProjectorCalibrationOptions ProjectorOptions(const CalibrationWorkflowOptions& workflow,
                                             const PatternSequence& patterns,
                                             const ChessboardSpec& board) {
  ProjectorCalibrationOptions options;
  options.board = board;
  options.projector.width = static_cast<std::uint32_t>(patterns.projector_width());
  options.projector.height = static_cast<std::uint32_t>(patterns.projector_height());
  options.projector.column_bits = patterns.column_bits();
  options.projector.row_bits = patterns.row_bits();
  options.decode.min_contrast = workflow.min_contrast;
  options.decode.min_bit_difference = workflow.min_bit_contrast;
  options.min_views = workflow.min_views;
  return options;
}

std::string TooFewProjectorViews(const ProjectorCalibrationOptions& options, int used,
                                 std::size_t total, const std::vector<SkippedView>& skipped) {
  return "projector calibration needs at least " + std::to_string(options.min_views) +
         " views with the " + BoardText(options.board) + " chessboard and the " +
         std::to_string(options.projector.image_count()) + "-image Gray-code sequence of the " +
         std::to_string(options.projector.width) + " x " +
         std::to_string(options.projector.height) + " projector, got " + std::to_string(used) +
         " of " + std::to_string(total) + SkippedSuffix(skipped);
}

// Robot and board poses of the hand-eye views, with each board pose's reprojection RMS.
struct HandEyeObservations {
  std::vector<Eigen::Isometry3d> X_BaseTool;
  std::vector<Eigen::Isometry3d> X_CameraBoard;
  std::vector<double> rms_px;
};

HandEyeObservations ObserveBoard(const CalibrationWorkflowOptions& options,
                                 const std::vector<StoredView>& views, const ChessboardSpec& board,
                                 const CameraIntrinsics& camera, CalibrationRun* run) {
  HandEyeObservations out;
  for (const auto& v : views) {
    if (!v.X_BaseTool) {
      Skip(options, kHandEyeCalibration, v.name, kNoRobotPose, run);
      continue;
    }
    const GrayImage image = LoadWhiteImage(v);
    // Another camera's images: the state, not the view, is wrong for them.
    if (image.width != camera.width || image.height != camera.height) {
      throw PreconditionError("hand-eye calibration: view " + v.name + " is " +
                              std::to_string(image.width) + " x " + std::to_string(image.height) +
                              " pixels but the camera intrinsics are for " +
                              std::to_string(camera.width) + " x " + std::to_string(camera.height));
    }
    BoardPose pose;
    if (!EstimateBoardPose(image, board, camera, &pose)) {
      Skip(options, kHandEyeCalibration, v.name, "chessboard not found", run);
      continue;
    }
    out.X_BaseTool.push_back(*v.X_BaseTool);
    out.X_CameraBoard.push_back(pose.X_CameraBoard);
    out.rms_px.push_back(pose.rms_px);
  }
  return out;
}

// Only points are needed to find the shelf's faces: no normals, no intensities.
ScanOptions ShelfScanOptions(const CalibrationWorkflowOptions& workflow) {
  ScanOptions options;
  options.with_normals = false;
  options.with_intensities = false;
  options.decode.min_contrast = workflow.min_contrast;
  options.decode.min_bit_contrast = workflow.min_bit_contrast;
  options.triangulation.min_depth_m = workflow.min_depth_m;
  options.triangulation.max_depth_m = workflow.max_depth_m;
  return options;
}

// The clouds of the shelf views in the base frame (X_BaseTool * X_ToolCamera).
std::vector<geometry::PointCloud> ShelfClouds(const CalibrationWorkflowOptions& workflow,
                                              const std::vector<StoredView>& views,
                                              const Eigen::Isometry3d& X_ToolCamera,
                                              ScanPipeline& pipeline, CalibrationRun* run) {
  const ScanOptions options = ShelfScanOptions(workflow);
  std::vector<geometry::PointCloud> clouds;
  for (const auto& v : views) {
    if (!v.X_BaseTool) {
      Skip(workflow, kShelfCalibration, v.name, kNoRobotPose, run);
      continue;
    }
    geometry::PointCloud cloud;
    double valid_fraction = 0.0;
    try {
      cloud = pipeline.ProcessView(LoadSequence(v, pipeline.patterns().num_images()), options,
                                   &valid_fraction);
    } catch (const std::invalid_argument& e) {
      Skip(workflow, kShelfCalibration, v.name, e.what(), run);
      continue;
    }
    if (valid_fraction <= 0.0) {
      Skip(workflow, kShelfCalibration, v.name,
           "no pixel decodes (is the projector lighting the shelf?)", run);
      continue;
    }
    TransformCloud(*v.X_BaseTool * X_ToolCamera, "base", &cloud);
    clouds.push_back(std::move(cloud));
  }
  return clouds;
}

// The pose of `kind` in `state`.
std::optional<Eigen::Isometry3d>* StatePose(CalibrationState* state, CalibrationKind kind) {
  switch (kind) {
    case CalibrationKind::kCameraProjectorExtrinsics:
      return &state->X_CameraProjector;
    case CalibrationKind::kHandEye:
      return &state->X_ToolCamera;
    case CalibrationKind::kShelfPose:
      return &state->X_BaseShelf;
    case CalibrationKind::kCameraIntrinsics:
    case CalibrationKind::kProjectorIntrinsics:
      break;
  }
  throw std::invalid_argument("calibration kind " + CalibrationKindName(kind) + " is not a pose");
}

}  // namespace

std::shared_ptr<ScanPipeline> MakeScanPipeline(const CalibrationState& state) {
  if (!state.camera || !state.projector || !state.X_CameraProjector) return nullptr;
  const camera::PinholeCamera projector = state.projector->ToPinholeCamera();
  return std::make_shared<ScanPipeline>(
      ScanCalibration{state.camera->ToPinholeCamera(), projector, *state.X_CameraProjector,
                      state.X_ToolCamera},
      PatternSequence(projector.width(), projector.height()));
}

PatternSequence ProjectorPatterns(const ProjectorBackend* projector,
                                  const CalibrationState& current) {
  if (projector) {
    return PatternSequence(static_cast<int>(projector->width()),
                           static_cast<int>(projector->height()));
  }
  if (current.projector) {
    return PatternSequence(static_cast<int>(current.projector->width),
                           static_cast<int>(current.projector->height));
  }
  throw PreconditionError(
      "projector calibration: the projector size is unknown (no projector device and no "
      "projector_intrinsics.json in calibration.dir or sensor.nominal_dir)");
}

ShelfTopModel KivaPodTop() {
  return {Eigen::Vector3d(0.0, 0.0, 1.9), Eigen::Vector3d(0.87, 0.0, 1.9),
          Eigen::Vector3d(0.87, 0.87, 1.9), Eigen::Vector3d(0.0, 0.87, 1.9)};
}

ViewSource FixedViews(std::vector<StoredView> views) {
  return [views = std::move(views)](ViewLayout) { return views; };
}

void CalibrationWorkflowOptions::Validate() const {
  if (min_views < 3) {
    throw std::invalid_argument("calibration workflow: min_views must be >= 3, got " +
                                std::to_string(min_views));
  }
  if (min_contrast < 0 || min_contrast > 255) {
    throw std::invalid_argument("calibration workflow: min_contrast must be in [0, 255]");
  }
  if (min_bit_contrast < 0 || min_bit_contrast > 255) {
    throw std::invalid_argument("calibration workflow: min_bit_contrast must be in [0, 255]");
  }
  if (!(min_depth_m > 0 && max_depth_m > min_depth_m && std::isfinite(max_depth_m))) {
    throw std::invalid_argument("calibration workflow: need 0 < min_depth_m < max_depth_m");
  }
  shelf_top.Validate();
}

std::string SaveCalibrationRun(const CalibrationStore& store, CalibrationRun* run) {
  if (run->intrinsics_files.empty() && !run->pose_file) {
    throw std::invalid_argument("SaveCalibrationRun: the run has no file to save");
  }
  std::string path;
  for (const auto& [kind, file] : run->intrinsics_files) path = store.SaveIntrinsics(kind, file);
  if (run->pose_file) {
    const auto& [kind, file] = *run->pose_file;
    path = store.SavePose(kind, file);
    *StatePose(&run->state, kind) = LoadPose(path, kind).pose;
  }
  return path;
}

CalibrationWorkflow::CalibrationWorkflow(CalibrationWorkflowOptions options)
    : options_(std::move(options)) {
  options_.Validate();
}

CalibrationRun CalibrationWorkflow::Camera(const ViewSource& source, const ChessboardSpec& board,
                                           const CalibrationState& current) const {
  CalibrationRun run;
  const std::vector<StoredView> views = source(ViewLayout::kImageFiles);
  const std::vector<ChessboardView> board_views = BoardViews(options_, views, board, &run);
  if (static_cast<int>(board_views.size()) < options_.min_views) {
    throw PreconditionError("calibration needs at least " + std::to_string(options_.min_views) +
                            " views with the " + BoardText(board) + " chessboard in sight, got " +
                            std::to_string(board_views.size()) + " of " +
                            std::to_string(views.size()));
  }
  CameraCalibrationOptions options;
  options.board = board;
  options.skip_views_without_board = true;
  options.min_views = options_.min_views;
  const CameraCalibrationResult result = CalibrateCamera(board_views, options);
  run.state = current;
  run.state.camera = result.intrinsics;
  run.state.camera_calibrated = true;
  MakeScanPipeline(run.state);  // Throws if the result cannot be used.
  run.intrinsics_files.emplace_back(CalibrationKind::kCameraIntrinsics,
                                    IntrinsicsFile{result.intrinsics, {"", result.rms_px, "px"}});
  run.views_used = static_cast<int>(result.used_views.size());
  run.rms_reprojection_error_px = result.rms_px;
  run.per_view_error_px = result.per_view_rms_px;
  return run;
}

CalibrationRun CalibrationWorkflow::Projector(const ViewSource& source, const ChessboardSpec& board,
                                              const CalibrationState& current,
                                              const ProjectorBackend* projector) const {
  const ProjectorCalibrationOptions options =
      ProjectorOptions(options_, ProjectorPatterns(projector, current), board);
  ProjectorCalibrator calibrator(options);
  CalibrationRun run;
  const std::vector<StoredView> views = source(ViewLayout::kSequenceFolders);
  for (const auto& v : views) {
    try {
      calibrator.AddView(v.name, LoadSequence(v, options.projector.image_count()));
    } catch (const std::invalid_argument& e) {
      Skip(options_, kProjectorCalibration, v.name, e.what(), &run);
    }
  }
  if (calibrator.view_count() < options.min_views) {
    throw PreconditionError(
        TooFewProjectorViews(options, calibrator.view_count(), views.size(), run.skipped));
  }
  ProjectorCalibrationResult result;
  try {
    result = calibrator.Calibrate();
  } catch (const std::invalid_argument& e) {
    throw PreconditionError(std::string("projector calibration: ") + e.what());
  }
  run.state = current;
  run.state.camera = result.camera;
  run.state.projector = result.projector;
  run.state.X_CameraProjector = result.X_CameraProjector;
  run.state.camera_calibrated = true;
  run.state.projector_calibrated = true;
  MakeScanPipeline(run.state);  // Throws if the result cannot be used.
  run.intrinsics_files.emplace_back(
      CalibrationKind::kCameraIntrinsics,
      IntrinsicsFile{result.camera, {"", result.camera_rms_px, "px"}});
  run.intrinsics_files.emplace_back(
      CalibrationKind::kProjectorIntrinsics,
      IntrinsicsFile{result.projector, {"", result.projector_rms_px, "px"}});
  run.pose_file.emplace(CalibrationKind::kCameraProjectorExtrinsics,
                        PoseFile{result.X_CameraProjector, {"", result.stereo_rms_px, "px"}});
  run.views_used = calibrator.view_count();
  run.rms_reprojection_error_px = result.stereo_rms_px;
  run.projector_rms_px = result.projector_rms_px;
  return run;
}

CalibrationRun CalibrationWorkflow::HandEye(const ViewSource& source, const ChessboardSpec& board,
                                            const CalibrationState& current) const {
  if (!current.camera) {
    throw PreconditionError(
        "hand-eye calibration needs the camera intrinsics (calibrate the camera first)");
  }
  CalibrationRun run;
  const std::vector<StoredView> views = source(ViewLayout::kSequenceFolders);
  const HandEyeObservations seen = ObserveBoard(options_, views, board, *current.camera, &run);
  if (static_cast<int>(seen.X_BaseTool.size()) < options_.min_views) {
    throw PreconditionError("hand-eye calibration needs at least " +
                            std::to_string(options_.min_views) +
                            " views with a robot pose and the " + BoardText(board) +
                            " chessboard in sight, got " + std::to_string(seen.X_BaseTool.size()) +
                            " of " + std::to_string(views.size()) + SkippedSuffix(run.skipped));
  }
  HandEyeOptions options;
  options.min_poses = options_.min_views;
  HandEyeResult result;
  try {
    result = CalibrateHandEye(seen.X_BaseTool, seen.X_CameraBoard, options);
  } catch (const std::invalid_argument& e) {
    // CalibrateHandEye's messages start with "hand-eye calibration".
    throw PreconditionError(std::string(e.what()) +
                            " (turn the wrist about different axes between views)");
  }
  run.state = current;
  run.state.X_ToolCamera = result.X_ToolCamera;
  run.state.hand_eye_calibrated = true;
  MakeScanPipeline(run.state);  // Throws if the result cannot be used.
  run.pose_file.emplace(CalibrationKind::kHandEye,
                        PoseFile{result.X_ToolCamera, {"", result.translation_rms_m, "m"}});
  run.views_used = static_cast<int>(seen.X_BaseTool.size());
  run.per_view_error_px = seen.rms_px;
  double sum_sq = 0.0;
  for (double e : seen.rms_px) sum_sq += e * e;
  run.rms_reprojection_error_px = std::sqrt(sum_sq / static_cast<double>(seen.rms_px.size()));
  run.residual_translation_m = result.translation_rms_m;
  run.residual_rotation_rad = result.rotation_rms_rad;
  return run;
}

CalibrationRun CalibrationWorkflow::ShelfPose(const ViewSource& source,
                                              const CalibrationState& current,
                                              ScanPipeline& pipeline) const {
  if (!current.X_ToolCamera) {
    throw PreconditionError("shelf pose calibration needs the hand-eye calibration");
  }
  CalibrationRun run;
  const std::vector<StoredView> views = source(ViewLayout::kSequenceFolders);
  const std::vector<geometry::PointCloud> clouds =
      ShelfClouds(options_, views, *current.X_ToolCamera, pipeline, &run);
  if (clouds.empty()) {
    throw PreconditionError(
        "shelf pose calibration needs at least one scan of the shelf's top front edge with "
        "its robot pose, got none of " +
        std::to_string(views.size()) + " views" + SkippedSuffix(run.skipped));
  }
  ShelfPoseResult result;
  try {
    result = EstimateShelfPose(MergeClouds(clouds).cloud, options_.shelf_top);
  } catch (const std::invalid_argument& e) {
    throw PreconditionError(std::string("shelf pose: ") + e.what());
  }
  run.state = current;
  run.state.X_BaseShelf = result.X_BaseShelf;
  run.state.shelf_calibrated = true;
  MakeScanPipeline(run.state);  // Throws if the result cannot be used.
  run.pose_file.emplace(CalibrationKind::kShelfPose,
                        PoseFile{result.X_BaseShelf, {"", result.fit_rms_m, "m"}});
  run.views_used = static_cast<int>(clouds.size());
  run.residual_translation_m = result.fit_rms_m;
  // How far the fitted shelf's up axis is from the measured top face's normal.
  run.residual_rotation_rad = std::acos(
      std::clamp(result.top_normal_Base.dot(result.X_BaseShelf.linear().col(2)), -1.0, 1.0));
  return run;
}

}  // namespace picking::scanner
