#include "services/simulator/core/physics_layout.h"

#include <btBulletDynamicsCommon.h>

#include <algorithm>
#include <cmath>
#include <optional>
#include <random>
#include <stdexcept>

#include "libs/apc/bins.h"
#include "libs/world/ray_scene.h"

namespace picking::simulator {

namespace {

// Each container is simulated in its own frame P: the container's frame moved to the centre
// of its free box (z up), so that coordinates stay small for Bullet's single precision.
btVector3 ToBt(const Eigen::Vector3d& v) { return btVector3(v.x(), v.y(), v.z()); }
Eigen::Vector3d FromBt(const btVector3& v) { return Eigen::Vector3d(v.x(), v.y(), v.z()); }

btTransform ToBt(const Eigen::Isometry3d& X) {
  const Eigen::Quaterniond q(X.linear());
  return btTransform(btQuaternion(q.x(), q.y(), q.z(), q.w()), ToBt(X.translation()));
}

Eigen::Isometry3d FromBt(const btTransform& X) {
  const btQuaternion q = X.getRotation();
  Eigen::Isometry3d out = Eigen::Isometry3d::Identity();
  // Renormalised in double precision, so that the pose is rigid to double accuracy.
  out.linear() = Eigen::Quaterniond(q.w(), q.x(), q.y(), q.z()).normalized().toRotationMatrix();
  out.translation() = FromBt(X.getOrigin());
  return out;
}

bool IsRigidPose(const Eigen::Isometry3d& X) {
  if (!X.matrix().allFinite()) return false;
  const Eigen::Matrix3d R = X.linear();
  return (R.transpose() * R - Eigen::Matrix3d::Identity()).norm() < 1e-6 && R.determinant() > 0;
}

}  // namespace

// One container and its walls as boxes, built once.
struct PhysicsContainer {
  std::string name;
  Eigen::Isometry3d X_BaseP = Eigen::Isometry3d::Identity();
  Eigen::AlignedBox3d release_P;  // where released items' boxes must lie (top: the ceiling)
  Eigen::AlignedBox3d contain_P;  // where settled items' boxes must lie
  Eigen::AlignedBox3d centre_P;   // where their centres must lie (the tote: below its rim)
  std::vector<std::unique_ptr<btBoxShape>> boxes;
  std::unique_ptr<btCompoundShape> shape;  // the boxes, static
};

struct PhysicsLayout::Impl {
  std::vector<PhysicsContainer> containers;

