#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "libs/world/cell_config.h"
#include "services/planner/core/distance_grid.h"
#include "services/planner/core/robot_geometry.h"

namespace octomap {
class OcTree;
}

namespace picking::planner {

/// Options of StaticCell.
struct StaticCellOptions {
  /// Distance grid cell of the shelf, tote and table, metres.
  double grid_resolution_m = 0.005;
  /// Surface sampling gap for the grids' seeds, metres.
  double surface_gap_m = 0.003;
  /// Grid cells whose centre may lie within this distance of a mesh hold the exact distance
  /// from their centre (DistanceGrid::Tighten), metres: a sphere up to this radius that the
  /// grid cannot clear is then within half a cell diagonal of touching, and only such spheres
  /// pay for the exact triangle distance. Larger: slower start-up (about 3 s for the shelf at
  /// 3 cm), fewer exact fallbacks; 0: none. The answers are the same either way.
  double exact_band_m = 0.03;
  /// The robot's pedestal below the base, an obstacle for every body but the base (base
  /// frame, metres). Empty box: none.
  Eigen::AlignedBox3d pedestal_Base =
      Eigen::AlignedBox3d(Eigen::Vector3d(-0.25, -0.25, -0.70), Eigen::Vector3d(0.25, 0.25, -0.05));
  /// The box the tool centre point must stay in (base frame, metres): the robot service's
  /// safety workspace (data/cell/robot_cell.yaml, safety.workspace_*), which refuses any
  /// motion that leaves it, so a plan leaving it is a collision here too. Empty box: none.
  Eigen::AlignedBox3d tcp_workspace_Base =
      Eigen::AlignedBox3d(Eigen::Vector3d(-1.2, -1.4, -0.68), Eigen::Vector3d(1.3, 1.4, 1.5));
};

/// The static cell as obstacles: the shelf, tote and table meshes (at their poses from the
/// cell description the simulator also loads), the floor plane and the pedestal. Holds a
/// distance grid per mesh for the fast check and FCL objects for the exact one. Immutable and
/// thread-safe after construction.
class StaticCell final {
 public:
  /// Throws std::invalid_argument for bad options.
  StaticCell(const world::CellModel& cell, const StaticCellOptions& options = {});
  ~StaticCell();
  StaticCell(const StaticCell&) = delete;
  StaticCell& operator=(const StaticCell&) = delete;

  struct Grid {
    std::string name;  ///< "shelf", "tote", "table".
    DistanceGrid grid;
  };
  /// Exact distance from `p_Base` to mesh `index`'s triangles (its grid's order), or
  /// `max_m` if none is closer: the fallback where a grid's bound is too loose to decide.
  float SurfaceDistance(std::size_t index, const Eigen::Vector3f& p_Base, float max_m) const;
  const std::vector<Grid>& grids() const { return grids_; }
  /// Every static obstacle at once (the meshes' grids, the floor, the pedestal) over 2 cm
  /// blocks of the grids' joint bounds; outside them it answers minus infinity (no bound).
  const BlockBound& blocks() const { return blocks_; }
  double floor_z_m() const { return floor_z_m_; }
  const Eigen::AlignedBox3d& pedestal_Base() const { return options_.pedestal_Base; }
  const Eigen::AlignedBox3d& tcp_workspace_Base() const { return options_.tcp_workspace_Base; }
  const world::CellModel& cell() const { return cell_; }

  struct Fcl;
  const Fcl& fcl() const { return *fcl_; }

 private:
  // blocks_ from the grids, the floor and the pedestal.
  void BuildBlocks();

