#pragma once

#include <Eigen/Core>

#include <array>
#include <optional>
#include <vector>

namespace picking::camera {

/// OpenCV's five-coefficient lens distortion (radial k1, k2, k3 and tangential p1, p2),
/// applied to normalised image coordinates (x, y) = (X / Z, Y / Z):
///   r2 = x^2 + y^2,  radial = 1 + k1 r2 + k2 r2^2 + k3 r2^3
///   x_d = x radial + 2 p1 x y + p2 (r2 + 2 x^2)
///   y_d = y radial + p1 (r2 + 2 y^2) + 2 p2 x y
/// All coefficients are dimensionless; all zero means no distortion.
struct Distortion {
  double k1 = 0.0;
  double k2 = 0.0;
  double p1 = 0.0;
  double p2 = 0.0;
  double k3 = 0.0;

  bool is_zero() const { return k1 == 0.0 && k2 == 0.0 && p1 == 0.0 && p2 == 0.0 && k3 == 0.0; }
  /// From coefficients in OpenCV's order (k1, k2, p1, p2, k3).
  static Distortion FromOpenCv(const std::array<double, 5>& k) {
    Distortion d;
    d.k1 = k[0];
    d.k2 = k[1];
    d.p1 = k[2];
    d.p2 = k[3];
    d.k3 = k[4];
    return d;
  }
};

/// Per-pixel viewing rays of a camera, precomputed once so that per-pixel code needs no
/// undistortion. Entry `v * width + u` holds the undistorted normalised coordinates (x, y) of
/// the centre of pixel (u, v); the ray through that pixel is (x, y, 1) in the camera frame.
struct RayTable {
  int width = 0;
  int height = 0;
  std::vector<Eigen::Vector2f> xy;  ///< Normalised coordinates, row-major, width * height.
};

/// The pinhole camera model with OpenCV distortion, used for both cameras and projectors
/// (a projector is an inverse camera: its "pixels" are mirror columns and rows).
///
/// Frames and units: the camera frame C has its origin at the centre of projection, z along
/// the optical axis (forward, into the scene), x to the right of the image and y down the
/// image; positions in metres. Pixel coordinates (u, v) follow OpenCV: u along image columns,
/// v along rows, the centre of pixel (i, j) at (u, v) = (i, j), so the image spans
/// [-0.5, width - 0.5] x [-0.5, height - 0.5]. Focal lengths and principal point are in
/// pixels.
///
/// Instances are immutable and cheap to copy; all methods are thread-safe.
class PinholeCamera final {
 public:
  /// Builds the model.
  /// @throws std::invalid_argument if width or height is not positive, fx or fy is not
  ///   positive and finite, cx or cy or a distortion coefficient is not finite, or the
  ///   distortion cannot be inverted over the image (round trip of the image border fails).
  PinholeCamera(int width, int height, double fx, double fy, double cx, double cy,
                const Distortion& distortion = {});

  int width() const { return width_; }
  int height() const { return height_; }
  double fx() const { return fx_; }
  double fy() const { return fy_; }
  double cx() const { return cx_; }
  double cy() const { return cy_; }
  const Distortion& distortion() const { return distortion_; }

  /// The 3x3 intrinsic matrix K = [fx 0 cx; 0 fy cy; 0 0 1].
  Eigen::Matrix3d K() const;

  /// Applies the lens distortion to undistorted normalised coordinates.
  Eigen::Vector2d Distort(const Eigen::Vector2d& xy_undistorted) const;

  /// Inverts Distort by Newton iteration (converges to 1e-12 in normalised units for any
  /// distortion accepted by the constructor inside the image).
  Eigen::Vector2d Undistort(const Eigen::Vector2d& xy_distorted) const;

  /// Pixel coordinates of undistorted normalised coordinates (x, y) (distortion applied).
  Eigen::Vector2d NormalizedToPixel(const Eigen::Vector2d& xy_undistorted) const;

  /// Undistorted normalised coordinates (x, y) of a pixel; the ray is (x, y, 1).
  Eigen::Vector2d PixelToNormalized(const Eigen::Vector2d& uv) const;

  /// Projects p_CameraPoint (metres, camera frame) to pixel coordinates. Returns nullopt if
  /// the point is not in front of the camera (z <= 0). The pixel may lie outside the image;
  /// check with Contains().
  std::optional<Eigen::Vector2d> Project(const Eigen::Vector3d& p_CameraPoint) const;

  /// Direction of the viewing ray through pixel (u, v) in the camera frame, scaled so that
  /// z == 1 (multiply by a depth in metres to get p_CameraPoint).
  Eigen::Vector3d Unproject(const Eigen::Vector2d& uv) const;

  /// Unit-length direction of the viewing ray through pixel (u, v), camera frame.
  Eigen::Vector3d RayDirection(const Eigen::Vector2d& uv) const;

  /// True if (u, v) lies inside the image area [-0.5, width - 0.5] x [-0.5, height - 0.5].
  bool Contains(const Eigen::Vector2d& uv) const;

  /// The ray of every pixel centre (see RayTable). Takes a few tens of milliseconds for a
  /// megapixel camera with distortion; compute it once and keep it.
  RayTable ComputeRayTable() const;

 private:
  int width_;
  int height_;
  double fx_;
  double fy_;
  double cx_;
  double cy_;
  Distortion distortion_;
};

}  // namespace picking::camera