  const PhysicsContainer& Find(const std::string& name) const {
    for (const auto& c : containers) {
      if (c.name == name) return c;
    }
    throw LayoutError(name, "unknown bin or container");
  }
};

namespace {

// The static cell is boxes, not its triangle mesh: measured, items resting on the pod's mesh
// kept jittering (Bullet's convex-triangle contacts) and most layouts never came to rest;
// box-box contacts rest. The boxes follow the mesh: measured by rays, 3 cm thick.
constexpr double kWall = 0.03;

// Boxes this close count as touching when deciding what a removed item supported: contacts at
// rest are within Bullet's margins of each other.
constexpr double kLooseTouchM = 0.002;

void AddBox(PhysicsContainer* c, const Eigen::AlignedBox3d& box_P,
            const Eigen::Matrix3d& R = Eigen::Matrix3d::Identity()) {
  c->boxes.push_back(std::make_unique<btBoxShape>(ToBt(0.5 * box_P.sizes())));
  c->boxes.back()->setMargin(0.001);
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = R;
  X.translation() = box_P.center();
  c->shape->addChildShape(ToBt(X), c->boxes.back().get());
}

// The bin floor's height along x (the depth) on the bin's centre line, every 5 mm, as
// (x, z) in P; simplified to straight pieces within 0.5 mm.
std::vector<Eigen::Vector2d> FloorProfile(const world::RayScene& shelf_S,
                                          const world::BinGeometry& bin,
                                          const Eigen::Vector3d& centre_S) {
  std::vector<Eigen::Vector2d> samples;
  const double x_end = bin.opening_x_m;
  for (double x = bin.inner_S.min().x(); x < x_end + 2.5e-3; x += 0.005) {
    const double xs = std::min(x, x_end - 1e-4);
    const auto hit = shelf_S.Cast(Eigen::Vector3d(xs, centre_S.y(), bin.inner_S.max().z() - 0.01),
                                  -Eigen::Vector3d::UnitZ(), bin.height_m() + 0.05);
    const double z = hit ? hit->p_BaseHit.z() : bin.inner_S.min().z();
    samples.emplace_back(xs - centre_S.x(), z - centre_S.z());
  }
  // Douglas-Peucker: keep the sample farthest from the chord while it is off by > 0.5 mm.
  std::vector<bool> keep(samples.size(), false);
  keep.front() = keep.back() = true;
  std::vector<std::pair<std::size_t, std::size_t>> todo{{0, samples.size() - 1}};
  while (!todo.empty()) {
    const auto [a, b] = todo.back();
    todo.pop_back();
    const Eigen::Vector2d d = (samples[b] - samples[a]).normalized();
    std::size_t worst = a;
    double worst_off = 5e-4;
    for (std::size_t k = a + 1; k < b; ++k) {
      const Eigen::Vector2d v = samples[k] - samples[a];
      const double off = std::abs(v.x() * d.y() - v.y() * d.x());
      if (off > worst_off) worst_off = off, worst = k;
    }
    if (worst == a) continue;
    keep[worst] = true;
    todo.push_back({a, worst});
    todo.push_back({worst, b});
  }
  std::vector<Eigen::Vector2d> out;
  for (std::size_t k = 0; k < samples.size(); ++k) {
    if (keep[k]) out.push_back(samples[k]);
  }
  return out;
}

// A bin: its floor (one box per straight piece of the profile), side walls, back wall and
// ceiling; open at the front.
PhysicsContainer MakeBin(const world::BinGeometry& bin, const world::RayScene& shelf_S,
                         const Eigen::Isometry3d& X_BaseShelf, const SettleOptions& o) {
  PhysicsContainer c;
  c.name = bin.name;
  const Eigen::Vector3d centre_S = bin.inner_S.center();
  c.X_BaseP = X_BaseShelf * Eigen::Translation3d(centre_S);
  const Eigen::Vector3d lo = bin.inner_S.min() - centre_S, hi = bin.inner_S.max() - centre_S;
  const double front = bin.opening_x_m - centre_S.x();
  c.shape = std::make_unique<btCompoundShape>();
  const std::vector<Eigen::Vector2d> floor = FloorProfile(shelf_S, bin, centre_S);
  for (std::size_t k = 0; k + 1 < floor.size(); ++k) {
    const Eigen::Vector2d d = floor[k + 1] - floor[k];
    const double length = d.norm() + 0.002;  // overlapping a little: no seam between pieces
    const double angle = std::atan2(d.y(), d.x());
    const Eigen::Matrix3d R =
        Eigen::AngleAxisd(-angle, Eigen::Vector3d::UnitY()).toRotationMatrix();
    const Eigen::Vector2d mid = 0.5 * (floor[k] + floor[k + 1]);
    const Eigen::Vector3d n(-std::sin(angle), 0.0, std::cos(angle));  // up, out of the floor
    const Eigen::Vector3d centre = Eigen::Vector3d(mid.x(), 0.0, mid.y()) - 0.5 * kWall * n;
    const Eigen::Vector3d half(0.5 * length, 0.5 * bin.width_m() + kWall, 0.5 * kWall);
    AddBox(&c, Eigen::AlignedBox3d(centre - half, centre + half), R);
  }
  const double z0 = lo.z() - kWall, z1 = hi.z() + kWall;
  AddBox(&c,
         {Eigen::Vector3d(lo.x() - kWall, lo.y() - kWall, z0), Eigen::Vector3d(front, lo.y(), z1)});
  AddBox(&c,
         {Eigen::Vector3d(lo.x() - kWall, hi.y(), z0), Eigen::Vector3d(front, hi.y() + kWall, z1)});
  AddBox(&c, {Eigen::Vector3d(lo.x() - kWall, lo.y(), z0), Eigen::Vector3d(lo.x(), hi.y(), z1)});
  AddBox(&c, {Eigen::Vector3d(lo.x(), lo.y(), hi.z()), Eigen::Vector3d(front, hi.y(), z1)});
  // Releases start above the floor's highest point.
  double floor_top = lo.z();
  for (const auto& p : floor) floor_top = std::max(floor_top, p.y());
  c.release_P = Eigen::AlignedBox3d(
      Eigen::Vector3d(lo.x() + o.wall_margin_m, lo.y() + o.wall_margin_m, floor_top),
      Eigen::Vector3d(front - o.opening_margin_m, hi.y() - o.wall_margin_m,
                      hi.z() - o.wall_margin_m));
  const Eigen::Vector3d tol = Eigen::Vector3d::Constant(o.containment_tolerance_m);
  c.contain_P = Eigen::AlignedBox3d(lo - tol, Eigen::Vector3d(front, hi.y(), hi.z()) + tol);
  c.centre_P = Eigen::AlignedBox3d(lo, Eigen::Vector3d(front, hi.y(), hi.z()));
  return c;
}

// The tote: its inner box as the cell measured it from the mesh (CellModel::tote_inner_T);
// walls up to its rim.
PhysicsContainer MakeTote(const world::CellModel& cell, const SettleOptions& o) {
  const Eigen::AlignedBox3d& inner_T = cell.tote_inner_T();
  if (inner_T.isEmpty()) throw std::invalid_argument("PhysicsLayout: the cell's tote box is empty");
  const Eigen::Vector3d inner_lo = inner_T.min(), inner_hi = inner_T.max();
  PhysicsContainer c;
  c.name = "tote";
  const Eigen::Vector3d centre_T = 0.5 * (inner_lo + inner_hi);
  c.X_BaseP = cell.config.X_BaseTote * Eigen::Translation3d(centre_T);
  const Eigen::Vector3d lo = inner_lo - centre_T, hi = inner_hi - centre_T;
  c.shape = std::make_unique<btCompoundShape>();
  const double w = kWall;
  AddBox(&c, {Eigen::Vector3d(lo.x() - w, lo.y() - w, lo.z() - w),
              Eigen::Vector3d(hi.x() + w, hi.y() + w, lo.z())});
  AddBox(&c, {Eigen::Vector3d(lo.x() - w, lo.y() - w, lo.z()),
              Eigen::Vector3d(lo.x(), hi.y() + w, hi.z())});
  AddBox(&c, {Eigen::Vector3d(hi.x(), lo.y() - w, lo.z()),
              Eigen::Vector3d(hi.x() + w, hi.y() + w, hi.z())});
  AddBox(&c,
         {Eigen::Vector3d(lo.x(), lo.y() - w, lo.z()), Eigen::Vector3d(hi.x(), lo.y(), hi.z())});
  AddBox(&c,
         {Eigen::Vector3d(lo.x(), hi.y(), lo.z()), Eigen::Vector3d(hi.x(), hi.y() + w, hi.z())});
  const double top = hi.z() + o.tote_stack_height_m;
  c.release_P = Eigen::AlignedBox3d(
      Eigen::Vector3d(lo.x() + o.wall_margin_m, lo.y() + o.wall_margin_m, lo.z()),
      Eigen::Vector3d(hi.x() - o.wall_margin_m, hi.y() - o.wall_margin_m, top));
  const Eigen::Vector3d tol = Eigen::Vector3d::Constant(o.containment_tolerance_m);
  c.contain_P = Eigen::AlignedBox3d(lo - tol, Eigen::Vector3d(hi.x(), hi.y(), top) + tol);
  // An item is in the tote while its centre is below the rim (SimWorld's classification).
  c.centre_P = Eigen::AlignedBox3d(lo, hi);
  return c;
}

std::vector<PhysicsContainer> MakeContainers(const world::CellModel& cell, const SettleOptions& o) {
  world::RayScene shelf_S;
  shelf_S.Add(0, cell.shelf, Eigen::Isometry3d::Identity());
  shelf_S.Commit();
  std::vector<PhysicsContainer> out;
  for (const auto& bin : cell.bins)
    out.push_back(MakeBin(bin, shelf_S, cell.config.X_BaseShelf, o));
  out.push_back(MakeTote(cell, o));
  return out;
}

void ValidateOptions(const SettleOptions& o) {
  const double values[] = {o.time_step_s,
                           o.rest_linear_speed_m_per_s,
                           o.rest_angular_speed_rad_per_s,
                           o.rest_time_s,
                           o.friction,
                           o.density_kg_per_m3,
                           o.linear_damping,
                           o.angular_damping,
                           o.item_margin_m,
                           o.flat_probability,
                           o.yaw_jitter_rad,
                           o.max_tilt_rad,
                           o.drop_gap_m,
                           o.wall_margin_m,
                           o.opening_margin_m,
                           o.tote_stack_height_m,
                           o.containment_tolerance_m,
                           o.max_penetration_m};
  for (double v : values) {
    if (!std::isfinite(v)) throw std::invalid_argument("SettleOptions: a value is not finite");
  }
  if (!(o.time_step_s > 0) || o.solver_iterations < 1 || o.max_steps_per_item < 1 ||
      !(o.rest_linear_speed_m_per_s > 0) || !(o.rest_angular_speed_rad_per_s > 0) ||
      o.rest_time_s < 0 || o.friction < 0 || o.linear_damping < 0 || o.linear_damping > 1 ||
      o.angular_damping < 0 || o.angular_damping > 1 || o.yaw_jitter_rad < 0 ||
      !(o.density_kg_per_m3 > 0) || o.item_margin_m < 0 || o.candidates_per_item < 1 ||
      o.flat_probability < 0 || o.flat_probability > 1 || o.max_tilt_rad < 0 || o.drop_gap_m < 0 ||
      o.wall_margin_m < 0 || o.opening_margin_m < 0 || o.tote_stack_height_m < 0 ||
      o.containment_tolerance_m < 0 || !(o.max_penetration_m > 0) || o.attempts < 1) {
    throw std::invalid_argument(
        "SettleOptions: time step, speeds, density and counts must be positive, the rest "
        "non-negative, flat_probability in [0, 1]");
  }
}

// One item to drop: its model and its box.
struct DropItem {
  std::size_t index = 0;  // in the caller's list
  const world::ItemModel* model = nullptr;
  Eigen::Vector3d half;  // half extents of box_I
};

// A Bullet world for one container. Members are destroyed in reverse order: the world first,
// while the bodies, shapes and the machinery it points to still exist.
struct Sim {
  btDefaultCollisionConfiguration config;
  btCollisionDispatcher dispatcher{&config};
  btDbvtBroadphase broadphase;
  btSequentialImpulseConstraintSolver solver;
  std::vector<std::unique_ptr<btCollisionShape>> shapes;
  std::vector<std::unique_ptr<btRigidBody>> bodies;
  btDiscreteDynamicsWorld world{&dispatcher, &broadphase, &solver, &config};
  std::vector<btRigidBody*> dynamic;  // parallel to the dropped items, in drop order

