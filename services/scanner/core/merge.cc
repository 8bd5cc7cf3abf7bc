#include "services/scanner/core/merge.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <unordered_map>

namespace picking::scanner {
namespace {

bool IsFinite(const Eigen::Vector3f& p) {
  return std::isfinite(p.x()) && std::isfinite(p.y()) && std::isfinite(p.z());
}

void CheckChannels(const geometry::PointCloud& cloud, const std::string& name) {
  const std::size_t n = cloud.points.size();
  if (!cloud.normals.empty() && cloud.normals.size() != n) {
    throw std::invalid_argument(name + ": normals has " + std::to_string(cloud.normals.size()) +
                                " entries for " + std::to_string(n) + " points");
  }
  if (!cloud.colors.empty() && cloud.colors.size() != n) {
    throw std::invalid_argument(name + ": colors has " + std::to_string(cloud.colors.size()) +
                                " entries for " + std::to_string(n) + " points");
  }
  if (!cloud.intensities.empty() && cloud.intensities.size() != n) {
    throw std::invalid_argument(name + ": intensities has " +
                                std::to_string(cloud.intensities.size()) + " entries for " +
                                std::to_string(n) + " points");
  }
}

// Removes the entries of every channel whose `keep` flag is 0 and makes the cloud unorganised.
void Compact(const std::vector<std::uint8_t>& keep, geometry::PointCloud* cloud) {
  std::size_t out = 0;
  for (std::size_t i = 0; i < cloud->points.size(); ++i) {
    if (!keep[i]) continue;
    cloud->points[out] = cloud->points[i];
    if (cloud->has_normals()) cloud->normals[out] = cloud->normals[i];
    if (cloud->has_colors()) cloud->colors[out] = cloud->colors[i];
    if (cloud->has_intensities()) cloud->intensities[out] = cloud->intensities[i];
    ++out;
  }
  cloud->points.resize(out);
  if (cloud->has_normals()) cloud->normals.resize(out);
  if (cloud->has_colors()) cloud->colors.resize(out);
  if (cloud->has_intensities()) cloud->intensities.resize(out);
  cloud->width = static_cast<std::uint32_t>(out);
  cloud->height = 1;
}

}  // namespace

std::size_t CountFinitePoints(const geometry::PointCloud& cloud) {
  return static_cast<std::size_t>(
      std::count_if(cloud.points.begin(), cloud.points.end(), IsFinite));
}

void TransformCloud(const Eigen::Isometry3d& X_TargetSource, const std::string& target_frame_id,
                    geometry::PointCloud* cloud) {
  const Eigen::Matrix3d R = X_TargetSource.linear();
  if (!X_TargetSource.matrix().allFinite() ||
      !(R.transpose() * R).isApprox(Eigen::Matrix3d::Identity(), 1e-6) || R.determinant() < 0) {
    throw std::invalid_argument("TransformCloud: X_TargetSource is not a finite rigid transform");
  }
  CheckChannels(*cloud, "TransformCloud: cloud");
  const Eigen::Matrix3f Rf = R.cast<float>();
  const Eigen::Vector3f tf = X_TargetSource.translation().cast<float>();
  for (auto& p : cloud->points) p = Rf * p + tf;  // NaN stays NaN.
  for (auto& n : cloud->normals) n = Rf * n;
  cloud->frame_id = target_frame_id;
}

MergeResult MergeClouds(const std::vector<geometry::PointCloud>& clouds,
                        const MergeOptions& options) {
  if (clouds.empty()) throw std::invalid_argument("MergeClouds: no clouds to merge");
  if (!(options.voxel_m >= 0.0) || !std::isfinite(options.voxel_m)) {
    throw std::invalid_argument("MergeClouds: voxel_m must be a finite number >= 0");
  }
  if (options.min_points_per_voxel < 1) {
    throw std::invalid_argument("MergeClouds: min_points_per_voxel must be >= 1");
  }
  bool all_normals = true, all_colors = true, all_intensities = true, all_organised = true;
  for (std::size_t i = 0; i < clouds.size(); ++i) {
    const auto& c = clouds[i];
    CheckChannels(c, "MergeClouds: cloud " + std::to_string(i));
    if (c.frame_id != clouds[0].frame_id) {
      throw std::invalid_argument("MergeClouds: cloud " + std::to_string(i) + " is in frame '" +
                                  c.frame_id + "', cloud 0 in '" + clouds[0].frame_id + "'");
    }
    all_normals = all_normals && c.has_normals();
    all_colors = all_colors && c.has_colors();
    all_intensities = all_intensities && c.has_intensities();
    all_organised = all_organised && c.is_organized() &&
                    static_cast<std::size_t>(c.width) * c.height == c.size() &&
                    c.width == clouds[0].width;
  }

  MergeResult result;
  geometry::PointCloud& out = result.cloud;
  out.frame_id = clouds[0].frame_id;

  if (options.voxel_m == 0.0) {
    std::size_t total = 0;
    for (const auto& c : clouds) total += c.size();
    out.points.reserve(total);
    for (const auto& c : clouds) {
      out.points.insert(out.points.end(), c.points.begin(), c.points.end());
      if (all_normals) out.normals.insert(out.normals.end(), c.normals.begin(), c.normals.end());
      if (all_colors) out.colors.insert(out.colors.end(), c.colors.begin(), c.colors.end());
      if (all_intensities) {
        out.intensities.insert(out.intensities.end(), c.intensities.begin(), c.intensities.end());
      }
    }
    if (all_organised) {
      out.width = clouds[0].width;
      out.height = static_cast<std::uint32_t>(total / std::max<std::uint32_t>(1, out.width));
    } else {
      std::vector<std::uint8_t> keep(out.points.size());
      for (std::size_t i = 0; i < keep.size(); ++i) keep[i] = IsFinite(out.points[i]) ? 1 : 0;
      Compact(keep, &out);
    }
    result.num_points = CountFinitePoints(out);
    return result;
  }

  // Voxel grid: accumulate per voxel in double precision.
  struct Accumulator {
    Eigen::Vector3d p_sum = Eigen::Vector3d::Zero();
    Eigen::Vector3d n_sum = Eigen::Vector3d::Zero();
    double i_sum = 0.0;
    std::array<std::uint8_t, 3> color{};
    int count = 0;
  };
  struct KeyHash {
    std::size_t operator()(const std::array<std::int64_t, 3>& k) const {
      std::uint64_t h = 1469598103934665603ull;
      for (std::int64_t v : k) {
        h ^= static_cast<std::uint64_t>(v) + 0x9e3779b97f4a7c15ull + (h << 6) + (h >> 2);
      }
      return static_cast<std::size_t>(h);
    }
  };
  std::unordered_map<std::array<std::int64_t, 3>, Accumulator, KeyHash> voxels;
  const double inv = 1.0 / options.voxel_m;
  for (const auto& c : clouds) {
    for (std::size_t i = 0; i < c.points.size(); ++i) {
      const Eigen::Vector3f& p = c.points[i];
      if (!IsFinite(p)) continue;
      const std::array<std::int64_t, 3> key{static_cast<std::int64_t>(std::floor(p.x() * inv)),
                                            static_cast<std::int64_t>(std::floor(p.y() * inv)),
                                            static_cast<std::int64_t>(std::floor(p.z() * inv))};
      Accumulator& a = voxels[key];
      a.p_sum += p.cast<double>();
      if (all_normals && IsFinite(c.normals[i])) a.n_sum += c.normals[i].cast<double>();
      if (all_intensities) a.i_sum += c.intensities[i];
      if (all_colors && a.count == 0) a.color = c.colors[i];
      ++a.count;
    }
  }
  std::vector<std::pair<std::array<std::int64_t, 3>, const Accumulator*>> sorted;
  sorted.reserve(voxels.size());
  for (const auto& [key, acc] : voxels) {
    if (acc.count >= options.min_points_per_voxel) sorted.emplace_back(key, &acc);
  }
  std::sort(sorted.begin(), sorted.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (const auto& [key, acc] : sorted) {
    out.points.push_back((acc->p_sum / acc->count).cast<float>());
    if (all_normals) {
      const double norm = acc->n_sum.norm();
      out.normals.push_back(norm > 1e-9 ? Eigen::Vector3f((acc->n_sum / norm).cast<float>())
                                        : Eigen::Vector3f(nan, nan, nan));
    }
    if (all_intensities) out.intensities.push_back(static_cast<float>(acc->i_sum / acc->count));
    if (all_colors) out.colors.push_back(acc->color);
  }
  out.width = static_cast<std::uint32_t>(out.points.size());
  out.height = 1;
  result.num_points = out.points.size();
  return result;
}

std::size_t CropToBox(const Eigen::Vector3d& min_m, const Eigen::Vector3d& max_m,
                      geometry::PointCloud* cloud) {
  for (int a = 0; a < 3; ++a) {
    if (std::isnan(min_m[a]) || std::isnan(max_m[a]) || min_m[a] > max_m[a]) {
      throw std::invalid_argument("CropToBox: min must not exceed max on axis " +
                                  std::string(1, "xyz"[a]) + " and neither may be NaN");
    }
  }
  CheckChannels(*cloud, "CropToBox: cloud");
  const Eigen::Vector3f lo = min_m.cast<float>(), hi = max_m.cast<float>();
  std::vector<std::uint8_t> keep(cloud->points.size());
  std::size_t kept = 0;
  for (std::size_t i = 0; i < cloud->points.size(); ++i) {
    const Eigen::Vector3f& p = cloud->points[i];
    keep[i] = IsFinite(p) && (p.array() >= lo.array()).all() && (p.array() <= hi.array()).all();
    kept += keep[i];
  }
  const bool organised = cloud->is_organized() &&
                         static_cast<std::size_t>(cloud->width) * cloud->height == cloud->size();
  if (organised) {
    const float nan = std::numeric_limits<float>::quiet_NaN();
    for (std::size_t i = 0; i < keep.size(); ++i) {
      if (keep[i]) continue;
      cloud->points[i] = Eigen::Vector3f(nan, nan, nan);
      if (cloud->has_normals()) cloud->normals[i] = Eigen::Vector3f(nan, nan, nan);
    }
  } else {
    Compact(keep, cloud);
  }
  return kept;
}

}  // namespace picking::scanner
