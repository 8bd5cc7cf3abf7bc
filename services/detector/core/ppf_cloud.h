#pragma once

#include <Eigen/Core>

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
/// points and, when the cloud has normals, their normalised mean. Voxels are ordered by their
/// integer coordinates, so the result is deterministic. Non-finite points are ignored.
/// Throws std::invalid_argument when voxel_m <= 0 or the cloud spans more than 2^20 voxels
/// along an axis.
geometry::PointCloud VoxelAverage(const geometry::PointCloud& cloud, float voxel_m);

/// A copy of `cloud` with normals from a PCA plane fit over the neighbours within
/// options.radius_m, oriented by options.orientation. Points with too few neighbours or a
/// non-finite coordinate are dropped. Throws std::invalid_argument for a non-positive radius.
geometry::PointCloud EstimatePcaNormals(const geometry::PointCloud& cloud,
                                        const PcaNormalOptions& options);

/// Largest distance between two points of `points`, metres (exact, O(n^2)); 0 when fewer
/// than two points.
float CloudDiameter(const std::vector<Eigen::Vector3f>& points);

}  // namespace picking::detector
