#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <cstdint>
#include <functional>
#include <limits>
#include <vector>

namespace picking::planner {

/// Options of DistanceGrid::Build.
struct DistanceGridOptions {
  /// Cell edge, metres (> 0).
  double resolution_m = 0.01;
  /// The grid covers the seeds' bounds grown by this much on every side, metres (> 0). A
  /// query outside the grid is at least this far from every seed (minus the allowance).
  double margin_m = 0.15;
  /// How far the geometry the seeds stand for may lie from its seed points, metres (>= 0):
  /// e.g. half a voxel diagonal for voxel centres, or the sampling gap of a surface.
  double seed_allowance_m = 0.0;
  /// Cells are aligned so that cell centres fall on (k + 0.5) * resolution for integer k
  /// (as OctoMap's voxel centres do), so voxel centres are cell centres.
  bool align_to_resolution = true;
};

/// Lower bounds of the distance to some geometry over blocks of space: for each block the
/// smallest bound any point of it can get (e.g. from DistanceGrid::LowerBoundIn of several
/// grids, the floor and the pedestal at once). One read, no square root, answers for any point
/// of a block: the quick test that lets most of a state's spheres go. Thread-safe (const).
class BlockBound final {
 public:
  BlockBound() = default;
  /// Lower bound on the distance from `p_F` to the geometry, metres.
  float Clearance(const Eigen::Vector3f& p_F) const {
    const Eigen::Vector3f u = (p_F - origin_F_) * inv_block_m_;
    if (!(u.x() >= 0.f && u.y() >= 0.f && u.z() >= 0.f && u.x() < size_f_.x() &&
          u.y() < size_f_.y() && u.z() < size_f_.z())) {
      return outside_clearance_m_;
    }
    const std::size_t i =
        (static_cast<std::size_t>(u.z()) * ny_ + static_cast<std::size_t>(u.y())) * nx_ +
        static_cast<std::size_t>(u.x());
    return bound_01mm_[i] * 1e-4f;
  }
  std::size_t memory_bytes() const { return bound_01mm_.size() * sizeof(std::uint16_t); }

  /// Blocks of edge `block_m` over `box_F`, each holding `lower_bound_in(block)`: a lower bound
  /// of the distance from any point of that block (an axis-aligned box, frame F) to the
  /// geometry, metres (negative values count as 0). Points outside `box_F` answer
  /// `outside_clearance_m`. Throws std::invalid_argument for an empty box or a block edge
  /// that is not positive.
  static BlockBound FromFunction(
      const Eigen::AlignedBox3f& box_F, float block_m,
      const std::function<float(const Eigen::AlignedBox3f&)>& lower_bound_in,
      float outside_clearance_m);

 private:
  Eigen::Vector3f origin_F_ = Eigen::Vector3f::Zero();
  Eigen::Vector3f size_f_ = Eigen::Vector3f::Zero();
  float inv_block_m_ = 1.f;
  float outside_clearance_m_ = 1e3f;
  int nx_ = 0, ny_ = 0;
  std::vector<std::uint16_t> bound_01mm_;
};

/// A Euclidean distance transform of a point set on a regular grid, for conservative
/// sphere queries: `Clearance(p)` is a lower bound on the distance from `p` to the geometry
/// the seeds stand for.
///
/// Each seed marks the cell that contains it; every cell stores the exact distance between
/// its centre and the nearest marked cell's centre (Felzenszwalb & Huttenlocher's separable
/// transform). For a query point p in cell g, the true distance to the geometry is at least
///   D(g) - |p - centre(g)| - (half the cell diagonal) - seed_allowance
/// since a seed lies within half a diagonal of its cell's centre and the geometry within the
/// allowance of a seed. Distances are stored in units of 0.1 mm, rounded down (uint16), so
/// the rounding only ever makes the bound smaller. Thread-safe (const) after Build.
class DistanceGrid final {
 public:
  DistanceGrid() = default;

  /// Builds the grid over `seeds` (metres, any frame F). Throws std::invalid_argument for
  /// bad options, non-finite seeds or a grid of more than `max_cells` cells.
  static DistanceGrid Build(const std::vector<Eigen::Vector3f>& seeds_F,
                            const DistanceGridOptions& options,
                            std::size_t max_cells = 200'000'000);

