#include "services/planner/core/collision_world.h"

#include <octomap/OcTree.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "libs/world/mesh_utils.h"
#include "services/planner/core/fcl_mesh.h"

namespace picking::planner {
namespace {

// Distance from p to an axis-aligned box (0 inside).
float BoxDistance(const Eigen::AlignedBox3f& box, const Eigen::Vector3f& p) {
  const Eigen::Vector3f d = (box.min() - p).cwiseMax(p - box.max()).cwiseMax(0.f);
  return d.norm();
}

}  // namespace

std::shared_ptr<MeshBvh> MakeMeshBvh(const world::TriangleMesh& mesh) {
  auto bvh = std::make_shared<MeshBvh>();
  std::vector<fcl::Vector3d> vertices;
  vertices.reserve(mesh.vertices.size());
  for (const auto& v : mesh.vertices) vertices.push_back(v.cast<double>());
  std::vector<fcl::Triangle> triangles;
  triangles.reserve(mesh.triangles.size());
  for (const auto& t : mesh.triangles) triangles.emplace_back(t[0], t[1], t[2]);
  bvh->beginModel(static_cast<int>(triangles.size()), static_cast<int>(vertices.size()));
  bvh->addSubModel(vertices, triangles);
  bvh->endModel();
  return bvh;
}

// The triangles of one static mesh in base, listed per cube of a coarse grid.
struct StaticCell::Buckets {
  static constexpr float kCell = 0.05f;
  Eigen::Vector3f origin;
  Eigen::Vector3i dims;
  std::vector<std::array<Eigen::Vector3f, 3>> triangles;
  std::vector<Eigen::Vector4f>
      balls;  // per triangle: the centroid and the farthest vertex's distance
  std::vector<std::uint32_t> start;  // CSR: bucket b's triangles are index[start[b]..start[b+1])
  std::vector<std::uint32_t> index;

