#include "services/scanner/core/calibration.h"

#include "services/scanner/core/patterns.h"

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/core/eigen.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace picking::scanner {
namespace {

cv::Mat WrapImage(const GrayImage& image) {
  return cv::Mat(static_cast<int>(image.height), static_cast<int>(image.width), CV_8UC1,
                 const_cast<std::uint8_t*>(image.pixels.data()));
}

void CheckImage(const GrayImage& image, const std::string& what) {
  if (image.width == 0 || image.height == 0 ||
      image.pixels.size() != static_cast<std::size_t>(image.width) * image.height) {
    throw std::invalid_argument(what + ": image is empty or its pixel count (" +
                                std::to_string(image.pixels.size()) + ") is not width x height (" +
                                std::to_string(image.width) + " x " + std::to_string(image.height) +
                                ")");
  }
}

cv::Matx33d CameraMatrix(const CameraIntrinsics& intrinsics) {
  return cv::Matx33d(intrinsics.fx, 0.0, intrinsics.cx, 0.0, intrinsics.fy, intrinsics.cy, 0.0, 0.0,
                     1.0);
}

CameraIntrinsics ToIntrinsics(const cv::Mat& K, const cv::Mat& dist, cv::Size size) {
  CameraIntrinsics intrinsics;
  intrinsics.width = static_cast<std::uint32_t>(size.width);
  intrinsics.height = static_cast<std::uint32_t>(size.height);
  intrinsics.fx = K.at<double>(0, 0);
  intrinsics.fy = K.at<double>(1, 1);
  intrinsics.cx = K.at<double>(0, 2);
  intrinsics.cy = K.at<double>(1, 2);
  const cv::Mat d = dist.reshape(1, 1);
  for (int i = 0; i < 5 && i < d.cols; ++i) intrinsics.distortion[i] = d.at<double>(0, i);
  return intrinsics;
}

cv::Mat DistortionVector(const CameraIntrinsics& intrinsics) {
  cv::Mat d(1, 5, CV_64F);
  for (int i = 0; i < 5; ++i) d.at<double>(0, i) = intrinsics.distortion[i];
  return d;
}

Eigen::Isometry3d ToIsometry(const cv::Mat& rvec_or_R, const cv::Mat& tvec) {
  cv::Mat R;
  if (rvec_or_R.rows == 3 && rvec_or_R.cols == 3) {
    R = rvec_or_R;
  } else {
    cv::Rodrigues(rvec_or_R, R);
  }
  Eigen::Matrix3d R_eigen;
  Eigen::Vector3d t_eigen;
  cv::cv2eigen(R, R_eigen);
  cv::Mat t = tvec.reshape(1, 3);
  cv::cv2eigen(t, t_eigen);
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = R_eigen;
  X.translation() = t_eigen;
  return X;
}

std::vector<cv::Point3f> BoardObjectPoints(const ChessboardSpec& board) {
  std::vector<cv::Point3f> points;
  for (const Eigen::Vector3d& p : board.CornerPositions()) {
    points.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()),
                        static_cast<float>(p.z()));
  }
  return points;
}

std::vector<cv::Point2f> ToCv(const std::vector<Eigen::Vector2d>& points) {
  std::vector<cv::Point2f> out;
  out.reserve(points.size());
  for (const auto& p : points)
    out.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()));
  return out;
}

struct IntrinsicFit {
  CameraIntrinsics intrinsics;
  double rms_px = 0.0;
  std::vector<double> per_view_rms_px;
  std::vector<Eigen::Isometry3d> X_DeviceBoard;
};

