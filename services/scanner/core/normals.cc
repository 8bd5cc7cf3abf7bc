#include "services/scanner/core/normals.h"

#include "services/scanner/core/band_pool.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
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

// On x86-64 with GCC the interior kernel is also compiled for AVX2 (eight floats per
// instruction; no FMA, so both versions round identically), chosen when the program loads.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
#define PICKING_NORMALS_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define PICKING_NORMALS_CLONES
#endif

// a ? b : c without a branch or a conditional load, so that the vectoriser takes it.
inline float Select(bool a, float b, float c) {
  std::uint32_t bits_b;
  std::uint32_t bits_c;
  std::memcpy(&bits_b, &b, sizeof(float));
  std::memcpy(&bits_c, &c, sizeof(float));
  const std::uint32_t mask = 0u - static_cast<std::uint32_t>(a);
  const std::uint32_t bits = (bits_b & mask) | (bits_c & ~mask);
  float result;
  std::memcpy(&result, &bits, sizeof(float));
  return result;
}

// The normals of n pixels whose four neighbours all exist, as SetNormal and Tangent compute
// them: p the first pixel's point, left / right its neighbours `step` away in the row, above
// / below those in the rows `step` away (points and normals x, y, z interleaved). Written
// with selects so that the compiler vectorises it. Returns the number of finite normals.
PICKING_NORMALS_CLONES int NormalsInterior(int n, const float* __restrict p,
                                           const float* __restrict left,
                                           const float* __restrict right,
                                           const float* __restrict above,
                                           const float* __restrict below, float max_jump,
                                           float* __restrict normals) {
  const float kNaN = std::numeric_limits<float>::quiet_NaN();
  int count = 0;
  for (int i = 0; i < n; ++i) {
    const float px = p[3 * i];
    const float py = p[3 * i + 1];
    const float pz = p[3 * i + 2];
    const float lx = left[3 * i];
    const float ly = left[3 * i + 1];
    const float lz = left[3 * i + 2];
    const float rx = right[3 * i];
    const float ry = right[3 * i + 1];
    const float rz = right[3 * i + 2];
    const float ax = above[3 * i];
    const float ay = above[3 * i + 1];
    const float az = above[3 * i + 2];
    const float bx = below[3 * i];
    const float by = below[3 * i + 1];
    const float bz = below[3 * i + 2];
    // False for NaN (a missing centre makes all four false).
    const bool left_ok = std::abs(lz - pz) <= max_jump;
    const bool right_ok = std::abs(rz - pz) <= max_jump;
    const bool above_ok = std::abs(az - pz) <= max_jump;
    const bool below_ok = std::abs(bz - pz) <= max_jump;
    const float dux = Select(right_ok, rx, px) - Select(left_ok, lx, px);
    const float duy = Select(right_ok, ry, py) - Select(left_ok, ly, py);
    const float duz = Select(right_ok, rz, pz) - Select(left_ok, lz, pz);
    const float dvx = Select(below_ok, bx, px) - Select(above_ok, ax, px);
    const float dvy = Select(below_ok, by, py) - Select(above_ok, ay, py);
    const float dvz = Select(below_ok, bz, pz) - Select(above_ok, az, pz);
    const float nx = duy * dvz - duz * dvy;
    const float ny = duz * dvx - dux * dvz;
    const float nz = dux * dvy - duy * dvx;
    const float norm2 = nx * nx + ny * ny + nz * nz;
    const float facing = nx * px + ny * py + nz * pz;
    const float scale = (facing > 0.0f ? -1.0f : 1.0f) / std::sqrt(norm2);
    const bool ok = (left_ok | right_ok) & (above_ok | below_ok) & (norm2 > 0.0f);
    normals[3 * i] = Select(ok, nx * scale, kNaN);
    normals[3 * i + 1] = Select(ok, ny * scale, kNaN);
    normals[3 * i + 2] = Select(ok, nz * scale, kNaN);
    count += ok;
  }
  return count;
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
  static_assert(sizeof(Eigen::Vector3f) == 3 * sizeof(float), "points are packed floats");
  const float* p = centre[step].data();
  count += static_cast<std::size_t>(NormalsInterior(width - 2 * step, p, p - 3 * step, p + 3 * step,
                                                    up[step].data(), down[step].data(), max_jump,
                                                    normals[step].data()));
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
