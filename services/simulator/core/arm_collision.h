#pragma once

#include <Eigen/Geometry>

#include <memory>
#include <string>

#include "libs/ur10/kinematics.h"
#include "libs/world/cell_config.h"
#include "libs/world/mesh.h"

namespace picking::simulator {

/// What hits the cell first at one arm configuration.
struct ArmCollision {
  bool in_collision = false;
  /// "<body> hits <object>": body is a UR10 link name ("forearm", "wrist_3", ...), "gripper" or
  /// "carried item <name>"; object is "shelf", "tote" or "table". Empty without collision.
  std::string detail;
};

/// An item held by the gripper, checked with the arm.
struct CarriedItem {
  int id = 0;  ///< Identifies the mesh for caching (the same id must mean the same mesh).
  std::string name;
  const world::TriangleMesh* mesh = nullptr;  ///< In the item frame.
  Eigen::Isometry3d X_BaseItem = Eigen::Isometry3d::Identity();
};

/// Collision test (FCL, exact mesh-mesh) of the UR10's links (ur_description collision meshes),
/// the gripper's tube (a cylinder from the flange toward the TCP, two when its head is bent:
/// the cell's
/// world::GripperConfig, without its last cup_length_m: a cup pressed onto a surface is
/// contact, not collision) and a carried item (its mesh) against the
/// static cell: shelf, tote and table. Items in the bins and the tote are not obstacles here
/// (a cup pressed onto an item is contact, modelled by the world's guarded move), and
/// self-collision is not checked. Not thread safe (caches the carried item's BVH).
class ArmCollisionChecker final {
 public:
  /// Loads the link meshes through `kinematics.model()`; the gripper is `cell.config.gripper`.
  /// Throws std::invalid_argument for a gripper with a non-positive radius, a negative cup
  /// length or a non-rigid X_ToolTcp, std::runtime_error if a link mesh cannot be read.
  ArmCollisionChecker(const world::CellModel& cell, const ur10::Ur10Kinematics& kinematics);
  ~ArmCollisionChecker();
  ArmCollisionChecker(const ArmCollisionChecker&) = delete;
  ArmCollisionChecker& operator=(const ArmCollisionChecker&) = delete;

  /// Checks the arm at joint positions `q_rad` (no limit check; must be finite) with an
  /// optional carried item. Bodies are tested from the tool back to the base, and the first
  /// hit is reported. Throws std::invalid_argument for non-finite joints or a carried item
  /// without a mesh.
  /// `head_angle_rad`: the gripper's head on its servo joint (world::GripperConfig), within
  /// its range (std::invalid_argument otherwise; only 0 for a straight gripper).
  ArmCollision Check(const ur10::JointVector& q_rad, const CarriedItem* carried = nullptr,
                     double head_angle_rad = 0.0) const;

  /// The gripper checked with the arm (the cell's).
  const world::GripperConfig& gripper() const { return gripper_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  world::GripperConfig gripper_;
};

}  // namespace picking::simulator
