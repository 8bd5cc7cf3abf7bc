#pragma once

#include <Eigen/Geometry>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "libs/camera/pinhole_camera.h"
#include "services/scanner/core/camera_backend.h"

namespace picking::scanner {

/// Pinhole intrinsics with Brown-Conrady distortion in OpenCV's convention: pixel centres at
/// integer coordinates, distortion (k1, k2, p1, p2, k3) applied to normalised coordinates.
struct CameraIntrinsics {
  std::uint32_t width = 0;             ///< Image width, pixels.
  std::uint32_t height = 0;            ///< Image height, pixels.
  double fx = 0.0;                     ///< Focal length along x, pixels.
  double fy = 0.0;                     ///< Focal length along y, pixels.
  double cx = 0.0;                     ///< Principal point x, pixels.
  double cy = 0.0;                     ///< Principal point y, pixels.
  std::array<double, 5> distortion{};  ///< k1, k2, p1, p2, k3.

  /// Projects p_DevicePoint (metres, z > 0) to distorted pixel coordinates.
  Eigen::Vector2d Project(const Eigen::Vector3d& p_DevicePoint) const;
  /// Throws std::invalid_argument naming the field when a value is not usable.
  void Validate() const;
  /// The same model as libs/camera's PinholeCamera (which validates it).
  camera::PinholeCamera ToPinholeCamera() const;
};

/// A planar chessboard target. The board frame has its origin at the first inner corner,
/// x along the rows of inner corners, y along the columns, z into the board.
struct ChessboardSpec {
  int inner_corners_x = 9;       ///< Inner corners per row, >= 2.
  int inner_corners_y = 6;       ///< Inner corners per column, >= 2.
  double square_size_m = 0.025;  ///< Edge of one square, metres, > 0.

  /// p_BoardCorner of every inner corner, row-major (x fastest), metres.
  std::vector<Eigen::Vector3d> CornerPositions() const;
  void Validate() const;
};

/// Finds the inner corners of `board` in `image` (cv::findChessboardCorners refined by
/// cv::cornerSubPix). Returns false when the board is not found; `corners_px` is row-major.
bool DetectChessboard(const GrayImage& image, const ChessboardSpec& board,
                      std::vector<Eigen::Vector2d>* corners_px);

/// The pose of a chessboard seen by a calibrated camera.
struct BoardPose {
  /// Pose of the board frame (ChessboardSpec) in the camera frame, metres.
  Eigen::Isometry3d X_CameraBoard = Eigen::Isometry3d::Identity();
  double rms_px = 0.0;                      ///< Reprojection RMS of the corners, pixels.
  std::vector<Eigen::Vector2d> corners_px;  ///< Detected corners in board order.
};

/// Finds `board` in `image` and its pose relative to a camera with `intrinsics`
/// (cv::solvePnP on the detected corners). A board whose inner corner counts have an odd
/// sum (e.g. 9 x 6) looks different when turned by half a turn; its frame is chosen so that the
/// square diagonally outside the first corner is the dark one, the same on every view (what
/// hand-eye calibration needs). Returns false when the board is not found.
/// @throws std::invalid_argument when the image size differs from the intrinsics' size.
bool EstimateBoardPose(const GrayImage& image, const ChessboardSpec& board,
                       const CameraIntrinsics& intrinsics, BoardPose* pose);

/// One chessboard image for camera calibration; `name` appears in error messages.
struct ChessboardView {
  std::string name;
  GrayImage image;
};

struct CameraCalibrationOptions {
  ChessboardSpec board;
  /// When false (default), an image without a detectable board is an error naming it;
  /// when true such images are skipped and listed in the result.
  bool skip_views_without_board = false;
  /// Fewest usable views; calibration needs at least 3.
  int min_views = 3;
  /// Estimate k3 too (default false: k3 = 0, which is stable for normal lenses).
  bool estimate_k3 = false;
};

struct CameraCalibrationResult {
  CameraIntrinsics intrinsics;
  double rms_px = 0.0;                           ///< Reprojection RMS over all corners, pixels.
  std::vector<std::string> used_views;           ///< Names of the views that were used.
  std::vector<double> per_view_rms_px;           ///< Reprojection RMS of each used view.
  std::vector<Eigen::Isometry3d> X_CameraBoard;  ///< Board pose in each used view.
  std::vector<std::string> skipped_views;        ///< Views without a detectable board.
};

/// Calibrates a camera from chessboard views (cv::calibrateCamera). Throws
/// std::invalid_argument when images differ in size, when a board is not found in a view
/// (naming the view) unless skipping is enabled, or when fewer than
/// max(3, options.min_views) views are usable.
CameraCalibrationResult CalibrateCamera(const std::vector<ChessboardView>& views,
                                        const CameraCalibrationOptions& options);

/// Resolution and Gray-code layout of a structured-light projector. The capture of one
/// pose is, in order: white, black, then for each column bit from the most significant
/// the pattern and its inverse, then the row bits likewise: 2 + 2 * (column_bits +
/// row_bits) images.
struct ProjectorSpec {
  std::uint32_t width = 912;    ///< Projector columns (DLP LightCrafter 4500: 912).
  std::uint32_t height = 1140;  ///< Projector rows (DLP LightCrafter 4500: 1140).
  int column_bits = 10;         ///< Gray-code bits for columns, 2^bits >= width.
  int row_bits = 11;            ///< Gray-code bits for rows, 2^bits >= height.

