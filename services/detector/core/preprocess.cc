#include "services/detector/core/preprocess.h"

#include <pcl/features/normal_3d_omp.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/search/kdtree.h>
#include <pcl/segmentation/extract_clusters.h>

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <random>
#include <sstream>
#include <stdexcept>
#include <unordered_map>
#include <unordered_set>

#include "libs/geometry/pcl_conversions.h"

namespace picking::detector {
namespace {

using geometry::PointCloud;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

bool Finite(const Eigen::Vector3f& p) { return p.allFinite(); }

// Keeps the points for which keep[i] is true. Organised clouds stay organised when asked
// (dropped points become NaN); otherwise the result is an unorganised cloud.
PointCloud Filter(const PointCloud& cloud, const std::vector<bool>& keep, bool keep_organized) {
  PointCloud out;
  out.frame_id = cloud.frame_id;
  if (cloud.is_organized() && keep_organized) {
    out = cloud;
    for (std::size_t i = 0; i < cloud.size(); ++i) {
      if (keep[i]) continue;
      out.points[i].setConstant(kNaN);
      if (out.has_normals()) out.normals[i].setConstant(kNaN);
    }
    return out;
  }
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!keep[i] || !Finite(cloud.points[i])) continue;
    out.points.push_back(cloud.points[i]);
    if (cloud.has_normals()) out.normals.push_back(cloud.normals[i]);
    if (cloud.has_colors()) out.colors.push_back(cloud.colors[i]);
    if (cloud.has_intensities()) out.intensities.push_back(cloud.intensities[i]);
  }
  out.width = static_cast<std::uint32_t>(out.points.size());
  out.height = 1;
  return out;
}

pcl::PointCloud<pcl::PointXYZ>::Ptr ToPcl(const PointCloud& cloud) {
  return pcl::make_shared<pcl::PointCloud<pcl::PointXYZ>>(geometry::ToPclXyz(cloud));
}

std::vector<int> FiniteIndices(const PointCloud& cloud) {
  std::vector<int> indices;
  indices.reserve(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i)
    if (Finite(cloud.points[i])) indices.push_back(static_cast<int>(i));
  return indices;
}

// Least-squares plane through the points `for_each_point` visits (it calls its argument with
// each point as an Eigen::Vector3d, the same points on both of its calls): the centroid and
// the eigenvector of the smallest scatter, turned to point along `toward`; nullopt for fewer
// than three points.
struct LeastSquaresPlane {
  Eigen::Vector4d coefficients = Eigen::Vector4d::Zero();  // n.p + d = 0, |n| = 1
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  std::size_t count = 0;  // Points fitted.
};
template <typename ForEachPoint>
std::optional<LeastSquaresPlane> FitLeastSquaresPlane(const ForEachPoint& for_each_point,
                                                      const Eigen::Vector3d& toward) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  std::size_t count = 0;
  for_each_point([&](const Eigen::Vector3d& p) {
    mean += p;
    ++count;
  });
  if (count < 3) return std::nullopt;
  mean /= static_cast<double>(count);
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for_each_point([&](const Eigen::Vector3d& p) { cov += (p - mean) * (p - mean).transpose(); });
  Eigen::Vector3d n = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(cov).eigenvectors().col(0);
  if (n.dot(toward) < 0.0) n = -n;
  LeastSquaresPlane out;
  out.coefficients << n, -n.dot(mean);
  out.centroid = mean;
  out.count = count;
  return out;
}

}  // namespace

void OrientedBox::Validate() const {
  if (!size_m.allFinite() || (size_m.array() <= 0.0).any()) {
    std::ostringstream s;
    s << "OrientedBox: size_m must be positive and finite, got " << size_m.transpose();
    throw std::invalid_argument(s.str());
  }
  if (!X_BaseBox.matrix().allFinite())
    throw std::invalid_argument("OrientedBox: X_BaseBox is not finite");
}

bool OrientedBox::Contains(const Eigen::Vector3d& p_BasePoint, double margin_m) const {
  const Eigen::Vector3d p_BoxPoint = X_BaseBox.inverse() * p_BasePoint;
  return ((p_BoxPoint.cwiseAbs() - 0.5 * size_m).array() <= margin_m).all();
}

