#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "services/planner/core/collision_world.h"

namespace picking::planner {

/// A convex polytope as half spaces n . p <= d (n unit), metres.
struct ConvexHull {
  std::vector<Eigen::Vector4d> planes;    ///< (n_x, n_y, n_z, d); coplanar facets merged.
  std::vector<Eigen::Vector3d> vertices;  ///< The hull's corners.
  /// True if p lies inside the hull grown by `margin_m` (every plane moved out by it).
  bool Contains(const Eigen::Vector3d& p, double margin_m) const {
    for (const auto& h : planes) {
      if (h.head<3>().dot(p) > h[3] + margin_m) return false;
    }
    return !planes.empty();
  }
  /// Axis-aligned bounds of the vertices grown by `margin_m`.
  Eigen::AlignedBox3d Bounds(double margin_m) const;
  /// The hull mapped by X_NewOld.
  ConvexHull Transformed(const Eigen::Isometry3d& X_NewOld) const;
};

/// The convex hull of a point set (qhull through PCL). Throws std::invalid_argument for
/// fewer than 4 points, non-finite points, or a flat set.
ConvexHull ComputeConvexHull(const std::vector<Eigen::Vector3f>& points);

/// A region whose points are removed from the scan and whose voxels are free: the target
/// item's convex hull at its detected pose, grown by a margin.
struct SceneCutOut {
  std::string item;
  ConvexHull hull_Base;
  double margin_m = 0.02;
};

/// Options of ScanScene.
struct ScanSceneOptions {
  /// OctoMap voxel edge, metres (the paper's 1 cm).
  double resolution_m = 0.01;
  /// Points outside this box (base frame) are left out; an empty box keeps every point
  /// within `max_extent_m` of the base. The planner sets it to the target container grown
  /// by a margin: the rest of the cell is the static cell's.
  Eigen::AlignedBox3d region_Base;
  double max_extent_m = 3.0;
  /// Distance grid margin around the voxels, metres: must exceed the largest body sphere.
  double grid_margin_m = 0.2;
  /// Also build the OctoMap for the exact check.
  bool build_octree = true;
  /// Surfaces the planner knows already (the static cell's distance grids; must outlive the
  /// scene): a point whose distance bound to one of them is below
  /// `known_surface_distance_m` is the cell itself and is left out, so the shelf's walls are
  /// not doubled by coarser voxels. The bound is loose by up to half a grid cell's diagonal
  /// near a surface (4 mm on the static cell's 5 mm grids), so a point goes from between
  /// this distance and that much more.
  std::vector<const DistanceGrid*> known_surfaces;
  double known_surface_distance_m = 0.01;
};

/// Counts of one ScanScene::Insert.
struct SceneUpdateStats {
  std::size_t points = 0;          ///< Points received.
  std::size_t points_invalid = 0;  ///< NaN / infinite (the scanner's holes).
  std::size_t points_outside = 0;  ///< Outside the region.
  std::size_t points_cut = 0;      ///< Inside a cut-out.
  std::size_t points_static = 0;   ///< On the static cell's surfaces.
  std::size_t voxels_added = 0;    ///< New occupied voxels.
  std::size_t voxels_cleared = 0;  ///< Occupied voxels freed by the cut-outs.
  std::size_t voxels_total = 0;    ///< Occupied voxels after the update.
};

/// The occupied voxels seen by one or more scans, with the target items' hulls cut out.
///
/// Points are binned straight into voxel keys (OctoMap's: floor(x / resolution)) through a
/// bitmap over the region, without ray casting: the scanner's views come from outside the
/// bins, and what a view does not see stays occupied only if another view saw it. A cut-out
/// frees the voxels inside it in the same update, including voxels of earlier scans, so a
/// moved or picked item leaves no stale obstacle behind. Not thread-safe; `Snapshot` returns
/// immutable obstacles for the checkers.
class ScanScene final {
 public:
  /// Throws std::invalid_argument for bad options.
  explicit ScanScene(const ScanSceneOptions& options);

  /// Adds `count` points (x, y, z floats, base frame) and applies `cut_outs`.
  SceneUpdateStats Insert(const float* xyz_Base, std::size_t count,
                          const std::vector<SceneCutOut>& cut_outs);

  /// Frees the voxels inside `cut_outs` without adding points.
  std::size_t Cut(const std::vector<SceneCutOut>& cut_outs);

  /// The distance grid (and OctoMap if asked for) of the current voxels.
  std::shared_ptr<const ScanObstacles> Snapshot() const;

  std::size_t num_voxels() const { return keys_.size(); }
  const ScanSceneOptions& options() const { return options_; }
  /// Centre of every occupied voxel, base frame.
  std::vector<Eigen::Vector3f> VoxelCentres() const;

 private:
  bool OnKnownSurface(const Eigen::Vector3f& p_Base) const;

  ScanSceneOptions options_;
  std::vector<std::uint64_t> keys_;  // sorted, unique: (kz << 32) | (ky << 16) | kx
};

}  // namespace picking::planner
