#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "libs/ur10/kinematics.h"
#include "libs/world/cell_config.h"
#include "libs/world/mesh.h"

namespace fcl {
template <typename S>
class CollisionGeometry;
}

namespace picking::planner {

using ur10::JointVector;

/// The moving bodies the planner checks: the UR10's seven links (ur10::Link order), the
/// gripper's tube and, when an item is held, the carried item.
enum Body : int {
  kBodyBase = 0,
  kBodyShoulder,
  kBodyUpperArm,
  kBodyForearm,
  kBodyWrist1,
  kBodyWrist2,
  kBodyWrist3,
  kBodyTool,  ///< The gripper tube, in the flange (`tool`) frame.
  kBodyItem,  ///< The carried item, in the item frame.
};
inline constexpr int kNumArmBodies = 8;  ///< Links and tool, without the item.
inline constexpr int kNumBodies = 9;

/// "base", "shoulder", ..., "wrist_3", "gripper", "carried item".
const char* BodyName(int body);

/// A sphere in a body's frame, metres. A coarse sphere may have finer children (a sphere
/// tree of two levels): together they enclose the same triangles, more tightly, and are only
/// looked at when the coarse sphere touches something.
struct Sphere {
  Eigen::Vector3f center_B = Eigen::Vector3f::Zero();
  float radius_m = 0.f;
  std::uint32_t first_child = 0;   ///< Index into the body's fine spheres.
  std::uint32_t num_children = 0;  ///< 0: a leaf (no finer spheres).
};

/// The spheres of one body: coarse ones and their children.
struct SphereTree {
  std::vector<Sphere> coarse;
  std::vector<Sphere> fine;
  std::size_t size() const { return coarse.size(); }
  bool empty() const { return coarse.empty(); }
};

/// The vacuum gripper on the flange: a tube from the flange to the suction cup, straight or
/// ending in a head on a servo joint (world::GripperConfig): the last `head_length_m` up to
/// the lip, turned by `head_angle_rad` about the tcp's x axis at the joint. For a given head
/// angle the gripper is rigid; AtHeadAngle gives it at another.
struct GripperGeometry {
  /// The suction cup's lip centre (`tcp`, +z out of the cup) in the flange frame (`tool`), with
  /// the head at head_angle_rad.
  Eigen::Isometry3d X_ToolTcp = Eigen::Isometry3d(Eigen::Translation3d(0.0, 0.0, 0.35));
  /// Radius of the tube and cup, metres (> 0).
  double tube_radius_m = 0.02;
  /// The compliant cup at the end of the tube, metres (>= 0): left out of the collision
  /// bodies, since a cup pressed onto a surface is contact, not collision.
  double cup_length_m = 0.02;
  /// From the head's joint to the lip along the tcp's z, metres: 0 for a straight gripper,
  /// else in (cup_length_m, tube length).
  double head_length_m = 0.0;
  /// The servo's range, radians (head angles in [-max, max]); 0 without a joint.
  double max_head_angle_rad = 0.0;
  /// The head's present angle, radians (0: straight).
  double head_angle_rad = 0.0;