  std::vector<const btRigidBody*> removed;  // taken out of `world` before its end

  ~Sim() {
    for (auto& b : bodies) {
      if (std::find(removed.begin(), removed.end(), b.get()) == removed.end()) {
        world.removeRigidBody(b.get());
      }
    }
  }

  void Remove(btRigidBody* body) {
    world.removeRigidBody(body);
    removed.push_back(body);
  }

  // Gravity, the solver's settings and the container's walls.
  void Init(const PhysicsContainer& c, const Eigen::Vector3d& gravity_P, const SettleOptions& o) {
    world.setGravity(btVector3(gravity_P.x(), gravity_P.y(), gravity_P.z()));
    world.getSolverInfo().m_numIterations = o.solver_iterations;
    world.getSolverInfo().m_splitImpulse = 1;  // resolve penetration without adding energy
    AddBody(c.shape.get(), 0.0, btTransform::getIdentity(), o);
  }

  // A dynamic item box (half sizes `half`, its centre at X_PB), one of `dynamic`.
  btRigidBody* AddItem(const Eigen::Vector3d& half, const btTransform& X_PB,
                       const SettleOptions& o) {
    auto box = std::make_unique<btBoxShape>(btVector3(half.x(), half.y(), half.z()));
    box->setMargin(std::min(o.item_margin_m, half.minCoeff() * 0.5));
    shapes.push_back(std::move(box));
    const double mass_kg = std::max(0.01, o.density_kg_per_m3 * 8 * half.prod());
    btRigidBody* body = AddBody(shapes.back().get(), mass_kg, X_PB, o);
    // Thin items falling off a pile must not pass through each other between steps.
    body->setCcdMotionThreshold(half.minCoeff());
    body->setCcdSweptSphereRadius(0.5 * half.minCoeff());
    dynamic.push_back(body);
    return body;
  }

  btRigidBody* AddBody(btCollisionShape* shape, double mass_kg, const btTransform& X_PB,
                       const SettleOptions& o) {
    btVector3 inertia(0, 0, 0);
    if (mass_kg > 0) shape->calculateLocalInertia(mass_kg, inertia);
    btRigidBody::btRigidBodyConstructionInfo info(mass_kg, nullptr, shape, inertia);
    info.m_startWorldTransform = X_PB;
    info.m_friction = o.friction;
    info.m_restitution = 0.0;
    info.m_linearDamping = o.linear_damping;
    info.m_angularDamping = o.angular_damping;
    bodies.push_back(std::make_unique<btRigidBody>(info));
    btRigidBody* body = bodies.back().get();
    // Rest is decided by SettleOptions' thresholds, not by Bullet's sleeping.
    body->setActivationState(DISABLE_DEACTIVATION);
    // Friction anchors keep resting contacts where they are: without them boxes creep and
    // turn slowly on each other and a pile never comes to rest.
    body->setCollisionFlags(body->getCollisionFlags() | btCollisionObject::CF_HAS_FRICTION_ANCHOR);
    world.addRigidBody(body);
    return body;
  }
};

// Why an attempt failed: names the item.
struct Failure {
  std::string what;
};

}  // namespace

PhysicsLayout::PhysicsLayout(const world::CellModel& cell, const world::ItemModelLibrary& models,
                             SettleOptions options)
    : models_(models), options_(options), impl_(std::make_unique<Impl>()) {
  ValidateOptions(options_);
  impl_->containers = MakeContainers(cell, options_);
}

PhysicsLayout::~PhysicsLayout() = default;

namespace {

// A release pose of an item's box: X_PB (B: the box's centre, item axes) and its lowest z.
struct Release {
  Eigen::Isometry3d X_PB = Eigen::Isometry3d::Identity();
  double z_bottom = 0.0;
};

// The highest static surface (cell or fixed item) under a 3 x 3 grid of the box's xy
// footprint, seen from `z_from` down; none if a ray misses (over a hole).
std::optional<double> StaticSupport(const Sim& sim, const Eigen::AlignedBox3d& box_P, double z_from,
                                    double z_to) {
  double support = -std::numeric_limits<double>::infinity();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      const double x = box_P.min().x() + (0.05 + 0.45 * i) * box_P.sizes().x();
      const double y = box_P.min().y() + (0.05 + 0.45 * j) * box_P.sizes().y();
      const btVector3 from(x, y, z_from), to(x, y, z_to);
      btCollisionWorld::ClosestRayResultCallback hit(from, to);
      hit.m_collisionFilterMask = btBroadphaseProxy::StaticFilter;
      sim.world.rayTest(from, to, hit);
      if (!hit.hasHit()) return std::nullopt;
      support = std::max(support, static_cast<double>(hit.m_hitPointWorld.z()));
    }
  }
  return support;
}

