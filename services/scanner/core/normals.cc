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

// Difference of the neighbours at -step and +step along one image axis (given as pointer
// offsets), falling back to a one-sided difference. Returns false if neither side is usable.
inline bool Tangent(const Eigen::Vector3f* points, const Eigen::Vector3f& centre, bool has_minus,
                    bool has_plus, std::ptrdiff_t offset, float max_jump,
                    Eigen::Vector3f* tangent) {
  const bool minus_ok =
      has_minus && std::abs(points[-offset].z() - centre.z()) <= max_jump;  // False for NaN.
  const bool plus_ok = has_plus && std::abs(points[offset].z() - centre.z()) <= max_jump;
  if (minus_ok && plus_ok) {
    *tangent = points[offset] - points[-offset];
  } else if (plus_ok) {
    *tangent = points[offset] - centre;
  } else if (minus_ok) {
    *tangent = centre - points[-offset];
  } else {
    return false;
  }
  return true;
}

}  // namespace

NormalResult EstimateNormals(geometry::PointCloud* cloud, const NormalOptions& options) {
  Require(cloud != nullptr, "cloud is null");
  Require(cloud->height > 1 &&
              static_cast<std::size_t>(cloud->width) * cloud->height == cloud->points.size(),
          "cloud is not organised (width " + std::to_string(cloud->width) + ", height " +
              std::to_string(cloud->height) + ", " + std::to_string(cloud->points.size()) +
              " points)");
  Require(options.step >= 1,
          "options.step must be at least 1, got " + std::to_string(options.step));
  Require(options.max_depth_jump_m > 0, "options.max_depth_jump_m must be positive");
  Require(options.num_threads >= 0, "options.num_threads must not be negative");

  const int width = static_cast<int>(cloud->width);
  const int height = static_cast<int>(cloud->height);
  const int step = options.step;
  const float max_jump = static_cast<float>(options.max_depth_jump_m * step);
  const float kNaN = std::numeric_limits<float>::quiet_NaN();
  cloud->normals.resize(cloud->points.size());
  const Eigen::Vector3f* points = cloud->points.data();
  Eigen::Vector3f* normals = cloud->normals.data();
  std::atomic<std::size_t> total{0};

  // Normal of pixel i from its tangents; false (and a NaN normal) if there is none.
  const auto set_normal = [&](std::size_t i, const Eigen::Vector3f& du, const Eigen::Vector3f& dv,
                              bool ok) {
    const Eigen::Vector3f& p = points[i];
    // Cross product written out: keeps it inlined whatever other libraries export.
    const float nx = du.y() * dv.z() - du.z() * dv.y();
    const float ny = du.z() * dv.x() - du.x() * dv.z();
    const float nz = du.x() * dv.y() - du.y() * dv.x();
    const float norm2 = nx * nx + ny * ny + nz * nz;
    if (!ok || !(norm2 > 0.0f)) {
      normals[i].setConstant(kNaN);
      return false;
    }
    // Unit length, and towards the sensor at the origin (n . p < 0).
    const float facing = nx * p.x() + ny * p.y() + nz * p.z();
    const float scale = (facing > 0.0f ? -1.0f : 1.0f) / std::sqrt(norm2);
    normals[i] = Eigen::Vector3f(nx * scale, ny * scale, nz * scale);
    return true;
  };
  // Any pixel, with the image borders checked.
  const auto general = [&](int x, int y) {
    const std::size_t i = static_cast<std::size_t>(y) * width + x;
    const Eigen::Vector3f& p = points[i];
    if (std::isnan(p.z())) {
      normals[i].setConstant(kNaN);
      return false;
    }
    Eigen::Vector3f du;
    Eigen::Vector3f dv;
    const bool ok = Tangent(points + i, p, x - step >= 0, x + step < width, step, max_jump, &du) &&
                    Tangent(points + i, p, y - step >= 0, y + step < height,
                            static_cast<std::ptrdiff_t>(step) * width, max_jump, &dv);
    return set_normal(i, du, dv, ok);
  };

  BandPool pool(options.num_threads);
  const int num_bands = (height + kRowsPerBand - 1) / kRowsPerBand;
  pool.Run(num_bands, [&](int band) {
    const int y0 = band * kRowsPerBand;
    const int y1 = std::min(height, y0 + kRowsPerBand);
    const std::ptrdiff_t down = static_cast<std::ptrdiff_t>(step) * width;
    std::size_t count = 0;
    for (int y = y0; y < y1; ++y) {
      if (y - step < 0 || y + step >= height || 2 * step >= width) {
        for (int x = 0; x < width; ++x) count += general(x, y);
        continue;
      }
      for (int x = 0; x < step; ++x) count += general(x, y);
      // Interior: all four neighbours exist; the one-sided fallbacks are selects.
      for (int x = step; x < width - step; ++x) {
        const std::size_t i = static_cast<std::size_t>(y) * width + x;
        const Eigen::Vector3f& p = points[i];
        if (std::isnan(p.z())) {
          normals[i].setConstant(kNaN);
          continue;
        }
        const Eigen::Vector3f& left = points[i - step];
        const Eigen::Vector3f& right = points[i + step];
        const Eigen::Vector3f& up = points[i - down];
        const Eigen::Vector3f& below = points[i + down];
        // False for NaN neighbours.
        const bool left_ok = std::abs(left.z() - p.z()) <= max_jump;
        const bool right_ok = std::abs(right.z() - p.z()) <= max_jump;
        const bool up_ok = std::abs(up.z() - p.z()) <= max_jump;
        const bool below_ok = std::abs(below.z() - p.z()) <= max_jump;
        const Eigen::Vector3f du = (right_ok ? right : p) - (left_ok ? left : p);
        const Eigen::Vector3f dv = (below_ok ? below : p) - (up_ok ? up : p);
        count += set_normal(i, du, dv, (left_ok || right_ok) && (up_ok || below_ok));
      }
      for (int x = width - step; x < width; ++x) count += general(x, y);
    }
    total.fetch_add(count, std::memory_order_relaxed);
  });
  NormalResult result;
  result.num_normals = total.load();
  return result;
}

}  // namespace picking::scanner
