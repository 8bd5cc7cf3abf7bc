#include "services/planner/core/collision_world.h"

#include <octomap/OcTree.h>

#include <algorithm>
#include <cmath>
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

// Squared distance from p to triangle abc (Ericson, Real-Time Collision Detection 5.1.5).
float PointTriangleDistance2(const Eigen::Vector3f& p, const Eigen::Vector3f& a,
                             const Eigen::Vector3f& b, const Eigen::Vector3f& c) {
  const Eigen::Vector3f ab = b - a, ac = c - a, ap = p - a;
  const float d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0.f && d2 <= 0.f) return ap.squaredNorm();
  const Eigen::Vector3f bp = p - b;
  const float d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0.f && d4 <= d3) return bp.squaredNorm();
  const float vc = d1 * d4 - d3 * d2;
  if (vc <= 0.f && d1 >= 0.f && d3 <= 0.f) {
    const float v = d1 / (d1 - d3);
    return (a + v * ab - p).squaredNorm();
  }
  const Eigen::Vector3f cp = p - c;
  const float d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0.f && d5 <= d6) return cp.squaredNorm();
  const float vb = d5 * d2 - d1 * d6;
  if (vb <= 0.f && d2 >= 0.f && d6 <= 0.f) {
    const float w = d2 / (d2 - d6);
    return (a + w * ac - p).squaredNorm();
  }
  const float va = d3 * d6 - d5 * d4;
  if (va <= 0.f && (d4 - d3) >= 0.f && (d5 - d6) >= 0.f) {
    const float w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return (b + w * (c - b) - p).squaredNorm();
  }
  const float denom = 1.f / (va + vb + vc);
  const float v = vb * denom, w = vc * denom;
  return (a + ab * v + ac * w - p).squaredNorm();
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
  std::vector<std::uint32_t> start;  // CSR: bucket b's triangles are index[start[b]..start[b+1])
  std::vector<std::uint32_t> index;

  Buckets(const world::TriangleMesh& mesh, const Eigen::Isometry3d& X_BaseMesh) {
    const Eigen::Isometry3f X = X_BaseMesh.cast<float>();
    Eigen::AlignedBox3f box;
    for (const auto& t : mesh.triangles) {
      triangles.push_back(
          {X * mesh.vertices[t[0]], X * mesh.vertices[t[1]], X * mesh.vertices[t[2]]});
      for (const auto& v : triangles.back()) box.extend(v);
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
  if (!(options_.grid_resolution_m > 0.0) || !(options_.surface_gap_m > 0.0)) {
    throw std::invalid_argument("StaticCell: grid resolution and surface gap must be > 0");
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
}

StaticCell::~StaticCell() = default;

// ---------------------------------------------------------------------------------------
// Fast check

FastChecker::FastChecker(const RobotGeometry& robot, const StaticCell& cell,
                         const ScanObstacles* scan)
    : robot_(robot), cell_(cell), scan_(scan) {}

bool FastChecker::IsFree(const JointVector& q_rad, const CarriedItem* carried,
                         float padding_m) const {
  return Run<false>(q_rad, carried, padding_m, nullptr);
}

CollisionReport FastChecker::Check(const JointVector& q_rad, const CarriedItem* carried,
                                   float padding_m) const {
  CollisionReport report;
  report.clearance_m = 1e3;
  Run<true>(q_rad, carried, padding_m, &report);
  return report;
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

template <bool kExplain>
bool FastChecker::Run(const JointVector& q_rad, const CarriedItem* carried, float padding_m,
                      CollisionReport* report) const {
  BodyPoses X;
  robot_.ComputePoses(q_rad, carried, &X);
  const int num_bodies = carried ? kNumBodies : kNumArmBodies;
  const float floor_z = static_cast<float>(cell_.floor_z_m());
  const Eigen::AlignedBox3f pedestal = cell_.pedestal_Base().cast<float>();
  const bool has_pedestal = !pedestal.isEmpty();
  const auto& grids = cell_.grids();
  // Smallest clearance minus radius over the obstacles; `which` names the worst one
  // (0 floor, 1 pedestal, 2 + i grid i, 2 + grids.size() the scan).
  // `exact`: where a static grid's bound cannot tell, measure the distance to the mesh's
  // triangles (done for leaf spheres, which are small).
  auto margin = [&](const Eigen::Vector3f& c, float r, int* which, bool exact) {
    float worst = c.z() - floor_z - r;
    *which = 0;
    if (has_pedestal) {
      const float d = BoxDistance(pedestal, c) - r;
      if (d < worst) worst = d, *which = 1;
    }
    for (std::size_t g = 0; g < grids.size(); ++g) {
      float d = grids[g].grid.Clearance(c);
      if (exact && d < r) d = cell_.SurfaceDistance(g, c, r);
      d -= r;
      if (d < worst) worst = d, *which = 2 + static_cast<int>(g);
    }
    if (scan_) {
      const float d = scan_->grid.Clearance(c) - r;
      if (d < worst) worst = d, *which = 2 + static_cast<int>(grids.size());
    }
    return worst;
  };
  bool free = true;
  auto hit = [&](int body, int which, const char* self_body, float clearance) {
    free = false;
    if constexpr (kExplain) {
      if (!report->in_collision || clearance < report->clearance_m) {
        report->in_collision = true;
        report->body = body;
        report->clearance_m = clearance + padding_m;
        if (self_body) {
          report->obstacle = std::string("self: ") + self_body;
        } else if (which == 0) {
          report->obstacle = "floor";
        } else if (which == 1) {
          report->obstacle = "pedestal";
        } else if (which - 2 < static_cast<int>(grids.size())) {
          report->obstacle = grids[which - 2].name;
        } else {
          report->obstacle = "scan";
        }
      }
    }
  };
  std::array<Eigen::Isometry3f, kNumBodies> Xf;
  std::array<const SphereTree*, kNumBodies> trees{};
  constexpr int kMaxCoarse = 256;
  Eigen::Vector3f centres[kMaxCoarse];
  int first[kNumBodies + 1] = {0};
  int n = 0;
  for (int b = 0; b < num_bodies; ++b) {
    first[b] = n;
    trees[b] = b == kBodyItem ? &carried->spheres_Item : &robot_.spheres(b);
    Xf[b] = X[b].cast<float>();
    for (const Sphere& s : trees[b]->coarse) {
      if (n == kMaxCoarse) throw std::logic_error("FastChecker: too many spheres");
      const Eigen::Vector3f c = Xf[b] * s.center_B;
      centres[n++] = c;
      // The base is fixed to the pedestal; it is only checked against the moving bodies.
      if (b == kBodyBase) continue;
      int which = 0;
      if (margin(c, s.radius_m + padding_m, &which, false) >= 0.f) continue;
      const Leaves leaves = LeavesOf(*trees[b], s);
      for (const Sphere* leaf = leaves.begin; leaf != leaves.end; ++leaf) {
        const float m = margin(Xf[b] * leaf->center_B, leaf->radius_m + padding_m, &which, true);
        if (m < 0.f) {
          hit(b, which, nullptr, m);
          if constexpr (!kExplain) return false;
          break;
        }
      }
    }
  }
  first[num_bodies] = n;
  for (const auto& [a, b] : robot_.self_pairs()) {
    if (b >= num_bodies) continue;
    if (const PairDistanceTable* table = robot_.pair_table(a, b)) {
      // No padding here: the padding covers travel in the workspace, and these two bodies
      // barely move relative to each other between checked states (wrist_1 and wrist_2
      // turn little there; MotionChecker spaces states by each joint's reach).
      const float d = table->LowerBound(q_rad[table->joint_u], q_rad[table->joint_v]);
      if (d <= 0.f) {
        hit(a, 0, BodyName(b), d);
        if constexpr (!kExplain) return false;
      }
      continue;
    }
    for (int i = first[a]; i < first[a + 1]; ++i) {
      const Sphere& si = trees[a]->coarse[i - first[a]];
      for (int j = first[b]; j < first[b + 1]; ++j) {
        const Sphere& sj = trees[b]->coarse[j - first[b]];
        const float r = si.radius_m + sj.radius_m + 2.f * padding_m;
        if ((centres[i] - centres[j]).squaredNorm() >= r * r) continue;
        // The coarse spheres touch: compare their leaves.
        const Leaves li = LeavesOf(*trees[a], si), lj = LeavesOf(*trees[b], sj);
        for (const Sphere* x = li.begin; x != li.end; ++x) {
          const Eigen::Vector3f cx = Xf[a] * x->center_B;
          for (const Sphere* y = lj.begin; y != lj.end; ++y) {
            const float ry = x->radius_m + y->radius_m + 2.f * padding_m;
            const float d2 = (cx - Xf[b] * y->center_B).squaredNorm();
            if (d2 < ry * ry) {
              hit(a, 0, BodyName(b), std::sqrt(d2) - ry);
              if constexpr (!kExplain) return false;
              goto next_pair;
            }
          }
        }
      }
    }
  next_pair:;
  }
  return free;
}

template bool FastChecker::Run<true>(const JointVector&, const CarriedItem*, float,
                                     CollisionReport*) const;
template bool FastChecker::Run<false>(const JointVector&, const CarriedItem*, float,
                                      CollisionReport*) const;

// ---------------------------------------------------------------------------------------
// Exact check

struct ExactChecker::Impl {
  const RobotGeometry& robot;
  const StaticCell& cell;
  // One collision object per body, built once (FCL computes a mesh's local bounds when the
  // object is made) and moved to each checked state.
  std::array<std::unique_ptr<fcl::CollisionObjectd>, kNumBodies> bodies;
  Eigen::Isometry3d X_ToolTube = Eigen::Isometry3d::Identity();
  Eigen::AlignedBox3d item_box;  // the box the item object was made for
  std::unique_ptr<fcl::CollisionObjectd> octree;

  Impl(const RobotGeometry& r, const StaticCell& c) : robot(r), cell(c) {}

  static bool Collide(const fcl::CollisionObjectd* a, const fcl::CollisionObjectd* b) {
    fcl::CollisionRequestd request;
    fcl::CollisionResultd result;
    fcl::collide(a, b, request, result);
    return result.isCollision();
  }
};

ExactChecker::ExactChecker(const RobotGeometry& robot, const StaticCell& cell,
                           const ScanObstacles* scan)
    : impl_(std::make_unique<Impl>(robot, cell)) {
  for (int i = 0; i < 7; ++i) {
    impl_->bodies[i] = std::make_unique<fcl::CollisionObjectd>(MakeMeshBvh(robot.link_mesh(i)));
  }
  if (robot.tube_length_m() > 1e-6) {
    impl_->bodies[kBodyTool] = std::make_unique<fcl::CollisionObjectd>(
        std::make_shared<fcl::Cylinderd>(robot.gripper().tube_radius_m, robot.tube_length_m()));
    impl_->X_ToolTube = robot.X_ToolTube();
  }
  if (scan && scan->octree) {
    impl_->octree =
        std::make_unique<fcl::CollisionObjectd>(std::make_shared<fcl::OcTreed>(scan->octree));
    impl_->octree->computeAABB();
  }
}

ExactChecker::~ExactChecker() = default;

CollisionReport ExactChecker::Check(const JointVector& q_rad, const CarriedItem* carried) const {
  if (!q_rad.allFinite()) throw std::invalid_argument("ExactChecker: non-finite joints");
  Impl& m = *impl_;
  BodyPoses X;
  m.robot.ComputePoses(q_rad, carried, &X);
  std::array<fcl::CollisionObjectd*, kNumBodies> bodies{};
  for (int i = 0; i < 7; ++i) {
    m.bodies[i]->setTransform(X[i]);
    m.bodies[i]->computeAABB();
    bodies[i] = m.bodies[i].get();
  }
  if (m.bodies[kBodyTool]) {
    m.bodies[kBodyTool]->setTransform(X[kBodyTool] * m.X_ToolTube);
    m.bodies[kBodyTool]->computeAABB();
    bodies[kBodyTool] = m.bodies[kBodyTool].get();
  }
  if (carried) {
    if (!m.bodies[kBodyItem] || !m.item_box.isApprox(carried->box_Item)) {
      m.bodies[kBodyItem] = std::make_unique<fcl::CollisionObjectd>(
          std::make_shared<fcl::Boxd>(carried->box_Item.sizes()));
      m.item_box = carried->box_Item;
    }
    m.bodies[kBodyItem]->setTransform(X[kBodyItem] *
                                      Eigen::Translation3d(carried->box_Item.center()));
    m.bodies[kBodyItem]->computeAABB();
    bodies[kBodyItem] = m.bodies[kBodyItem].get();
  }
  CollisionReport report;
  const int num_bodies = carried ? kNumBodies : kNumArmBodies;
  auto hit = [&](int body, const std::string& obstacle) {
    report.in_collision = true;
    report.body = body;
    report.obstacle = obstacle;
    return report;
  };
  // From the gripper end back: the bodies that move most are the likeliest to hit.
  for (int b = num_bodies - 1; b >= 1; --b) {
    if (!bodies[b]) continue;
    for (const auto& object : m.cell.fcl().objects) {
      if (Impl::Collide(bodies[b], object.object.get())) return hit(b, object.name);
    }
    if (m.octree && Impl::Collide(bodies[b], m.octree.get())) return hit(b, "scan");
  }
  for (const auto& [a, b] : m.robot.self_pairs()) {
    if (b >= num_bodies || !bodies[a] || !bodies[b]) continue;
    if (Impl::Collide(bodies[a], bodies[b])) return hit(a, std::string("self: ") + BodyName(b));
  }
  return report;
}

}  // namespace picking::planner