IntrinsicFit FitIntrinsics(const std::vector<std::vector<cv::Point3f>>& object_points,
                           const std::vector<std::vector<cv::Point2f>>& image_points, cv::Size size,
                           bool estimate_k3) {
  cv::Mat K, dist, per_view, std_intrinsics, std_extrinsics;
  std::vector<cv::Mat> rvecs, tvecs;
  int flags = estimate_k3 ? 0 : cv::CALIB_FIX_K3;
  const cv::TermCriteria criteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-12);
  IntrinsicFit fit;
  fit.rms_px = cv::calibrateCamera(object_points, image_points, size, K, dist, rvecs, tvecs,
                                   std_intrinsics, std_extrinsics, per_view, flags, criteria);
  fit.intrinsics = ToIntrinsics(K, dist, size);
  for (int i = 0; i < per_view.rows; ++i) fit.per_view_rms_px.push_back(per_view.at<double>(i, 0));
  for (std::size_t i = 0; i < rvecs.size(); ++i) {
    fit.X_DeviceBoard.push_back(ToIsometry(rvecs[i], tvecs[i]));
  }
  return fit;
}

}  // namespace

Eigen::Vector2d CameraIntrinsics::Project(const Eigen::Vector3d& p_DevicePoint) const {
  const double x = p_DevicePoint.x() / p_DevicePoint.z();
  const double y = p_DevicePoint.y() / p_DevicePoint.z();
  const double k1 = distortion[0], k2 = distortion[1], p1 = distortion[2], p2 = distortion[3],
               k3 = distortion[4];
  const double r2 = x * x + y * y;
  const double radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
  const double xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
  const double yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
  return {fx * xd + cx, fy * yd + cy};
}

camera::PinholeCamera CameraIntrinsics::ToPinholeCamera() const {
  return camera::PinholeCamera(static_cast<int>(width), static_cast<int>(height), fx, fy, cx, cy,
                               camera::Distortion::FromOpenCv(distortion));
}

void CameraIntrinsics::Validate() const {
  auto fail = [](const std::string& field, double value) {
    throw std::invalid_argument("CameraIntrinsics." + field +
                                " is invalid: " + std::to_string(value));
  };
  if (width == 0) fail("width", width);
  if (height == 0) fail("height", height);
  if (!(fx > 0.0) || !std::isfinite(fx)) fail("fx", fx);
  if (!(fy > 0.0) || !std::isfinite(fy)) fail("fy", fy);
  if (!std::isfinite(cx)) fail("cx", cx);
  if (!std::isfinite(cy)) fail("cy", cy);
  for (int i = 0; i < 5; ++i) {
    if (!std::isfinite(distortion[i])) fail("distortion[" + std::to_string(i) + "]", distortion[i]);
  }
}

std::vector<Eigen::Vector3d> ChessboardSpec::CornerPositions() const {
  std::vector<Eigen::Vector3d> corners;
  corners.reserve(static_cast<std::size_t>(inner_corners_x) * inner_corners_y);
  for (int y = 0; y < inner_corners_y; ++y) {
    for (int x = 0; x < inner_corners_x; ++x) {
      corners.emplace_back(x * square_size_m, y * square_size_m, 0.0);
    }
  }
  return corners;
}

void ChessboardSpec::Validate() const {
  if (inner_corners_x < 2 || inner_corners_y < 2) {
    throw std::invalid_argument("ChessboardSpec needs at least 2 x 2 inner corners, got " +
                                std::to_string(inner_corners_x) + " x " +
                                std::to_string(inner_corners_y));
  }
  if (!(square_size_m > 0.0)) {
    throw std::invalid_argument("ChessboardSpec.square_size_m must be > 0, got " +
                                std::to_string(square_size_m));
  }
}

bool DetectChessboard(const GrayImage& image, const ChessboardSpec& board,
                      std::vector<Eigen::Vector2d>* corners_px) {
  CheckImage(image, "DetectChessboard");
  board.Validate();
  const cv::Mat mat = WrapImage(image);
  const cv::Size pattern(board.inner_corners_x, board.inner_corners_y);
  std::vector<cv::Point2f> corners;
  const bool found = cv::findChessboardCorners(
      mat, pattern, corners,
      // FAST_CHECK rejects an image with no board in sight at once; without it the search
      // over thresholds can take minutes on a large frame.
      cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_FAST_CHECK);
  if (!found) return false;
  cv::cornerSubPix(mat, corners, cv::Size(11, 11), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 50, 1e-3));
  corners_px->clear();
  for (const auto& c : corners) corners_px->emplace_back(c.x, c.y);
  return true;
}

