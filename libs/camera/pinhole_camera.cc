#include "libs/camera/pinhole_camera.h"

#include <Eigen/Dense>

#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>

namespace picking::camera {
namespace {

void Require(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument("PinholeCamera: " + what);
}

// Distortion and its 2x2 Jacobian with respect to the undistorted coordinates.
Eigen::Vector2d DistortWithJacobian(const Distortion& d, const Eigen::Vector2d& xy,
                                    Eigen::Matrix2d* jacobian) {
  const double x = xy.x();
  const double y = xy.y();
  const double r2 = x * x + y * y;
  const double radial = 1.0 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3));
  const double xd = x * radial + 2.0 * d.p1 * x * y + d.p2 * (r2 + 2.0 * x * x);
  const double yd = y * radial + d.p1 * (r2 + 2.0 * y * y) + 2.0 * d.p2 * x * y;
  if (jacobian != nullptr) {
    // d(radial)/d(r2)
    const double dradial = d.k1 + r2 * (2.0 * d.k2 + 3.0 * d.k3 * r2);
    (*jacobian)(0, 0) = radial + 2.0 * x * x * dradial + 2.0 * d.p1 * y + 6.0 * d.p2 * x;
    (*jacobian)(0, 1) = 2.0 * x * y * dradial + 2.0 * d.p1 * x + 2.0 * d.p2 * y;
    (*jacobian)(1, 0) = 2.0 * x * y * dradial + 2.0 * d.p1 * x + 2.0 * d.p2 * y;
    (*jacobian)(1, 1) = radial + 2.0 * y * y * dradial + 6.0 * d.p1 * y + 2.0 * d.p2 * x;
  }
  return {xd, yd};
}

}  // namespace

PinholeCamera::PinholeCamera(int width, int height, double fx, double fy, double cx, double cy,
                             const Distortion& distortion)
    : width_(width), height_(height), fx_(fx), fy_(fy), cx_(cx), cy_(cy), distortion_(distortion) {
  Require(width > 0, "width must be positive, got " + std::to_string(width));
  Require(height > 0, "height must be positive, got " + std::to_string(height));
  // Bounds that keep every back-projected ray (u - cx) / fx finite and normalisable, far
  // beyond any real lens: a denormal focal length made ray directions infinite.
  constexpr double kMinFocalPx = 1e-3, kMaxFocalPx = 1e7, kMaxPrincipalPx = 1e6;
  Require(std::isfinite(fx) && fx >= kMinFocalPx && fx <= kMaxFocalPx,
          "fx must be in [0.001, 1e7] px");
  Require(std::isfinite(fy) && fy >= kMinFocalPx && fy <= kMaxFocalPx,
          "fy must be in [0.001, 1e7] px");
  Require(std::isfinite(cx) && std::abs(cx) <= kMaxPrincipalPx,
          "cx must be within 1e6 px of the image origin");
  Require(std::isfinite(cy) && std::abs(cy) <= kMaxPrincipalPx,
          "cy must be within 1e6 px of the image origin");
  Require(std::isfinite(distortion.k1) && std::isfinite(distortion.k2) &&
              std::isfinite(distortion.p1) && std::isfinite(distortion.p2) &&
              std::isfinite(distortion.k3),
          "distortion coefficients must be finite");
  if (distortion.is_zero()) return;
  // The distortion must be invertible over the image: undistort points along the border
  // and the centre, check the round trip and that the mapping does not fold there.
  constexpr int kSamplesPerEdge = 32;
  const double u_max = width - 0.5;
  const double v_max = height - 0.5;
  for (int i = 0; i <= kSamplesPerEdge; ++i) {
    const double s = static_cast<double>(i) / kSamplesPerEdge;
    const Eigen::Vector2d samples[] = {{-0.5 + s * width, -0.5},
                                       {-0.5 + s * width, v_max},
                                       {-0.5, -0.5 + s * height},
                                       {u_max, -0.5 + s * height},
                                       {-0.5 + s * width, -0.5 + s * height}};
    for (const Eigen::Vector2d& uv : samples) {
      const Eigen::Vector2d xy = PixelToNormalized(uv);
      const Eigen::Vector2d back = NormalizedToPixel(xy);
      Eigen::Matrix2d jacobian;
      DistortWithJacobian(distortion_, xy, &jacobian);
      if (!xy.allFinite() || (back - uv).norm() > 1e-6 || jacobian.determinant() <= 0.0) {
        std::ostringstream message;
        message << "distortion (k1=" << distortion.k1 << ", k2=" << distortion.k2
                << ", p1=" << distortion.p1 << ", p2=" << distortion.p2 << ", k3=" << distortion.k3
                << ") is not invertible at pixel (" << uv.x() << ", " << uv.y() << ")";
        throw std::invalid_argument("PinholeCamera: " + message.str());
      }
    }
  }
}

