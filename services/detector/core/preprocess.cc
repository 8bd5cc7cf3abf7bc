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

// ---- RemoveBoxFloor stages ----------------------------------------------------------------

// Throws unless every distance, angle and count of `options` is in range (one message for all).
void ValidateFloorRemovalOptions(const FloorRemovalOptions& options) {
  if (!(options.search_height_m > 0.0) || !(options.max_tilt_rad > 0.0) ||
      !(options.distance_threshold_m > 0.0) || !(options.margin_m >= 0.0) ||
      options.max_iterations < 1 || options.max_planes < 1 || !(options.min_step_m > 0.0) ||
      !(options.normal_threshold_rad > 0.0)) {
    throw std::invalid_argument("RemoveBoxFloor: a distance, angle or count is out of range");
  }
}

// A floor candidate: a point near the box's bottom face with its normal (zero when the cloud
// has no normals), both in the Box frame.
struct FloorCandidate {
  Eigen::Vector3d p_BoxPoint;
  Eigen::Vector3d n_BoxPoint;
};

// The finite points at most search_height_m above the box's bottom face (z = bottom_z_Box in
// the Box frame), in the Box frame; with normals, only those with a finite normal within
// max_tilt_rad of the box's +z (cos_tilt = cos(max_tilt_rad)). In cloud order.
std::vector<FloorCandidate> CollectFloorCandidates(const PointCloud& cloud,
                                                   const Eigen::Isometry3d& X_BoxBase,
                                                   double bottom_z_Box, double search_height_m,
                                                   double cos_tilt) {
  const bool normals = cloud.has_normals();
  std::vector<FloorCandidate> candidates;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!cloud.points[i].allFinite()) continue;
    const Eigen::Vector3d p_BoxPoint = X_BoxBase * cloud.points[i].cast<double>();
    if (p_BoxPoint.z() > bottom_z_Box + search_height_m) continue;
    Eigen::Vector3d n_BoxPoint = Eigen::Vector3d::Zero();
    if (normals) {
      if (!cloud.normals[i].allFinite()) continue;
      n_BoxPoint = X_BoxBase.linear() * cloud.normals[i].cast<double>();
      if (n_BoxPoint.z() < cos_tilt) continue;
    }
    candidates.push_back({p_BoxPoint, n_BoxPoint});
  }
  return candidates;
}

// Whether a candidate supports a plane (n.p + d = 0, Box frame): it lies within threshold_m of
// it and, with normals, has its normal within normal_threshold_rad of the plane's, so that a
// plane grazing two parallel surfaces (an item's top and the floor beyond it) at a slant
// collects no inliers from either.
struct FloorInlierTest {
  double threshold_m = 0.0;
  double cos_normal = 1.0;  // cos(normal_threshold_rad)
  bool normals = false;     // The cloud has normals (else they are not compared).

  bool operator()(const Eigen::Vector4d& plane_Box, const FloorCandidate& c) const {
    return std::abs(plane_Box.head<3>().dot(c.p_BoxPoint) + plane_Box[3]) <= threshold_m &&
           (!normals || plane_Box.head<3>().dot(c.n_BoxPoint) >= cos_normal);
  }
};

// How one floor plane is fitted to the candidates.
struct FloorPlaneFitOptions {
  FloorInlierTest inlier;
  double cos_tilt = 1.0;   // cos(max_tilt_rad): the plane's normal is this close to +z.
  int max_iterations = 1;  // RANSAC hypotheses.
};

// A fitted floor plane, Box frame; num_inliers == 0 when no plane was found.
struct FloorPlaneFit {
  Eigen::Vector4d plane_Box = Eigen::Vector4d::Zero();        // n.p + d = 0, n.z > 0
  Eigen::Vector2d centroid_xy_Box = Eigen::Vector2d::Zero();  // Of its inliers.
  std::size_t num_inliers = 0;
};