void ValidateCloud(const PointCloud& cloud, const CloudLimits& limits) {
  if (cloud.empty()) throw std::invalid_argument("point cloud is empty");
  if (cloud.size() > limits.max_points) {
    throw std::invalid_argument("point cloud has " + std::to_string(cloud.size()) +
                                " points, more than the configured maximum of " +
                                std::to_string(limits.max_points));
  }
  const auto check_channel = [&](std::size_t n, const char* name) {
    if (n != 0 && n != cloud.size())
      throw std::invalid_argument(std::string("point cloud channel '") + name + "' has " +
                                  std::to_string(n) + " entries for " +
                                  std::to_string(cloud.size()) + " points");
  };
  check_channel(cloud.normals.size(), "normals");
  check_channel(cloud.colors.size(), "colors");
  check_channel(cloud.intensities.size(), "intensities");
  if (static_cast<std::size_t>(cloud.width) * cloud.height != cloud.size())
    throw std::invalid_argument("point cloud width * height (" + std::to_string(cloud.width) +
                                " * " + std::to_string(cloud.height) + ") != number of points (" +
                                std::to_string(cloud.size()) + ")");
  if (std::none_of(cloud.points.begin(), cloud.points.end(), Finite))
    throw std::invalid_argument(
        "point cloud has no finite point (every point has a NaN or infinite coordinate)");
}

PointCloud CropToBox(const PointCloud& cloud, const OrientedBox& box, const CropOptions& options) {
  ValidateCloud(cloud, options.limits);
  box.Validate();
  // Overlap of the box's axis-aligned bounds with the cloud's finite bounds.
  Eigen::AlignedBox3d cloud_bounds;
  for (const auto& p : cloud.points)
    if (Finite(p)) cloud_bounds.extend(p.cast<double>());
  Eigen::AlignedBox3d box_bounds;
  for (int corner = 0; corner < 8; ++corner) {
    const Eigen::Vector3d p_BoxCorner(((corner & 1) ? 0.5 : -0.5) * box.size_m.x(),
                                      ((corner & 2) ? 0.5 : -0.5) * box.size_m.y(),
                                      ((corner & 4) ? 0.5 : -0.5) * box.size_m.z());
    box_bounds.extend(box.X_BaseBox * p_BoxCorner);
  }
  if (!cloud_bounds.intersects(box_bounds)) {
    std::ostringstream s;
    s << "CropToBox: the region (bounds " << box_bounds.min().transpose() << " .. "
      << box_bounds.max().transpose() << ") lies outside the cloud's bounds ("
      << cloud_bounds.min().transpose() << " .. " << cloud_bounds.max().transpose()
      << "); check the bin/tote pose and that the scan covers it";
    throw std::invalid_argument(s.str());
  }
  const BoxContainment inside(box);
  std::vector<bool> keep(cloud.size(), false);
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!Finite(cloud.points[i])) continue;
    keep[i] = inside(cloud.points[i]);
  }
  return Filter(cloud, keep, options.keep_organized);
}

PointCloud RemoveBoxWalls(const PointCloud& cloud, const OrientedBox& box,
                          const WallRemovalOptions& options) {
  ValidateCloud(cloud, options.limits);
  box.Validate();
  if (!(options.margin_m >= 0.0))
    throw std::invalid_argument("RemoveBoxWalls: margin_m must be >= 0");
  const Eigen::Isometry3f X_BoxBase = box.X_BaseBox.inverse().cast<float>();
  const Eigen::Vector3f half = (0.5 * box.size_m).cast<float>();
  const float margin = static_cast<float>(options.margin_m);
  std::vector<bool> keep(cloud.size(), true);
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!Finite(cloud.points[i])) {
      keep[i] = false;
      continue;
    }
    const Eigen::Vector3f p = X_BoxBase * cloud.points[i];
    for (int axis = 0; axis < 3 && keep[i]; ++axis) {
      // Distance to the face must be within margin, and the point must lie over the face
      // (within its extent on the other two axes, plus margin).
      const int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
      const bool over_face =
          std::abs(p[a1]) <= half[a1] + margin && std::abs(p[a2]) <= half[a2] + margin;
      if (!over_face) continue;
      if ((options.faces & (1u << (2 * axis))) && std::abs(p[axis] + half[axis]) <= margin)
        keep[i] = false;
      if ((options.faces & (1u << (2 * axis + 1))) && std::abs(p[axis] - half[axis]) <= margin)
        keep[i] = false;
    }
  }
  return Filter(cloud, keep, options.keep_organized);
}

