// RobotGeometry's choice of self-collision pairs: it samples configurations and checks the
// link meshes with FCL, so it lives beside the other FCL code of the library.

#include <algorithm>
#include <cmath>
#include <random>

#include "services/planner/core/fcl_mesh.h"
#include "services/planner/core/robot_geometry.h"

namespace picking::planner {

float PairDistanceTable::LowerBound(double q_u, double q_v) const {
  const double step = 2.0 * M_PI / n;
  auto node = [&](double q, int* index) {
    const double u = q / step;
    const double k = std::round(u);
    *index = static_cast<int>(((static_cast<long long>(k) % n) + n) % n);
    return std::abs(u - k) * step;  // radians from the node
  };
  int iu = 0, iv = 0;
  const double du = node(q_u, &iu), dv = node(q_v, &iv);
  return distance_m[iu * n + iv] - static_cast<float>(lipschitz_u_m * du + lipschitz_v_m * dv);
}

const PairDistanceTable* RobotGeometry::pair_table(int a, int b) const {
  for (const auto& t : pair_tables_) {
    if (t.body_a == a && t.body_b == b) return &t;
  }
  return nullptr;
}

void RobotGeometry::BuildPairTables(
    const std::array<std::shared_ptr<fcl::CollisionGeometry<double>>, kNumArmBodies>& geometry,
    const std::array<Eigen::Isometry3d, kNumArmBodies>& X_BodyGeometry) {
  // The forearm and wrist_2: their relative pose is set by wrist_1's and wrist_2's angles
  // (joints 3 and 4) alone.
  const int a = kBodyForearm, b = kBodyWrist2;
  if (std::find(self_pairs_.begin(), self_pairs_.end(), std::make_pair(a, b)) ==
      self_pairs_.end()) {
    return;
  }
  PairDistanceTable table;
  table.body_a = a;
  table.body_b = b;
  table.joint_u = 3;
  table.joint_v = 4;
  table.n = 120;  // 3 degree nodes
  // How far wrist_2's points move per radian: about joint 4 (wrist_2's own axis) at most
  // their distance from its origin; about joint 3 at most that plus the offset between the
  // two joints' frames.
  const ur10::Ur10Model& model = kinematics_.model();
  float r_b = 0.f;
  for (const auto& v : link_meshes_[b].vertices) r_b = std::max(r_b, v.norm());
  const float offset =
      static_cast<float>(model.X_ParentLink(ur10::Link::kWrist2).translation().norm());
  table.lipschitz_v_m = r_b;
  table.lipschitz_u_m = r_b + offset;
  table.distance_m.resize(table.n * table.n);
  JointVector q = JointVector::Zero();
  q << 0.0, -1.5, 1.5, 0.0, 0.0, 0.0;
  BodyPoses X;
  for (int iu = 0; iu < table.n; ++iu) {
    for (int iv = 0; iv < table.n; ++iv) {
      q[3] = 2.0 * M_PI * iu / table.n;
      q[4] = 2.0 * M_PI * iv / table.n;
      ComputePoses(q, nullptr, &X);
      fcl::CollisionObjectd oa(geometry[a], X[a] * X_BodyGeometry[a]);
      fcl::CollisionObjectd ob(geometry[b], X[b] * X_BodyGeometry[b]);
      fcl::DistanceRequestd request;
      fcl::DistanceResultd result;
      fcl::distance(&oa, &ob, request, result);
      table.distance_m[iu * table.n + iv] = static_cast<float>(std::max(0.0, result.min_distance));
    }
  }
  pair_tables_.push_back(std::move(table));
}

namespace {

// A solid cylinder's circumscribed prism (so it holds the cylinder) from `p0_m` along the unit
// `axis` for `length_m`, appended to `mesh`; `radius_m` is the prism's circumradius.
void AddPrism(const Eigen::Vector3d& p0_m, const Eigen::Vector3d& axis, double length_m,
              double radius_m, world::TriangleMesh* mesh) {
  constexpr int kSides = 32;
  const Eigen::Vector3d u = axis.unitOrthogonal(), v = axis.cross(u);
  const auto base = static_cast<std::uint32_t>(mesh->vertices.size());
  for (int end = 0; end < 2; ++end) {
    for (int k = 0; k < kSides; ++k) {
      const double a = 2.0 * M_PI * k / kSides;
      const Eigen::Vector3d p =
          p0_m + end * length_m * axis + radius_m * (std::cos(a) * u + std::sin(a) * v);
      mesh->vertices.push_back(p.cast<float>());
    }
  }
  for (int end = 0; end < 2; ++end) {
    mesh->vertices.push_back((p0_m + end * length_m * axis).cast<float>());
  }
  const std::uint32_t c0 = base + 2 * kSides, c1 = c0 + 1;
  for (std::uint32_t k = 0; k < kSides; ++k) {
    const std::uint32_t k1 = (k + 1) % kSides;
    const std::uint32_t a0 = base + k, b0 = base + k1, a1 = base + kSides + k,
                        b1 = base + kSides + k1;
    mesh->triangles.push_back({a0, b0, b1});
    mesh->triangles.push_back({a0, b1, a1});
    mesh->triangles.push_back({c0, b0, a0});
    mesh->triangles.push_back({c1, a1, b1});
  }
}

}  // namespace

void RobotGeometry::BuildGripper() {
  const GripperGeometry& g = gripper_;
  const double r = g.tube_radius_m;
  SphereTree& spheres = spheres_[kBodyTool];
  spheres = SphereTree();
  fcl_geometry_[kBodyTool].reset();
  X_ToolTube_ = Eigen::Isometry3d::Identity();
  // Spheres along a cylinder from p0 along `axis` (unit) for `length`, of radius `radius`.
  auto add_spheres = [&](const Eigen::Vector3d& p0, const Eigen::Vector3d& axis, double length,
                         double radius) {
    Eigen::Isometry3d X_ToolAxis = Eigen::Isometry3d::Identity();
    X_ToolAxis.linear() =
        Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), axis).toRotationMatrix();
    X_ToolAxis.translation() = p0;
    for (Sphere s : CylinderSpheres(radius, length)) {
      s.center_B = X_ToolAxis.cast<float>() * s.center_B;
      spheres.coarse.push_back(s);
    }
    return X_ToolAxis;
  };
  if (!g.bent()) {
    // One cylinder from the flange to the cup's base.
    const Eigen::Vector3d p_ToolLip = g.X_ToolTcp.translation();
    const double length = std::max(0.0, p_ToolLip.norm() - g.cup_length_m);
    if (length <= 1e-6) return;
    const Eigen::Isometry3d X_ToolAxis =
        add_spheres(Eigen::Vector3d::Zero(), p_ToolLip.normalized(), length, r);
    X_ToolTube_ = X_ToolAxis * Eigen::Translation3d(0.0, 0.0, 0.5 * length);
    fcl_geometry_[kBodyTool] = std::make_shared<fcl::Cylinderd>(r, length);
    fcl_geometry_[kBodyTool]->computeLocalAABB();
    return;
  }
  // The tube to the joint, carried on by a radius past it (that covers the joint's knuckle,
  // a ball of the tube's radius), and the head from the joint to the cup's base: each a
  // 32-sided prism around its cylinder, the spheres around the prism.
  const double r_prism = r / std::cos(M_PI / 32);
  const Eigen::Vector3d p_J = g.p_ToolJoint();
  const Eigen::Vector3d z_Tcp = g.X_ToolTcp.linear().col(2);
  world::TriangleMesh mesh;
  mesh.name = "gripper";
  AddPrism(Eigen::Vector3d::Zero(), p_J.normalized(), p_J.norm() + r, r_prism, &mesh);
  AddPrism(p_J, z_Tcp, g.head_length_m - g.cup_length_m, r_prism, &mesh);
  add_spheres(Eigen::Vector3d::Zero(), p_J.normalized(), p_J.norm() + r, r_prism);
  add_spheres(p_J, z_Tcp, g.head_length_m - g.cup_length_m, r_prism);
  fcl_geometry_[kBodyTool] = MakeMeshBvh(mesh);
  fcl_geometry_[kBodyTool]->computeLocalAABB();
}