// The best-supported RANSAC hypothesis (normal turned up and within max tilt of +z) among
// `points` and its support; the support is counted on a bounded random subset so large
// candidate sets stay fast. A count of 0: no hypothesis had support.
struct FloorRansacResult {
  Eigen::Vector4d plane_Box = Eigen::Vector4d::Zero();
  std::size_t count = 0;
};
FloorRansacResult RansacFloorPlane(const std::vector<FloorCandidate>& points,
                                   const FloorPlaneFitOptions& options, std::mt19937& rng) {
  std::uniform_int_distribution<std::size_t> pick(0, points.size() - 1);
  constexpr std::size_t kScoreSamples = 3000;
  std::vector<std::size_t> subset;
  for (std::size_t i = 0; i < std::min(kScoreSamples, points.size()); ++i) {
    subset.push_back(points.size() <= kScoreSamples ? i : pick(rng));
  }
  FloorRansacResult best;
  for (int it = 0; it < options.max_iterations; ++it) {
    const Eigen::Vector3d& a = points[pick(rng)].p_BoxPoint;
    Eigen::Vector3d n = (points[pick(rng)].p_BoxPoint - a).cross(points[pick(rng)].p_BoxPoint - a);
    if (n.norm() < 1e-12) continue;
    n.normalize();
    if (n.z() < 0.0) n = -n;
    if (n.z() < options.cos_tilt) continue;
    Eigen::Vector4d hypothesis;
    hypothesis << n, -n.dot(a);
    std::size_t count = 0;
    for (std::size_t i : subset) count += options.inlier(hypothesis, points[i]) ? 1 : 0;
    if (count > best.count) {
      best.count = count;
      best.plane_Box = hypothesis;
    }
  }
  return best;
}

// Least-squares refits of `plane_Box` on its inliers among `points`, twice (the refitted plane
// gathers its inliers anew); a refit tilted beyond max tilt ends the refits and the previous
// plane is kept. Fewer than three inliers: num_inliers 0 (and no plane).
FloorPlaneFit RefitFloorPlane(const std::vector<FloorCandidate>& points, Eigen::Vector4d plane_Box,
                              const FloorPlaneFitOptions& options) {
  FloorPlaneFit out;
  std::size_t num = 0;
  for (int refit = 0; refit < 2; ++refit) {
    const auto fitted = FitLeastSquaresPlane(
        [&](const auto& visit) {
          for (const auto& c : points) {
            if (options.inlier(plane_Box, c)) visit(c.p_BoxPoint);
          }
        },
        Eigen::Vector3d::UnitZ());
    if (!fitted) {
      out.num_inliers = 0;
      return out;
    }
    num = fitted->count;
    if (fitted->coefficients.z() < options.cos_tilt) break;
    plane_Box = fitted->coefficients;
    out.centroid_xy_Box = fitted->centroid.head<2>();
  }
  out.plane_Box = plane_Box;
  out.num_inliers = num;
  return out;
}

// One floor plane among `points`: RANSAC, then least-squares refits on its inliers.
FloorPlaneFit FitFloorPlane(const std::vector<FloorCandidate>& points,
                            const FloorPlaneFitOptions& options, std::mt19937& rng) {
  const FloorRansacResult ransac = RansacFloorPlane(points, options, rng);
  if (ransac.count == 0) return FloorPlaneFit{};
  return RefitFloorPlane(points, ransac.plane_Box, options);
}

// Footprint cells of kFootprintCell_m metres over the Box xy plane.
constexpr double kFootprintCell_m = 0.02;
std::int64_t FootprintCell(const Eigen::Vector3d& p_BoxPoint) {
  const auto x = static_cast<std::int64_t>(std::floor(p_BoxPoint.x() / kFootprintCell_m));
  const auto y = static_cast<std::int64_t>(std::floor(p_BoxPoint.y() / kFootprintCell_m));
  return (x << 32) ^ (y & 0xFFFFFFFF);
}

