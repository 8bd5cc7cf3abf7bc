// Scene helpers: the intrinsics fit of an organised view and the merge of stacked views.
#include "services/detector/core/estimators.h"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>

namespace picking::detector {

namespace {

// Gauss-Newton fit of (fx, fy, cx, cy, k1, k2, p1, p2) to samples (x/z, y/z, u, v), started
// from the pinhole fit u = fu[0] x/z + fu[1], v = fv[0] y/z + fv[1].
std::optional<PinholeCamera> FitDistortedIntrinsics(const std::vector<Eigen::Vector4d>& all,
                                                    int width, int height,
                                                    const Eigen::Vector2d& fu,
                                                    const Eigen::Vector2d& fv, double max_rms_px) {
  using Vector8d = Eigen::Matrix<double, 8, 1>;
  using Matrix8d = Eigen::Matrix<double, 8, 8>;
  const std::size_t stride = std::max<std::size_t>(1, all.size() / 4000);
  std::vector<Eigen::Vector4d> samples;
  for (std::size_t i = 0; i < all.size(); i += stride) samples.push_back(all[i]);
  Vector8d k;
  k << fu[0], fv[0], fu[1], fv[1], 0.0, 0.0, 0.0, 0.0;
  // Pixel of normalised (x, y) and its Jacobian with respect to the parameters.
  const auto project = [](const Vector8d& c, double x, double y,
                          Eigen::Matrix<double, 2, 8>* J) -> Eigen::Vector2d {
    const double r2 = x * x + y * y;
    const double radial = 1.0 + c[4] * r2 + c[5] * r2 * r2;
    const double xd = x * radial + 2.0 * c[6] * x * y + c[7] * (r2 + 2.0 * x * x);
    const double yd = y * radial + c[6] * (r2 + 2.0 * y * y) + 2.0 * c[7] * x * y;
    if (J) {
      J->setZero();
      (*J)(0, 0) = xd;
      (*J)(0, 2) = 1.0;
      (*J)(1, 1) = yd;
      (*J)(1, 3) = 1.0;
      (*J)(0, 4) = c[0] * x * r2;
      (*J)(0, 5) = c[0] * x * r2 * r2;
      (*J)(0, 6) = c[0] * 2.0 * x * y;
      (*J)(0, 7) = c[0] * (r2 + 2.0 * x * x);
      (*J)(1, 4) = c[1] * y * r2;
      (*J)(1, 5) = c[1] * y * r2 * r2;
      (*J)(1, 6) = c[1] * (r2 + 2.0 * y * y);
      (*J)(1, 7) = c[1] * 2.0 * x * y;
    }
    return {c[0] * xd + c[2], c[1] * yd + c[3]};
  };
  const auto rms = [&](const Vector8d& c) {
    double sum = 0.0;
    for (const auto& s : samples) {
      sum += (project(c, s[0], s[1], nullptr) - s.tail<2>()).squaredNorm();
    }
    return std::sqrt(sum / static_cast<double>(samples.size()));
  };
  double current = rms(k);
  for (int iteration = 0; iteration < 20; ++iteration) {
    Matrix8d JtJ = Matrix8d::Zero();
    Vector8d Jtr = Vector8d::Zero();
    Eigen::Matrix<double, 2, 8> J;
    for (const auto& s : samples) {
      const Eigen::Vector2d r = project(k, s[0], s[1], &J) - s.tail<2>();
      JtJ += J.transpose() * J;
      Jtr += J.transpose() * r;
    }
    const Vector8d step = JtJ.ldlt().solve(-Jtr);
    if (!step.allFinite()) break;
    const Vector8d next = k + step;
    const double next_rms = rms(next);
    if (!(next_rms < current)) break;
    const bool converged = current - next_rms < 1e-6 * current;
    k = next;
    current = next_rms;
    if (converged) break;
  }
  if (!(current <= max_rms_px) || !(k[0] > 0.0) || !(k[1] > 0.0)) return std::nullopt;
  try {
    Distortion distortion;
    distortion.k1 = k[4];
    distortion.k2 = k[5];
    distortion.p1 = k[6];
    distortion.p2 = k[7];
    return PinholeCamera(width, height, k[0], k[1], k[2], k[3], distortion);
  } catch (const std::invalid_argument&) {
    return std::nullopt;  // A distortion that cannot be inverted over the image.
  }
}

}  // namespace

std::optional<PinholeCamera> FitOrganizedIntrinsics(const geometry::PointCloud& cloud,
                                                    const Eigen::Isometry3d& X_BaseSensor,
                                                    double max_rms_px, int pixel_step) {
  if (!cloud.is_organized() ||
      static_cast<std::size_t>(cloud.width) * cloud.height != cloud.points.size()) {
    return std::nullopt;
  }
  const std::uint32_t step = static_cast<std::uint32_t>(std::max(1, pixel_step));
  const Eigen::Isometry3d X_SensorBase = X_BaseSensor.inverse();
  // Normal equations of [a 1] [f c]^T = pixel for each axis.
  Eigen::Matrix2d Au = Eigen::Matrix2d::Zero(), Av = Eigen::Matrix2d::Zero();
  Eigen::Vector2d bu = Eigen::Vector2d::Zero(), bv = Eigen::Vector2d::Zero();
  std::size_t n = 0;
  std::vector<Eigen::Vector4d> samples;  // (x/z, y/z, u, v)
  for (std::uint32_t v = 0; v < cloud.height; v += step) {
    for (std::uint32_t u = 0; u < cloud.width; u += step) {
      const Eigen::Vector3f& p = cloud.points[static_cast<std::size_t>(v) * cloud.width + u];
      if (!p.allFinite()) continue;
      const Eigen::Vector3d q = X_SensorBase * p.cast<double>();
      if (!(q.z() > 1e-6)) continue;
      const double a = q.x() / q.z();
      const double b = q.y() / q.z();
      Au += Eigen::Vector2d(a, 1.0) * Eigen::Vector2d(a, 1.0).transpose();
      bu += Eigen::Vector2d(a, 1.0) * static_cast<double>(u);
      Av += Eigen::Vector2d(b, 1.0) * Eigen::Vector2d(b, 1.0).transpose();
      bv += Eigen::Vector2d(b, 1.0) * static_cast<double>(v);
      samples.emplace_back(a, b, u, v);
      ++n;
    }
  }
  if (n < 100) return std::nullopt;
  const Eigen::Vector2d fu = Au.ldlt().solve(bu);
  const Eigen::Vector2d fv = Av.ldlt().solve(bv);
  if (!fu.allFinite() || !fv.allFinite() || !(fu[0] > 0.0) || !(fv[0] > 0.0)) return std::nullopt;
  double sum_sq = 0.0;
  for (const auto& s : samples) {
    const double du = fu[0] * s[0] + fu[1] - s[2];
    const double dv = fv[0] * s[1] + fv[1] - s[3];
    sum_sq += du * du + dv * dv;
  }
  const int width = static_cast<int>(cloud.width);
  const int height = static_cast<int>(cloud.height);
  if (std::sqrt(sum_sq / static_cast<double>(n)) <= max_rms_px) {
    return PinholeCamera(width, height, fu[0], fv[0], fu[1], fv[1]);
  }
  return FitDistortedIntrinsics(samples, width, height, fu, fv, max_rms_px);
}

void UseScreenedViews(EstimatorOptions* options) {
  options->ppf.appearance.screened_per_view = true;
  options->refine.verify.appearance.screened_per_view = true;
}

namespace {
// Every 4th pixel of every 4th row: some 50 000 points of a megapixel view.
constexpr int kViewFitPixelStep = 4;
}  // namespace

StackedViews MergeStackedViews(const geometry::PointCloud& stacked,
                               const std::vector<Eigen::Isometry3d>& X_BaseSensors,
                               const PinholeCamera& fallback_camera,
                               const AppearanceOptions& appearance,
                               const OrientedBox* keep_inside) {
  const std::size_t views = X_BaseSensors.size();
  if (views == 0) throw std::invalid_argument("MergeStackedViews: no view sensor pose");
  for (std::size_t k = 0; k < views; ++k) {
    if (!X_BaseSensors[k].matrix().allFinite()) {
      throw std::invalid_argument("MergeStackedViews: the sensor pose of view " +
                                  std::to_string(k) + " is not finite");
    }
  }
  if (!stacked.is_organized() || stacked.height % views != 0 ||
      static_cast<std::size_t>(stacked.width) * stacked.height != stacked.points.size()) {
    throw std::invalid_argument(
        "MergeStackedViews: " + std::to_string(views) +
        " views need an organised cloud whose height is a multiple of the view count (the "
        "views stacked row-wise), got " +
        std::to_string(stacked.width) + " x " + std::to_string(stacked.height));
  }
  const std::size_t rows = stacked.height / views;
  const std::size_t block = rows * stacked.width;
  const bool normals = stacked.has_normals();
  const bool intensities = stacked.has_intensities() && normals;
  StackedViews out;
  const BoxContainment inside(keep_inside != nullptr ? *keep_inside : OrientedBox{});
  for (std::size_t k = 0; k < views; ++k) {
    geometry::PointCloud view;
    view.width = stacked.width;
    view.height = static_cast<std::uint32_t>(rows);
    const auto first = stacked.points.begin() + static_cast<std::ptrdiff_t>(k * block);
    view.points.assign(first, first + static_cast<std::ptrdiff_t>(block));
    const std::optional<PinholeCamera> fitted =
        FitOrganizedIntrinsics(view, X_BaseSensors[k], 1.0, kViewFitPixelStep);
    out.fitted_cameras += fitted ? 1 : 0;
    out.sensors.push_back(SensorView{X_BaseSensors[k], fitted.value_or(fallback_camera)});
    const Eigen::Vector3f viewpoint = X_BaseSensors[k].translation().cast<float>();
    for (std::size_t i = k * block; i < (k + 1) * block; ++i) {
      if (!stacked.points[i].allFinite()) continue;
      if (keep_inside != nullptr && !inside(stacked.points[i])) continue;
      out.cloud.points.push_back(stacked.points[i]);
      if (normals) out.cloud.normals.push_back(stacked.normals[i]);
      if (stacked.has_colors()) out.cloud.colors.push_back(stacked.colors[i]);
      if (intensities) {
        out.cloud.intensities.push_back(
            CompensatedViewIntensity(stacked.intensities[i], stacked.points[i], stacked.normals[i],
                                     viewpoint, appearance)
                .value_or(std::numeric_limits<float>::quiet_NaN()));
      }
    }
  }
  out.cloud.width = static_cast<std::uint32_t>(out.cloud.points.size());
  out.cloud.height = 1;
  return out;
}

}  // namespace picking::detector