// A random orientation: a face down (the largest, or any), a yaw near a multiple of 90
// degrees, then a tilt about a random horizontal axis. `tidy`: the largest face down, square
// to the walls, not tilted.
Eigen::Matrix3d RandomOrientation(const SettleOptions& o, bool tidy, std::mt19937* rng) {
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  Eigen::Matrix3d R_face = Eigen::Matrix3d::Identity();
  if (tidy) {
    return Eigen::AngleAxisd(std::floor(unit(*rng) * 4) * M_PI / 2, Eigen::Vector3d::UnitZ())
        .toRotationMatrix();
  }
  if (unit(*rng) >= o.flat_probability) {
    const int face = std::min(5, static_cast<int>(unit(*rng) * 6));
    Eigen::Vector3d down_I = Eigen::Vector3d::Zero();
    down_I[face / 2] = face % 2 == 0 ? 1.0 : -1.0;
    R_face =
        Eigen::Quaterniond::FromTwoVectors(down_I, -Eigen::Vector3d::UnitZ()).toRotationMatrix();
  }
  // Square to the walls for half of the candidates: in a narrow bin a wide item fits only so.
  const double jitter = unit(*rng) < 0.5 ? 0.0 : (2 * unit(*rng) - 1) * o.yaw_jitter_rad;
  const double yaw = std::floor(unit(*rng) * 4) * M_PI / 2 + jitter;
  const double tilt_axis = unit(*rng) * 2 * M_PI;
  const double tilt = unit(*rng) * o.max_tilt_rad;
  const Eigen::Vector3d axis(std::cos(tilt_axis), std::sin(tilt_axis), 0.0);
  return (Eigen::AngleAxisd(tilt, axis) * Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()))
             .toRotationMatrix() *
         R_face;
}

// The release of a box turned by R with its centre over `xy`: on the highest static surface
// or body's bounding box under its footprint; none if a ray misses or it would reach above
// the container's ceiling.
std::optional<Release> ReleaseAt(const Sim& sim, const PhysicsContainer& c, const DropItem& item,
                                 const SettleOptions& o, const Eigen::Matrix3d& R,
                                 const Eigen::Vector2d& xy) {
  const Eigen::AlignedBox3d& region = c.release_P;
  const Eigen::Vector3d ext = R.cwiseAbs() * item.half;  // half sizes of the turned box
  const Eigen::AlignedBox3d foot(Eigen::Vector3d(xy.x() - ext.x(), xy.y() - ext.y(), 0),
                                 Eigen::Vector3d(xy.x() + ext.x(), xy.y() + ext.y(), 0));
  const std::optional<double> floor =
      StaticSupport(sim, foot, region.max().z(), region.min().z() - 0.1);
  if (!floor) return std::nullopt;
  double support = *floor;
  for (const btRigidBody* body : sim.dynamic) {
    btVector3 bmin, bmax;
    body->getAabb(bmin, bmax);
    if (bmax.x() < foot.min().x() || bmin.x() > foot.max().x() || bmax.y() < foot.min().y() ||
        bmin.y() > foot.max().y()) {
      continue;
    }
    support = std::max(support, static_cast<double>(bmax.z()));
  }
  const double z_bottom = support + o.drop_gap_m;
  if (z_bottom + 2 * ext.z() > region.max().z()) return std::nullopt;
  Release r;
  r.X_PB.linear() = R;
  r.X_PB.translation() = Eigen::Vector3d(xy.x(), xy.y(), z_bottom + ext.z());
  r.z_bottom = z_bottom;
  return r;
}

// The lowest of the candidate release poses whose box clears every body's bounding box and
// stays under the container's ceiling; none if no candidate does. `tidy`: see
// RandomOrientation.
std::optional<Release> LowestRelease(const Sim& sim, const PhysicsContainer& c,
                                     const DropItem& item, const SettleOptions& o, bool tidy,
                                     std::mt19937* rng) {
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const Eigen::AlignedBox3d& region = c.release_P;
  std::optional<Release> best;
  for (int k = 0; k < o.candidates_per_item; ++k) {
    const Eigen::Matrix3d R = RandomOrientation(o, tidy, rng);
    const Eigen::Vector3d ext = R.cwiseAbs() * item.half;
    const Eigen::Vector3d lo = region.min() + ext, hi = region.max() - ext;
    if (lo.x() > hi.x() || lo.y() > hi.y() || lo.z() > hi.z()) continue;
    const Eigen::Vector2d xy(lo.x() + unit(*rng) * (hi.x() - lo.x()),
                             lo.y() + unit(*rng) * (hi.y() - lo.y()));
    const std::optional<Release> r = ReleaseAt(sim, c, item, o, R, xy);
    if (r && (!best || r->z_bottom < best->z_bottom)) best = r;
  }
  return best;
}