  /// The cell description's gripper with its head at `head_angle_rad`.
  static GripperGeometry FromCell(const world::GripperConfig& config, double head_angle_rad = 0.0);
  /// This gripper with its head at `head_angle_rad`. Throws std::invalid_argument for an angle
  /// outside the servo's range (any angle but 0 without a joint).
  GripperGeometry AtHeadAngle(double head_angle_rad) const;
  /// The joint's centre in the flange frame (the lip's for a straight gripper).
  Eigen::Vector3d p_ToolJoint() const;
  /// No point of the gripper lies further than this from the flange's origin, metres.
  double reach_m() const { return p_ToolJoint().norm() + head_length_m; }
  /// Whether the head is turned off the tube's line (the tube is then two cylinders).
  bool bent() const;
};

/// A sphere enclosing every coarse sphere of `tree` (radius -1 for an empty tree): around
/// the centres' bounding box's centre, tight enough for an arm's elongated links.
Sphere EnclosingSphereOf(const SphereTree& tree);

/// Options of FitSpheres.
struct SphereFitOptions {
  /// A cluster of triangles is cut into pieces along its longest extent until that extent is
  /// at most this fraction of its second-longest one (unitless, > 0). Smaller: more, tighter
  /// spheres.
  double split_ratio = 0.6;
  /// Triangles are first cut until no edge is longer than this, metres (> 0), so that a long
  /// triangle can be shared out between clusters.
  double max_edge_m = 0.01;
  /// The children of a coarse sphere cover cubes of this edge, metres (> 0).
  double fine_cell_m = 0.04;
};

/// Spheres that together enclose every triangle of `mesh` (mapped into the body frame by
/// X_BodyMesh): each sphere's radius is the largest distance from its centre to a vertex of
/// its triangles, and a ball that holds a triangle's vertices holds the triangle.
SphereTree FitSpheres(const world::TriangleMesh& mesh, const Eigen::Isometry3d& X_BodyMesh,
                      const SphereFitOptions& options = {});

/// Spheres enclosing a solid cylinder of `radius_m` around the z axis from z = 0 to
/// `length_m`, each covering a slab no longer than `radius_m` (exact: radius
/// sqrt(r^2 + (slab / 2)^2)).
std::vector<Sphere> CylinderSpheres(double radius_m, double length_m);

/// An item held by the gripper: its bounding box in the item frame and where it sits
/// relative to the suction cup.
struct CarriedItem {
  std::string name;
  Eigen::AlignedBox3d box_Item;
  Eigen::Isometry3d X_TcpItem = Eigen::Isometry3d::Identity();
  SphereTree spheres_Item;  ///< Filled by MakeCarriedItem.
  Sphere bound_Item;        ///< EnclosingSphereOf(spheres_Item), filled by MakeCarriedItem.
};

/// A carried item with its enclosing spheres. Throws std::invalid_argument for an empty or
/// non-finite box or a non-rigid X_TcpItem.
CarriedItem MakeCarriedItem(const std::string& name, const Eigen::AlignedBox3d& box_Item,
                            const Eigen::Isometry3d& X_TcpItem);

/// A lower bound of the distance between two bodies whose relative pose depends on two joints
/// only (the forearm and wrist_2: wrist_1's and wrist_2's angles), tabulated over both
/// angles with FCL's exact mesh distance. Between table nodes the distance changes at most
/// by how far the bodies' points move (`lipschitz_m` per radian of each joint).
struct PairDistanceTable {
  int body_a = -1, body_b = -1;
  int joint_u = 0, joint_v = 0;   ///< Joint indices (0-5) the relative pose depends on.
  int n = 0;                      ///< Nodes per joint over one turn.
  std::vector<float> distance_m;  ///< n * n, at angles 2 pi i / n (row u, column v).
  float lipschitz_u_m = 0.f, lipschitz_v_m = 0.f;
  /// Lower bound of the bodies' distance at these joint angles, metres.
  float LowerBound(double q_u, double q_v) const;
};

/// Poses of the bodies in the base frame at one joint configuration.
using BodyPoses = std::array<Eigen::Isometry3d, kNumBodies>;

/// The arm and gripper as collision bodies: the link meshes (data/ur10/collision, in their
/// link frames), the gripper tube, enclosing spheres for each, and the body pairs that are
/// checked against each other (self-collision).
class RobotGeometry final {
 public:
  /// Loads the link meshes through `kinematics.model()`. Throws std::invalid_argument for bad
  /// gripper geometry, std::runtime_error if a mesh cannot be read.
  RobotGeometry(const ur10::Ur10Kinematics& kinematics, const GripperGeometry& gripper,
                const SphereFitOptions& fit = {});