  Buckets(const world::TriangleMesh& mesh, const Eigen::Isometry3d& X_BaseMesh) {
    const Eigen::Isometry3f X = X_BaseMesh.cast<float>();
    Eigen::AlignedBox3f box;
    for (const auto& t : mesh.triangles) {
      triangles.push_back(
          {X * mesh.vertices[t[0]], X * mesh.vertices[t[1]], X * mesh.vertices[t[2]]});
      for (const auto& v : triangles.back()) box.extend(v);
      const auto& t3 = triangles.back();
      const Eigen::Vector3f centroid = (t3[0] + t3[1] + t3[2]) / 3.f;
      const float radius = std::max(
          {(t3[0] - centroid).norm(), (t3[1] - centroid).norm(), (t3[2] - centroid).norm()});
      balls.emplace_back(centroid.x(), centroid.y(), centroid.z(), radius * (1.f + 1e-6f) + 1e-6f);
    }
    origin = box.min() - Eigen::Vector3f::Constant(kCell);
    dims = ((box.max() - origin) / kCell).array().ceil().cast<int>() + 1;
    const std::size_t n = static_cast<std::size_t>(dims.x()) * dims.y() * dims.z();
    std::vector<std::vector<std::uint32_t>> lists(n);
    for (std::uint32_t i = 0; i < triangles.size(); ++i) {
      Eigen::AlignedBox3f t;
      for (const auto& v : triangles[i]) t.extend(v);
      const Eigen::Vector3i lo = Cell(t.min()), hi = Cell(t.max());
      for (int z = lo.z(); z <= hi.z(); ++z)
        for (int y = lo.y(); y <= hi.y(); ++y)
          for (int x = lo.x(); x <= hi.x(); ++x) lists[Index(x, y, z)].push_back(i);
    }
    start.assign(n + 1, 0);
    for (std::size_t b = 0; b < n; ++b) start[b + 1] = start[b] + lists[b].size();
    index.reserve(start[n]);
    for (const auto& l : lists) index.insert(index.end(), l.begin(), l.end());
  }
  Eigen::Vector3i Cell(const Eigen::Vector3f& p) const {
    return ((p - origin) / kCell).array().floor().cast<int>().max(0).min(dims.array() - 1);
  }
  std::size_t Index(int x, int y, int z) const {
    return (static_cast<std::size_t>(z) * dims.y() + y) * dims.x() + x;
  }
  float Distance(const Eigen::Vector3f& p, float max_m) const {
    const Eigen::Vector3i lo = Cell(p - Eigen::Vector3f::Constant(max_m));
    const Eigen::Vector3i hi = Cell(p + Eigen::Vector3f::Constant(max_m));
    float best2 = max_m * max_m;
    for (int z = lo.z(); z <= hi.z(); ++z)
      for (int y = lo.y(); y <= hi.y(); ++y)
        for (int x = lo.x(); x <= hi.x(); ++x) {
          const std::size_t b = Index(x, y, z);
          for (std::uint32_t k = start[b]; k < start[b + 1]; ++k) {
            // A triangle whose enclosing ball is no nearer than the best so far is skipped
            // (one subtraction and dot product against the exact distance's dozens).
            const Eigen::Vector4f& ball = balls[index[k]];
            const float reach = ball.w() + std::sqrt(best2);
            if ((p - ball.head<3>()).squaredNorm() >= reach * reach) continue;
            const auto& t = triangles[index[k]];
            best2 = std::min(best2, PointTriangleDistance2(p, t[0], t[1], t[2]));
          }
        }
    return std::sqrt(best2);
  }
};

float StaticCell::SurfaceDistance(std::size_t index, const Eigen::Vector3f& p_Base,
                                  float max_m) const {
  return buckets_[index]->Distance(p_Base, max_m);
}

std::string CollisionReport::ToString() const {
  if (!in_collision) return {};
  return std::string(BodyName(body)) + " hits " + obstacle;
}

// ---------------------------------------------------------------------------------------
// Static cell

struct StaticCell::Fcl {
  struct Object {
    std::string name;
    std::shared_ptr<fcl::CollisionGeometryd> geometry;
    fcl::Transform3d X_BaseObject;
    std::unique_ptr<fcl::CollisionObjectd> object;  // built once: its AABB is computed here
  };
  std::vector<Object> objects;  // shelf, tote, table, floor, pedestal
  void Finish() {
    for (Object& o : objects) {
      o.object = std::make_unique<fcl::CollisionObjectd>(o.geometry, o.X_BaseObject);
      o.object->computeAABB();
    }
  }
};

StaticCell::StaticCell(const world::CellModel& cell, const StaticCellOptions& options)
    : cell_(cell), options_(options), fcl_(std::make_unique<Fcl>()) {
  if (!(options_.grid_resolution_m > 0.0) || !(options_.surface_gap_m > 0.0) ||
      !(options_.exact_band_m >= 0.0) || !std::isfinite(options_.exact_band_m)) {
    throw std::invalid_argument(
        "StaticCell: grid resolution and surface gap must be > 0, the exact band >= 0");
  }
  floor_z_m_ = cell_.config.floor_z_m();
  struct Part {
    const char* name;
    const world::TriangleMesh* mesh;
    Eigen::Isometry3d X_BaseMesh;
  };
  const Part parts[] = {{"shelf", &cell_.shelf, cell_.config.X_BaseShelf},
                        {"tote", &cell_.tote, cell_.config.X_BaseTote},
                        {"table", &cell_.table, cell_.config.X_BaseTable}};
  for (const Part& part : parts) {
    if (part.mesh->empty()) continue;
    std::vector<Eigen::Vector3f> seeds;
    SampleSurface(part.mesh->vertices, part.mesh->triangles, part.X_BaseMesh,
                  options_.surface_gap_m, &seeds);
    DistanceGridOptions grid_options;
    grid_options.resolution_m = options_.grid_resolution_m;
    grid_options.seed_allowance_m = options_.surface_gap_m;
    grid_options.margin_m = 0.16;
    grids_.push_back({part.name, DistanceGrid::Build(seeds, grid_options)});
    buckets_.push_back(std::make_unique<Buckets>(*part.mesh, part.X_BaseMesh));
    if (options_.exact_band_m > 0.0) {
      grids_.back().grid.Tighten(static_cast<float>(options_.exact_band_m),
                                 buckets_.back()->triangles);
    }
    fcl_->objects.push_back({part.name, MakeMeshBvh(*part.mesh), part.X_BaseMesh, nullptr});
  }
  fcl_->objects.push_back(
      {"floor",
       // FCL's half space is the solid n . p <= d: everything below the floor.
       std::make_shared<fcl::Halfspaced>(fcl::Vector3d(0.0, 0.0, 1.0), floor_z_m_),
       fcl::Transform3d::Identity(), nullptr});
  if (!options_.pedestal_Base.isEmpty()) {
    fcl::Transform3d X = fcl::Transform3d::Identity();
    X.translation() = options_.pedestal_Base.center();
    fcl_->objects.push_back(
        {"pedestal", std::make_shared<fcl::Boxd>(options_.pedestal_Base.sizes()), X, nullptr});
  }
  fcl_->Finish();
  BuildBlocks();
}

void StaticCell::BuildBlocks() {
  Eigen::AlignedBox3f box;
  for (const Grid& g : grids_) box.extend(g.grid.bounds_F());
  if (box.isEmpty()) return;
  const float floor_z = static_cast<float>(floor_z_m_);
  const Eigen::AlignedBox3f pedestal = options_.pedestal_Base.cast<float>();
  blocks_ = BlockBound::FromFunction(
      box, 0.02f,
      [&](const Eigen::AlignedBox3f& block) {
        float d = block.min().z() - floor_z;
        if (!pedestal.isEmpty()) {
          const Eigen::Vector3f gap =
              (pedestal.min() - block.max()).cwiseMax(block.min() - pedestal.max()).cwiseMax(0.f);
          d = std::min(d, gap.norm());
        }
        for (const Grid& g : grids_) d = std::min(d, g.grid.LowerBoundIn(block));
        return d;
      },
      -std::numeric_limits<float>::infinity());
}

StaticCell::~StaticCell() = default;

// ---------------------------------------------------------------------------------------
// Fast check

FastChecker::FastChecker(const RobotGeometry& robot, const StaticCell& cell,
                         const ScanObstacles* scan)
    : robot_(robot),
      cell_(cell),
      scan_(scan),
      floor_z_m_(static_cast<float>(cell.floor_z_m())),
      pedestal_Base_(cell.pedestal_Base().cast<float>()) {
  for (int b = 0; b < kNumArmBodies; ++b) arm_bounds_[b] = EnclosingSphereOf(robot.spheres(b));
  if (scan_) scan_bit_ = 1u << (num_obstacles() - 1);
}

bool FastChecker::IsFree(const JointVector& q_rad, const CarriedItem* carried,
                         float padding_m) const {
  return Run<RunMode::kIsFree>(q_rad, carried, padding_m, 0.f, nullptr) >= 0.f;
}

CollisionReport FastChecker::Check(const JointVector& q_rad, const CarriedItem* carried,
                                   float padding_m) const {
  CollisionReport report;
  report.clearance_m = 1e3;
  Run<RunMode::kExplain>(q_rad, carried, padding_m, 0.f, &report);
  return report;
}

float FastChecker::Slack(const JointVector& q_rad, const CarriedItem* carried, float padding_m,
                         float cap_m) const {
  return Run<RunMode::kSlack>(q_rad, carried, padding_m, std::max(0.f, cap_m), nullptr);
}

namespace {

// The leaves under a coarse sphere: its children, or itself if it has none.
struct Leaves {
  const Sphere* begin;
  const Sphere* end;
};
Leaves LeavesOf(const SphereTree& tree, const Sphere& s) {
  if (s.num_children == 0) return {&s, &s + 1};
  const Sphere* first = tree.fine.data() + s.first_child;
  return {first, first + s.num_children};
}

}  // namespace

FastChecker::PosedSpheres::PosedSpheres(const RobotGeometry& robot,
                                        const std::array<Sphere, kNumArmBodies>& arm_bounds,
                                        const BodyPoses& X, const CarriedItem* carried,
                                        bool pose_centres) {
  num_bodies = carried ? kNumBodies : kNumArmBodies;
  int n = 0;
  for (int b = 0; b < num_bodies; ++b) {
    first[b] = n;
    trees[b] = b == kBodyItem ? &carried->spheres_Item : &robot.spheres(b);
    Xf[b] = X[b].cast<float>();
    n += static_cast<int>(trees[b]->coarse.size());
    if (n > kMaxCoarse) throw std::logic_error("FastChecker: too many spheres");
    const Sphere& bound = b == kBodyItem ? carried->bound_Item : arm_bounds[b];
    bound_centres[b] = Xf[b] * bound.center_B;
    bound_radii_m[b] = bound.radius_m;
  }
  first[num_bodies] = n;
  if (pose_centres) {
    for (int b = 0; b < num_bodies; ++b) PoseCentres(b);
  }
}

void FastChecker::PosedSpheres::PoseCentres(int b) {
  const auto& coarse = trees[b]->coarse;
  for (std::size_t i = 0; i < coarse.size(); ++i) {
    centres[first[b] + i] = Xf[b] * coarse[i].center_B;
  }
}

int FastChecker::num_obstacles() const {
  return kObstacleFirstMesh + static_cast<int>(cell_.grids().size()) + (scan_ ? 1 : 0);
}

float FastChecker::Margin(const Eigen::Vector3f& c, float r, bool exact, std::uint32_t mask,
                          int* which, DeferredContacts* deferred, std::uint32_t* touching,
                          float touch_below_m) const {
  float worst = std::numeric_limits<float>::infinity();
  *which = -1;
  if (touching) *touching = 0;
  auto consider = [&](int obstacle, float d) {
    if (d < worst) worst = d, *which = obstacle;
    if (touching && d < touch_below_m) *touching |= 1u << obstacle;
  };
  if (mask & (1u << kObstacleFloor)) {
    consider(kObstacleFloor, c.z() - floor_z_m_ - r);
  }
  if ((mask & (1u << kObstaclePedestal)) && !pedestal_Base_.isEmpty()) {
    consider(kObstaclePedestal, BoxDistance(pedestal_Base_, c) - r);
  }
  // A check that defers contacts only asks whether there is a hit: the first will do.
  if (deferred && worst < 0.f) return worst;
  const auto& grids = cell_.grids();
  for (std::size_t g = 0; g < grids.size(); ++g) {
    const int obstacle = kObstacleFirstMesh + static_cast<int>(g);
    if (!(mask & (1u << obstacle))) continue;
    float d = grids[g].grid.Clearance(c);
    // Where the cell's bound cannot clear the sphere, the eight centres around it may clear
    // it or, with exact cells, prove the contact (upper bound below the radius); only the
    // spheres between the two bounds measure triangles.
    if (exact && d < r) {
      const DistanceGrid::Bounds near = grids[g].grid.NearBounds(c);
      d = std::max(d, near.lower_m);
      if (d < r && near.upper_m >= r) {
        if (deferred && deferred->size < DeferredContacts::kCapacity) {
          deferred->contacts[deferred->size++] = {c, r, static_cast<int>(g)};
          d = r;
        } else {
          d = cell_.SurfaceDistance(g, c, r);
        }
      }
    }
    consider(obstacle, d - r);
    if (deferred && worst < 0.f) return worst;
  }
  const int scan_obstacle = kObstacleFirstMesh + static_cast<int>(grids.size());
  if (scan_ && (mask & (1u << scan_obstacle)))
    consider(scan_obstacle, scan_->grid.Clearance(c) - r);
  return worst;
}

float FastChecker::SelfPairSlack(std::size_t pair, const JointVector& q_rad,
                                 const PosedSpheres& posed, float padding_m, float cap_m) const {
  const auto [a, b] = robot_.self_pairs()[pair];
  if (const PairDistanceTable* table = robot_.pair_table(a, b)) {
    // No padding here: the padding covers travel in the workspace, and these two bodies
    // barely move relative to each other between checked states (wrist_1 and wrist_2
    // turn little there; MotionChecker also bounds the step by the table).
    const float d = table->LowerBound(q_rad[table->joint_u], q_rad[table->joint_v]);
    return d > 0.f ? cap_m : std::min(d, -std::numeric_limits<float>::denorm_min());
  }
  // Every sphere of a body lies in its enclosing sphere: enclosing spheres apart by the cap
  // keep every pair of their spheres at least that far apart.
  const float reach = posed.bound_radii_m[a] + posed.bound_radii_m[b] + 2.f * padding_m + cap_m;
  if ((posed.bound_centres[a] - posed.bound_centres[b]).squaredNorm() >= reach * reach) {
    return cap_m;
  }
  const auto& Xf = posed.Xf;
  const auto& trees = posed.trees;
  const auto& centres = posed.centres;
  const auto& first = posed.first;
  float slack = cap_m;
  // Only the spheres of each body that come within reach of the other's enclosing sphere
  // can come within reach of one of its spheres (each lies inside it): of the tube's 17
  // and the forearm's 9, a few near the wrist.
  std::array<int, PosedSpheres::kMaxCoarse> near_b;
  int num_near_b = 0;
  for (int j = first[b]; j < first[b + 1]; ++j) {
    const float r =
        posed.bound_radii_m[a] + trees[b]->coarse[j - first[b]].radius_m + 2.f * padding_m + cap_m;
    if ((centres[j] - posed.bound_centres[a]).squaredNorm() < r * r) near_b[num_near_b++] = j;
  }
  thread_local std::vector<Eigen::Vector3f> leaves_b;  // b's leaves in base, reused
  for (int i = first[a]; i < first[a + 1]; ++i) {
    const Sphere& si = trees[a]->coarse[i - first[a]];
    const float reach_b = si.radius_m + posed.bound_radii_m[b] + 2.f * padding_m + slack;
    if ((centres[i] - posed.bound_centres[b]).squaredNorm() >= reach_b * reach_b) continue;
    for (int n = 0; n < num_near_b; ++n) {
      const int j = near_b[n];
      const Sphere& sj = trees[b]->coarse[j - first[b]];
      const float r = si.radius_m + sj.radius_m + 2.f * padding_m;
      const float reach = r + slack;
      const float d2 = (centres[i] - centres[j]).squaredNorm();
      if (d2 >= reach * reach) continue;
      if (d2 >= r * r) {
        slack = std::sqrt(d2) - r;
        continue;
      }
      // The coarse spheres touch: compare their leaves, b's posed once (a coarse sphere of a
      // wrist or the shoulder holds 50-100 of them).
      const Leaves li = LeavesOf(*trees[a], si), lj = LeavesOf(*trees[b], sj);
      const std::size_t num_y = static_cast<std::size_t>(lj.end - lj.begin);
      if (leaves_b.size() < num_y) leaves_b.resize(num_y);
      for (std::size_t k = 0; k < num_y; ++k) leaves_b[k] = Xf[b] * lj.begin[k].center_B;
      for (const Sphere* x = li.begin; x != li.end; ++x) {
        const Eigen::Vector3f cx = Xf[a] * x->center_B;
        for (std::size_t k = 0; k < num_y; ++k) {
          const float ry = x->radius_m + lj.begin[k].radius_m + 2.f * padding_m;
          const float reach_y = ry + slack;
          const float e2 = (cx - leaves_b[k]).squaredNorm();
          if (e2 >= reach_y * reach_y) continue;
          slack = std::sqrt(e2) - ry;
          if (slack < 0.f) return slack;
        }
      }
    }
  }
  return slack;
}

float FastChecker::TcpInsideWorkspace(const BodyPoses& X) const {
  const Eigen::AlignedBox3d& box = cell_.tcp_workspace_Base();
  if (box.isEmpty()) return std::numeric_limits<float>::infinity();
  const Eigen::Vector3d p = X[kBodyTool] * robot_.gripper().X_ToolTcp.translation();
  return static_cast<float>(std::min((p - box.min()).minCoeff(), (box.max() - p).minCoeff()));
}

template <FastChecker::RunMode kMode>
float FastChecker::Run(const JointVector& q_rad, const CarriedItem* carried, float padding_m,
                       float cap_m, CollisionReport* report) const {
  constexpr bool kExplain = kMode == RunMode::kExplain;
  BodyPoses X;
  robot_.ComputePoses(q_rad, carried, &X);
  const int num_bodies = carried ? kNumBodies : kNumArmBodies;
  const std::uint32_t all_obstacles = (1u << num_obstacles()) - 1u;
  // The smallest margin seen, capped; negative once something is hit.
  float slack = cap_m;
  auto hit = [&](int body, int which, const char* self_body, float clearance) {
    slack = std::min(slack, clearance);
    if constexpr (kExplain) {
      if (!report->in_collision || clearance < report->clearance_m) {
        report->in_collision = true;
        report->body = body;
        report->clearance_m = clearance + padding_m;
        report->obstacle = self_body ? std::string("self: ") + self_body : ObstacleName(which);
      }
    }
  };
  // The tcp inside the robot's workspace box, by the padding: no sphere, a point.
  if (const float inside = TcpInsideWorkspace(X) - padding_m; inside < slack) {
    if (inside < 0.f) {
      hit(kBodyTool, kObstacleWorkspace, nullptr, inside);
      if constexpr (!kExplain) return slack;
    } else {
      slack = inside;
    }
  }
  // Each body's spheres are posed when it is reached: a state that collides at the gripper
  // or the item needs the arm's not at all.
  PosedSpheres posed(robot_, arm_bounds_, X, carried, /*pose_centres=*/false);
  // IsFree only asks whether anything is hit: the triangles wait until nothing else is.
  DeferredContacts deferred;
  DeferredContacts* const defer = kMode == RunMode::kIsFree ? &deferred : nullptr;
  // From the carried item and the gripper down the arm: the bodies that reach into a bin are
  // the ones that hit, so a colliding state is found with fewer spheres read. The base (body
  // 0) is fixed to the pedestal; it is only checked against the moving bodies.
  for (int b = num_bodies - 1; b >= 1; --b) {
    const SphereTree& tree = *posed.trees[b];
    posed.PoseCentres(b);
    for (std::size_t i = 0; i < tree.coarse.size(); ++i) {
      const Sphere& s = tree.coarse[i];
      const Eigen::Vector3f& c = posed.centres[posed.first[b] + i];
      if (QuickMargin(c, s.radius_m + padding_m) >= slack) continue;
      int which = 0;
      std::uint32_t touching = 0;
      const float m = Margin(c, s.radius_m + padding_m, false, all_obstacles, &which, nullptr,
                             &touching, slack);
      if (m >= slack) continue;
      if (m >= 0.f) {
        slack = m;
        continue;
      }
      // The leaves are measured only against the obstacles their coarse sphere may touch.
      const Leaves leaves = LeavesOf(tree, s);
      for (const Sphere* leaf = leaves.begin; leaf != leaves.end; ++leaf) {
        const Eigen::Vector3f leaf_c = posed.Xf[b] * leaf->center_B;
        if (QuickMargin(leaf_c, leaf->radius_m + padding_m, touching) >= slack) continue;
        const float ml = Margin(leaf_c, leaf->radius_m + padding_m, true, touching, &which, defer);
        if (ml >= 0.f) {
          slack = std::min(slack, ml);
          continue;
        }
        hit(b, which, nullptr, ml);
        if constexpr (!kExplain) return slack;
        break;
      }
    }
  }
  posed.PoseCentres(0);
  const auto& pairs = robot_.self_pairs();
  for (std::size_t p = 0; p < pairs.size(); ++p) {
    if (pairs[p].second >= num_bodies) continue;
    // Two bodies close in on each other from both sides: half their distance each.
    const float d = SelfPairSlack(p, q_rad, posed, padding_m, std::max(0.f, 2.f * slack));
    if (d >= 0.f) {
      slack = std::min(slack, 0.5f * d);
      continue;
    }
    hit(pairs[p].first, 0, BodyName(pairs[p].second), d);
    if constexpr (!kExplain) return slack;
  }
  for (int k = 0; k < deferred.size; ++k) {
    const auto& contact = deferred.contacts[k];
    const float m = cell_.SurfaceDistance(contact.grid, contact.c, contact.r) - contact.r;
    if (m < 0.f) return m;
  }
  return slack;
}

Proximity FastChecker::Near(const JointVector& q_rad, const BodyPoses& X,
                            const CarriedItem* carried) const {
  const int num_bodies = carried ? kNumBodies : kNumArmBodies;
  const int num = num_obstacles();
  const std::uint32_t all_obstacles = (1u << num) - 1u;
  Proximity near;
  const PosedSpheres posed(robot_, arm_bounds_, X, carried);
  for (int b = 1; b < num_bodies; ++b) {
    const SphereTree& tree = *posed.trees[b];
    for (std::size_t i = 0; i < tree.coarse.size(); ++i) {
      const Sphere& s = tree.coarse[i];
      const Eigen::Vector3f& c = posed.centres[posed.first[b] + i];
      // Most coarse spheres are clear of everything at once; the others are looked at for
      // each obstacle on its own: the coarse sphere clear of it, or else every leaf.
      if (QuickMargin(c, s.radius_m) >= 0.f) continue;
      int which = 0;
      std::uint32_t touching = 0;
      if (Margin(c, s.radius_m, false, all_obstacles, &which, nullptr, &touching) >= 0.f) {
        continue;
      }
      for (int o = 0; o < num; ++o) {
        const std::uint32_t bit = 1u << o;
        if (!(touching & bit) || (near.near_obstacles[b] & bit)) continue;
        const Leaves leaves = LeavesOf(tree, s);
        for (const Sphere* leaf = leaves.begin; leaf != leaves.end; ++leaf) {
          if (Margin(posed.Xf[b] * leaf->center_B, leaf->radius_m, true, bit, &which) < 0.f) {
            near.near_obstacles[b] |= bit;
            break;
          }
        }
      }
    }
  }
  const auto& pairs = robot_.self_pairs();
  near.near_self.assign(pairs.size(), 0);
  for (std::size_t p = 0; p < pairs.size(); ++p) {
    if (pairs[p].second >= num_bodies) continue;
    near.near_self[p] = SelfPairSlack(p, q_rad, posed, 0.f, 0.f) < 0.f;
  }
  return near;
}

std::string FastChecker::ObstacleName(int obstacle) const {
  if (obstacle == kObstacleWorkspace) return "the workspace's bounds";
  if (obstacle == kObstacleFloor) return "floor";
  if (obstacle == kObstaclePedestal) return "pedestal";
  const auto& grids = cell_.grids();
  const int g = obstacle - kObstacleFirstMesh;
  if (g >= 0 && g < static_cast<int>(grids.size())) return grids[g].name;
  return "scan";
}

// ---------------------------------------------------------------------------------------
// Exact check

struct ExactChecker::Impl {
  const RobotGeometry& robot;
  const StaticCell& cell;
  FastChecker spheres;  // the broad phase
  bool sphere_broad_phase = true;
  std::shared_ptr<fcl::CollisionGeometryd> octree;
  // The fast check's obstacle number of each of the cell's FCL objects; the scan's.
  std::vector<int> cell_obstacle;
  int scan_obstacle = 0;