PlaneRemovalResult RemoveDominantPlane(const PointCloud& cloud,
                                       const PlaneRemovalOptions& options) {
  ValidateCloud(cloud, options.limits);
  if (!(options.distance_threshold_m > 0.0))
    throw std::invalid_argument("RemoveDominantPlane: distance_threshold_m must be > 0");
  if (options.max_iterations < 1)
    throw std::invalid_argument("RemoveDominantPlane: max_iterations must be >= 1");
  const std::vector<int> finite = FiniteIndices(cloud);
  PlaneRemovalResult result;
  if (finite.size() < 3) {
    result.cloud = cloud;
    return result;
  }
  std::mt19937 rng(options.seed);
  std::uniform_int_distribution<std::size_t> pick(0, finite.size() - 1);
  const double threshold = options.distance_threshold_m;
  // Score hypotheses on a bounded random subset so large clouds stay fast.
  constexpr std::size_t kScoreSamples = 4000;
  std::vector<int> subset;
  if (finite.size() <= kScoreSamples) {
    subset = finite;
  } else {
    subset.reserve(kScoreSamples);
    for (std::size_t i = 0; i < kScoreSamples; ++i) subset.push_back(finite[pick(rng)]);
  }
  Eigen::Vector4d best_plane = Eigen::Vector4d::Zero();
  std::size_t best_count = 0;
  for (int it = 0; it < options.max_iterations; ++it) {
    const Eigen::Vector3d a = cloud.points[finite[pick(rng)]].cast<double>();
    const Eigen::Vector3d b = cloud.points[finite[pick(rng)]].cast<double>();
    const Eigen::Vector3d c = cloud.points[finite[pick(rng)]].cast<double>();
    Eigen::Vector3d n = (b - a).cross(c - a);
    if (n.norm() < 1e-12) continue;
    n.normalize();
    const double d = -n.dot(a);
    std::size_t count = 0;
    for (int i : subset)
      if (std::abs(n.dot(cloud.points[i].cast<double>()) + d) <= threshold) ++count;
    if (count > best_count) {
      best_count = count;
      best_plane << n, d;
    }
  }
  if (best_count == 0) {
    result.cloud = cloud;
    return result;
  }
  // Least-squares refit on all inliers, then the final inlier set.
  const auto inliers_of = [&](const Eigen::Vector4d& plane) {
    std::vector<int> in;
    for (int i : finite)
      if (std::abs(plane.head<3>().dot(cloud.points[i].cast<double>()) + plane[3]) <= threshold)
        in.push_back(i);
    return in;
  };
  std::vector<int> inliers = inliers_of(best_plane);
  const auto refit = FitLeastSquaresPlane(
      [&](const auto& visit) {
        for (int i : inliers) visit(cloud.points[i].cast<double>());
      },
      best_plane.head<3>());
  if (refit) {
    const Eigen::Vector4d refined = refit->coefficients;
    std::vector<int> refined_inliers = inliers_of(refined);
    if (refined_inliers.size() >= inliers.size()) {
      best_plane = refined;
      inliers = std::move(refined_inliers);
    }
  }
  if (static_cast<double>(inliers.size()) <
      options.min_inlier_fraction * static_cast<double>(finite.size())) {
    result.cloud = cloud;
    return result;
  }
  std::vector<bool> keep(cloud.size(), true);
  for (int i : inliers) keep[i] = false;
  result.cloud = Filter(cloud, keep, options.keep_organized);
  result.plane = best_plane;
  result.num_inliers = inliers.size();
  result.removed = true;
  return result;
}

