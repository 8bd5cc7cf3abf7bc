#include "services/detector/core/ppf_cloud.h"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>

#include "services/detector/core/kdtree.h"

namespace picking::detector {
namespace {

bool PointValid(const geometry::PointCloud& cloud, std::size_t i) {
  if (!cloud.points[i].allFinite()) return false;
  return !cloud.has_normals() || cloud.normals[i].allFinite();
}

void PushPoint(const geometry::PointCloud& in, std::size_t i, geometry::PointCloud* out) {
  out->points.push_back(in.points[i]);
  if (in.has_normals()) out->normals.push_back(in.normals[i]);
  if (in.has_colors()) out->colors.push_back(in.colors[i]);
  if (in.has_intensities()) out->intensities.push_back(in.intensities[i]);
}

void FinishUnorganized(geometry::PointCloud* cloud) {
  cloud->width = static_cast<std::uint32_t>(cloud->points.size());
  cloud->height = 1;
}

}  // namespace

void CheckCloudChannels(const geometry::PointCloud& cloud, const char* what) {
  const std::size_t n = cloud.points.size();
  auto check = [&](std::size_t size, const char* channel) {
    if (size != 0 && size != n) {
      throw std::invalid_argument(std::string(what) + ": " + channel + " has " +
                                  std::to_string(size) + " entries for " + std::to_string(n) +
                                  " points");
    }
  };
  check(cloud.normals.size(), "normals");
  check(cloud.colors.size(), "colors");
  check(cloud.intensities.size(), "intensities");
}

geometry::PointCloud RemoveInvalidPoints(const geometry::PointCloud& cloud) {
  CheckCloudChannels(cloud, "RemoveInvalidPoints");
  geometry::PointCloud out;
  out.frame_id = cloud.frame_id;
  out.points.reserve(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (PointValid(cloud, i)) PushPoint(cloud, i, &out);
  }
  FinishUnorganized(&out);
  return out;
}

geometry::PointCloud EveryNthPoint(const geometry::PointCloud& cloud, std::size_t stride) {
  if (stride == 0) throw std::invalid_argument("EveryNthPoint: stride must be >= 1");
  geometry::PointCloud out;
  for (std::size_t i = 0; i < cloud.size(); i += stride) {
    out.points.push_back(cloud.points[i]);
    if (cloud.has_normals()) out.normals.push_back(cloud.normals[i]);
  }
  FinishUnorganized(&out);
  return out;
}

geometry::PointCloud VoxelAverage(const geometry::PointCloud& cloud, float voxel_m) {
  CheckCloudChannels(cloud, "VoxelAverage");
  if (!(voxel_m > 0.0f) || !std::isfinite(voxel_m)) {
    throw std::invalid_argument("VoxelAverage: voxel_m must be positive, got " +
                                std::to_string(voxel_m));
  }
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::max());
  Eigen::Vector3f hi = -lo;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!PointValid(cloud, i)) continue;
    lo = lo.cwiseMin(cloud.points[i]);
    hi = hi.cwiseMax(cloud.points[i]);
  }
  geometry::PointCloud out;
  out.frame_id = cloud.frame_id;
  if (lo.x() > hi.x()) {
    FinishUnorganized(&out);
    return out;
  }
  const Eigen::Vector3f extent = (hi - lo) / voxel_m;
  constexpr float kMaxCells = static_cast<float>(1 << 20);
  if (extent.maxCoeff() >= kMaxCells) {
    throw std::invalid_argument("VoxelAverage: cloud extent " +
                                std::to_string((hi - lo).maxCoeff()) + " m spans too many " +
                                std::to_string(voxel_m) + " m voxels");
  }
  std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed;
  keyed.reserve(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!PointValid(cloud, i)) continue;
    const Eigen::Vector3f c = (cloud.points[i] - lo) / voxel_m;
    const auto ix = static_cast<std::uint64_t>(c.x());
    const auto iy = static_cast<std::uint64_t>(c.y());
    const auto iz = static_cast<std::uint64_t>(c.z());
    keyed.emplace_back((ix << 42) | (iy << 21) | iz, static_cast<std::uint32_t>(i));
  }
  std::sort(keyed.begin(), keyed.end());
  for (std::size_t b = 0; b < keyed.size();) {
    std::size_t e = b;
    Eigen::Vector3d p_sum = Eigen::Vector3d::Zero();
    Eigen::Vector3d n_sum = Eigen::Vector3d::Zero();
    Eigen::Vector3d c_sum = Eigen::Vector3d::Zero();
    double i_sum = 0.0;
    int i_count = 0;
    while (e < keyed.size() && keyed[e].first == keyed[b].first) {
      const std::uint32_t i = keyed[e].second;
      p_sum += cloud.points[i].cast<double>();
      if (cloud.has_normals()) n_sum += cloud.normals[i].cast<double>();
      if (cloud.has_colors()) {
        c_sum += Eigen::Vector3d(cloud.colors[i][0], cloud.colors[i][1], cloud.colors[i][2]);
      }
      if (cloud.has_intensities() && std::isfinite(cloud.intensities[i])) {
        i_sum += cloud.intensities[i];
        ++i_count;
      }
      ++e;
    }
    const double count = static_cast<double>(e - b);
    if (cloud.has_normals()) {
      // Normals that cancel out (a thin wall seen from both sides) give no usable normal.
      if (n_sum.norm() < 1e-6 * count) {
        b = e;
        continue;
      }
      out.normals.push_back(n_sum.normalized().cast<float>());
    }
    out.points.push_back((p_sum / count).cast<float>());
    if (cloud.has_colors()) {
      const Eigen::Vector3d c = c_sum / count;
      out.colors.push_back({static_cast<std::uint8_t>(std::lround(c.x())),
                            static_cast<std::uint8_t>(std::lround(c.y())),
                            static_cast<std::uint8_t>(std::lround(c.z()))});
    }
    if (cloud.has_intensities()) {
      // NaN intensities (not measurable there) are left out; none measured stays NaN.
      out.intensities.push_back(i_count > 0 ? static_cast<float>(i_sum / i_count)
                                            : std::numeric_limits<float>::quiet_NaN());
    }
    b = e;
  }
  FinishUnorganized(&out);
  return out;
}