CameraCalibrationResult CalibrateCamera(const std::vector<ChessboardView>& views,
                                        const CameraCalibrationOptions& options) {
  options.board.Validate();
  const int min_views = std::max(3, options.min_views);
  CameraCalibrationResult result;
  std::vector<std::vector<cv::Point3f>> object_points;
  std::vector<std::vector<cv::Point2f>> image_points;
  const std::vector<cv::Point3f> board_points = BoardObjectPoints(options.board);
  cv::Size size;
  for (const ChessboardView& view : views) {
    CheckImage(view.image, "view '" + view.name + "'");
    const cv::Size view_size(static_cast<int>(view.image.width),
                             static_cast<int>(view.image.height));
    if (size.area() == 0) {
      size = view_size;
    } else if (size != view_size) {
      throw std::invalid_argument("view '" + view.name + "' is " + std::to_string(view_size.width) +
                                  " x " + std::to_string(view_size.height) +
                                  " but the first view is " + std::to_string(size.width) + " x " +
                                  std::to_string(size.height));
    }
    std::vector<Eigen::Vector2d> corners;
    if (!DetectChessboard(view.image, options.board, &corners)) {
      if (!options.skip_views_without_board) {
        throw std::invalid_argument("chessboard (" + std::to_string(options.board.inner_corners_x) +
                                    " x " + std::to_string(options.board.inner_corners_y) +
                                    " inner corners) not found in view '" + view.name + "'");
      }
      result.skipped_views.push_back(view.name);
      continue;
    }
    object_points.push_back(board_points);
    image_points.push_back(ToCv(corners));
    result.used_views.push_back(view.name);
  }
  if (static_cast<int>(image_points.size()) < min_views) {
    throw std::invalid_argument("camera calibration needs at least " + std::to_string(min_views) +
                                " views with a detected chessboard, got " +
                                std::to_string(image_points.size()) + " of " +
                                std::to_string(views.size()));
  }
  IntrinsicFit fit = FitIntrinsics(object_points, image_points, size, options.estimate_k3);
  result.intrinsics = fit.intrinsics;
  result.rms_px = fit.rms_px;
  result.per_view_rms_px = std::move(fit.per_view_rms_px);
  result.X_CameraBoard = std::move(fit.X_DeviceBoard);
  return result;
}

namespace {

// Mean grey level in a disc of `radius_px` around `p` (pixels outside the image ignored);
// -1 when the disc lies outside the image.
double MeanLevel(const GrayImage& image, const cv::Point2f& p, double radius_px) {
  const int r = std::max(1, static_cast<int>(radius_px));
  const int x0 = static_cast<int>(std::lround(p.x)), y0 = static_cast<int>(std::lround(p.y));
  double sum = 0.0;
  int count = 0;
  for (int y = y0 - r; y <= y0 + r; ++y) {
    for (int x = x0 - r; x <= x0 + r; ++x) {
      if (x < 0 || y < 0 || x >= static_cast<int>(image.width) ||
          y >= static_cast<int>(image.height) ||
          (x - x0) * (x - x0) + (y - y0) * (y - y0) > r * r) {
        continue;
      }
      sum += image.at(static_cast<std::uint32_t>(x), static_cast<std::uint32_t>(y));
      ++count;
    }
  }
  return count > 0 ? sum / count : -1.0;
}

}  // namespace

