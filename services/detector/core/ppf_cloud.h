#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <vector>

#include "libs/geometry/point_cloud.h"

namespace picking::detector {

/// How estimated normals are given their sign.
enum class NormalOrientation {
  kTowardViewpoint,      ///< n . (viewpoint - p) >= 0: a sensor's view (scenes).
  kOutwardFromCentroid,  ///< n . (p - centroid) >= 0: closed or convex models.
};

/// Options of EstimatePcaNormals.
struct PcaNormalOptions {
  float radius_m = 0.01f;  ///< Neighbourhood radius of the plane fit, metres (> 0).
  int min_neighbors = 5;   ///< Points with fewer neighbours (itself included) are dropped.
  NormalOrientation orientation = NormalOrientation::kTowardViewpoint;
  Eigen::Vector3f viewpoint = Eigen::Vector3f::Zero();  ///< In the cloud's frame, metres.
};

/// Throws std::invalid_argument naming `what` when the cloud's optional channels have a
/// length different from the point count.
void CheckCloudChannels(const geometry::PointCloud& cloud, const char* what);

/// The points (and normals, colours, intensities) whose coordinates, and normal when present,
/// are finite. The result is unorganised. Throws std::invalid_argument on inconsistent
/// channel lengths.
geometry::PointCloud RemoveInvalidPoints(const geometry::PointCloud& cloud);

/// One point per occupied voxel of edge `voxel_m` (metres, > 0): the centroid of the voxel's
/// points and, when the cloud has normals, their normalised mean (intensities: the mean of
/// the finite ones, NaN when none is). Voxels are ordered by their
/// integer coordinates, so the result is deterministic. Non-finite points are ignored.
/// Throws std::invalid_argument when voxel_m <= 0 or the cloud spans more than 2^20 voxels
/// along an axis.
/// Every `stride`-th point (>= 1) of `cloud` with its normal (when it has normals), as an
/// unorganised cloud: a quick, deterministic thinning of a model for coarse passes and
/// screenings. Throws std::invalid_argument for stride 0.
geometry::PointCloud EveryNthPoint(const geometry::PointCloud& cloud, std::size_t stride);

geometry::PointCloud VoxelAverage(const geometry::PointCloud& cloud, float voxel_m);

/// A copy of `cloud` with normals from a PCA plane fit over the neighbours within
/// options.radius_m, oriented by options.orientation. Points with too few neighbours or a
/// non-finite coordinate are dropped. Throws std::invalid_argument for a non-positive radius.
geometry::PointCloud EstimatePcaNormals(const geometry::PointCloud& cloud,
                                        const PcaNormalOptions& options);

/// Largest distance between two points of `points`, metres (exact, O(n^2)); 0 when fewer
/// than two points.
float CloudDiameter(const std::vector<Eigen::Vector3f>& points);

/// Options of FindSpheres.
struct SphereSearchOptions {
  /// A point supports a sphere when it lies within this distance of its surface, metres.
  double distance_threshold_m = 0.002;
  /// ... and its normal is within this angle of the sphere's outward normal, radians.
  double normal_threshold_rad = 0.35;
  int max_iterations = 300;  ///< RANSAC hypotheses per sphere (one point and its normal each).
  int max_spheres = 3;       ///< Spheres returned at most (>= 1).
  /// A sphere needs at least this many supporting points (>= 1).
  std::size_t min_inliers = 50;
  std::uint32_t seed = 7;
};

/// A sphere of known radius found in a cloud.
struct SphereFit {
  Eigen::Vector3d p_Centre = Eigen::Vector3d::Zero();  ///< In the cloud's frame, metres.
  std::size_t inliers = 0;
};

/// Spheres of radius `radius_m` in `cloud` (points in metres with unit normals pointing out of
/// the surfaces, e.g. toward the sensor), most supported first: RANSAC over one point and its
/// normal (centre = p - radius_m n), support counted over up to 4000 sampled points,
/// least-squares refit of the centre on the inliers with the radius fixed; the next sphere is
/// searched among the points no earlier sphere supports. A sphere's pose is its centre, so
/// this replaces a pose search for a ball. Deterministic for a given seed. Throws
/// std::invalid_argument for a non-positive radius, a cloud without normals or bad options.
std::vector<SphereFit> FindSpheres(const geometry::PointCloud& cloud, double radius_m,
                                   const SphereSearchOptions& options = {});

}  // namespace picking::detector
