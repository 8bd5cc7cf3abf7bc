#pragma once

#include <Eigen/Geometry>

#include <memory>
#include <string>

#include "libs/ur10/kinematics.h"
#include "libs/world/cell_config.h"
#include "libs/world/mesh.h"

namespace picking::simulator {

/// The suction tool as a collision body: an aluminium tube along the flange's z axis from
/// the flange to the cup's lip.
struct ToolGeometry {
  /// Cup lip frame in the flange frame (+z out of the cup); its z offset is the tube length.
  Eigen::Isometry3d X_FlangeTool = Eigen::Isometry3d(Eigen::Translation3d(0.0, 0.0, 0.35));
  /// Radius of the tube and cup, metres (> 0).
  double radius_m = 0.02;
  /// The last part of the tube before the lip (the compliant cup) is left out of the check, so
  /// that a cup pressed onto a surface is contact, not collision. Metres (>= 0).
  double cup_length_m = 0.02;
};

/// What hits the cell first at one arm configuration.
struct ArmCollision {
  bool in_collision = false;
  /// "<body> hits <object>": body is a UR10 link name ("forearm", "wrist_3", ...), "tool" or
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
/// the suction tool (a cylinder, see ToolGeometry) and a carried item (its mesh) against the
/// static cell: shelf, tote and table. Items in the bins and the tote are not obstacles here
/// (a cup pressed onto an item is contact, modelled by the world's guarded move), and
/// self-collision is not checked. Not thread safe (caches the carried item's BVH).
class ArmCollisionChecker final {
 public:
  /// Loads the link meshes through `kinematics.model()`. Throws std::invalid_argument for a
  /// non-positive radius, a negative cup length or a non-rigid X_FlangeTool,
  /// std::runtime_error if a link mesh cannot be read.
  ArmCollisionChecker(const world::CellModel& cell, const ur10::Ur10Kinematics& kinematics,
                      const ToolGeometry& tool);
  ~ArmCollisionChecker();
  ArmCollisionChecker(const ArmCollisionChecker&) = delete;
  ArmCollisionChecker& operator=(const ArmCollisionChecker&) = delete;

  /// Checks the arm at joint positions `q_rad` (no limit check; must be finite) with an
  /// optional carried item. Bodies are tested from the tool back to the base, and the first
  /// hit is reported. Throws std::invalid_argument for non-finite joints or a carried item
  /// without a mesh.
  ArmCollision Check(const ur10::JointVector& q_rad, const CarriedItem* carried = nullptr) const;

  const ToolGeometry& tool() const { return tool_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  ToolGeometry tool_;
};

}  // namespace picking::simulator