bool EstimateBoardPose(const GrayImage& image, const ChessboardSpec& board,
                       const CameraIntrinsics& intrinsics, BoardPose* pose) {
  CheckImage(image, "EstimateBoardPose");
  intrinsics.Validate();
  if (image.width != intrinsics.width || image.height != intrinsics.height) {
    throw std::invalid_argument(
        "EstimateBoardPose: the image is " + std::to_string(image.width) + " x " +
        std::to_string(image.height) + " but the camera intrinsics are for " +
        std::to_string(intrinsics.width) + " x " + std::to_string(intrinsics.height));
  }
  std::vector<Eigen::Vector2d> corners;
  if (!DetectChessboard(image, board, &corners)) return false;
  const std::vector<cv::Point3f> object = BoardObjectPoints(board);
  const cv::Mat K(CameraMatrix(intrinsics));
  const cv::Mat d = DistortionVector(intrinsics);
  const auto solve = [&](const std::vector<Eigen::Vector2d>& c, cv::Mat* rvec, cv::Mat* tvec) {
    const std::vector<cv::Point2f> points = ToCv(c);
    if (!cv::solvePnP(object, points, K, d, *rvec, *tvec, false, cv::SOLVEPNP_ITERATIVE)) {
      return false;
    }
    return true;
  };
  cv::Mat rvec, tvec;
  if (!solve(corners, &rvec, &tvec)) return false;
  if ((board.inner_corners_x + board.inner_corners_y) % 2 == 1) {
    // The squares diagonally outside the first and the last corner differ in colour.
    const double s = board.square_size_m;
    const std::vector<cv::Point3f> probes{
        cv::Point3f(static_cast<float>(-0.5 * s), static_cast<float>(-0.5 * s), 0.0f),
        cv::Point3f(static_cast<float>((board.inner_corners_x - 0.5) * s),
                    static_cast<float>((board.inner_corners_y - 0.5) * s), 0.0f)};
    std::vector<cv::Point2f> probes_px;
    cv::projectPoints(probes, rvec, tvec, K, d, probes_px);
    const double square_px = (corners[1] - corners[0]).norm();
    const double first = MeanLevel(image, probes_px[0], 0.25 * square_px);
    const double last = MeanLevel(image, probes_px[1], 0.25 * square_px);
    if (first >= 0.0 && last >= 0.0 && first > last) {
      std::reverse(corners.begin(), corners.end());
      if (!solve(corners, &rvec, &tvec)) return false;
    }
  }
  std::vector<cv::Point2f> reprojected;
  cv::projectPoints(object, rvec, tvec, K, d, reprojected);
  double sum_sq = 0.0;
  for (std::size_t i = 0; i < corners.size(); ++i) {
    const double dx = reprojected[i].x - corners[i].x();
    const double dy = reprojected[i].y - corners[i].y();
    sum_sq += dx * dx + dy * dy;
  }
  pose->X_CameraBoard = ToIsometry(rvec, tvec);
  pose->rms_px = std::sqrt(sum_sq / static_cast<double>(corners.size()));
  pose->corners_px = std::move(corners);
  return true;
}

void ProjectorSpec::Validate() const {
  if (width == 0 || height == 0) throw std::invalid_argument("ProjectorSpec size must be > 0");
  if (column_bits < 1 || column_bits > 16 || (1u << column_bits) < width) {
    throw std::invalid_argument("ProjectorSpec.column_bits=" + std::to_string(column_bits) +
                                " cannot code " + std::to_string(width) + " columns");
  }
  if (row_bits < 1 || row_bits > 16 || (1u << row_bits) < height) {
    throw std::invalid_argument("ProjectorSpec.row_bits=" + std::to_string(row_bits) +
                                " cannot code " + std::to_string(height) + " rows");
  }
}