std::vector<std::pair<int, int>> RobotGeometry::SelectTouchingPairs(
    const std::vector<std::pair<int, int>>& candidates) const {
  std::array<Eigen::Isometry3d, kNumArmBodies> X_BodyGeometry;
  X_BodyGeometry.fill(Eigen::Isometry3d::Identity());
  X_BodyGeometry[kBodyTool] = X_ToolTube_;
  // 2,000 seeded samples, as MoveIt's setup assistant takes thousands: a pair that never
  // touches is kept apart by the joint limits and the chain's offsets; one that always
  // touches is built together.
  std::mt19937 rng(20160101);
  const JointVector lo = kinematics_.model().min_position_rad();
  const JointVector hi = kinematics_.model().max_position_rad();
  std::vector<int> touching(candidates.size(), 0);
  constexpr int kSamples = 2000;
  BodyPoses X;
  for (int s = 0; s < kSamples; ++s) {
    JointVector q;
    for (int j = 0; j < 6; ++j) q[j] = std::uniform_real_distribution<double>(lo[j], hi[j])(rng);
    ComputePoses(q, nullptr, &X);
    for (std::size_t k = 0; k < candidates.size(); ++k) {
      const auto [a, b] = candidates[k];
      fcl::CollisionObjectd oa(fcl_geometry_[a], X[a] * X_BodyGeometry[a]);
      fcl::CollisionObjectd ob(fcl_geometry_[b], X[b] * X_BodyGeometry[b]);
      fcl::CollisionRequestd request;
      fcl::CollisionResultd result;
      fcl::collide(&oa, &ob, request, result);
      touching[k] += result.isCollision();
    }
  }
  std::vector<std::pair<int, int>> pairs;
  for (std::size_t k = 0; k < candidates.size(); ++k) {
    if (touching[k] > 0 && touching[k] < kSamples * 95 / 100) pairs.push_back(candidates[k]);
  }
  return pairs;
}

void RobotGeometry::ChooseSelfPairs() {
  // Built once here, shared by every exact check (a BVH takes milliseconds to build).
  auto& geometry = fcl_geometry_;
  std::array<Eigen::Isometry3d, kNumArmBodies> X_BodyGeometry;
  for (int i = 0; i < 7; ++i) {
    geometry[i] = MakeMeshBvh(link_meshes_[i]);
    geometry[i]->computeLocalAABB();
    X_BodyGeometry[i] = Eigen::Isometry3d::Identity();
  }
  X_BodyGeometry[kBodyTool] = X_ToolTube_;
  std::vector<std::pair<int, int>> candidates;
  for (int a = 0; a < kNumArmBodies; ++a) {
    for (int b = a + 2; b < kNumArmBodies; ++b) {
      if (geometry[a] && geometry[b]) candidates.emplace_back(a, b);
    }
  }
  self_pairs_ = SelectTouchingPairs(candidates);
  BuildPairTables(geometry, X_BodyGeometry);
  // The carried item against every body but the gripper and wrist_3 it hangs from.
  for (int a = 0; a < kBodyWrist3; ++a) self_pairs_.emplace_back(a, kBodyItem);
}

}  // namespace picking::planner
