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

void RobotGeometry::ChooseSelfPairs() {
  // Built once here, shared by every exact check (a BVH takes milliseconds to build).
  auto& geometry = fcl_geometry_;
  std::array<Eigen::Isometry3d, kNumArmBodies> X_BodyGeometry;
  for (int i = 0; i < 7; ++i) {
    geometry[i] = MakeMeshBvh(link_meshes_[i]);
    geometry[i]->computeLocalAABB();
    X_BodyGeometry[i] = Eigen::Isometry3d::Identity();
  }
  if (tube_length_m_ > 1e-6) {
    geometry[kBodyTool] = std::make_shared<fcl::Cylinderd>(gripper_.tube_radius_m, tube_length_m_);
    geometry[kBodyTool]->computeLocalAABB();
    X_BodyGeometry[kBodyTool] = X_ToolTube_;
  }
  std::vector<std::pair<int, int>> candidates;
  for (int a = 0; a < kNumArmBodies; ++a) {
    for (int b = a + 2; b < kNumArmBodies; ++b) {
      if (geometry[a] && geometry[b]) candidates.emplace_back(a, b);
    }
  }
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
      fcl::CollisionObjectd oa(geometry[a], X[a] * X_BodyGeometry[a]);
      fcl::CollisionObjectd ob(geometry[b], X[b] * X_BodyGeometry[b]);
      fcl::CollisionRequestd request;
      fcl::CollisionResultd result;
      fcl::collide(&oa, &ob, request, result);
      touching[k] += result.isCollision();
    }
  }
  for (std::size_t k = 0; k < candidates.size(); ++k) {
    if (touching[k] > 0 && touching[k] < kSamples * 95 / 100) self_pairs_.push_back(candidates[k]);
  }
  BuildPairTables(geometry, X_BodyGeometry);
  // The carried item against every body but the gripper and wrist_3 it hangs from.
  for (int a = 0; a < kBodyWrist3; ++a) self_pairs_.emplace_back(a, kBodyItem);
}

}  // namespace picking::planner
