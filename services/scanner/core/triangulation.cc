#include "services/scanner/core/triangulation.h"

#include "services/scanner/core/band_pool.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <type_traits>

namespace picking::scanner {
namespace {

constexpr int kRowsPerBand = 16;

void Require(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument("Triangulator: " + what);
}

}  // namespace

Triangulator::Triangulator(const camera::PinholeCamera& camera,
                           const camera::PinholeCamera& projector,
                           const Eigen::Isometry3d& X_CameraProjector,
                           const TriangulationOptions& options)
    : camera_width_(camera.width()),
      camera_height_(camera.height()),
      projector_width_(projector.width()),
      projector_height_(projector.height()),
      options_(options) {
  Require(options.max_residual_projector_px >= 0,
          "options.max_residual_projector_px must not be negative");
  Require(options.min_depth_m > 0 && options.max_depth_m > options.min_depth_m,
          "options need 0 < min_depth_m < max_depth_m, got [" +
              std::to_string(options.min_depth_m) + ", " + std::to_string(options.max_depth_m) +
              "]");
  Require(options.min_neighbors >= 0 && options.min_neighbors <= 8,
          "options.min_neighbors must be in [0, 8], got " + std::to_string(options.min_neighbors));
  Require(options.neighbor_depth_tolerance_m >= 0,
          "options.neighbor_depth_tolerance_m must not be negative");
  Require(options.num_threads >= 0, "options.num_threads must not be negative");
  const Eigen::Matrix3d R = X_CameraProjector.linear();
  Require(X_CameraProjector.matrix().allFinite() &&
              (R * R.transpose() - Eigen::Matrix3d::Identity()).norm() < 1e-6 &&
              R.determinant() > 0,
          "X_CameraProjector must be a finite rigid transform");

  pool_ = std::make_unique<BandPool>(options.num_threads);
  projector_focal_px_ = static_cast<float>(std::min(projector.fx(), projector.fy()));
  const Eigen::Vector3d p_CameraProjector = X_CameraProjector.translation();
  p_CameraProjector_ = p_CameraProjector.cast<float>();
  rays_ = camera.ComputeRayTable().xy;

  const Eigen::Matrix3f R_CameraProjector = R.cast<float>();
  projector_rays_.resize(static_cast<std::size_t>(projector_width_) * projector_height_);
  pool_->Run(projector_height_, [&](int row) {
    for (int column = 0; column < projector_width_; ++column) {
      const Eigen::Vector3f e =
          (R_CameraProjector * projector.RayDirection(Eigen::Vector2d(column, row)).cast<float>())
              .normalized();
      projector_rays_[static_cast<std::size_t>(row) * projector_width_ + column] =
          Eigen::Vector4f(e.x(), e.y(), e.z(), -e.dot(p_CameraProjector_));
    }
  });
}

Triangulator::~Triangulator() = default;

TriangulationResult Triangulator::Run(const CorrespondenceMap& map,
                                      const ImageView* intensity) const {
  TriangulationResult result;
  Run(map, intensity, &result);
  return result;
}

void Triangulator::Run(const CorrespondenceMap& map, const ImageView* intensity,
                       TriangulationResult* result) const {
  Require(result != nullptr, "result is null");
  const std::size_t n = static_cast<std::size_t>(camera_width_) * camera_height_;
  Require(map.width == camera_width_ && map.height == camera_height_,
          "correspondence map is " + std::to_string(map.width) + " x " +
              std::to_string(map.height) + " but the camera is " + std::to_string(camera_width_) +
              " x " + std::to_string(camera_height_));
  Require(map.column.size() == n && map.row.size() == n && map.valid.size() == n,
          "correspondence map buffers are not width * height long");
  if (intensity != nullptr) {
    Require(intensity->data != nullptr && intensity->width == camera_width_ &&
                intensity->height == camera_height_ && intensity->stride_bytes >= camera_width_,
            "intensity image is " + std::to_string(intensity->width) + " x " +
                std::to_string(intensity->height) + " (or has no data / a short stride) but " +
                "the camera is " + std::to_string(camera_width_) + " x " +
                std::to_string(camera_height_));
  }
  const bool subpixel = map.has_subpixel();
  if (subpixel) {
    Require(map.column_subpixel.size() == n && map.row_subpixel.size() == n,
            "sub-pixel correspondence maps are not width * height long");
  }
  const int num_bands = (camera_height_ + kRowsPerBand - 1) / kRowsPerBand;
  // The projector image spans [-0.5, size - 0.5]; NaN fails the test too.
  const float max_u = static_cast<float>(projector_width_) - 0.5f;
  const float max_v = static_cast<float>(projector_height_) - 0.5f;
  const auto inside = [&](std::size_t i) {
    return map.column[i] < projector_width_ && map.row[i] < projector_height_ &&
           (!subpixel || (map.column_subpixel[i] >= -0.5f && map.column_subpixel[i] <= max_u &&
                          map.row_subpixel[i] >= -0.5f && map.row_subpixel[i] <= max_v));
  };
  {
    // A branch-free pass over all pixels finds whether any is bad; only then are they
    // searched for the first one to name it.
    std::atomic<int> outside{0};
    const std::uint8_t* valid = map.valid.data();
    const std::uint16_t* column = map.column.data();
    const std::uint16_t* row = map.row.data();
    const float* u = map.column_subpixel.data();
    const float* v = map.row_subpixel.data();
    const int projector_width = projector_width_;
    const int projector_height = projector_height_;
    pool_->Run(num_bands, [&](int band) {
      const std::size_t i0 = static_cast<std::size_t>(band) * kRowsPerBand * camera_width_;
      const std::size_t i1 =
          static_cast<std::size_t>(std::min(camera_height_, (band + 1) * kRowsPerBand)) *
          camera_width_;
      int local = 0;
      for (std::size_t i = i0; i < i1; ++i) {
        local |= valid[i] & ((column[i] >= projector_width) | (row[i] >= projector_height));
      }
      if (subpixel) {
        for (std::size_t i = i0; i < i1; ++i) {
          local |=
              valid[i] & !((u[i] >= -0.5f) & (u[i] <= max_u) & (v[i] >= -0.5f) & (v[i] <= max_v));
        }
      }
      if (local) outside.store(1, std::memory_order_relaxed);
    });
    for (std::size_t i = 0; outside.load() && i < n; ++i) {
      if (!map.valid[i] || inside(i)) continue;
      if (map.column[i] >= projector_width_ || map.row[i] >= projector_height_) {
        Require(false, "correspondence (" + std::to_string(map.column[i]) + ", " +
                           std::to_string(map.row[i]) + ") at pixel " + std::to_string(i) +
                           " lies outside the " + std::to_string(projector_width_) + " x " +
                           std::to_string(projector_height_) + " projector");
      }
      Require(false, "sub-pixel correspondence (" + std::to_string(map.column_subpixel[i]) + ", " +
                         std::to_string(map.row_subpixel[i]) + ") at pixel " + std::to_string(i) +
                         " lies outside the " + std::to_string(projector_width_) + " x " +
                         std::to_string(projector_height_) + " projector");
    }
  }

  geometry::PointCloud& cloud = result->cloud;
  cloud.width = static_cast<std::uint32_t>(camera_width_);
  cloud.height = static_cast<std::uint32_t>(camera_height_);
  cloud.frame_id = options_.frame_id;
  cloud.points.resize(n);
  cloud.normals.clear();
  cloud.colors.clear();
  if (intensity != nullptr) {
    cloud.intensities.resize(n);
  } else {
    cloud.intensities.clear();
  }

  const float kNaN = std::numeric_limits<float>::quiet_NaN();
  const float residual_scale =
      static_cast<float>(options_.max_residual_projector_px) / projector_focal_px_;
  // ray distance <= k * distance_from_projector / f
  const float residual_factor = residual_scale * residual_scale;
  const float min_depth = static_cast<float>(options_.min_depth_m);
  const float max_depth = static_cast<float>(options_.max_depth_m);
  const Eigen::Vector3f o = p_CameraProjector_;
  std::atomic<std::size_t> rejected_residual{0};
  std::atomic<std::size_t> rejected_depth{0};
  std::atomic<std::size_t> num_points{0};

  // The projector ray of a sub-pixel correspondence, interpolated bilinearly between the rays
  // of the four nearest mirror centres (the ray table is smooth; its curvature over one
  // mirror is far below the noise).
  const int last_column = std::max(0, projector_width_ - 2);
  const int last_row = std::max(0, projector_height_ - 2);
  const std::ptrdiff_t down = projector_height_ > 1 ? projector_width_ : 0;
  const std::ptrdiff_t right = projector_width_ > 1 ? 1 : 0;
  const auto interpolated_ray = [&](float u, float v) -> Eigen::Vector4f {
    // Truncation: u in (-0.5, 0) gives u0 = 0 and a < 0, a short extrapolation.
    const int u0 = std::min(last_column, std::max(0, static_cast<int>(u)));
    const int v0 = std::min(last_row, std::max(0, static_cast<int>(v)));
    const float a = u - static_cast<float>(u0);
    const float b = v - static_cast<float>(v0);
    const Eigen::Vector4f* e00 =
        projector_rays_.data() + static_cast<std::size_t>(v0) * projector_width_ + u0;
    const Eigen::Vector4f top = e00[0] + a * (e00[right] - e00[0]);
    const Eigen::Vector4f bottom = e00[down] + a * (e00[down + right] - e00[down]);
    return top + b * (bottom - top);
  };

  const auto run_band = [&](auto subpixel_tag, int band) {
    constexpr bool kSubpixel = decltype(subpixel_tag)::value;
    const int y0 = band * kRowsPerBand;
    const int y1 = std::min(camera_height_, y0 + kRowsPerBand);
    std::size_t local_residual = 0;
    std::size_t local_depth = 0;
    std::size_t local_points = 0;
    for (int y = y0; y < y1; ++y) {
      const std::size_t row_start = static_cast<std::size_t>(y) * camera_width_;
      if (intensity != nullptr) {
        const std::uint8_t* src = intensity->row(y);
        float* dst = cloud.intensities.data() + row_start;
        for (int x = 0; x < camera_width_; ++x) dst[x] = src[x] * (1.0f / 255.0f);
      }
      for (int x = 0; x < camera_width_; ++x) {
        const std::size_t i = row_start + x;
        Eigen::Vector3f& point = cloud.points[i];
        if (!map.valid[i]) {
          point.setConstant(kNaN);
          continue;
        }
        // Closest point on the camera ray t d (d = (x, y, 1)) to the projector ray o + s e.
        const Eigen::Vector2f& ray = rays_[i];
        Eigen::Vector4f e;
        if constexpr (kSubpixel) {
          e = interpolated_ray(map.column_subpixel[i], map.row_subpixel[i]);
        } else {
          e = projector_rays_[static_cast<std::size_t>(map.row[i]) * projector_width_ +
                              map.column[i]];
        }
        const float dd = ray.x() * ray.x() + ray.y() * ray.y() + 1.0f;
        const float de = ray.x() * e.x() + ray.y() * e.y() + e.z();
        const float dw = -(ray.x() * o.x() + ray.y() * o.y() + o.z());  // d . (0 - o)
        const float ew = e.w();                                         // e . (0 - o)
        const float denominator = dd - de * de;
        const float inverse = 1.0f / denominator;
        const float t = (de * ew - dw) * inverse;
        const float s = (dd * ew - de * dw) * inverse;
        // Plain float arithmetic (no Eigen expression calls) keeps this loop inlined.
        const float px = t * ray.x();
        const float py = t * ray.y();
        const float gx = px - (o.x() + s * e.x());
        const float gy = py - (o.y() + s * e.y());
        const float gz = t - (o.z() + s * e.z());
        if (!(denominator > 1e-9f * dd) || !(t >= min_depth && t <= max_depth) || !(s > 0)) {
          ++local_depth;
          point.setConstant(kNaN);
        } else if (gx * gx + gy * gy + gz * gz > residual_factor * s * s) {
          ++local_residual;
          point.setConstant(kNaN);
        } else {
          point = Eigen::Vector3f(px, py, t);
          ++local_points;
        }
      }
    }
    rejected_residual.fetch_add(local_residual, std::memory_order_relaxed);
    rejected_depth.fetch_add(local_depth, std::memory_order_relaxed);
    num_points.fetch_add(local_points, std::memory_order_relaxed);
  };
  if (subpixel) {
    pool_->Run(num_bands, [&](int band) { run_band(std::true_type{}, band); });
  } else {
    pool_->Run(num_bands, [&](int band) { run_band(std::false_type{}, band); });
  }
  result->num_rejected_residual = rejected_residual.load();
  result->num_rejected_depth = rejected_depth.load();
  result->num_removed_isolated = 0;

  if (options_.remove_isolated && options_.min_neighbors > 0) {
    // Decide from the unfiltered cloud, then remove, so the result does not depend on the
    // order in which bands run.
    std::vector<std::vector<std::size_t>> remove(num_bands);
    const float tolerance = static_cast<float>(options_.neighbor_depth_tolerance_m);
    const int min_neighbors = options_.min_neighbors;
    pool_->Run(num_bands, [&](int band) {
      const int y0 = band * kRowsPerBand;
      const int y1 = std::min(camera_height_, y0 + kRowsPerBand);
      const int w = camera_width_;
      const Eigen::Vector3f* points = cloud.points.data();
      for (int y = y0; y < y1; ++y) {
        const bool interior_row = y > 0 && y + 1 < camera_height_;
        for (int x = 0; x < w; ++x) {
          const std::size_t i = static_cast<std::size_t>(y) * w + x;
          const float z = points[i].z();
          if (std::isnan(z)) continue;
          int neighbors = 0;
          if (interior_row && x > 0 && x + 1 < w) {
            // Comparisons with NaN are false, so missing neighbours do not count.
            const Eigen::Vector3f* up = points + i - w;
            const Eigen::Vector3f* down = points + i + w;
            neighbors =
                (std::abs(up[-1].z() - z) <= tolerance) + (std::abs(up[0].z() - z) <= tolerance) +
                (std::abs(up[1].z() - z) <= tolerance) +
                (std::abs(points[i - 1].z() - z) <= tolerance) +
                (std::abs(points[i + 1].z() - z) <= tolerance) +
                (std::abs(down[-1].z() - z) <= tolerance) +
                (std::abs(down[0].z() - z) <= tolerance) + (std::abs(down[1].z() - z) <= tolerance);
          } else {
            for (int dy = -1; dy <= 1; ++dy) {
              const int yy = y + dy;
              if (yy < 0 || yy >= camera_height_) continue;
              for (int dx = -1; dx <= 1; ++dx) {
                const int xx = x + dx;
                if ((dx == 0 && dy == 0) || xx < 0 || xx >= w) continue;
                neighbors +=
                    std::abs(points[static_cast<std::size_t>(yy) * w + xx].z() - z) <= tolerance;
              }
            }
          }
          if (neighbors < min_neighbors) remove[band].push_back(i);
        }
      }
    });
    std::size_t removed = 0;
    for (const std::vector<std::size_t>& band : remove) {
      for (const std::size_t i : band) cloud.points[i].setConstant(kNaN);
      removed += band.size();
    }
    result->num_removed_isolated = removed;
  }
  result->num_points = num_points.load() - result->num_removed_isolated;
}

}  // namespace picking::scanner
