#pragma once

#include <Eigen/Geometry>

#include <cstddef>
#include <cstdint>
#include <vector>

#include "libs/geometry/point_cloud.h"

namespace picking::detector {

/// An oriented box region, e.g. a shelf bin's or the tote's inner volume.
///
/// The Box frame has its origin at the box centre and its axes along the box edges; the box
/// spans [-size/2, +size/2] along each axis. `X_BaseBox` is the pose of the Box frame in the
/// cloud's frame (normally the robot base), `size_m` the full edge lengths in metres.
struct OrientedBox {
  Eigen::Isometry3d X_BaseBox = Eigen::Isometry3d::Identity();
  Eigen::Vector3d size_m = Eigen::Vector3d::Zero();

  /// Throws std::invalid_argument when a size is not positive and finite.
  void Validate() const;
  bool Contains(const Eigen::Vector3d& p_BasePoint, double margin_m = 0.0) const;
};

/// OrientedBox::Contains (margin 0) for many points: the box's pose is inverted once, and
/// points are tested in float.
class BoxContainment final {
 public:
  explicit BoxContainment(const OrientedBox& box)
      : X_BoxBase_(box.X_BaseBox.inverse().cast<float>()),
        half_size_((0.5 * box.size_m).cast<float>()) {}
  bool operator()(const Eigen::Vector3f& p_BasePoint) const {
    return ((X_BoxBase_ * p_BasePoint).cwiseAbs() - half_size_).maxCoeff() <= 0.0f;
  }