// Where no random pose finds room: the item flat, square to the walls, pushed against the
// walls or against the bounding boxes of the items already in (1 mm apart), the lowest of
// those positions; a tight row of boxes that random positions seldom hit. No randomness.
std::optional<Release> PackedRelease(const Sim& sim, const PhysicsContainer& c,
                                     const DropItem& item, const SettleOptions& o) {
  constexpr double kGapM = 0.001;
  const Eigen::AlignedBox3d& region = c.release_P;
  std::optional<Release> best;
  for (const double yaw : {0.0, M_PI / 2}) {
    const Eigen::Matrix3d R = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    const Eigen::Vector3d ext = R.cwiseAbs() * item.half;
    const Eigen::Vector3d lo = region.min() + ext, hi = region.max() - ext;
    if (lo.x() > hi.x() || lo.y() > hi.y() || lo.z() > hi.z()) continue;
    std::vector<double> xs = {lo.x(), hi.x()}, ys = {lo.y(), hi.y()};
    for (const btRigidBody* body : sim.dynamic) {
      btVector3 bmin, bmax;
      body->getAabb(bmin, bmax);
      xs.push_back(bmax.x() + kGapM + ext.x());
      xs.push_back(bmin.x() - kGapM - ext.x());
      ys.push_back(bmax.y() + kGapM + ext.y());
      ys.push_back(bmin.y() - kGapM - ext.y());
    }
    for (const double x : xs) {
      for (const double y : ys) {
        if (x < lo.x() || x > hi.x() || y < lo.y() || y > hi.y()) continue;
        const std::optional<Release> r = ReleaseAt(sim, c, item, o, R, Eigen::Vector2d(x, y));
        if (r && (!best || r->z_bottom < best->z_bottom)) best = r;
      }
    }
  }
  return best;
}

// Steps until, over a window of rest_time_s, every dropped body moved less than the rest
// speeds allow (displacement, not velocity: contact jitter does not add up, creep does); a
// failure if the budget ends first, or a body falls out or stops being finite. With `lost`
// (parallel to the bodies), a body that falls out or stops being finite is taken out of the
// simulation and flagged there instead of failing.
std::optional<Failure> StepToRest(Sim* sim, const PhysicsContainer& c,
                                  const std::vector<DropItem>& dropped, const SettleOptions& o,
                                  int* steps, std::vector<bool>* lost = nullptr) {
  const int window = std::max(1, static_cast<int>(std::ceil(o.rest_time_s / o.time_step_s)));
  const double max_move_m = o.rest_linear_speed_m_per_s * window * o.time_step_s;
  const double max_turn_rad = o.rest_angular_speed_rad_per_s * window * o.time_step_s;
  std::vector<btTransform> start;
  for (const btRigidBody* body : sim->dynamic) start.push_back(body->getCenterOfMassTransform());
  for (int s = 1; s <= o.max_steps_per_item; ++s) {
    // maxSubSteps = 0: exactly one step of time_step_s, no interpolation.
    sim->world.stepSimulation(o.time_step_s, 0);
    ++*steps;
    if (s % window != 0) continue;
    bool at_rest = true;
    for (std::size_t i = 0; i < sim->dynamic.size(); ++i) {
      if (lost && (*lost)[i]) continue;
      const btTransform& X = sim->dynamic[i]->getCenterOfMassTransform();
      const std::string& name = dropped[i].model->item->name;
      if (lost && (!FromBt(X.getOrigin()).allFinite() ||
                   X.getOrigin().z() < c.contain_P.min().z() - 0.05)) {
        sim->Remove(sim->dynamic[i]);
        (*lost)[i] = true;
        continue;
      }
      if (!FromBt(X.getOrigin()).allFinite()) {
        return Failure{"'" + name + "' left the simulation (not finite)"};
      }
      if (X.getOrigin().z() < c.contain_P.min().z() - 0.05) {
        return Failure{"'" + name + "' fell out"};
      }
      const double turn = X.getRotation().angleShortestPath(start[i].getRotation());
      if ((X.getOrigin() - start[i].getOrigin()).length() > max_move_m || turn > max_turn_rad) {
        at_rest = false;
      }
      start[i] = X;
    }
    if (at_rest) return std::nullopt;
  }
  return Failure{"'" + dropped.back().model->item->name + "' did not come to rest in " +
                 std::to_string(o.max_steps_per_item) + " steps"};
}

// How deep two boxes (half sizes, poses of their centres) interpenetrate: the least overlap
// over the 15 separating axes; <= 0 when apart.
double BoxOverlap(const Eigen::Vector3d& ha, const Eigen::Isometry3d& Xa, const Eigen::Vector3d& hb,
                  const Eigen::Isometry3d& Xb) {
  const Eigen::Matrix3d A = Xa.linear(), B = Xb.linear();
  const Eigen::Vector3d d = Xb.translation() - Xa.translation();
  double least = std::numeric_limits<double>::infinity();
  const auto axis = [&](const Eigen::Vector3d& n) {
    const double ra = (A.transpose() * n).cwiseAbs().dot(ha);
    const double rb = (B.transpose() * n).cwiseAbs().dot(hb);
    least = std::min(least, ra + rb - std::abs(n.dot(d)));
  };
  for (int i = 0; i < 3; ++i) {
    axis(A.col(i));
    axis(B.col(i));
    for (int j = 0; j < 3; ++j) {
      const Eigen::Vector3d c = A.col(i).cross(B.col(j));
      if (c.norm() > 1e-6) axis(c.normalized());
    }
  }
  return least;
}

// The deepest contact at rest: between items, exactly from their boxes (Bullet's manifolds
// keep at most four points a pair and may miss the deepest); with the cell, from Bullet.
double MaxPenetration(Sim* sim, const std::vector<DropItem>& dropped) {
  sim->world.performDiscreteCollisionDetection();
  double deepest = 0.0;
  for (int m = 0; m < sim->dispatcher.getNumManifolds(); ++m) {
    const btPersistentManifold* manifold = sim->dispatcher.getManifoldByIndexInternal(m);
    for (int k = 0; k < manifold->getNumContacts(); ++k) {
      deepest = std::max(deepest, -static_cast<double>(manifold->getContactPoint(k).getDistance()));
    }
  }
  for (std::size_t i = 0; i < dropped.size(); ++i) {
    const Eigen::Isometry3d Xi = FromBt(sim->dynamic[i]->getCenterOfMassTransform());
    for (std::size_t j = i + 1; j < dropped.size(); ++j) {
      const Eigen::Isometry3d Xj = FromBt(sim->dynamic[j]->getCenterOfMassTransform());
      deepest = std::max(deepest, BoxOverlap(dropped[i].half, Xi, dropped[j].half, Xj));
    }
  }
  return deepest;
}