Eigen::Matrix3d PinholeCamera::K() const {
  Eigen::Matrix3d k;
  k << fx_, 0.0, cx_, 0.0, fy_, cy_, 0.0, 0.0, 1.0;
  return k;
}

Eigen::Vector2d PinholeCamera::Distort(const Eigen::Vector2d& xy_undistorted) const {
  return DistortWithJacobian(distortion_, xy_undistorted, nullptr);
}

Eigen::Vector2d PinholeCamera::Undistort(const Eigen::Vector2d& xy_distorted) const {
  if (distortion_.is_zero()) return xy_distorted;
  Eigen::Vector2d xy = xy_distorted;
  constexpr int kMaxIterations = 50;
  for (int iteration = 0; iteration < kMaxIterations; ++iteration) {
    Eigen::Matrix2d jacobian;
    const Eigen::Vector2d error = DistortWithJacobian(distortion_, xy, &jacobian) - xy_distorted;
    if (error.squaredNorm() < 1e-26) break;
    const double det = jacobian.determinant();
    if (!(std::abs(det) > 1e-12)) break;
    Eigen::Vector2d step = jacobian.inverse() * error;
    // Damp very large steps so a poor start cannot jump to a far root.
    const double step_norm = step.norm();
    const double max_step = 0.5 * (1.0 + xy.norm());
    if (step_norm > max_step) step *= max_step / step_norm;
    xy -= step;
  }
  return xy;
}

Eigen::Vector2d PinholeCamera::NormalizedToPixel(const Eigen::Vector2d& xy_undistorted) const {
  const Eigen::Vector2d xy_d = Distort(xy_undistorted);
  return {fx_ * xy_d.x() + cx_, fy_ * xy_d.y() + cy_};
}

Eigen::Vector2d PinholeCamera::PixelToNormalized(const Eigen::Vector2d& uv) const {
  return Undistort(Eigen::Vector2d((uv.x() - cx_) / fx_, (uv.y() - cy_) / fy_));
}

std::optional<Eigen::Vector2d> PinholeCamera::Project(const Eigen::Vector3d& p_CameraPoint) const {
  if (!(p_CameraPoint.z() > 0.0)) return std::nullopt;
  return NormalizedToPixel(p_CameraPoint.head<2>() / p_CameraPoint.z());
}

Eigen::Vector3d PinholeCamera::Unproject(const Eigen::Vector2d& uv) const {
  const Eigen::Vector2d xy = PixelToNormalized(uv);
  return {xy.x(), xy.y(), 1.0};
}

Eigen::Vector3d PinholeCamera::RayDirection(const Eigen::Vector2d& uv) const {
  return Unproject(uv).normalized();
}

bool PinholeCamera::Contains(const Eigen::Vector2d& uv) const {
  return uv.x() >= -0.5 && uv.y() >= -0.5 && uv.x() <= width_ - 0.5 && uv.y() <= height_ - 0.5;
}

RayTable PinholeCamera::ComputeRayTable() const {
  RayTable table;
  table.width = width_;
  table.height = height_;
  table.xy.resize(static_cast<std::size_t>(width_) * height_);
  for (int v = 0; v < height_; ++v) {
    for (int u = 0; u < width_; ++u) {
      const Eigen::Vector2d xy = PixelToNormalized(Eigen::Vector2d(u, v));
      table.xy[static_cast<std::size_t>(v) * width_ + u] = xy.cast<float>();
    }
  }
  return table;
}

}  // namespace picking::camera