geometry::PointCloud EstimatePcaNormals(const geometry::PointCloud& cloud,
                                        const PcaNormalOptions& options) {
  if (!(options.radius_m > 0.0f) || !std::isfinite(options.radius_m)) {
    throw std::invalid_argument("EstimatePcaNormals: radius_m must be positive, got " +
                                std::to_string(options.radius_m));
  }
  geometry::PointCloud valid = RemoveInvalidPoints(cloud);
  valid.normals.clear();
  const KdTree tree(valid.points);
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& p : valid.points) centroid += p.cast<double>();
  if (!valid.empty()) centroid /= static_cast<double>(valid.size());

  geometry::PointCloud out;
  out.frame_id = cloud.frame_id;
  out.points.reserve(valid.size());
  out.normals.reserve(valid.size());
  std::vector<std::int32_t> neighbors;
  for (std::size_t i = 0; i < valid.size(); ++i) {
    const Eigen::Vector3f& p = valid.points[i];
    tree.RadiusSearch(p, options.radius_m, &neighbors);
    if (static_cast<int>(neighbors.size()) < std::max(3, options.min_neighbors)) continue;
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (std::int32_t j : neighbors) mean += valid.points[j].cast<double>();
    mean /= static_cast<double>(neighbors.size());
    Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
    for (std::int32_t j : neighbors) {
      const Eigen::Vector3d d = valid.points[j].cast<double>() - mean;
      cov.noalias() += d * d.transpose();
    }
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver;
    solver.computeDirect(cov);
    Eigen::Vector3d n = solver.eigenvectors().col(0);
    if (!n.allFinite() || n.norm() < 0.5) continue;
    n.normalize();
    const Eigen::Vector3d reference =
        options.orientation == NormalOrientation::kTowardViewpoint
            ? Eigen::Vector3d(options.viewpoint.cast<double>() - p.cast<double>())
            : Eigen::Vector3d(p.cast<double>() - centroid);
    if (n.dot(reference) < 0.0) n = -n;
    PushPoint(valid, i, &out);
    out.normals.push_back(n.cast<float>());
  }
  FinishUnorganized(&out);
  return out;
}