// A failure naming the first item whose box ends outside the container's box.
std::optional<Failure> CheckContained(const Sim& sim, const PhysicsContainer& c,
                                      const std::vector<DropItem>& dropped) {
  for (std::size_t i = 0; i < sim.dynamic.size(); ++i) {
    const Eigen::Isometry3d X_PB = FromBt(sim.dynamic[i]->getCenterOfMassTransform());
    const Eigen::Vector3d& h = dropped[i].half;
    if (!c.centre_P.contains(X_PB.translation())) {
      return Failure{"'" + dropped[i].model->item->name + "' ended outside " + c.name};
    }
    for (int corner = 0; corner < 8; ++corner) {
      const Eigen::Vector3d p_B((corner & 1 ? 1 : -1) * h.x(), (corner & 2 ? 1 : -1) * h.y(),
                                (corner & 4 ? 1 : -1) * h.z());
      if (!c.contain_P.contains(X_PB * p_B)) {
        return Failure{"'" + dropped[i].model->item->name + "' ended outside " + c.name};
      }
    }
  }
  return std::nullopt;
}

struct AttemptResult {
  std::optional<Failure> failure;
  std::vector<Eigen::Isometry3d> X_PB;  // parallel to the dropped items
  int steps = 0;
  double max_penetration_m = 0.0;
  double max_speed_m_per_s = 0.0;
};

// One try at settling `items` (in drop order) in `c` beside the fixed `existing` boxes.
// `packed`: each item goes where PackedRelease puts it when it finds a place (the last
// attempt: a pile of boxes in rows, which random drops seldom make).
AttemptResult SettleOnce(const PhysicsContainer& c, const std::vector<DropItem>& items,
                         const std::vector<std::pair<Eigen::Vector3d, Eigen::Isometry3d>>& fixed,
                         const Eigen::Vector3d& gravity_P, const SettleOptions& o,
                         std::seed_seq* seed, bool packed) {
  std::mt19937 rng(*seed);
  AttemptResult out;
  Sim sim;
  sim.Init(c, gravity_P, o);
  for (const auto& [half, X_PB] : fixed) {
    sim.shapes.push_back(std::make_unique<btBoxShape>(ToBt(half)));
    sim.AddBody(sim.shapes.back().get(), 0.0, ToBt(X_PB), o);
  }
  std::vector<DropItem> dropped;
  for (const DropItem& item : items) {
    std::optional<Release> release;
    if (packed) release = PackedRelease(sim, c, item, o);
    if (!release) release = LowestRelease(sim, c, item, o, false, &rng);
    // Where a random pose finds no room, a tidy one (flat, square to the walls) may, or one
    // pushed against the walls and the items already in.
    if (!release) release = LowestRelease(sim, c, item, o, true, &rng);
    if (!release) release = PackedRelease(sim, c, item, o);
    if (!release) {
      out.failure = Failure{"no room for '" + item.model->item->name + "' even stacked (" +
                            std::to_string(dropped.size()) + " of " + std::to_string(items.size()) +
                            " items in)"};
      return out;
    }
    sim.AddItem(item.half, ToBt(release->X_PB), o);
    dropped.push_back(item);
    out.failure = StepToRest(&sim, c, dropped, o, &out.steps);
    if (out.failure) return out;
  }
  out.failure = CheckContained(sim, c, dropped);
  if (out.failure) return out;
  out.max_penetration_m = MaxPenetration(&sim, dropped);
  if (out.max_penetration_m > o.max_penetration_m) {
    out.failure = Failure{"items interpenetrate by " + std::to_string(out.max_penetration_m * 1e3) +
                          " mm at rest"};
  }
  for (const btRigidBody* body : sim.dynamic) {
    out.X_PB.push_back(FromBt(body->getCenterOfMassTransform()));
    out.max_speed_m_per_s =
        std::max(out.max_speed_m_per_s, static_cast<double>(body->getLinearVelocity().length()));
  }
  return out;
}

}  // namespace

SettleResult PhysicsLayout::SettleIn(const std::string& container,
                                     const std::vector<std::string>& items,
                                     const std::vector<PlacedItem>& existing,
                                     std::uint32_t seed) const {
  const PhysicsContainer& c = impl_->Find(container);
  const Eigen::Isometry3d X_PBase = c.X_BaseP.inverse();
  std::vector<std::pair<Eigen::Vector3d, Eigen::Isometry3d>> fixed;
  for (const PlacedItem& p : existing) {
    if (!IsRigidPose(p.X_BaseItem)) {
      throw LayoutError(container, "pose of '" + p.name + "' is not a finite rigid transform");
    }
    const auto model = models_.Get(p.name);  // throws UnknownItemError
    fixed.push_back({0.5 * model->box_I.sizes(),
                     X_PBase * p.X_BaseItem * Eigen::Translation3d(model->box_I.center())});
  }
  // The largest footprints go first, so that wide flat items lie low and small ones end on
  // top and in the gaps (dropped last, a wide item finds no room above the others).
  std::vector<std::shared_ptr<const world::ItemModel>> models;
  std::vector<DropItem> order;
  for (std::size_t i = 0; i < items.size(); ++i) {
    models.push_back(models_.Get(items[i]));
    order.push_back({i, models.back().get(), 0.5 * models.back()->box_I.sizes()});
  }
  std::stable_sort(order.begin(), order.end(), [](const DropItem& a, const DropItem& b) {
    return a.half.x() * a.half.y() > b.half.x() * b.half.y();
  });
  // Gravity along the floor frame's -z (Base is upright in the cell, but need not be).
  const Eigen::Vector3d gravity_P = X_PBase.linear() * Eigen::Vector3d(0, 0, -9.81);

  SettleResult result;
  std::optional<Failure> failure;
  for (int attempt = 0; attempt < options_.attempts; ++attempt) {
    std::seed_seq seq{seed, static_cast<std::uint32_t>(attempt)};
    // Each retry drops the items more tidily; the last one flat, square and untilted, so a
    // refusal means that even a tidy pile does not fit.
    SettleOptions o = options_;
    if (options_.attempts > 1) {
      const double tidiness = static_cast<double>(attempt) / (options_.attempts - 1);
      o.flat_probability += (1.0 - o.flat_probability) * tidiness;
      o.max_tilt_rad *= 1.0 - tidiness;
      o.yaw_jitter_rad *= 1.0 - tidiness;
    }
    const bool last = options_.attempts > 1 && attempt == options_.attempts - 1;
    AttemptResult a = SettleOnce(c, order, fixed, gravity_P, o, &seq, last);
    result.steps += a.steps;
    if (a.failure) {
      failure = a.failure;
      ++result.retries;
      continue;
    }
    result.items.resize(items.size());
    for (std::size_t k = 0; k < order.size(); ++k) {
      const DropItem& d = order[k];
      result.items[d.index] = {
          items[d.index], container,
          c.X_BaseP * a.X_PB[k] * Eigen::Translation3d(-d.model->box_I.center())};
    }
    result.max_penetration_m = a.max_penetration_m;
    result.max_speed_m_per_s = a.max_speed_m_per_s;
    return result;
  }
  throw LayoutError(container, failure->what + " (" + std::to_string(items.size()) + " items, " +
                                   std::to_string(options_.attempts) + " attempts)");
}