// Height (Box z, metres) of a plane (Box frame, n.z != 0) above the Box point (xy, 0).
double PlaneHeightAt(const Eigen::Vector4d& plane_Box, const Eigen::Vector2d& xy_Box) {
  return -(plane_Box[0] * xy_Box.x() + plane_Box[1] * xy_Box.y() + plane_Box[3]) / plane_Box[2];
}

// An extracted plane with its inliers' footprint, Box frame.
struct FloorPlane {
  Eigen::Vector4d plane_Box = Eigen::Vector4d::Zero();        // n.p + d = 0
  Eigen::Vector2d centroid_xy_Box = Eigen::Vector2d::Zero();  // Of its inliers.
  bool floor = true;                                          // False: an item's top, not floor.
  std::unordered_set<std::int64_t> cells;  // Footprint: FootprintCell()s holding its inliers.
};

// Up to max_planes planes (normal near the box's +z, n.z > 0), each by RANSAC over the
// candidates the earlier ones left (one random sequence from `seed` for all), refitted by
// least squares on its inliers; stops at the first plane with fewer than min_inliers inliers.
struct FloorPlaneExtractionOptions {
  FloorPlaneFitOptions fit;
  int max_planes = 1;
  std::size_t min_inliers = 0;
  std::uint32_t seed = 0;
};
std::vector<FloorPlane> ExtractFloorPlanes(std::vector<FloorCandidate> candidates,
                                           const FloorPlaneExtractionOptions& options) {
  std::mt19937 rng(options.seed);
  std::vector<FloorPlane> planes;
  while (static_cast<int>(planes.size()) < options.max_planes &&
         candidates.size() >= options.min_inliers) {
    const FloorPlaneFit fit = FitFloorPlane(candidates, options.fit, rng);
    if (fit.num_inliers < options.min_inliers) break;
    FloorPlane plane;
    plane.plane_Box = fit.plane_Box;
    plane.centroid_xy_Box = fit.centroid_xy_Box;
    std::vector<FloorCandidate> rest;
    for (const auto& c : candidates) {
      if (!options.fit.inlier(plane.plane_Box, c)) {
        rest.push_back(c);
      } else {
        plane.cells.insert(FootprintCell(c.p_BoxPoint));
      }
    }
    candidates = std::move(rest);
    planes.push_back(std::move(plane));
  }
  return planes;
}

// Clears `floor` of the planes that are not floor. The floor is the lowest surface: a plane
// that lies more than min_step_m above another one where its own inliers are, and does not
// pass below it where the other's inliers are, is the top of an item standing on that one.
// (Where it would pass below the other one the two are parts of a bent board. The item's top
// need not lie high above the other plane at the other's inliers: a level item on a tilted
// board crosses the board's plane there.) A plane passing higher than max_centre_height_m at
// the box's centre is an item's top face over a hidden floor.
void MarkItemTopPlanes(double bottom_z_Box, double max_centre_height_m, double min_step_m,
                       std::vector<FloorPlane>* planes) {
  for (FloorPlane& plane : *planes) {
    if (PlaneHeightAt(plane.plane_Box, Eigen::Vector2d::Zero()) - bottom_z_Box >
        max_centre_height_m) {
      plane.floor = false;
    }
    for (const FloorPlane& other : *planes) {
      if (&other == &plane) continue;
      const auto rise = [&](const Eigen::Vector2d& xy_Box) {
        return PlaneHeightAt(plane.plane_Box, xy_Box) - PlaneHeightAt(other.plane_Box, xy_Box);
      };
      if (rise(plane.centroid_xy_Box) > min_step_m && rise(other.centroid_xy_Box) > -min_step_m) {
        plane.floor = false;
      }
    }
  }
}