  /// The same arm with another gripper (or the same gripper's head at another angle): the
  /// links' meshes, spheres, BVHs and distance tables shared, the gripper's bodies rebuilt,
  /// and the gripper paired with every link it could reach. Takes well under a millisecond
  /// plus the gripper's BVH. Throws std::invalid_argument for bad gripper geometry.
  RobotGeometry WithGripper(const GripperGeometry& gripper) const;

  const ur10::Ur10Kinematics& kinematics() const { return kinematics_; }
  const GripperGeometry& gripper() const { return gripper_; }
  /// Link mesh of body 0..6 in its link frame.
  const world::TriangleMesh& link_mesh(int body) const { return link_meshes_[body]; }
  /// Pose of the gripper's FCL geometry in the flange frame: a straight tube's centre (a
  /// cylinder along z from the flange to the cup's base); identity for a bent one (a mesh).
  const Eigen::Isometry3d& X_ToolTube() const { return X_ToolTube_; }
  /// FCL geometry of body 0..7 (the links' meshes as BVHs in their link frames; the gripper
  /// in X_ToolTube(): a cylinder, or for a bent head a BVH of the two cylinders' circumscribed
  /// prisms; null without a tube), shared by every exact check.
  const std::shared_ptr<fcl::CollisionGeometry<double>>& fcl_geometry(int body) const {
    return fcl_geometry_[body];
  }
  /// Spheres of bodies 0..7 in their body frames.
  const SphereTree& spheres(int body) const { return spheres_[body]; }
  std::size_t num_arm_spheres() const;

  /// Pairs of bodies (a < b) checked for self-collision, chosen as MoveIt's setup assistant
  /// does from seeded random configurations within the limits: not adjacent in the chain, and
  /// neither never (the joint limits keep them apart) nor always (built together) touching,
  /// by the exact meshes. The carried item is paired with every body but the gripper and
  /// wrist_3 it hangs from.
  const std::vector<std::pair<int, int>>& self_pairs() const { return self_pairs_; }
  /// Distance tables of the self pairs that have one (their spheres stay too close over
  /// much of the joint space to tell them apart).
  const std::vector<PairDistanceTable>& pair_tables() const { return pair_tables_; }
  /// The table of pair (a, b), or nullptr.
  const PairDistanceTable* pair_table(int a, int b) const;

  /// Body poses at `q_rad` (bodies 0..7; the item's, X_BaseTcp * X_TcpItem, if `carried`).
  void ComputePoses(const JointVector& q_rad, const CarriedItem* carried, BodyPoses* X) const;

  /// The tcp in base at q.
  Eigen::Isometry3d X_BaseTcp(const JointVector& q_rad) const {
    return kinematics_.ForwardKinematics(q_rad) * gripper_.X_ToolTcp;
  }

 private:
  void ChooseSelfPairs();
  // The candidates that touch in some but not nearly all of 2,000 seeded random states (FCL).
  std::vector<std::pair<int, int>> SelectTouchingPairs(
      const std::vector<std::pair<int, int>>& candidates) const;
  // The gripper's spheres and FCL geometry from gripper_.
  void BuildGripper();
  void BuildPairTables(
      const std::array<std::shared_ptr<fcl::CollisionGeometry<double>>, kNumArmBodies>& geometry,
      const std::array<Eigen::Isometry3d, kNumArmBodies>& X_BodyGeometry);

  ur10::Ur10Kinematics kinematics_;
  GripperGeometry gripper_;
  std::array<world::TriangleMesh, 7> link_meshes_;
  std::array<SphereTree, kNumArmBodies> spheres_;
  Eigen::Isometry3d X_ToolTube_ = Eigen::Isometry3d::Identity();
  std::array<std::shared_ptr<fcl::CollisionGeometry<double>>, kNumArmBodies> fcl_geometry_;
  std::vector<std::pair<int, int>> self_pairs_;
  std::vector<PairDistanceTable> pair_tables_;
};

}  // namespace picking::planner