  int image_count() const { return 2 + 2 * (column_bits + row_bits); }
  void Validate() const;
};

/// Projector column and row seen by every camera pixel; -1 where not decodable.
struct ProjectorCorrespondence {
  std::uint32_t width = 0;
  std::uint32_t height = 0;
  std::vector<std::int32_t> column;  ///< Row-major, projector column index or -1.
  std::vector<std::int32_t> row;     ///< Row-major, projector row index or -1.
};

struct GrayCodeDecodeOptions {
  /// A pixel is decodable when white - black >= min_contrast (gray levels) ...
  int min_contrast = 20;
  /// ... and every bit's |pattern - inverse| >= min_bit_difference (gray levels).
  int min_bit_difference = 4;
};

/// Decodes one pose's captures (ProjectorSpec order). Throws std::invalid_argument when the
/// image count or sizes are wrong.
ProjectorCorrespondence DecodeGrayCode(const std::vector<GrayImage>& images,
                                       const ProjectorSpec& projector,
                                       const GrayCodeDecodeOptions& options = {});

struct ProjectorCalibrationOptions {
  ChessboardSpec board;
  ProjectorSpec projector;
  GrayCodeDecodeOptions decode;
  /// Half size of the square camera window around each corner in which the local
  /// homography is fitted, pixels (Moreno & Taubin use 47 x 47 windows).
  int window_radius_px = 23;
  /// Fewest decoded pixels in a window; a corner with fewer makes the view unusable.
  int min_window_pixels = 200;
  /// Fewest usable poses.
  int min_views = 3;
  /// Estimate k3 of camera and projector (default false).
  bool estimate_k3 = false;
};

/// The chessboard corners of one pose, in camera and projector pixels.
struct ProjectorCalibrationView {
  std::string name;
  std::vector<Eigen::Vector2d> camera_corners_px;
  std::vector<Eigen::Vector2d> projector_corners_px;
};

struct ProjectorCalibrationResult {
  CameraIntrinsics camera;
  CameraIntrinsics projector;
  /// Pose of the projector in the camera frame (x right, y down, z forward for both).
  Eigen::Isometry3d X_CameraProjector = Eigen::Isometry3d::Identity();
  double camera_rms_px = 0.0;     ///< Reprojection RMS of the camera calibration.
  double projector_rms_px = 0.0;  ///< Reprojection RMS of the projector calibration.
  double stereo_rms_px = 0.0;     ///< RMS of cv::stereoCalibrate.
  std::vector<ProjectorCalibrationView> views;
};

/// Projector and camera-projector calibration after Moreno & Taubin, "Simple, accurate and
/// robust projector-camera calibration" (3DIMPVT 2012): each pose's Gray code is decoded,
/// a homography from camera to projector pixels is fitted in a window around each
/// chessboard corner and maps the corner into the projector, the projector is calibrated
/// as an inverse camera, and cv::stereoCalibrate gives X_CameraProjector.
///
/// Captures are added one pose at a time so that only the corners are kept in memory.
class ProjectorCalibrator final {
 public:
  /// Throws std::invalid_argument when `options` are out of range.
  explicit ProjectorCalibrator(const ProjectorCalibrationOptions& options);

  /// Adds one pose's captures (ProjectorSpec order). Throws std::invalid_argument naming
  /// `name` when the images are malformed, when the board is not found in the white image,
  /// or when a corner has too few decoded pixels around it; the calibrator is unchanged then.
  const ProjectorCalibrationView& AddView(const std::string& name,
                                          const std::vector<GrayImage>& images);

  /// Adds a pose whose corners were measured elsewhere (same validation).
  void AddCorners(const ProjectorCalibrationView& view);

  int view_count() const { return static_cast<int>(views_.size()); }

  /// Calibrates camera, projector and their relative pose. Throws std::invalid_argument
  /// when fewer than max(3, options.min_views) poses were added.
  ProjectorCalibrationResult Calibrate() const;

 private:
  ProjectorCalibrationOptions options_;
  std::uint32_t camera_width_ = 0;
  std::uint32_t camera_height_ = 0;
  std::vector<ProjectorCalibrationView> views_;
};

struct HandEyeOptions {
  enum class Method { kTsai, kPark, kHoraud, kAndreff, kDaniilidis };
  Method method = Method::kPark;
  /// Fewest pose pairs; at least 3 are required.
  int min_poses = 3;
  /// Relative tool rotations smaller than this carry no information, radians.
  double min_rotation_rad = 0.05;
  /// The relative rotation axes must span at least this angle, radians; otherwise the
  /// motions are degenerate (all about parallel axes) and the translation is unobservable.
  double min_axis_spread_rad = 0.1;
};

struct HandEyeResult {
  /// Pose of the camera in the tool (flange) frame.
  Eigen::Isometry3d X_ToolCamera = Eigen::Isometry3d::Identity();
  /// Mean pose of the board in the robot base frame implied by the solution.
  Eigen::Isometry3d X_BaseBoard = Eigen::Isometry3d::Identity();
  /// RMS spread of the board position in the base frame over all poses, metres.
  double translation_rms_m = 0.0;
  /// RMS spread of the board orientation in the base frame, radians.
  double rotation_rms_rad = 0.0;
};

/// Eye-in-hand calibration (camera on the robot wrist) with cv::calibrateHandEye from
/// robot poses X_BaseTool[i] and board poses X_CameraBoard[i] observed at the same time.
/// Throws std::invalid_argument when the lists differ in length, hold fewer than
/// max(3, options.min_poses) poses, or the motions are degenerate.
HandEyeResult CalibrateHandEye(const std::vector<Eigen::Isometry3d>& X_BaseTool,
                               const std::vector<Eigen::Isometry3d>& X_CameraBoard,
                               const HandEyeOptions& options = {});

}  // namespace picking::scanner