  world::CellModel cell_;
  StaticCellOptions options_;
  double floor_z_m_ = 0.0;
  std::vector<Grid> grids_;
  BlockBound blocks_;
  struct Buckets;
  std::vector<std::unique_ptr<Buckets>> buckets_;  // one per grid
  std::unique_ptr<Fcl> fcl_;
};

/// Occupied space seen by a scan: the voxels of an OctoMap and their distance grid. Built
/// by BuildScanScene (scene.h); immutable and thread-safe afterwards.
struct ScanObstacles {
  DistanceGrid grid;                              ///< Over the occupied voxels' centres.
  BlockBound blocks;                              ///< `grid` over 2 cm blocks.
  std::shared_ptr<const octomap::OcTree> octree;  ///< For the exact check; may be null.
  std::size_t num_occupied_voxels = 0;
  /// The occupied voxels' centres and edge (a carried item's contacts, VoxelContacts).
  std::vector<Eigen::Vector3f> voxel_centres_Base;
  double voxel_m = 0.0;
};

/// What a state check found.
struct CollisionReport {
  bool in_collision = false;
  int body = -1;         ///< Body (see Body) that hits; -1 when free.
  std::string obstacle;  ///< "shelf", "tote", "table", "floor", "pedestal", "scan", or
                         ///< "self: <body name>".
  /// Lower bound of the clearance of the worst sphere (fast check; metres, < 0 in
  /// collision). The exact check leaves it at 0.
  double clearance_m = 0.0;
  /// "<body> hits <obstacle>" or empty.
  std::string ToString() const;
};

/// Obstacles of the fast check, in the order of its bit masks: the floor, the pedestal, the
/// static cell's meshes (StaticCell::grids() order), the scan.
inline constexpr int kObstacleFloor = 0;
inline constexpr int kObstaclePedestal = 1;
inline constexpr int kObstacleFirstMesh = 2;
/// Not an obstacle of the masks: the tool centre point outside StaticCell::tcp_workspace_Base.
inline constexpr int kObstacleWorkspace = -1;

/// What the enclosing spheres cannot rule out at one state: for each body, the obstacles it
/// may touch (bit o of `near_obstacles[body]`, obstacles numbered as above, the scan
/// last), and for each of the robot's self pairs whether the two bodies may touch. Whatever
/// is not flagged is clear for the exact meshes too (the spheres enclose them).
struct Proximity {
  std::array<std::uint32_t, kNumBodies> near_obstacles{};
  std::vector<char> near_self;  ///< One per RobotGeometry::self_pairs() entry.
};

/// The fast, conservative check of the search: the bodies' enclosing spheres against the
/// static cell's and the scan's distance grids, the floor and pedestal, and each other. Never
/// calls free a state that the exact check (FCL on the meshes) calls colliding; it may call
/// colliding a state that is free by up to a couple of centimetres of clearance.
/// Thread-safe (const).
class FastChecker final {
 public:
  /// Keeps references: `robot`, `cell` and `scan` (may be null) must outlive the checker.
  FastChecker(const RobotGeometry& robot, const StaticCell& cell, const ScanObstacles* scan);

  /// True if the arm (and `carried`, if given) at `q_rad` touches nothing. `padding_m`
  /// grows every sphere (e.g. to cover the motion between two checked states).
  bool IsFree(const JointVector& q_rad, const CarriedItem* carried = nullptr,
              float padding_m = 0.f) const;
  /// As IsFree, saying what hits what (slower).
  CollisionReport Check(const JointVector& q_rad, const CarriedItem* carried = nullptr,
                        float padding_m = 0.f) const;
  /// How much farther than `padding_m` every point of the bodies at `q_rad` is from the
  /// obstacles (and from the other bodies, half their distance), metres, capped at `cap_m`:
  /// each point may move that far and stay clear by `padding_m`. Negative where IsFree with
  /// the same padding is false. Self pairs with a distance table only say whether they touch.
  float Slack(const JointVector& q_rad, const CarriedItem* carried, float padding_m,
              float cap_m) const;
  /// Every body-obstacle and self pair the spheres cannot prove clear at body poses `X`
  /// (from RobotGeometry::ComputePoses with the same `carried` and joints `q_rad`): the
  /// broad phase of the exact check.
  Proximity Near(const JointVector& q_rad, const BodyPoses& X, const CarriedItem* carried) const;
  /// How far inside the cell's tcp workspace box the tool centre point is at body poses `X`
  /// (negative: outside; infinity without a box), metres.
  float TcpInsideWorkspace(const BodyPoses& X) const;
  /// Number of obstacles: floor, pedestal, the static meshes, the scan (last, if any).
  int num_obstacles() const;
  /// "floor", "pedestal", a static mesh's name or "scan".
  std::string ObstacleName(int obstacle) const;

  const RobotGeometry& robot() const { return robot_; }