float CloudDiameter(const std::vector<Eigen::Vector3f>& points) {
  float best = 0.0f;
  for (std::size_t i = 0; i < points.size(); ++i) {
    for (std::size_t j = i + 1; j < points.size(); ++j) {
      best = std::max(best, (points[i] - points[j]).squaredNorm());
    }
  }
  return std::sqrt(best);
}

std::vector<SphereFit> FindSpheres(const geometry::PointCloud& cloud, double radius_m,
                                   const SphereSearchOptions& options) {
  if (!(radius_m > 0.0) || !std::isfinite(radius_m)) {
    throw std::invalid_argument("FindSpheres: radius_m must be positive and finite");
  }
  if (!(options.distance_threshold_m > 0.0) || !(options.normal_threshold_rad > 0.0) ||
      options.max_iterations < 1 || options.max_spheres < 1 || options.min_inliers < 1) {
    throw std::invalid_argument("FindSpheres: a threshold or count is out of range");
  }
  CheckCloudChannels(cloud, "FindSpheres cloud");
  if (!cloud.has_normals()) throw std::invalid_argument("FindSpheres: the cloud has no normals");
  std::vector<std::size_t> points;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (cloud.points[i].allFinite() && cloud.normals[i].allFinite() &&
        cloud.normals[i].squaredNorm() > 0.25f) {
      points.push_back(i);
    }
  }
  const double cos_normal = std::cos(options.normal_threshold_rad);
  const auto supports = [&](const Eigen::Vector3d& c, std::size_t i) {
    const Eigen::Vector3d d = cloud.points[i].cast<double>() - c;
    const double r = d.norm();
    if (std::abs(r - radius_m) > options.distance_threshold_m || r <= 0.0) return false;
    return cloud.normals[i].cast<double>().normalized().dot(d / r) >= cos_normal;
  };
  std::mt19937 rng(options.seed);
  std::vector<SphereFit> out;
  while (static_cast<int>(out.size()) < options.max_spheres &&
         points.size() >= options.min_inliers) {
    std::uniform_int_distribution<std::size_t> pick(0, points.size() - 1);
    constexpr std::size_t kScoreSamples = 4000;
    std::vector<std::size_t> subset;
    if (points.size() <= kScoreSamples) {
      subset = points;
    } else {
      for (std::size_t k = 0; k < kScoreSamples; ++k) subset.push_back(points[pick(rng)]);
    }
    Eigen::Vector3d best = Eigen::Vector3d::Zero();
    std::size_t best_count = 0;
    for (int it = 0; it < options.max_iterations; ++it) {
      const std::size_t i = points[pick(rng)];
      const Eigen::Vector3d c =
          cloud.points[i].cast<double>() - radius_m * cloud.normals[i].cast<double>().normalized();
      std::size_t count = 0;
      for (std::size_t j : subset) count += supports(c, j) ? 1 : 0;
      if (count > best_count) {
        best_count = count;
        best = c;
      }
    }
    if (best_count == 0) break;
    // Centre refit with the radius fixed: each inlier votes for the centre at radius_m
    // behind it along its direction from the current centre.
    std::size_t inliers = 0;
    for (int refit = 0; refit < 5; ++refit) {
      Eigen::Vector3d sum = Eigen::Vector3d::Zero();
      inliers = 0;
      for (std::size_t j : points) {
        if (!supports(best, j)) continue;
        const Eigen::Vector3d p = cloud.points[j].cast<double>();
        sum += p - radius_m * (p - best).normalized();
        ++inliers;
      }
      if (inliers == 0) break;
      best = sum / static_cast<double>(inliers);
    }
    if (inliers < options.min_inliers) break;
    out.push_back({best, inliers});
    std::vector<std::size_t> rest;
    for (std::size_t j : points) {
      if (!supports(best, j)) rest.push_back(j);
    }
    points = std::move(rest);
  }
  return out;
}

}  // namespace picking::detector