PlaneRemovalResult RemoveBoxFloor(const PointCloud& cloud, const OrientedBox& box,
                                  const FloorRemovalOptions& options) {
  ValidateCloud(cloud, options.limits);
  box.Validate();
  if (!(options.search_height_m > 0.0) || !(options.max_tilt_rad > 0.0) ||
      !(options.distance_threshold_m > 0.0) || !(options.margin_m >= 0.0) ||
      options.max_iterations < 1 || options.max_planes < 1 || !(options.min_step_m > 0.0) ||
      !(options.normal_threshold_rad > 0.0)) {
    throw std::invalid_argument("RemoveBoxFloor: a distance, angle or count is out of range");
  }
  const Eigen::Isometry3d X_BoxBase = box.X_BaseBox.inverse();
  const double bottom_z = -0.5 * box.size_m.z();
  const double cos_tilt = std::cos(options.max_tilt_rad);
  const bool normals = cloud.has_normals();
  // Candidates in the Box frame.
  // Candidates in the Box frame, with their normals (zero without normals).
  struct Candidate {
    Eigen::Vector3d p;
    Eigen::Vector3d n;
  };
  std::vector<Candidate> candidates;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!cloud.points[i].allFinite()) continue;
    const Eigen::Vector3d p = X_BoxBase * cloud.points[i].cast<double>();
    if (p.z() > bottom_z + options.search_height_m) continue;
    Eigen::Vector3d n = Eigen::Vector3d::Zero();
    if (normals) {
      if (!cloud.normals[i].allFinite()) continue;
      n = X_BoxBase.linear() * cloud.normals[i].cast<double>();
      if (n.z() < cos_tilt) continue;
    }
    candidates.push_back({p, n});
  }
  PlaneRemovalResult result;
  result.cloud = cloud;
  if (candidates.size() < std::max<std::size_t>(3, options.min_inliers)) return result;

  // Up to max_planes planes (normal near the box's +z, n.z > 0), each by RANSAC over the
  // candidates the earlier ones left, refitted by least squares on its inliers.
  std::mt19937 rng(options.seed);
  const double threshold = options.distance_threshold_m;
  struct Plane {
    Eigen::Vector4d coefficients = Eigen::Vector4d::Zero();  // n.p + d = 0, Box frame
    Eigen::Vector2d centroid_xy = Eigen::Vector2d::Zero();   // of its inliers, Box frame
    bool floor = true;
    std::unordered_set<std::int64_t> cells;  // footprint: grid cells holding its inliers
  };
  // Footprint cells of kCell metres over the Box xy plane.
  constexpr double kCell = 0.02;
  const auto cell_of = [&](const Eigen::Vector3d& p) {
    const auto x = static_cast<std::int64_t>(std::floor(p.x() / kCell));
    const auto y = static_cast<std::int64_t>(std::floor(p.y() / kCell));
    return (x << 32) ^ (y & 0xFFFFFFFF);
  };
  const auto height = [](const Eigen::Vector4d& plane, const Eigen::Vector2d& xy) {
    return -(plane[0] * xy.x() + plane[1] * xy.y() + plane[3]) / plane[2];
  };
  // Inliers lie within the distance threshold and, with normals, have their normal within
  // normal_threshold_rad of the plane's: a plane grazing two parallel surfaces (an item's top
  // and the floor beyond it) at a slant collects no inliers from either.
  const double cos_normal = std::cos(options.normal_threshold_rad);
  const auto inlier = [&](const Eigen::Vector4d& plane, const Candidate& c) {
    return std::abs(plane.head<3>().dot(c.p) + plane[3]) <= threshold &&
           (!normals || plane.head<3>().dot(c.n) >= cos_normal);
  };
  const auto fit = [&](const std::vector<Candidate>& points, Plane* plane) {
    std::uniform_int_distribution<std::size_t> pick(0, points.size() - 1);
    constexpr std::size_t kScoreSamples = 3000;
    std::vector<std::size_t> subset;
    for (std::size_t i = 0; i < std::min(kScoreSamples, points.size()); ++i) {
      subset.push_back(points.size() <= kScoreSamples ? i : pick(rng));
    }
    Eigen::Vector4d best = Eigen::Vector4d::Zero();
    std::size_t best_count = 0;
    for (int it = 0; it < options.max_iterations; ++it) {
      const Eigen::Vector3d& a = points[pick(rng)].p;
      Eigen::Vector3d n = (points[pick(rng)].p - a).cross(points[pick(rng)].p - a);
      if (n.norm() < 1e-12) continue;
      n.normalize();
      if (n.z() < 0.0) n = -n;
      if (n.z() < cos_tilt) continue;
      Eigen::Vector4d hypothesis;
      hypothesis << n, -n.dot(a);
      std::size_t count = 0;
      for (std::size_t i : subset) count += inlier(hypothesis, points[i]) ? 1 : 0;
      if (count > best_count) {
        best_count = count;
        best = hypothesis;
      }
    }
    if (best_count == 0) return std::size_t{0};
    // Least-squares refits on the inliers (twice: the refitted plane gathers its inliers
    // anew).
    std::size_t num = 0;
    for (int refit = 0; refit < 2; ++refit) {
      const auto fitted = FitLeastSquaresPlane(
          [&](const auto& visit) {
            for (const auto& c : points) {
              if (inlier(best, c)) visit(c.p);
            }
          },
          Eigen::Vector3d::UnitZ());
      if (!fitted) return std::size_t{0};
      num = fitted->count;
      if (fitted->coefficients.z() < cos_tilt) break;
      best = fitted->coefficients;
      plane->centroid_xy = fitted->centroid.head<2>();
    }
    plane->coefficients = best;
    return num;
  };
  std::vector<Plane> planes;
  while (static_cast<int>(planes.size()) < options.max_planes &&
         candidates.size() >= options.min_inliers) {
    Plane plane;
    if (fit(candidates, &plane) < options.min_inliers) break;
    std::vector<Candidate> rest;
    for (const auto& c : candidates) {
      if (!inlier(plane.coefficients, c)) {
        rest.push_back(c);
      } else {
        plane.cells.insert(cell_of(c.p));
      }
    }
    candidates = std::move(rest);
    planes.push_back(std::move(plane));
  }
  // The floor is the lowest surface: a plane that lies more than min_step_m above another
  // one where its own inliers are, and does not pass below it where the other's inliers are,
  // is the top of an item standing on that one. (Where it would pass below the other one the
  // two are parts of a bent board. The item's top need not lie high above the other plane at
  // the other's inliers: a level item on a tilted board crosses the board's plane there.) A
  // plane passing higher than max_centre_height_m at the box's centre is an item's top face
  // over a hidden floor.
  for (Plane& plane : planes) {
    if (height(plane.coefficients, Eigen::Vector2d::Zero()) - bottom_z >
        options.max_centre_height_m) {
      plane.floor = false;
    }
    for (const Plane& other : planes) {
      if (&other == &plane) continue;
      const auto rise = [&](const Eigen::Vector2d& xy) {
        return height(plane.coefficients, xy) - height(other.coefficients, xy);
      };
      if (rise(plane.centroid_xy) > options.min_step_m &&
          rise(other.centroid_xy) > -options.min_step_m) {
        plane.floor = false;
      }
    }
  }
  std::vector<const Plane*> floors;
  for (const Plane& plane : planes) {
    if (plane.floor) floors.push_back(&plane);
  }
  if (floors.empty()) return result;
  // A point is floor when it lies below the lowest floor plane at its place or less than
  // margin_m above it, or likewise for a floor plane whose footprint holds the point (a
  // higher part of the board, e.g. a lip).
  std::vector<bool> keep(cloud.size(), true);
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!cloud.points[i].allFinite()) continue;
    const Eigen::Vector3d p = X_BoxBase * cloud.points[i].cast<double>();
    const std::int64_t cell = cell_of(p);
    double lowest = std::numeric_limits<double>::infinity();
    bool floor = false;
    for (const Plane* plane : floors) {
      const double h = p.z() - height(plane->coefficients, p.head<2>());
      lowest = std::min(lowest, h);
      if (h * plane->coefficients[2] < options.margin_m && plane->cells.count(cell) > 0) {
        floor = true;
      }
    }
    if (floor || lowest * floors.front()->coefficients[2] < options.margin_m) {
      keep[i] = false;
      ++result.num_inliers;
    }
  }
  result.cloud = Filter(cloud, keep, options.keep_organized);
  // The floor plane with the most support (the first found), in the cloud's frame.
  const Eigen::Vector4d& best = floors.front()->coefficients;
  const Eigen::Vector3d n_Base = box.X_BaseBox.linear() * best.head<3>();
  const Eigen::Vector3d p_Base = box.X_BaseBox * (-best[3] * best.head<3>());
  result.plane << n_Base, -n_Base.dot(p_Base);
  result.removed = true;
  return result;
}