  Impl(const RobotGeometry& r, const StaticCell& c, const ScanObstacles* scan)
      : robot(r), cell(c), spheres(r, c, scan) {}

  static bool Collide(const fcl::CollisionGeometryd* a, const Eigen::Isometry3d& X_BaseA,
                      const fcl::CollisionGeometryd* b, const fcl::Transform3d& X_BaseB) {
    fcl::CollisionRequestd request;
    fcl::CollisionResultd result;
    fcl::collide(a, X_BaseA, b, X_BaseB, request, result);
    return result.isCollision();
  }
};

ExactChecker::ExactChecker(const RobotGeometry& robot, const StaticCell& cell,
                           const ScanObstacles* scan, bool sphere_broad_phase)
    : impl_(std::make_unique<Impl>(robot, cell, scan)) {
  Impl& m = *impl_;
  m.sphere_broad_phase = sphere_broad_phase;
  if (scan && scan->octree) {
    m.octree = std::make_shared<fcl::OcTreed>(scan->octree);
    m.octree->computeLocalAABB();
  }
  const auto& grids = cell.grids();
  for (const auto& object : cell.fcl().objects) {
    int obstacle = object.name == "floor" ? kObstacleFloor : kObstaclePedestal;
    for (std::size_t g = 0; g < grids.size(); ++g) {
      if (grids[g].name == object.name) obstacle = kObstacleFirstMesh + static_cast<int>(g);
    }
    m.cell_obstacle.push_back(obstacle);
  }
  m.scan_obstacle = kObstacleFirstMesh + static_cast<int>(grids.size());
}

ExactChecker::~ExactChecker() = default;

CollisionReport ExactChecker::Check(const JointVector& q_rad, const CarriedItem* carried) const {
  if (!q_rad.allFinite()) throw std::invalid_argument("ExactChecker: non-finite joints");
  const Impl& m = *impl_;
  BodyPoses X;
  m.robot.ComputePoses(q_rad, carried, &X);
  const int num_bodies = carried ? kNumBodies : kNumArmBodies;
  // Each body's geometry and its pose in base.
  std::array<const fcl::CollisionGeometryd*, kNumBodies> geometry{};
  std::array<Eigen::Isometry3d, kNumBodies> X_BaseGeometry;
  for (int i = 0; i < kNumArmBodies; ++i) {
    geometry[i] = m.robot.fcl_geometry(i).get();
    X_BaseGeometry[i] = i == kBodyTool ? X[i] * m.robot.X_ToolTube() : X[i];
  }
  std::shared_ptr<fcl::Boxd> item_box;
  if (carried) {
    item_box = std::make_shared<fcl::Boxd>(carried->box_Item.sizes());
    item_box->computeLocalAABB();
    geometry[kBodyItem] = item_box.get();
    X_BaseGeometry[kBodyItem] = X[kBodyItem] * Eigen::Translation3d(carried->box_Item.center());
  }
  Proximity near;
  if (m.sphere_broad_phase) {
    near = m.spheres.Near(q_rad, X, carried);
  } else {
    near.near_obstacles.fill(~0u);
    near.near_self.assign(m.robot.self_pairs().size(), 1);
  }
  CollisionReport report;
  auto hit = [&](int body, const std::string& obstacle) {
    report.in_collision = true;
    report.body = body;
    report.obstacle = obstacle;
    return report;
  };
  if (m.spheres.TcpInsideWorkspace(X) < 0.f) {
    return hit(kBodyTool, m.spheres.ObstacleName(kObstacleWorkspace));
  }
  const auto& objects = m.cell.fcl().objects;
  // From the gripper end back: the bodies that move most are the likeliest to hit.
  for (int b = num_bodies - 1; b >= 1; --b) {
    if (!geometry[b]) continue;
    for (std::size_t k = 0; k < objects.size(); ++k) {
      if (!(near.near_obstacles[b] & (1u << m.cell_obstacle[k]))) continue;
      if (Impl::Collide(geometry[b], X_BaseGeometry[b], objects[k].geometry.get(),
                        objects[k].X_BaseObject)) {
        return hit(b, objects[k].name);
      }
    }
    if (m.octree && (near.near_obstacles[b] & (1u << m.scan_obstacle)) &&
        Impl::Collide(geometry[b], X_BaseGeometry[b], m.octree.get(),
                      fcl::Transform3d::Identity())) {
      return hit(b, "scan");
    }
  }
  const auto& pairs = m.robot.self_pairs();
  for (std::size_t p = 0; p < pairs.size(); ++p) {
    const auto [a, b] = pairs[p];
    if (b >= num_bodies || !geometry[a] || !geometry[b] || !near.near_self[p]) continue;
    if (Impl::Collide(geometry[a], X_BaseGeometry[a], geometry[b], X_BaseGeometry[b])) {
      return hit(a, std::string("self: ") + BodyName(b));
    }
  }
  return report;
}

}  // namespace picking::planner
