#pragma once

#include <Eigen/Geometry>

#include <string>

#include "services/planner/core/grasps.h"

namespace picking::planner {

/// Options of CheckTubeReach. Lengths in metres.
struct TubeReachOptions {
  /// From the cup's lip (the tcp) to the flange, along the tcp's z axis: the gripper's
  /// X_ToolTcp z (0.35 m in data/cell/default_cell.yaml).
  double lip_to_flange_m = 0.35;
  /// The compliant cup at the lip end, not a collision body (GripperGeometry::cup_length_m).
  double cup_length_m = 0.02;
  double tube_radius_m = 0.02;
  /// A head on a joint (GripperGeometry::head_length_m; 0: a straight tube) turned by
  /// head_angle_rad about the grasp tcp's x axis: the head lies along -approach from the lip
  /// to the joint, the rest of the tube from the joint toward the flange along the grasp
  /// tcp's -(0, sin a, cos a).
  double head_length_m = 0.0;
  double head_angle_rad = 0.0;
  /// The container's inner box is its free box (world::BinGeometry::inner_S: the closest wall
  /// and the lowest ceiling point over the whole depth), so the real wall may lie a little
  /// beyond a face; a tube that crosses a face by no more than this is left to the collision
  /// checks.
  double wall_tolerance_m = 0.01;
  /// The pod's walls do not reach the opening plane everywhere (their front edges are
  /// rounded and set back a little), so only the part of the tube's axis at least this far
  /// behind the opening plane is tested against the faces.
  double front_edge_m = 0.02;
};

/// Whether the tube, straight or bent at its head, can stand at a grasp.
struct TubeReachResult {
  bool reaches = true;
  /// The face the tube runs into: "ceiling", "floor", "back wall", "side wall" (a bin) or
  /// "side wall", "floor" (the tote); empty when it reaches.
  std::string wall;
  /// Distance from the lip along the tube at which the tube's surface meets that face, and
  /// how far past the face the tube reaches before it leaves the container, metres.
  double meets_at_m = 0.0;
  double penetration_m = 0.0;
  /// The grasp point's depth behind the opening plane and the container's inner size along
  /// the face's normal (a bin's height for its ceiling), metres.
  double depth_m = 0.0;
  double container_size_m = 0.0;
  /// Angle between the tube (-approach) and the opening direction, radians.
  double angle_rad = 0.0;
  /// One line a person can act on, e.g. "the straight 0.35 m tube, 60 deg from the opening
  /// direction, meets the ceiling 0.17 m from the cup: it cannot reach a '+z face' 0.21 m deep
  /// in a 0.19 m-high bin".
  std::string message;
};

/// The geometric test of a grasp before any search: at the grasp the tube lies along
/// -approach from the lip to the flange (or, bent, to the joint and on from there),
/// whatever the arm does, so it must leave the container through its opening before it
/// crosses one of the inner box's other faces (by more than wall_tolerance_m). A failure here means
/// every descent to the grasp ends in collision. `grasp` is in the base frame; the container's box
/// is its free inner box.
TubeReachResult CheckTubeReach(const GraspContainer& container, const GraspCandidate& grasp,
                               const TubeReachOptions& options = {});

}  // namespace picking::planner