ProjectorCorrespondence DecodeGrayCode(const std::vector<GrayImage>& images,
                                       const ProjectorSpec& projector,
                                       const GrayCodeDecodeOptions& options) {
  projector.Validate();
  if (static_cast<int>(images.size()) != projector.image_count()) {
    throw std::invalid_argument("Gray-code capture needs " +
                                std::to_string(projector.image_count()) + " images, got " +
                                std::to_string(images.size()));
  }
  for (std::size_t i = 0; i < images.size(); ++i) {
    CheckImage(images[i], "Gray-code image " + std::to_string(i));
    if (images[i].width != images[0].width || images[i].height != images[0].height) {
      throw std::invalid_argument("Gray-code image " + std::to_string(i) +
                                  " differs in size from image 0");
    }
  }
  ProjectorCorrespondence out;
  out.width = images[0].width;
  out.height = images[0].height;
  const std::size_t n = images[0].pixels.size();
  out.column.assign(n, -1);
  out.row.assign(n, -1);
  const auto decode = [&](std::size_t pixel, int first_image, int bits,
                          std::uint32_t limit) -> std::int32_t {
    std::uint32_t gray = 0;
    for (int b = 0; b < bits; ++b) {
      const int pattern = images[first_image + 2 * b].pixels[pixel];
      const int inverse = images[first_image + 2 * b + 1].pixels[pixel];
      const int difference = pattern - inverse;
      if (std::abs(difference) < options.min_bit_difference) return -1;
      gray = (gray << 1) | (difference > 0 ? 1u : 0u);
    }
    const std::uint32_t value = GrayDecode(gray);
    return value < limit ? static_cast<std::int32_t>(value) : -1;
  };
  for (std::size_t i = 0; i < n; ++i) {
    if (static_cast<int>(images[0].pixels[i]) - images[1].pixels[i] < options.min_contrast)
      continue;
    const std::int32_t column = decode(i, 2, projector.column_bits, projector.width);
    if (column < 0) continue;
    const std::int32_t row =
        decode(i, 2 + 2 * projector.column_bits, projector.row_bits, projector.height);
    if (row < 0) continue;
    out.column[i] = column;
    out.row[i] = row;
  }
  return out;
}

ProjectorCalibrator::ProjectorCalibrator(const ProjectorCalibrationOptions& options)
    : options_(options) {
  options_.board.Validate();
  options_.projector.Validate();
  if (options_.window_radius_px < 2) {
    throw std::invalid_argument("ProjectorCalibrationOptions.window_radius_px must be >= 2");
  }
  if (options_.min_window_pixels < 8) {
    throw std::invalid_argument("ProjectorCalibrationOptions.min_window_pixels must be >= 8");
  }
}

const ProjectorCalibrationView& ProjectorCalibrator::AddView(const std::string& name,
                                                             const std::vector<GrayImage>& images) {
  const std::string where = "projector calibration view '" + name + "'";
  if (static_cast<int>(images.size()) != options_.projector.image_count()) {
    throw std::invalid_argument(where + ": needs " +
                                std::to_string(options_.projector.image_count()) + " images, got " +
                                std::to_string(images.size()));
  }
  ProjectorCorrespondence correspondence;
  try {
    correspondence = DecodeGrayCode(images, options_.projector, options_.decode);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(where + ": " + e.what());
  }
  ProjectorCalibrationView view;
  view.name = name;
  if (!DetectChessboard(images[0], options_.board, &view.camera_corners_px)) {
    throw std::invalid_argument(where + ": chessboard not found in the white image");
  }
  const int r = options_.window_radius_px;
  const int w = static_cast<int>(correspondence.width);
  const int h = static_cast<int>(correspondence.height);
  for (std::size_t c = 0; c < view.camera_corners_px.size(); ++c) {
    const Eigen::Vector2d& corner = view.camera_corners_px[c];
    const int x0 = static_cast<int>(std::lround(corner.x()));
    const int y0 = static_cast<int>(std::lround(corner.y()));
    std::vector<cv::Point2f> camera_points, projector_points;
    for (int y = std::max(0, y0 - r); y <= std::min(h - 1, y0 + r); ++y) {
      for (int x = std::max(0, x0 - r); x <= std::min(w - 1, x0 + r); ++x) {
        const std::size_t i = static_cast<std::size_t>(y) * w + x;
        if (correspondence.column[i] < 0) continue;
        camera_points.emplace_back(static_cast<float>(x), static_cast<float>(y));
        projector_points.emplace_back(static_cast<float>(correspondence.column[i]),
                                      static_cast<float>(correspondence.row[i]));
      }
    }
    if (static_cast<int>(camera_points.size()) < options_.min_window_pixels) {
      throw std::invalid_argument(where + ": corner " + std::to_string(c) + " has only " +
                                  std::to_string(camera_points.size()) +
                                  " decoded pixels around it (need " +
                                  std::to_string(options_.min_window_pixels) + ")");
    }
    const cv::Mat H = cv::findHomography(camera_points, projector_points, cv::RANSAC, 1.5);
    if (H.empty()) {
      throw std::invalid_argument(where + ": no local homography for corner " + std::to_string(c));
    }
    const cv::Vec3d q = cv::Matx33d(H) * cv::Vec3d(corner.x(), corner.y(), 1.0);
    view.projector_corners_px.emplace_back(q[0] / q[2], q[1] / q[2]);
  }
  if (camera_width_ == 0) {
    camera_width_ = correspondence.width;
    camera_height_ = correspondence.height;
  } else if (camera_width_ != correspondence.width || camera_height_ != correspondence.height) {
    throw std::invalid_argument(where + ": camera image size differs from the previous views");
  }
  views_.push_back(std::move(view));
  return views_.back();
}

