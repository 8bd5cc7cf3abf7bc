#pragma once

#include "libs/geometry/point_cloud.h"

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

}  // namespace picking::scanner
