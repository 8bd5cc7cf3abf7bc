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

  BandPool pool(options.num_threads);
  const int num_bands = (height + kRowsPerBand - 1) / kRowsPerBand;
  pool.Run(num_bands, [&](int band) {
    const int y0 = band * kRowsPerBand;
    const int y1 = std::min(height, y0 + kRowsPerBand);
    std::size_t count = 0;
    for (int y = y0; y < y1; ++y) {
      const bool has_up = y - step >= 0;
      const bool has_down = y + step < height;
      for (int x = 0; x < width; ++x) {
        const std::size_t i = static_cast<std::size_t>(y) * width + x;
        const Eigen::Vector3f& p = points[i];
        Eigen::Vector3f& normal = normals[i];
        normal.setConstant(kNaN);
        if (std::isnan(p.z())) continue;
        Eigen::Vector3f du;
        Eigen::Vector3f dv;
        if (!Tangent(points + i, p, x - step >= 0, x + step < width, step, max_jump, &du) ||
            !Tangent(points + i, p, has_up, has_down, static_cast<std::ptrdiff_t>(step) * width,
                     max_jump, &dv)) {
          continue;
        }
        // Cross product written out: keeps it inlined whatever other libraries export.
        const float nx = du.y() * dv.z() - du.z() * dv.y();
        const float ny = du.z() * dv.x() - du.x() * dv.z();
        const float nz = du.x() * dv.y() - du.y() * dv.x();
        const float norm2 = nx * nx + ny * ny + nz * nz;
        if (!(norm2 > 0.0f)) continue;
        // Unit length, and towards the sensor at the origin (n . p < 0).
        const float facing = nx * p.x() + ny * p.y() + nz * p.z();
        const float scale = (facing > 0.0f ? -1.0f : 1.0f) / std::sqrt(norm2);
        normal = Eigen::Vector3f(nx * scale, ny * scale, nz * scale);
        ++count;
      }
    }
    total.fetch_add(count, std::memory_order_relaxed);
  });
  NormalResult result;
  result.num_normals = total.load();
  return result;
}

}  // namespace picking::scanner