  /// Lower bound on the distance from `p_F` to the seeded geometry, metres (negative near
  /// or inside it). An empty grid (no seeds) answers a large value.
  float Clearance(const Eigen::Vector3f& p_F) const {
    const Eigen::Vector3f u = (p_F - origin_F_) * inv_resolution_;
    if (!(u.x() >= 0.f && u.y() >= 0.f && u.z() >= 0.f && u.x() < size_f_.x() &&
          u.y() < size_f_.y() && u.z() < size_f_.z())) {
      return outside_clearance_m_;
    }
    const int ix = static_cast<int>(u.x()), iy = static_cast<int>(u.y()),
              iz = static_cast<int>(u.z());
    const Eigen::Vector3f offset((u.x() - ix - 0.5f), (u.y() - iy - 0.5f), (u.z() - iz - 0.5f));
    const float d = distance_01mm_[(static_cast<std::size_t>(iz) * ny_ + iy) * nx_ + ix] * 1e-4f;
    return d - offset.norm() * resolution_ - allowance_m_;
  }

  /// Replaces the bound of every cell whose centre may lie within `band_m` of the geometry by
  /// the exact distance from its centre to `triangles_F` (the geometry the seeds were sampled
  /// from). A query in such a cell is then loose only by twice its offset from the centre (at
  /// most a cell diagonal), not by the seeds' spacing and another half diagonal as well, so a
  /// sphere check needs its exact fallback less often. Each triangle visits the cells of its
  /// bounding box grown by the band. Throws std::invalid_argument for a negative or non-finite
  /// band.
  void Tighten(float band_m, const std::vector<std::array<Eigen::Vector3f, 3>>& triangles_F);

  /// Lower and upper bounds on the distance from `p_F` to the geometry from the eight cell
  /// centres around it (the distance is 1-Lipschitz: each centre's bound minus, or its exact
  /// distance plus, the way to it): tighter than Clearance, for the spheres it cannot clear.
  /// `upper_m` is infinite unless a tightened cell (Tighten) is among the eight. Outside the
  /// grid: the outside bound and infinity.
  struct Bounds {
    float lower_m;
    float upper_m;
  };
  Bounds NearBounds(const Eigen::Vector3f& p_F) const;

  /// Lower bound on the distance from any point of `box_F` to the seeded geometry, metres:
  /// the smallest over the cells the box overlaps, and the outside answer where it leaves
  /// the grid.
  float LowerBoundIn(const Eigen::AlignedBox3f& box_F) const;

  bool empty() const { return distance_01mm_.empty(); }
  double resolution_m() const { return resolution_; }
  /// Bounds of the grid (outer faces of its cells), frame F.
  Eigen::AlignedBox3f bounds_F() const;
  /// Added to every query: half a cell diagonal plus the seed allowance, metres.
  float allowance_m() const { return allowance_m_; }
  /// What a query outside the grid answers, metres.
  float outside_clearance_m() const { return outside_clearance_m_; }
  std::size_t num_cells() const { return distance_01mm_.size(); }
  std::size_t memory_bytes() const { return distance_01mm_.size() * sizeof(std::uint16_t); }

 private:
  // Tighten's work for one triangle: the cells within the band of its plane and box.
  void TightenNear(const std::array<Eigen::Vector3f, 3>& triangle_F, float band_m);

  Eigen::Vector3f origin_F_ = Eigen::Vector3f::Zero();  // min corner of cell (0, 0, 0)
  Eigen::Vector3f size_f_ = Eigen::Vector3f::Zero();    // nx, ny, nz as floats
  float resolution_ = 0.01f;
  float inv_resolution_ = 100.f;
  float allowance_m_ = 0.f;
  float outside_clearance_m_ = 1e3f;
  // Stored values below this hold a tightened cell's exact distance (0: none).
  std::uint16_t exact_cap_01mm_ = 0;
  int nx_ = 0, ny_ = 0, nz_ = 0;
  std::vector<std::uint16_t> distance_01mm_;
};

/// Squared distance from `p` to triangle abc (Ericson, Real-Time Collision Detection 5.1.5).
float PointTriangleDistance2(const Eigen::Vector3f& p, const Eigen::Vector3f& a,
                             const Eigen::Vector3f& b, const Eigen::Vector3f& c);

/// Points on the surface of triangles no farther than `gap_m` from any surface point: the
/// triangles are subdivided until every edge is at most `gap_m * sqrt(3)` and their vertices
/// returned (a point of a triangle is within longest-edge / sqrt(3) of a vertex).
/// `vertices` and `triangles` as in world::TriangleMesh; the points are mapped by X_FMesh.
void SampleSurface(const std::vector<Eigen::Vector3f>& vertices,
                   const std::vector<std::array<std::uint32_t, 3>>& triangles,
                   const Eigen::Isometry3d& X_FMesh, double gap_m,
                   std::vector<Eigen::Vector3f>* points_F);

}  // namespace picking::planner