 private:
  enum class RunMode { kIsFree, kExplain, kSlack };
  /// The check: the smallest margin of the spheres grown by `padding_m` (half of it between
  /// two bodies), capped at `cap_m`, negative once something is hit (kIsFree and kSlack stop
  /// there; kExplain goes on to report the worst hit).
  template <RunMode kMode>
  float Run(const JointVector& q_rad, const CarriedItem* carried, float padding_m, float cap_m,
            CollisionReport* report) const;
  /// A quick lower bound of the smallest margin of sphere (c, r) over every obstacle: the
  /// static grids read by block (BlockBound), so that the spheres well clear of everything
  /// are let go after reads that stay in the cache.
  float QuickMargin(const Eigen::Vector3f& c, float r) const { return QuickMargin(c, r, ~0u); }
  /// QuickMargin over the obstacles in `mask` only: the static cell's blocks are read if a
  /// static obstacle is in it, the scan's if the scan is.
  float QuickMargin(const Eigen::Vector3f& c, float r, std::uint32_t mask) const {
    float d = std::numeric_limits<float>::infinity();
    if (mask & ~scan_bit_) d = cell_.blocks().Clearance(c);
    if (mask & scan_bit_) d = std::min(d, scan_->blocks.Clearance(c));
    return d - r;
  }
  /// Sphere-mesh contacts that only the mesh's triangles can decide (the grid's bounds
  /// straddle the radius), kept for the end of an IsFree check: most colliding states hold a
  /// contact the bounds prove, and then no triangle is measured.
  struct DeferredContacts {
    static constexpr int kCapacity = 32;
    struct Contact {
      Eigen::Vector3f c;
      float r;
      int grid;
    };
    std::array<Contact, kCapacity> contacts;
    int size = 0;
  };
  /// Smallest margin (clearance minus radius) of sphere (c, r) over the obstacles in
  /// `mask`, its obstacle in `which`; `exact`: measure triangles where a grid cannot tell,
  /// or with `deferred` (while it has room) keep that grid's contact there and count it as
  /// margin 0 for now; such a call only asks whether there is a hit, and returns at the first
  /// obstacle that proves one. `touching`, if given, receives the obstacles of `mask` whose margin
  /// is below `touch_below_m` (the others cannot lower a check's slack or hit).
  float Margin(const Eigen::Vector3f& c, float r, bool exact, std::uint32_t mask, int* which,
               DeferredContacts* deferred = nullptr, std::uint32_t* touching = nullptr,
               float touch_below_m = 0.f) const;
  /// The bodies at one state: their poses in float, their sphere trees and their coarse
  /// spheres' centres in base, body b's from `first[b]` on (posed by the constructor, or
  /// with `pose_centres` false only once PoseCentres(b) is called).
  struct PosedSpheres {
    static constexpr int kMaxCoarse = 256;
    PosedSpheres(const RobotGeometry& robot, const std::array<Sphere, kNumArmBodies>& arm_bounds,
                 const BodyPoses& X, const CarriedItem* carried, bool pose_centres = true);
    void PoseCentres(int b);
    int num_bodies = 0;
    std::array<Eigen::Isometry3f, kNumBodies> Xf;
    std::array<const SphereTree*, kNumBodies> trees{};
    std::array<Eigen::Vector3f, kMaxCoarse> centres;
    std::array<int, kNumBodies + 1> first{};
    /// Each body's enclosing sphere (EnclosingSphereOf) in base: two bodies whose enclosing
    /// spheres are far enough apart need none of their spheres compared.
    std::array<Eigen::Vector3f, kNumBodies> bound_centres;
    std::array<float, kNumBodies> bound_radii_m{};
  };
  /// The distance of self pair `pair` (an index of robot().self_pairs()) beyond its spheres
  /// grown by `padding_m` each, capped at `cap_m`; negative when they touch. A pair with a
  /// distance table answers `cap_m` or its negative bound.
  float SelfPairSlack(std::size_t pair, const JointVector& q_rad, const PosedSpheres& posed,
                      float padding_m, float cap_m) const;

  const RobotGeometry& robot_;
  const StaticCell& cell_;
  const ScanObstacles* scan_;
  std::array<Sphere, kNumArmBodies> arm_bounds_;  // EnclosingSphereOf each arm body, body frame
  // The floor and pedestal in float, as the spheres are (read on every sphere).
  float floor_z_m_ = 0.f;
  Eigen::AlignedBox3f pedestal_Base_;
  std::uint32_t scan_bit_ = 0;  // the scan's obstacle bit, 0 without a scan
};

/// The exact check that validates every returned trajectory: FCL on the link meshes, the
/// gripper tube (a cylinder) and the carried item (its box) against the cell's meshes, the
/// floor (a half space), the pedestal (a box), the scan's OctoMap (fcl::OcTree) and each
/// other (the same body pairs as the fast check). Thread-safe (const): FCL is asked with
/// each body's geometry and pose, no shared objects are moved.
class ExactChecker final {
 public:
  /// `sphere_broad_phase`: skip the FCL queries of the body-obstacle and self pairs whose
  /// enclosing spheres prove them clear (the same answer, see FastChecker::Near); false runs
  /// FCL on every pair (for the differential tests).
  ExactChecker(const RobotGeometry& robot, const StaticCell& cell, const ScanObstacles* scan,
               bool sphere_broad_phase = true);
  ~ExactChecker();

  CollisionReport Check(const JointVector& q_rad, const CarriedItem* carried = nullptr) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace picking::planner