void ProjectorCalibrator::AddCorners(const ProjectorCalibrationView& view) {
  const std::size_t expected =
      static_cast<std::size_t>(options_.board.inner_corners_x) * options_.board.inner_corners_y;
  if (view.camera_corners_px.size() != expected || view.projector_corners_px.size() != expected) {
    throw std::invalid_argument("projector calibration view '" + view.name + "' needs " +
                                std::to_string(expected) + " camera and projector corners");
  }
  views_.push_back(view);
}

ProjectorCalibrationResult ProjectorCalibrator::Calibrate() const {
  const int min_views = std::max(3, options_.min_views);
  if (static_cast<int>(views_.size()) < min_views) {
    throw std::invalid_argument("projector calibration needs at least " +
                                std::to_string(min_views) + " chessboard poses, got " +
                                std::to_string(views_.size()));
  }
  if (camera_width_ == 0) {
    throw std::invalid_argument(
        "projector calibration: camera image size unknown (add at least one view with images)");
  }
  const std::vector<cv::Point3f> board_points = BoardObjectPoints(options_.board);
  std::vector<std::vector<cv::Point3f>> object_points(views_.size(), board_points);
  std::vector<std::vector<cv::Point2f>> camera_points, projector_points;
  for (const auto& view : views_) {
    camera_points.push_back(ToCv(view.camera_corners_px));
    projector_points.push_back(ToCv(view.projector_corners_px));
  }
  const cv::Size camera_size(static_cast<int>(camera_width_), static_cast<int>(camera_height_));
  const cv::Size projector_size(static_cast<int>(options_.projector.width),
                                static_cast<int>(options_.projector.height));
  const IntrinsicFit camera =
      FitIntrinsics(object_points, camera_points, camera_size, options_.estimate_k3);
  const IntrinsicFit projector =
      FitIntrinsics(object_points, projector_points, projector_size, options_.estimate_k3);

  cv::Mat K_camera(CameraMatrix(camera.intrinsics)),
      K_projector(CameraMatrix(projector.intrinsics));
  cv::Mat d_camera = DistortionVector(camera.intrinsics);
  cv::Mat d_projector = DistortionVector(projector.intrinsics);
  cv::Mat R, T, E, F;
  ProjectorCalibrationResult result;
  result.stereo_rms_px = cv::stereoCalibrate(
      object_points, camera_points, projector_points, K_camera, d_camera, K_projector, d_projector,
      camera_size, R, T, E, F, cv::CALIB_FIX_INTRINSIC,
      cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-12));
  // stereoCalibrate maps camera-frame points into the projector frame: X_ProjectorCamera.
  result.X_CameraProjector = ToIsometry(R, T).inverse();
  result.camera = camera.intrinsics;
  result.projector = projector.intrinsics;
  result.camera_rms_px = camera.rms_px;
  result.projector_rms_px = projector.rms_px;
  result.views = views_;
  return result;
}

