#pragma once

#include "libs/geometry/point_cloud.h"

#include <Eigen/Core>

#include <cstddef>

namespace picking::scanner {

struct NormalOptions {
  /// Neighbours are taken `step` pixels away on each side (1 = adjacent pixels); larger
  /// steps smooth quantisation noise of the depth at the cost of detail.
  int step = 2;
  /// A neighbour counts only if its depth differs from the centre's by at most this much
  /// times the pixel distance (so normals do not bridge depth discontinuities).
  double max_depth_jump_m = 0.01;
  int num_threads = 0;  ///< Threads including the caller; 0 = all cores.
};

struct NormalResult {
  std::size_t num_normals = 0;  ///< Points that received a finite normal.
};

/// Estimates per-point normals of an organised cloud from neighbouring pixels: the cross
/// product of the horizontal and vertical central differences (one-sided where one side is
/// missing or across a depth jump), normalised and oriented towards the sensor at the
/// origin of the cloud's frame (n . p < 0). Points without enough neighbours get NaN
/// normals. Fills cloud->normals (same length as points).
/// @throws std::invalid_argument if the cloud is not organised (height > 1 and
///   width * height == size), step < 1, max_depth_jump_m <= 0 or num_threads < 0.
NormalResult EstimateNormals(geometry::PointCloud* cloud, const NormalOptions& options = {});

/// The normals of one row of an organised cloud as EstimateNormals computes them: `centre`
/// is the row (width points), `up` and `down` the rows `step` above and below (null where
/// outside the cloud), max_jump = max_depth_jump_m * step in metres. Writes width normals
/// (NaN where there is none) and returns the number of finite ones. For pipelines that
/// compute the cloud row by row (Triangulator with normals).
std::size_t EstimateNormalsRow(const Eigen::Vector3f* up, const Eigen::Vector3f* centre,
                               const Eigen::Vector3f* down, int width, int step, float max_jump,
                               Eigen::Vector3f* normals);

/// @throws std::invalid_argument, the message starting with `who`, if options.step < 1,
///   options.max_depth_jump_m <= 0 or options.num_threads < 0.
void CheckNormalOptions(const NormalOptions& options, const char* who);

}  // namespace picking::scanner