// Which points of the cloud are floor. A point is floor when it lies below the lowest floor
// plane at its place or less than margin_m above it, or likewise for a floor plane whose
// footprint holds the point (a higher part of the board, e.g. a lip). `floors` is not empty;
// its first (best-supported) plane's n.z scales the "lowest" test.
struct FloorPointsResult {
  std::vector<bool> keep;     // Per cloud point: false for floor.
  std::size_t num_floor = 0;  // Points marked floor.
};
FloorPointsResult FindFloorPoints(const PointCloud& cloud, const Eigen::Isometry3d& X_BoxBase,
                                  const std::vector<const FloorPlane*>& floors, double margin_m) {
  FloorPointsResult out;
  out.keep.assign(cloud.size(), true);
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!cloud.points[i].allFinite()) continue;
    const Eigen::Vector3d p_BoxPoint = X_BoxBase * cloud.points[i].cast<double>();
    const std::int64_t cell = FootprintCell(p_BoxPoint);
    double lowest = std::numeric_limits<double>::infinity();
    bool floor = false;
    for (const FloorPlane* plane : floors) {
      const double h = p_BoxPoint.z() - PlaneHeightAt(plane->plane_Box, p_BoxPoint.head<2>());
      lowest = std::min(lowest, h);
      if (h * plane->plane_Box[2] < margin_m && plane->cells.count(cell) > 0) {
        floor = true;
      }
    }
    if (floor || lowest * floors.front()->plane_Box[2] < margin_m) {
      out.keep[i] = false;
      ++out.num_floor;
    }
  }
  return out;
}

// A plane (n.p + d = 0, |n| = 1) given in the Box frame, expressed in the Base (cloud) frame.
Eigen::Vector4d PlaneInBase(const Eigen::Vector4d& plane_Box, const Eigen::Isometry3d& X_BaseBox) {
  const Eigen::Vector3d n_Base = X_BaseBox.linear() * plane_Box.head<3>();
  const Eigen::Vector3d p_BasePlanePoint = X_BaseBox * (-plane_Box[3] * plane_Box.head<3>());
  Eigen::Vector4d plane_Base;
  plane_Base << n_Base, -n_Base.dot(p_BasePlanePoint);
  return plane_Base;
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
  ValidateFloorRemovalOptions(options);
  const Eigen::Isometry3d X_BoxBase = box.X_BaseBox.inverse();
  const double bottom_z_Box = -0.5 * box.size_m.z();
  const double cos_tilt = std::cos(options.max_tilt_rad);
  std::vector<FloorCandidate> candidates =
      CollectFloorCandidates(cloud, X_BoxBase, bottom_z_Box, options.search_height_m, cos_tilt);
  PlaneRemovalResult result;
  result.cloud = cloud;
  if (candidates.size() < std::max<std::size_t>(3, options.min_inliers)) return result;

  FloorPlaneExtractionOptions extraction;
  extraction.fit.inlier.threshold_m = options.distance_threshold_m;
  extraction.fit.inlier.cos_normal = std::cos(options.normal_threshold_rad);
  extraction.fit.inlier.normals = cloud.has_normals();
  extraction.fit.cos_tilt = cos_tilt;
  extraction.fit.max_iterations = options.max_iterations;
  extraction.max_planes = options.max_planes;
  extraction.min_inliers = options.min_inliers;
  extraction.seed = options.seed;
  std::vector<FloorPlane> planes = ExtractFloorPlanes(std::move(candidates), extraction);
  MarkItemTopPlanes(bottom_z_Box, options.max_centre_height_m, options.min_step_m, &planes);
  std::vector<const FloorPlane*> floors;
  for (const FloorPlane& plane : planes) {
    if (plane.floor) floors.push_back(&plane);
  }
  if (floors.empty()) return result;
  const FloorPointsResult floor_points =
      FindFloorPoints(cloud, X_BoxBase, floors, options.margin_m);
  result.num_inliers += floor_points.num_floor;
  result.cloud = Filter(cloud, floor_points.keep, options.keep_organized);
  // The floor plane with the most support (the first found), in the cloud's frame.
  result.plane = PlaneInBase(floors.front()->plane_Box, box.X_BaseBox);
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