namespace {

Eigen::Vector3d RotationVector(const Eigen::Matrix3d& R) {
  const Eigen::AngleAxisd aa(R);
  return aa.angle() * aa.axis();
}

}  // namespace

namespace {

// Observability: the relative tool rotations must be large enough and about at least two
// non-parallel axes (Tsai & Lenz); otherwise part of X_ToolCamera is undetermined.
void CheckHandEyeMotions(const std::vector<Eigen::Isometry3d>& X_BaseTool,
                         const HandEyeOptions& options) {
  std::vector<Eigen::Vector3d> axes;
  for (std::size_t i = 0; i < X_BaseTool.size(); ++i) {
    for (std::size_t j = i + 1; j < X_BaseTool.size(); ++j) {
      const Eigen::Matrix3d R_ij = X_BaseTool[i].linear().transpose() * X_BaseTool[j].linear();
      const Eigen::AngleAxisd aa(R_ij);
      if (aa.angle() >= options.min_rotation_rad) axes.push_back(aa.axis());
    }
  }
  if (axes.size() < 2) {
    throw std::invalid_argument(
        "hand-eye calibration: degenerate motions, fewer than two relative tool rotations "
        "exceed " +
        std::to_string(options.min_rotation_rad) + " rad");
  }
  double max_spread = 0.0;
  for (std::size_t i = 0; i < axes.size(); ++i) {
    for (std::size_t j = i + 1; j < axes.size(); ++j) {
      const double c = std::min(1.0, std::abs(axes[i].dot(axes[j])));
      max_spread = std::max(max_spread, std::acos(c));
    }
  }
  if (max_spread < options.min_axis_spread_rad) {
    throw std::invalid_argument(
        "hand-eye calibration: degenerate motions, all relative tool rotations are about "
        "parallel axes (spread " +
        std::to_string(max_spread) + " rad < " + std::to_string(options.min_axis_spread_rad) +
        " rad)");
  }
}

// OpenCV's hand-eye solution (the options' method) for the pose pairs: X_ToolCamera.
Eigen::Isometry3d SolveHandEye(const std::vector<Eigen::Isometry3d>& X_BaseTool,
                               const std::vector<Eigen::Isometry3d>& X_CameraBoard,
                               const HandEyeOptions& options) {
  std::vector<cv::Mat> R_gripper2base, t_gripper2base, R_target2cam, t_target2cam;
  for (std::size_t i = 0; i < X_BaseTool.size(); ++i) {
    // Fresh matrices each time: cv::Mat shares its buffer when pushed into a vector.
    cv::Mat R_tool, t_tool, R_board, t_board;
    cv::eigen2cv(Eigen::Matrix3d(X_BaseTool[i].linear()), R_tool);
    cv::eigen2cv(Eigen::Vector3d(X_BaseTool[i].translation()), t_tool);
    cv::eigen2cv(Eigen::Matrix3d(X_CameraBoard[i].linear()), R_board);
    cv::eigen2cv(Eigen::Vector3d(X_CameraBoard[i].translation()), t_board);
    R_gripper2base.push_back(R_tool);
    t_gripper2base.push_back(t_tool);
    R_target2cam.push_back(R_board);
    t_target2cam.push_back(t_board);
  }
  cv::HandEyeCalibrationMethod method = cv::CALIB_HAND_EYE_PARK;
  switch (options.method) {
    case HandEyeOptions::Method::kTsai:
      method = cv::CALIB_HAND_EYE_TSAI;
      break;
    case HandEyeOptions::Method::kPark:
      method = cv::CALIB_HAND_EYE_PARK;
      break;
    case HandEyeOptions::Method::kHoraud:
      method = cv::CALIB_HAND_EYE_HORAUD;
      break;
    case HandEyeOptions::Method::kAndreff:
      method = cv::CALIB_HAND_EYE_ANDREFF;
      break;
    case HandEyeOptions::Method::kDaniilidis:
      method = cv::CALIB_HAND_EYE_DANIILIDIS;
      break;
  }
  cv::Mat R_cam2gripper, t_cam2gripper;
  cv::calibrateHandEye(R_gripper2base, t_gripper2base, R_target2cam, t_target2cam, R_cam2gripper,
                       t_cam2gripper, method);
  return ToIsometry(R_cam2gripper, t_cam2gripper);
}

// Consistency: every pose pair implies a board pose in the base frame; their mean and
// spread go into *result.
void MeasureHandEyeConsistency(const std::vector<Eigen::Isometry3d>& X_BaseTool,
                               const std::vector<Eigen::Isometry3d>& X_CameraBoard,
                               HandEyeResult* result_ptr) {
  HandEyeResult& result = *result_ptr;
  std::vector<Eigen::Isometry3d> X_BaseBoard;
  Eigen::Vector3d mean_translation = Eigen::Vector3d::Zero();
  Eigen::Vector4d quaternion_sum = Eigen::Vector4d::Zero();
  for (std::size_t i = 0; i < X_BaseTool.size(); ++i) {
    X_BaseBoard.push_back(X_BaseTool[i] * result.X_ToolCamera * X_CameraBoard[i]);
    mean_translation += X_BaseBoard.back().translation();
    Eigen::Quaterniond q(X_BaseBoard.back().linear());
    if (i > 0 && q.coeffs().dot(quaternion_sum) < 0.0) q.coeffs() *= -1.0;
    quaternion_sum += q.coeffs();
  }
  mean_translation /= static_cast<double>(X_BaseBoard.size());
  const Eigen::Quaterniond mean_rotation(Eigen::Vector4d(quaternion_sum.normalized()));
  result.X_BaseBoard = Eigen::Isometry3d::Identity();
  result.X_BaseBoard.linear() = mean_rotation.toRotationMatrix();
  result.X_BaseBoard.translation() = mean_translation;
  double translation_sq = 0.0, rotation_sq = 0.0;
  for (const auto& X : X_BaseBoard) {
    translation_sq += (X.translation() - mean_translation).squaredNorm();
    rotation_sq +=
        RotationVector(result.X_BaseBoard.linear().transpose() * X.linear()).squaredNorm();
  }
  result.translation_rms_m = std::sqrt(translation_sq / X_BaseBoard.size());
  result.rotation_rms_rad = std::sqrt(rotation_sq / X_BaseBoard.size());
}

}  // namespace