PointCloud VoxelDownsample(const PointCloud& cloud, double leaf_size_m, const CloudLimits& limits) {
  ValidateCloud(cloud, limits);
  if (!(leaf_size_m > 0.0) || !std::isfinite(leaf_size_m))
    throw std::invalid_argument("VoxelDownsample: leaf_size_m must be positive");
  struct Accumulator {
    Eigen::Vector3d p = Eigen::Vector3d::Zero();
    Eigen::Vector3d n = Eigen::Vector3d::Zero();
    Eigen::Vector3d rgb = Eigen::Vector3d::Zero();
    double intensity = 0.0;
    int count = 0;
    int normal_count = 0;
    int intensity_count = 0;
    std::size_t first = 0;
  };
  const auto key_of = [&](const Eigen::Vector3f& p) {
    const Eigen::Vector3d q = (p.cast<double>() / leaf_size_m).array().floor();
    // 21 bits per axis around the origin.
    const auto part = [](double v) {
      return static_cast<std::uint64_t>(static_cast<std::int64_t>(v) + (1 << 20)) & 0x1FFFFF;
    };
    return part(q.x()) | (part(q.y()) << 21) | (part(q.z()) << 42);
  };
  std::unordered_map<std::uint64_t, Accumulator> voxels;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const auto& p = cloud.points[i];
    if (!Finite(p)) continue;
    auto [it, inserted] = voxels.try_emplace(key_of(p));
    Accumulator& a = it->second;
    if (inserted) a.first = i;
    a.p += p.cast<double>();
    ++a.count;
    if (cloud.has_normals() && cloud.normals[i].allFinite()) {
      a.n += cloud.normals[i].cast<double>();
      ++a.normal_count;
    }
    if (cloud.has_colors())
      a.rgb += Eigen::Vector3d(cloud.colors[i][0], cloud.colors[i][1], cloud.colors[i][2]);
    if (cloud.has_intensities() && std::isfinite(cloud.intensities[i])) {
      a.intensity += cloud.intensities[i];
      ++a.intensity_count;
    }
  }
  // Output in order of first occurrence so the result is deterministic.
  std::vector<const Accumulator*> ordered;
  ordered.reserve(voxels.size());
  for (const auto& [key, a] : voxels) ordered.push_back(&a);
  std::sort(ordered.begin(), ordered.end(),
            [](const Accumulator* l, const Accumulator* r) { return l->first < r->first; });
  PointCloud out;
  out.frame_id = cloud.frame_id;
  for (const Accumulator* a : ordered) {
    out.points.push_back((a->p / a->count).cast<float>());
    if (cloud.has_normals()) {
      Eigen::Vector3f n = Eigen::Vector3f::Constant(kNaN);
      if (a->normal_count > 0 && a->n.norm() > 1e-9) n = a->n.normalized().cast<float>();
      out.normals.push_back(n);
    }
    if (cloud.has_colors()) {
      const Eigen::Vector3d c = (a->rgb / a->count).array().round();
      out.colors.push_back({static_cast<std::uint8_t>(c[0]), static_cast<std::uint8_t>(c[1]),
                            static_cast<std::uint8_t>(c[2])});
    }
    if (cloud.has_intensities()) {
      // NaN intensities (not measurable there) are left out; none measured stays NaN.
      out.intensities.push_back(
          a->intensity_count > 0 ? static_cast<float>(a->intensity / a->intensity_count) : kNaN);
    }
  }
  out.width = static_cast<std::uint32_t>(out.points.size());
  out.height = 1;
  return out;
}

