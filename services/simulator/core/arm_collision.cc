#include "services/simulator/core/arm_collision.h"

#include <fcl/fcl.h>

#include <cmath>
#include <stdexcept>
#include <utility>
#include <vector>

namespace picking::simulator {
namespace {

using Bvh = fcl::BVHModel<fcl::OBBRSSd>;

std::shared_ptr<Bvh> MakeBvh(const world::TriangleMesh& mesh) {
  auto bvh = std::make_shared<Bvh>();
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

bool IsRigid(const Eigen::Isometry3d& X) {
  if (!X.matrix().allFinite()) return false;
  const Eigen::Matrix3d R = X.linear();
  return (R.transpose() * R - Eigen::Matrix3d::Identity()).norm() < 1e-6 &&
         std::abs(R.determinant() - 1.0) < 1e-6;
}

}  // namespace

struct ArmCollisionChecker::Impl {
  struct Obstacle {
    std::string name;
    std::unique_ptr<fcl::CollisionObjectd> object;
  };
  std::vector<Obstacle> obstacles;
  std::shared_ptr<const ur10::Ur10Kinematics> kinematics;
  std::array<std::shared_ptr<Bvh>, ur10::kNumLinks> links;
  std::shared_ptr<fcl::Cylinderd> tube;  // null for a tool too short to have a tube
  Eigen::Isometry3d X_ToolTube = Eigen::Isometry3d::Identity();
  mutable int carried_id = 0;
  mutable const world::TriangleMesh* carried_mesh = nullptr;
  mutable std::shared_ptr<Bvh> carried;

  // Name of the first obstacle `geometry` at X_BaseBody touches, or empty.
  std::string Hit(const std::shared_ptr<fcl::CollisionGeometryd>& geometry,
                  const Eigen::Isometry3d& X_BaseBody) const {
    fcl::CollisionObjectd body(geometry, X_BaseBody);
    for (const Obstacle& obstacle : obstacles) {
      fcl::CollisionRequestd request;
      fcl::CollisionResultd result;
      fcl::collide(&body, obstacle.object.get(), request, result);
      if (result.isCollision()) return obstacle.name;
    }
    return {};
  }
};

ArmCollisionChecker::ArmCollisionChecker(const world::CellModel& cell,
                                         const ur10::Ur10Kinematics& kinematics)
    : impl_(std::make_unique<Impl>()), gripper_(cell.config.gripper) {
  if (!(gripper_.tube_radius_m > 0.0) || !std::isfinite(gripper_.tube_radius_m)) {
    throw std::invalid_argument("gripper.tube_radius_m must be finite and > 0");
  }
  if (!(gripper_.cup_length_m >= 0.0) || !std::isfinite(gripper_.cup_length_m)) {
    throw std::invalid_argument("gripper.cup_length_m must be finite and >= 0");
  }
  if (!IsRigid(gripper_.X_ToolTcp)) {
    throw std::invalid_argument("gripper.X_ToolTcp must be a finite rigid transform");
  }
  impl_->kinematics = std::make_shared<ur10::Ur10Kinematics>(kinematics.model());
  auto add = [&](const std::string& name, const world::TriangleMesh& mesh,
                 const Eigen::Isometry3d& X_BaseObject) {
    if (mesh.empty()) return;
    auto object = std::make_unique<fcl::CollisionObjectd>(MakeBvh(mesh), X_BaseObject);
    object->computeAABB();
    impl_->obstacles.push_back({name, std::move(object)});
  };
  add("shelf", cell.shelf, cell.config.X_BaseShelf);
  add("tote", cell.tote, cell.config.X_BaseTote);
  add("table", cell.table, cell.config.X_BaseTable);
  for (int i = 0; i < ur10::kNumLinks; ++i) {
    impl_->links[i] = MakeBvh(kinematics.model().LoadCollisionMesh(static_cast<ur10::Link>(i)));
  }
  const Eigen::Vector3d p_ToolTcp = gripper_.X_ToolTcp.translation();
  const double length = p_ToolTcp.norm() - gripper_.cup_length_m;
  if (length > 1e-6) {
    impl_->tube = std::make_shared<fcl::Cylinderd>(gripper_.tube_radius_m, length);
    const Eigen::Vector3d axis = p_ToolTcp.normalized();
    impl_->X_ToolTube.linear() =
        Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), axis).toRotationMatrix();
    impl_->X_ToolTube.translation() = 0.5 * length * axis;
  }
}

ArmCollisionChecker::~ArmCollisionChecker() = default;

ArmCollision ArmCollisionChecker::Check(const ur10::JointVector& q_rad,
                                        const CarriedItem* carried) const {
  if (!q_rad.allFinite()) throw std::invalid_argument("ArmCollisionChecker: non-finite joints");
  if (carried && !carried->mesh) {
    throw std::invalid_argument("ArmCollisionChecker: carried item without a mesh");
  }
  ArmCollision out;
  auto report = [&](const std::string& body, const std::string& object) {
    out.in_collision = true;
    out.detail = body + " hits " + object;
    return out;
  };
  if (carried) {
    if (!impl_->carried || impl_->carried_id != carried->id ||
        impl_->carried_mesh != carried->mesh) {
      impl_->carried = MakeBvh(*carried->mesh);
      impl_->carried_id = carried->id;
      impl_->carried_mesh = carried->mesh;
    }
    const std::string hit = impl_->Hit(impl_->carried, carried->X_BaseItem);
    if (!hit.empty()) return report("carried item " + carried->name, hit);
  }
  const Eigen::Isometry3d X_BaseTool = impl_->kinematics->ForwardKinematics(q_rad);
  if (impl_->tube) {
    const std::string hit = impl_->Hit(impl_->tube, X_BaseTool * impl_->X_ToolTube);
    if (!hit.empty()) return report("gripper", hit);
  }
  const auto frames = impl_->kinematics->LinkFrames(q_rad);
  const ur10::Ur10Model& model = impl_->kinematics->model();
  for (int i = ur10::kNumLinks - 1; i >= 0; --i) {
    const auto link = static_cast<ur10::Link>(i);
    const std::string hit = impl_->Hit(impl_->links[i], frames[i] * model.X_LinkMesh(link));
    if (!hit.empty()) return report(ur10::LinkName(link), hit);
  }
  return out;
}

}  // namespace picking::simulator