SettleResult PhysicsLayout::Settle(const apc::Task& task, std::uint32_t seed) const {
  // Every name is checked before any work, so that the error names the first bad one.
  for (const auto& [bin, items] : task.bin_contents) {
    if (!apc::IsBinName(bin)) throw LayoutError(bin, "not a bin name");
    for (const auto& item : items) models_.catalogue().at(item);
  }
  for (const auto& item : task.tote_contents) models_.catalogue().at(item);

  SettleResult result;
  const auto add = [&result](const SettleResult& part) {
    result.items.insert(result.items.end(), part.items.begin(), part.items.end());
    result.steps += part.steps;
    result.retries += part.retries;
    result.max_penetration_m = std::max(result.max_penetration_m, part.max_penetration_m);
    result.max_speed_m_per_s = std::max(result.max_speed_m_per_s, part.max_speed_m_per_s);
  };
  std::uint32_t k = 0;
  for (const auto& [bin, items] : task.bin_contents) {
    ++k;
    if (!items.empty()) add(SettleIn(bin, items, {}, seed * 7919u + k));
  }
  if (!task.tote_contents.empty())
    add(SettleIn("tote", task.tote_contents, {}, seed * 7919u + 1000u));
  return result;
}

namespace {

// `X_PB` raised along `up_P` in 1 mm steps until the box `half` there overlaps none of the
// `others` boxes by more than 0.1 mm (resting contact is not an overlap); at most 0.5 m.
Eigen::Isometry3d LiftClear(const Eigen::Vector3d& half, Eigen::Isometry3d X_PB,
                            const std::vector<DropItem>& others,
                            const std::vector<Eigen::Isometry3d>& X_POthers,
                            const Eigen::Vector3d& up_P, std::size_t self) {
  constexpr double kStepM = 0.001, kMaxLiftM = 0.5, kTouchM = 1e-4;
  for (double lift = 0.0; lift < kMaxLiftM; lift += kStepM) {
    bool clear = true;
    for (std::size_t j = 0; j < others.size() && clear; ++j) {
      if (j != self) clear = BoxOverlap(half, X_PB, others[j].half, X_POthers[j]) <= kTouchM;
    }
    if (clear) return X_PB;
    X_PB.translation() += kStepM * up_P;
  }
  return X_PB;
}

// A sweep that ignores one body (the one being swept).
struct SweepIgnoring : btCollisionWorld::ClosestConvexResultCallback {
  SweepIgnoring(const btCollisionObject* self, const btVector3& from, const btVector3& to)
      : ClosestConvexResultCallback(from, to), self(self) {}
  bool needsCollision(btBroadphaseProxy* proxy) const override {
    if (static_cast<const btCollisionObject*>(proxy->m_clientObject) == self) return false;
    return ClosestConvexResultCallback::needsCollision(proxy);
  }
  const btCollisionObject* self;
};

// How far `body` (a box, at rest) falls along -up_P before it first touches the container or
// another item: from rest under gravity alone it moves straight down, so a sweep of its box
// finds the contact the solver will meet. Up to `max_m` when nothing is below.
double FallUntilContact(Sim* sim, btRigidBody* body, const Eigen::Vector3d& up_P, double max_m) {
  const btTransform from = body->getCenterOfMassTransform();
  btTransform to = from;
  to.setOrigin(from.getOrigin() - ToBt(max_m * up_P));
  SweepIgnoring sweep(body, from.getOrigin(), to.getOrigin());
  sim->world.updateAabbs();
  sim->world.convexSweepTest(static_cast<const btConvexShape*>(body->getCollisionShape()), from, to,
                             sweep);
  return sweep.hasHit() ? sweep.m_closestHitFraction * max_m : max_m;
}

}  // namespace

namespace {

// Which of the items lose their support when the box `removed_half` at X_PRemoved is taken
// away: those whose boxes touch it (within `touch_m`) with their centres above its lowest
// point, then, in turn, those touching a loose item with their centres above its centre.
// Items under it or merely beside it keep their support.
std::vector<bool> LooseItems(const std::vector<DropItem>& items,
                             const std::vector<Eigen::Isometry3d>& X_PB,
                             const Eigen::Vector3d& removed_half,
                             const Eigen::Isometry3d& X_PRemoved, const Eigen::Vector3d& up_P,
                             double touch_m) {
  std::vector<bool> loose(items.size(), false);
  std::vector<std::size_t> todo;
  const double removed_bottom =
      X_PRemoved.translation().dot(up_P) -
      (X_PRemoved.linear().transpose() * up_P).cwiseAbs().dot(removed_half);
  for (std::size_t i = 0; i < items.size(); ++i) {
    if (X_PB[i].translation().dot(up_P) > removed_bottom &&
        BoxOverlap(items[i].half, X_PB[i], removed_half, X_PRemoved) > -touch_m) {
      loose[i] = true;
      todo.push_back(i);
    }
  }
  while (!todo.empty()) {
    const std::size_t k = todo.back();
    todo.pop_back();
    for (std::size_t i = 0; i < items.size(); ++i) {
      if (!loose[i] && X_PB[i].translation().dot(up_P) > X_PB[k].translation().dot(up_P) &&
          BoxOverlap(items[i].half, X_PB[i], items[k].half, X_PB[k]) > -touch_m) {
        loose[i] = true;
        todo.push_back(i);
      }
    }
  }
  return loose;
}

}  // namespace

