#include "services/scanner/core/normals.h"

#include "services/scanner/core/band_pool.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace picking::scanner {
namespace {

constexpr int kRowsPerBand = 16;

void Require(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument("EstimateNormals: " + what);
}

// Writes the unit normal of point p from its tangents du and dv, towards the sensor at the
// origin (n . p < 0); NaN and false if !ok or the tangents are parallel.
inline bool SetNormal(const Eigen::Vector3f& p, const Eigen::Vector3f& du,
                      const Eigen::Vector3f& dv, bool ok, Eigen::Vector3f* normal) {
  // Cross product written out: keeps it inlined whatever other libraries export.
  const float nx = du.y() * dv.z() - du.z() * dv.y();
  const float ny = du.z() * dv.x() - du.x() * dv.z();
  const float nz = du.x() * dv.y() - du.y() * dv.x();
  const float norm2 = nx * nx + ny * ny + nz * nz;
  if (!ok || !(norm2 > 0.0f)) {
    normal->setConstant(std::numeric_limits<float>::quiet_NaN());
    return false;
  }
  const float facing = nx * p.x() + ny * p.y() + nz * p.z();
  const float scale = (facing > 0.0f ? -1.0f : 1.0f) / std::sqrt(norm2);
  *normal = Eigen::Vector3f(nx * scale, ny * scale, nz * scale);
  return true;
}

// Difference of the neighbours `minus` and `plus` (null where outside the image), falling
// back to a one-sided difference from the centre. False if neither side is usable.
inline bool Tangent(const Eigen::Vector3f* minus, const Eigen::Vector3f& centre,
                    const Eigen::Vector3f* plus, float max_jump, Eigen::Vector3f* tangent) {
  // False for NaN neighbours.
  const bool minus_ok = minus != nullptr && std::abs(minus->z() - centre.z()) <= max_jump;
  const bool plus_ok = plus != nullptr && std::abs(plus->z() - centre.z()) <= max_jump;
  if (!minus_ok && !plus_ok) return false;
  *tangent = (plus_ok ? *plus : centre) - (minus_ok ? *minus : centre);
  return true;
}

}  // namespace

std::size_t EstimateNormalsRow(const Eigen::Vector3f* up, const Eigen::Vector3f* centre,
                               const Eigen::Vector3f* down, int width, int step, float max_jump,
                               Eigen::Vector3f* normals) {
  std::size_t count = 0;
  // Any pixel, with the image borders checked.
  const auto general = [&](int x) {
    const Eigen::Vector3f& p = centre[x];
    if (std::isnan(p.z())) {
      normals[x].setConstant(std::numeric_limits<float>::quiet_NaN());
      return false;
    }
    Eigen::Vector3f du;
    Eigen::Vector3f dv;
    const bool ok = Tangent(x - step >= 0 ? centre + x - step : nullptr, p,
                            x + step < width ? centre + x + step : nullptr, max_jump, &du) &&
                    Tangent(up != nullptr ? up + x : nullptr, p,
                            down != nullptr ? down + x : nullptr, max_jump, &dv);
    return SetNormal(p, du, dv, ok, normals + x);
  };
  if (up == nullptr || down == nullptr || 2 * step >= width) {
    for (int x = 0; x < width; ++x) count += general(x);
    return count;
  }
  for (int x = 0; x < step; ++x) count += general(x);
  // Interior: all four neighbours exist; the one-sided fallbacks are selects.
  for (int x = step; x < width - step; ++x) {
    const Eigen::Vector3f& p = centre[x];
    if (std::isnan(p.z())) {
      normals[x].setConstant(std::numeric_limits<float>::quiet_NaN());
      continue;
    }
    const Eigen::Vector3f& left = centre[x - step];
    const Eigen::Vector3f& right = centre[x + step];
    const Eigen::Vector3f& above = up[x];
    const Eigen::Vector3f& below = down[x];
    const bool left_ok = std::abs(left.z() - p.z()) <= max_jump;  // False for NaN.
    const bool right_ok = std::abs(right.z() - p.z()) <= max_jump;
    const bool above_ok = std::abs(above.z() - p.z()) <= max_jump;
    const bool below_ok = std::abs(below.z() - p.z()) <= max_jump;
    const Eigen::Vector3f du = (right_ok ? right : p) - (left_ok ? left : p);
    const Eigen::Vector3f dv = (below_ok ? below : p) - (above_ok ? above : p);
    count += SetNormal(p, du, dv, (left_ok || right_ok) && (above_ok || below_ok), normals + x);
  }
  for (int x = width - step; x < width; ++x) count += general(x);
  return count;
}

void CheckNormalOptions(const NormalOptions& options, const char* who) {
  const std::string prefix = std::string(who) + ": ";
  if (options.step < 1) {
    throw std::invalid_argument(prefix + "options.step must be at least 1, got " +
                                std::to_string(options.step));
  }
  if (!(options.max_depth_jump_m > 0)) {
    throw std::invalid_argument(prefix + "options.max_depth_jump_m must be positive");
  }
  if (options.num_threads < 0) {
    throw std::invalid_argument(prefix + "options.num_threads must not be negative");
  }
}

NormalResult EstimateNormals(geometry::PointCloud* cloud, const NormalOptions& options) {
  Require(cloud != nullptr, "cloud is null");
  Require(cloud->height > 1 &&
              static_cast<std::size_t>(cloud->width) * cloud->height == cloud->points.size(),
          "cloud is not organised (width " + std::to_string(cloud->width) + ", height " +
              std::to_string(cloud->height) + ", " + std::to_string(cloud->points.size()) +
              " points)");
  CheckNormalOptions(options, "EstimateNormals");

  const int width = static_cast<int>(cloud->width);
  const int height = static_cast<int>(cloud->height);
  const int step = options.step;
  const float max_jump = static_cast<float>(options.max_depth_jump_m * step);
  cloud->normals.resize(cloud->points.size());
  const Eigen::Vector3f* points = cloud->points.data();
  Eigen::Vector3f* normals = cloud->normals.data();
  std::atomic<std::size_t> total{0};

  BandPool pool(options.num_threads);
  const int num_bands = (height + kRowsPerBand - 1) / kRowsPerBand;
  pool.Run(num_bands, [&](int band) {
    const int y0 = band * kRowsPerBand;
    const int y1 = std::min(height, y0 + kRowsPerBand);
    std::size_t count = 0;
    for (int y = y0; y < y1; ++y) {
      const auto row = [&](int yy) { return points + static_cast<std::size_t>(yy) * width; };
      count += EstimateNormalsRow(y - step >= 0 ? row(y - step) : nullptr, row(y),
                                  y + step < height ? row(y + step) : nullptr, width, step,
                                  max_jump, normals + static_cast<std::size_t>(y) * width);
    }
    total.fetch_add(count, std::memory_order_relaxed);
  });
  NormalResult result;
  result.num_normals = total.load();
  return result;
}

}  // namespace picking::scanner