PointCloud EstimateNormals(const PointCloud& cloud, const NormalOptions& options) {
  ValidateCloud(cloud, options.limits);
  if (options.k_neighbors < 3)
    throw std::invalid_argument("EstimateNormals: k_neighbors must be >= 3");
  const std::vector<int> finite = FiniteIndices(cloud);
  auto pcl_cloud = ToPcl(cloud);
  auto indices = pcl::make_shared<std::vector<int>>(finite);
  pcl::NormalEstimationOMP<pcl::PointXYZ, pcl::Normal> estimator(2);
  estimator.setInputCloud(pcl_cloud);
  estimator.setIndices(indices);
  estimator.setSearchMethod(pcl::make_shared<pcl::search::KdTree<pcl::PointXYZ>>());
  estimator.setKSearch(options.k_neighbors);
  pcl::PointCloud<pcl::Normal> normals;
  estimator.compute(normals);

  PointCloud out = cloud;
  out.normals.assign(cloud.size(), Eigen::Vector3f::Constant(kNaN));
  Eigen::Vector3f centroid = Eigen::Vector3f::Zero();
  for (int i : finite) centroid += cloud.points[i];
  centroid /= static_cast<float>(finite.size());
  const Eigen::Vector3f viewpoint = options.p_BaseViewpoint.cast<float>();
  for (std::size_t k = 0; k < finite.size(); ++k) {
    const auto& n = normals.points[k];
    Eigen::Vector3f normal(n.normal_x, n.normal_y, n.normal_z);
    if (!normal.allFinite() || normal.norm() < 1e-6f) continue;
    normal.normalize();
    const Eigen::Vector3f& p = cloud.points[finite[k]];
    const bool flip = options.orient_outward_from_centroid ? normal.dot(p - centroid) < 0.0f
                                                           : normal.dot(viewpoint - p) < 0.0f;
    out.normals[finite[k]] = flip ? -normal : normal;
  }
  return out;
}