HandEyeResult CalibrateHandEye(const std::vector<Eigen::Isometry3d>& X_BaseTool,
                               const std::vector<Eigen::Isometry3d>& X_CameraBoard,
                               const HandEyeOptions& options) {
  if (X_BaseTool.size() != X_CameraBoard.size()) {
    throw std::invalid_argument("hand-eye calibration: " + std::to_string(X_BaseTool.size()) +
                                " robot poses but " + std::to_string(X_CameraBoard.size()) +
                                " board poses");
  }
  const int min_poses = std::max(3, options.min_poses);
  if (static_cast<int>(X_BaseTool.size()) < min_poses) {
    throw std::invalid_argument("hand-eye calibration needs at least " + std::to_string(min_poses) +
                                " poses, got " + std::to_string(X_BaseTool.size()));
  }
  CheckHandEyeMotions(X_BaseTool, options);
  HandEyeResult result;
  result.X_ToolCamera = SolveHandEye(X_BaseTool, X_CameraBoard, options);
  if (!result.X_ToolCamera.matrix().allFinite()) {
    throw std::invalid_argument("hand-eye calibration failed: the solution is not finite");
  }

  MeasureHandEyeConsistency(X_BaseTool, X_CameraBoard, &result);
  return result;
}

}  // namespace picking::scanner
