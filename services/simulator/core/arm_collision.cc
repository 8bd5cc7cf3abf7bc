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

// A piece of the gripper's tube: a cylinder in the flange frame.
struct TubePiece {
  std::shared_ptr<fcl::Cylinderd> shape;
  Eigen::Isometry3d X_ToolPiece = Eigen::Isometry3d::Identity();
};

// The gripper's tube without its cup: one cylinder when straight, the tube to the joint and
// the head when bent.
std::vector<TubePiece> TubePieces(const world::GripperConfig& gripper, double head_angle_rad) {
  // A cylinder from `p0` along the unit `axis` for `length`, in the flange frame.
  std::vector<TubePiece> pieces;
  auto add = [&](const Eigen::Vector3d& p0, const Eigen::Vector3d& axis, double length) {
    if (length <= 1e-6) return;
    TubePiece piece;
    piece.shape = std::make_shared<fcl::Cylinderd>(gripper.tube_radius_m, length);
    piece.X_ToolPiece.linear() =
        Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), axis).toRotationMatrix();
    piece.X_ToolPiece.translation() = p0 + 0.5 * length * axis;
    pieces.push_back(std::move(piece));
  };
  const Eigen::Isometry3d X_ToolTcp = gripper.X_ToolTcpAt(head_angle_rad);
  const Eigen::Vector3d z_Tcp = X_ToolTcp.linear().col(2);
  const Eigen::Vector3d p_ToolJoint = gripper.p_ToolJoint();
  if (gripper.head_length_m == 0.0 || head_angle_rad == 0.0) {
    const Eigen::Vector3d p_ToolTcp = X_ToolTcp.translation();
    add(Eigen::Vector3d::Zero(), p_ToolTcp.normalized(), p_ToolTcp.norm() - gripper.cup_length_m);
  } else {
    // The tube to the joint, on by a radius over the joint's knuckle, and the head.
    add(Eigen::Vector3d::Zero(), p_ToolJoint.normalized(),
        p_ToolJoint.norm() + gripper.tube_radius_m);
    add(p_ToolJoint, z_Tcp, gripper.head_length_m - gripper.cup_length_m);
  }
  return pieces;
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
  std::vector<TubePiece> tube_pieces;  // with the head straight
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
  impl_->tube_pieces = TubePieces(gripper_, 0.0);
}

ArmCollisionChecker::~ArmCollisionChecker() = default;

ArmCollision ArmCollisionChecker::Check(const ur10::JointVector& q_rad, const CarriedItem* carried,
                                        double head_angle_rad) const {
  if (!q_rad.allFinite()) throw std::invalid_argument("ArmCollisionChecker: non-finite joints");
  if (const std::string problem =
          world::HeadAngleProblem(head_angle_rad, gripper_.max_head_angle_rad);
      !problem.empty()) {
    throw std::invalid_argument("ArmCollisionChecker: head angle " + problem);
  }
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
  const std::vector<TubePiece> bent =
      head_angle_rad == 0.0 ? std::vector<TubePiece>{} : TubePieces(gripper_, head_angle_rad);
  for (const TubePiece& piece : head_angle_rad == 0.0 ? impl_->tube_pieces : bent) {
    const std::string hit = impl_->Hit(piece.shape, X_BaseTool * piece.X_ToolPiece);
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