std::vector<std::vector<int>> EuclideanClusters(const PointCloud& cloud,
                                                const ClusterOptions& options,
                                                std::vector<std::vector<int>>* representatives) {
  ValidateCloud(cloud, options.limits);
  if (!(options.tolerance_m > 0.0))
    throw std::invalid_argument("EuclideanClusters: tolerance_m must be > 0");
  if (options.min_size > options.max_size)
    throw std::invalid_argument("EuclideanClusters: min_size > max_size");
  if (!(options.subsample_voxel_m >= 0.0 && options.subsample_voxel_m < options.tolerance_m))
    throw std::invalid_argument(
        "EuclideanClusters: subsample_voxel_m must be in [0, tolerance_m), got " +
        std::to_string(options.subsample_voxel_m));
  auto pcl_cloud = ToPcl(cloud);
  auto indices = pcl::make_shared<std::vector<int>>(FiniteIndices(cloud));
  // Voxel of each finite point and one representative per voxel.
  std::vector<int> voxel_of;  // per finite point (position in *indices), index into reps
  std::vector<int> reps;
  if (options.subsample_voxel_m > 0.0) {
    const double inv = 1.0 / options.subsample_voxel_m;
    std::unordered_map<std::uint64_t, int> voxels;
    voxels.reserve(indices->size() / 4 + 1);
    voxel_of.reserve(indices->size());
    for (int i : *indices) {
      const Eigen::Vector3f& p = cloud.points[i];
      const auto key = [&](float v) {
        return static_cast<std::uint64_t>(static_cast<std::int64_t>(std::floor(v * inv)) &
                                          0x1FFFFF);
      };
      const std::uint64_t k = key(p.x()) | key(p.y()) << 21 | key(p.z()) << 42;
      const auto [it, inserted] = voxels.emplace(k, static_cast<int>(reps.size()));
      if (inserted) reps.push_back(i);
      voxel_of.push_back(it->second);
    }
  }
  const std::vector<int> all_finite = *indices;
  if (options.subsample_voxel_m > 0.0) *indices = reps;
  auto tree = pcl::make_shared<pcl::search::KdTree<pcl::PointXYZ>>();
  tree->setInputCloud(pcl_cloud, indices);
  pcl::EuclideanClusterExtraction<pcl::PointXYZ> extraction;
  extraction.setClusterTolerance(options.tolerance_m);
  const bool subsampled = options.subsample_voxel_m > 0.0;
  extraction.setMinClusterSize(
      subsampled
          ? 1
          : static_cast<int>(std::min<std::size_t>(
                options.min_size, static_cast<std::size_t>(std::numeric_limits<int>::max()))));
  extraction.setMaxClusterSize(static_cast<int>(
      std::min<std::size_t>(subsampled ? std::numeric_limits<int>::max() : options.max_size,
                            static_cast<std::size_t>(std::numeric_limits<int>::max()))));
  extraction.setSearchMethod(tree);
  extraction.setInputCloud(pcl_cloud);
  extraction.setIndices(indices);
  std::vector<pcl::PointIndices> clusters;
  extraction.extract(clusters);
  // Members and representatives of each cluster, then the clusters within the size limits,
  // largest first.
  std::vector<std::vector<int>> members(clusters.size());
  std::vector<std::vector<int>> reps_of(clusters.size());
  if (subsampled) {
    // Representative (point index) -> cluster, then every point joins its voxel's cluster.
    std::unordered_map<int, int> cluster_of_rep;
    for (std::size_t c = 0; c < clusters.size(); ++c) {
      for (int i : clusters[c].indices) cluster_of_rep[i] = static_cast<int>(c);
      if (representatives != nullptr) {
        reps_of[c].assign(clusters[c].indices.begin(), clusters[c].indices.end());
        std::sort(reps_of[c].begin(), reps_of[c].end());
      }
    }
    for (std::size_t k = 0; k < all_finite.size(); ++k) {
      const auto it = cluster_of_rep.find(reps[voxel_of[k]]);
      if (it != cluster_of_rep.end()) members[it->second].push_back(all_finite[k]);
    }
  } else {
    for (std::size_t c = 0; c < clusters.size(); ++c) {
      members[c].assign(clusters[c].indices.begin(), clusters[c].indices.end());
      std::sort(members[c].begin(), members[c].end());
      if (representatives != nullptr) reps_of[c] = members[c];
    }
  }
  std::vector<std::size_t> kept;
  for (std::size_t c = 0; c < members.size(); ++c) {
    if (members[c].size() >= options.min_size && members[c].size() <= options.max_size) {
      kept.push_back(c);
    }
  }
  std::stable_sort(kept.begin(), kept.end(), [&members](std::size_t a, std::size_t b) {
    return members[a].size() > members[b].size();
  });
  std::vector<std::vector<int>> out;
  out.reserve(kept.size());
  if (representatives != nullptr) representatives->clear();
  for (std::size_t c : kept) {
    out.push_back(std::move(members[c]));
    if (representatives != nullptr) representatives->push_back(std::move(reps_of[c]));
  }
  return out;
}

PointCloud SelectPoints(const PointCloud& cloud, const std::vector<int>& indices) {
  PointCloud out;
  out.frame_id = cloud.frame_id;
  for (int i : indices) {
    if (i < 0 || static_cast<std::size_t>(i) >= cloud.size())
      throw std::out_of_range("SelectPoints: index " + std::to_string(i) + " out of range");
    out.points.push_back(cloud.points[i]);
    if (cloud.has_normals()) out.normals.push_back(cloud.normals[i]);
    if (cloud.has_colors()) out.colors.push_back(cloud.colors[i]);
    if (cloud.has_intensities()) out.intensities.push_back(cloud.intensities[i]);
  }
  out.width = static_cast<std::uint32_t>(out.points.size());
  out.height = 1;
  return out;
}

}  // namespace picking::detector