 private:
  Eigen::Isometry3f X_BoxBase_;
  Eigen::Vector3f half_size_;
};

/// Faces of an OrientedBox, as bit flags, named by the Box-frame axis they are normal to.
enum BoxFace : std::uint32_t {
  kFaceMinX = 1u << 0,
  kFaceMaxX = 1u << 1,
  kFaceMinY = 1u << 2,
  kFaceMaxY = 1u << 3,
  kFaceMinZ = 1u << 4,  ///< The floor when the Box z axis points up.
  kFaceMaxZ = 1u << 5,
  kAllFaces = 63u,
};

/// Checks common to every pre-processing step.
struct CloudLimits {
  /// Clouds with more points than this are refused (std::invalid_argument).
  std::size_t max_points = 5'000'000;
};

/// Throws std::invalid_argument when the cloud is empty, larger than limits.max_points, has
/// inconsistent channel sizes or organisation, or has no finite point.
void ValidateCloud(const geometry::PointCloud& cloud, const CloudLimits& limits = {});

struct CropOptions {
  CloudLimits limits;
  /// Keep an organised cloud organised: points outside the box become NaN (with NaN
  /// normals) instead of being dropped. Unorganised clouds always drop them.
  bool keep_organized = true;
};

/// Points of `cloud` inside `box` (frames: both in the cloud's frame).
/// Throws std::invalid_argument on an invalid cloud (see ValidateCloud) or box, and when the
/// box does not overlap the bounding box of the cloud's finite points at all (the region is
/// outside what the sensor saw: wrong bin pose or wrong scan).
geometry::PointCloud CropToBox(const geometry::PointCloud& cloud, const OrientedBox& box,
                               const CropOptions& options = {});

struct WallRemovalOptions {
  /// Points within this distance of a selected inner face (inside or outside it) are removed,
  /// metres.
  double margin_m = 0.01;
  /// Which faces are walls (a shelf bin: every face but the open front; the tote: every face
  /// but the open top).
  std::uint32_t faces = kAllFaces & ~kFaceMaxZ;
  /// As in CropOptions.
  bool keep_organized = true;
  CloudLimits limits;
};

/// Removes the points of `cloud` that lie on the selected inner faces of `box`.
/// Throws as CropToBox (except that no overlap check is done).
geometry::PointCloud RemoveBoxWalls(const geometry::PointCloud& cloud, const OrientedBox& box,
                                    const WallRemovalOptions& options = {});

struct PlaneRemovalOptions {
  double distance_threshold_m = 0.005;  ///< RANSAC inlier distance.
  int max_iterations = 500;
  /// The plane is removed only if it holds at least this fraction of the finite points.
  double min_inlier_fraction = 0.1;
  std::uint32_t seed = 42;
  bool keep_organized = true;
  CloudLimits limits;
};

struct PlaneRemovalResult {
  geometry::PointCloud cloud;  ///< The input without the plane's inliers.
  /// Plane n.p + d = 0 with |n| = 1, in the cloud's frame; zero when no plane was removed.
  Eigen::Vector4d plane = Eigen::Vector4d::Zero();
  std::size_t num_inliers = 0;
  bool removed = false;
};

/// Finds the dominant plane with RANSAC (3-point hypotheses, least-squares refit on the
/// inliers) and removes its inliers. Throws as ValidateCloud.
PlaneRemovalResult RemoveDominantPlane(const geometry::PointCloud& cloud,
                                       const PlaneRemovalOptions& options = {});

struct FloorRemovalOptions {
  /// The floor is searched among the points at most this high above the box's bottom face
  /// (shelf boards are not flat: they rise and sag by a few centimetres), metres.
  double search_height_m = 0.05;
  /// The floor plane's normal is within this angle of the box's +z axis, radians; points
  /// with normals further from +z are not floor candidates.
  double max_tilt_rad = 0.3;
  /// A floor plane passes at most this high above the box's bottom face at the box's centre
  /// (a higher plane is an item's top face over a hidden floor), metres.
  double max_centre_height_m = 0.03;
  double distance_threshold_m = 0.004;  ///< RANSAC inlier distance, metres.
  /// With normals, inliers also have their normal within this angle of the plane's, radians.
  double normal_threshold_rad = 0.05;
  /// Points below their floor plane or less than this above it are removed, metres: items
  /// at least about twice as thick survive.
  double margin_m = 0.005;
  int max_iterations = 300;  ///< RANSAC hypotheses per plane.
  /// At most this many planes are extracted from the candidates, one after the other.
  int max_planes = 4;
  /// A plane lying more than this above another one at its own inliers, and not this much
  /// below it at the other's, is the top of an item standing on the other, not floor, metres.
  double min_step_m = 0.006;
  /// A plane needs this many supporting candidates.
  std::size_t min_inliers = 500;
  std::uint32_t seed = 42;
  bool keep_organized = true;
  CloudLimits limits;
};

/// Removes the floor of a box region (a shelf bin's board, the tote's bottom) as measured in
/// the cloud, and only the floor: candidates are the points near the box's bottom face (with
/// upward normals when the cloud has normals); up to max_planes planes with normals near the
/// box's +z are extracted from them one after the other (RANSAC, least-squares refit, the
/// inliers leave the candidates). A plane is floor unless it passes higher than
/// max_centre_height_m at the box's centre or is the top of a flat item standing on another
/// plane: more than min_step_m above it at its own inliers and not below it (by min_step_m) at
/// the other's, which also holds for a level item on a tilted board. Every point
/// below the lowest floor plane at its place or within margin_m above it is removed, and
/// likewise for a floor plane with inliers in the point's 2 cm cell of the box's xy grid (a
/// higher part of the board), so a flat item on a tilted or uneven board stays when its top is
/// seen above floor that is visible elsewhere. `plane` of the result is the best-supported floor
/// plane, n.p + d = 0 in the cloud's frame with n toward the box's +z. Throws as ValidateCloud,
/// std::invalid_argument on bad options or box.
PlaneRemovalResult RemoveBoxFloor(const geometry::PointCloud& cloud, const OrientedBox& box,
                                  const FloorRemovalOptions& options = {});

/// Voxel-grid down-sampling: one point per occupied voxel at the mean of its points (normals
/// averaged and re-normalised, colours averaged, intensities averaged over the finite ones
/// and NaN where none is). The result is unorganised.
/// Throws std::invalid_argument on leaf_size_m <= 0 or an invalid cloud.
geometry::PointCloud VoxelDownsample(const geometry::PointCloud& cloud, double leaf_size_m,
                                     const CloudLimits& limits = {});

struct NormalOptions {
  /// Neighbours used for each normal (PCA of the k nearest points).
  int k_neighbors = 16;
  /// Normals are flipped to face this viewpoint (cloud frame), e.g. the sensor position.
  Eigen::Vector3d p_BaseViewpoint = Eigen::Vector3d::Zero();
  /// When true, normals are instead flipped to point away from the centroid of the cloud
  /// (for closed object models).
  bool orient_outward_from_centroid = false;
  CloudLimits limits;
};

/// Returns `cloud` with `normals` filled (PCL NormalEstimationOMP); non-finite points and
/// points whose neighbourhood is degenerate get NaN normals. Organisation is kept.
/// Throws as ValidateCloud and std::invalid_argument on k_neighbors < 3.
geometry::PointCloud EstimateNormals(const geometry::PointCloud& cloud,
                                     const NormalOptions& options = {});

struct ClusterOptions {
  double tolerance_m = 0.01;  ///< Max gap between neighbouring points of one cluster.
  std::size_t min_size = 50;
  std::size_t max_size = 1'000'000;
  /// When > 0 (metres, below tolerance_m), clusters are grown over one representative point
  /// per voxel of this size and every point joins the cluster of its voxel: on a dense scan
  /// (sub-millimetre spacing, hundreds of neighbours within tolerance_m) this is many times
  /// faster, and gaps are measured between representatives (within one voxel diagonal of
  /// the exact clusters). 0: every point (exact).
  double subsample_voxel_m = 0.0;
  CloudLimits limits;
};

/// Euclidean clusters of the finite points (pcl::EuclideanClusterExtraction), each as indices
/// into `cloud.points`, largest first; min_size and max_size count points of `cloud`. Throws
/// as ValidateCloud and std::invalid_argument on tolerance_m <= 0, min_size > max_size or a
/// subsample_voxel_m outside [0, tolerance_m). `representatives`, when given, receives for
/// each cluster (same order) its points that stood for their voxel (one per
/// subsample_voxel_m voxel; without subsampling, every member): a thinned copy of the cluster
/// for nearest-cluster lookups.
std::vector<std::vector<int>> EuclideanClusters(
    const geometry::PointCloud& cloud, const ClusterOptions& options = {},
    std::vector<std::vector<int>>* representatives = nullptr);

/// A copy of the listed points (unorganised) with their channels.
geometry::PointCloud SelectPoints(const geometry::PointCloud& cloud,
                                  const std::vector<int>& indices);

}  // namespace picking::detector