RestResult PhysicsLayout::SettleFrom(const std::string& container,
                                     const std::vector<PlacedItem>& items,
                                     const std::optional<PlacedItem>& removed,
                                     std::optional<std::size_t> released) const {
  const PhysicsContainer& c = impl_->Find(container);
  if (released && *released >= items.size()) {
    throw std::out_of_range("PhysicsLayout::Release: item " + std::to_string(*released) + " of " +
                            std::to_string(items.size()));
  }
  // Every input is checked before any work: a bad one changes nothing.
  const Eigen::Isometry3d X_PBase = c.X_BaseP.inverse();
  std::vector<PlacedItem> all = items;
  if (removed) all.push_back(*removed);
  std::vector<std::shared_ptr<const world::ItemModel>> models;
  std::vector<DropItem> boxes;
  std::vector<Eigen::Isometry3d> X_PB;  // box centres
  for (std::size_t i = 0; i < all.size(); ++i) {
    if (!IsRigidPose(all[i].X_BaseItem)) {
      throw LayoutError(container, "pose of '" + all[i].name + "' is not a finite rigid transform");
    }
    models.push_back(models_.Get(all[i].name));  // throws UnknownItemError
    boxes.push_back({i, models.back().get(), 0.5 * models.back()->box_I.sizes()});
    X_PB.push_back(X_PBase * all[i].X_BaseItem * Eigen::Translation3d(models[i]->box_I.center()));
  }
  const Eigen::Vector3d gravity_P = X_PBase.linear() * Eigen::Vector3d(0, 0, -9.81);
  const Eigen::Vector3d up_P = -gravity_P.normalized();

  RestResult result;
  result.loose.assign(items.size(), false);
  if (removed) {
    result.loose = LooseItems({boxes.begin(), boxes.end() - 1}, X_PB, boxes.back().half,
                              X_PB.back(), up_P, kLooseTouchM);
    boxes.pop_back();
    X_PB.pop_back();
  }
  if (released) {
    const std::size_t r = *released;
    const Eigen::Isometry3d lifted = LiftClear(boxes[r].half, X_PB[r], boxes, X_PB, up_P, r);
    result.release_lift_m = (lifted.translation() - X_PB[r].translation()).norm();
    X_PB[r] = lifted;
    result.loose[r] = true;
  }
  // The loose items are bodies; the others, fixed obstacles that keep their poses exactly.
  Sim sim;
  sim.Init(c, gravity_P, options_);
  std::vector<DropItem> moving;
  for (std::size_t i = 0; i < boxes.size(); ++i) {
    if (result.loose[i]) {
      sim.AddItem(boxes[i].half, ToBt(X_PB[i]), options_);
      moving.push_back(boxes[i]);
    } else {
      sim.shapes.push_back(std::make_unique<btBoxShape>(ToBt(boxes[i].half)));
      sim.AddBody(sim.shapes.back().get(), 0.0, ToBt(X_PB[i]), options_);
    }
  }
  if (released) {
    const std::size_t k = std::count(result.loose.begin(), result.loose.begin() + *released, true);
    // Far enough to pass the container's floor: a fall that meets nothing is a fall out.
    const double max_m = X_PB[*released].translation().dot(up_P) - c.contain_P.min().z() + 0.1;
    result.drop_height_m = FallUntilContact(&sim, sim.dynamic[k], up_P, std::max(max_m, 0.1));
  }
  std::vector<bool> lost(moving.size(), false);
  if (!moving.empty()) {
    result.at_rest = !StepToRest(&sim, c, moving, options_, &result.steps, &lost).has_value();
  } else {
    result.at_rest = true;
  }
  result.max_penetration_m = MaxPenetration(&sim, moving);
  result.left_container.assign(items.size(), false);
  for (std::size_t i = 0, k = 0; i < boxes.size(); ++i) {
    Eigen::Isometry3d X_PB_end = X_PB[i];
    if (result.loose[i]) {
      const Eigen::Isometry3d X = FromBt(sim.dynamic[k]->getCenterOfMassTransform());
      if (IsRigidPose(X)) X_PB_end = X;  // else it left the simulation as not finite
      result.left_container[i] = lost[k];
      ++k;
    }
    result.items.push_back(
        {items[i].name, container,
         result.loose[i] ? c.X_BaseP * X_PB_end * Eigen::Translation3d(-models[i]->box_I.center())
                         : items[i].X_BaseItem});
  }
  return result;
}

RestResult PhysicsLayout::Resettle(const std::string& container,
                                   const std::vector<PlacedItem>& items,
                                   const PlacedItem& removed) const {
  return SettleFrom(container, items, removed, std::nullopt);
}

RestResult PhysicsLayout::Release(const std::string& container,
                                  const std::vector<PlacedItem>& items,
                                  std::size_t released) const {
  return SettleFrom(container, items, std::nullopt, released);
}

std::optional<std::string> PhysicsLayout::ContainerUnder(const Eigen::Vector3d& half,
                                                         const Eigen::Isometry3d& X_BaseBox) const {
  for (const PhysicsContainer& c : impl_->containers) {
    const Eigen::Isometry3d X_PB = c.X_BaseP.inverse() * X_BaseBox;
    const Eigen::Vector3d ext = X_PB.linear().cwiseAbs() * half;
    const Eigen::Vector3d& p = X_PB.translation();
    const Eigen::AlignedBox3d& free = c.centre_P;
    const bool over = p.x() - ext.x() >= free.min().x() && p.x() + ext.x() <= free.max().x() &&
                      p.y() - ext.y() >= free.min().y() && p.y() + ext.y() <= free.max().y();
    const bool is_tote = c.name == "tote";
    if (over && p.z() > free.min().z() && (is_tote || p.z() < free.max().z())) return c.name;
  }
  return std::nullopt;
}

}  // namespace picking::simulator
