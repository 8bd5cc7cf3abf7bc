#pragma once

#include "libs/geometry/point_cloud.h"

#include <Eigen/Geometry>

#include <cstddef>
#include <string>
#include <vector>

namespace picking::scanner {

/// Maps every point of `cloud` (and its normals) by X_TargetSource, the pose of the cloud's
/// frame in the target frame, and renames the frame to `target_frame_id`. NaN points stay
/// NaN, so organised clouds stay organised.
/// @throws std::invalid_argument if X_TargetSource is not a finite rigid transform or the
///   cloud's optional channels have the wrong length.
void TransformCloud(const Eigen::Isometry3d& X_TargetSource, const std::string& target_frame_id,
                    geometry::PointCloud* cloud);

/// Options of MergeClouds.
struct MergeOptions {
  /// Edge of the voxels in which points of all views are averaged, metres. 0 (default)
  /// keeps every point: the clouds are stacked, which keeps an organised result when every
  /// view is organised with the same width (height = sum of the heights).
  double voxel_m = 0.0;
  /// With voxels: a voxel needs at least this many points (over all views) to give a point.
  int min_points_per_voxel = 1;
};

/// Result of MergeClouds.
struct MergeResult {
  geometry::PointCloud cloud;
  std::size_t num_points = 0;  ///< Finite points in `cloud`.
};

/// Merges clouds given in one frame (every frame_id must be equal). Without voxels the
/// clouds are concatenated (NaN points kept for organised input, so the result is
/// organised if all inputs are organised with one width; otherwise it is unorganised and
/// NaN points are dropped). With voxels, the finite points are binned into a grid of
/// `voxel_m` cubes and each occupied voxel gives one point: the mean position, the mean
/// normal renormalised (if every cloud has normals), the mean intensity (if every cloud
/// has intensities) and the colour of the first point; the result is unorganised and
/// sorted by voxel, so it does not depend on the order of the points within a voxel.
/// Channels present in only some inputs are dropped.
/// @throws std::invalid_argument for no clouds, differing frame ids, a negative or NaN
///   voxel size, min_points_per_voxel < 1, or a cloud with inconsistent channel lengths.
MergeResult MergeClouds(const std::vector<geometry::PointCloud>& clouds,
                        const MergeOptions& options = {});

/// Keeps the points inside the axis-aligned box [min_m, max_m] of the cloud's frame. An
/// organised cloud stays organised (points outside become NaN, their normals NaN too); an
/// unorganised one loses them. Returns the number of finite points left.
/// @throws std::invalid_argument if a bound is NaN or min_m exceeds max_m on some axis.
std::size_t CropToBox(const Eigen::Vector3d& min_m, const Eigen::Vector3d& max_m,
                      geometry::PointCloud* cloud);

/// Number of points with finite coordinates.
std::size_t CountFinitePoints(const geometry::PointCloud& cloud);

}  // namespace picking::scanner
