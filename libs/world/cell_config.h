#pragma once

#include <Eigen/Geometry>

#include <stdexcept>
#include <string>
#include <vector>

#include "libs/world/mesh.h"
#include "libs/world/shelf_bins.h"

namespace picking::world {

/// Thrown for an unreadable or invalid cell configuration. The message names the file and the
/// field (e.g. "shelf.X_BaseShelf.orientation").
class CellConfigError final : public std::runtime_error {
 public:
  CellConfigError(const std::string& source, const std::string& field, const std::string& what);
  const std::string& field() const { return field_; }

 private:
  std::string field_;
};

/// The vacuum gripper on the UR10's flange: an aluminium tube along the flange's z axis from
/// the flange to the suction cup. Frames: `Tool` is the UR10 flange (tool0); `Tcp` is the
/// tool centre point, the centre of the cup's lip, +z out of the cup (the approach direction).
/// Every service that needs the tool centre point takes it from here.
///
/// The gripper may end in a head on a servo joint (the paper's tote gripper): the last
/// `head_length_m` of the tube, up to the lip, turns about the joint's axis, the x axis of
/// the tcp frame at the joint. At head angle 0 the gripper is straight and the tcp is
/// X_ToolTcp; at angle a it is X_ToolTcpAt(a): the head turned by a about that axis.
struct GripperConfig {
  /// Pose of the TCP in the flange frame with the head straight (rigid; metres).
  Eigen::Isometry3d X_ToolTcp = Eigen::Isometry3d::Identity();
  /// From the head's joint to the lip, along the tcp's z axis, metres: 0 for a straight
  /// gripper without a joint; otherwise longer than cup_length_m and shorter than the tube.
  double head_length_m = 0.0;
  /// The servo's range: head angles lie in [-max, +max], radians (0 without a joint).
  double max_head_angle_rad = 0.0;
  /// The tcp in the flange frame with the head at `head_angle_rad` (X_ToolTcp at 0).
  Eigen::Isometry3d X_ToolTcpAt(double head_angle_rad) const;
  /// The joint's centre in the flange frame (the tcp's origin at 0 for a straight gripper).
  Eigen::Vector3d p_ToolJoint() const;
  /// Radius of the tube and the cup, metres (> 0).
  double tube_radius_m = 0.0;
  /// Length of the compliant cup at the end of the tube, metres (>= 0 and shorter than the
  /// tube, whose length is |p_ToolTcp|). Collision checks leave it out, so that a cup pressed
  /// onto a surface is contact, not collision.
  double cup_length_m = 0.0;
};

/// Why a head angle cannot be set on a servo of range +-`max_head_angle_rad` (0: a gripper
/// without a joint): "" when it can, else e.g. "2 rad is outside the servo's range of
/// +-1.5708 rad". NaN and infinities are refused. Every service checks angles with this.
std::string HeadAngleProblem(double head_angle_rad, double max_head_angle_rad);

/// Layout of the static cell and the robot's gripper. Every pose is in the UR10 base frame
/// (Base), metres, except X_WorldBase and the gripper's X_ToolTcp. World is the floor frame
/// (z = 0 on the floor, z up).
struct CellConfig {
  std::string source;                                             ///< File it was read from.
  Eigen::Isometry3d X_WorldBase = Eigen::Isometry3d::Identity();  ///< Robot base on the floor.
  Eigen::Isometry3d X_BaseShelf = Eigen::Isometry3d::Identity();  ///< Shelf mesh frame.
  std::string shelf_mesh_path;  ///< Absolute path of the shelf mesh (STL, x out of the bins).
  Eigen::Isometry3d X_BaseTote = Eigen::Isometry3d::Identity();  ///< Tote mesh frame.
  std::string tote_mesh_path;  ///< Absolute path of the tote mesh (STL, z up, floor at z = 0).
  Eigen::Isometry3d X_BaseTable = Eigen::Isometry3d::Identity();  ///< Centre of the table top.
  Eigen::Vector3d table_size_m = Eigen::Vector3d::Zero();         ///< Table length, width, height.
  GripperConfig gripper;  ///< The gripper on the flange, with the tool centre point.

  /// Floor height in the base frame (metres).
  double floor_z_m() const { return X_WorldBase.inverse().translation().z(); }
};

/// Reads a cell configuration (YAML). Layout:
///
///     version: 1
///     robot_base: {X_WorldBase: <pose>}
///     shelf: {X_BaseShelf: <pose>, mesh: <path>}
///     tote:  {X_BaseTote: <pose>, mesh: <path>}
///     table: {X_BaseTable: <pose>, size_m: [l, w, h]}
///     gripper: {X_ToolTcp: <pose>, tube_radius_m: r, cup_length_m: c}
///
/// where <pose> is `{position: [x, y, z], orientation: [w, x, y, z]}` (metres; a unit
/// quaternion, norm within 1e-3 of 1, normalised on reading). Relative mesh paths are
/// resolved against the YAML file's folder and must exist. The gripper needs r > 0 and
/// 0 <= c < |p_ToolTcp| (the tube's length). Throws CellConfigError naming the file and the
/// field for a missing, mistyped or invalid entry (a missing section names the section, e.g.
/// "gripper"), or an unknown key.
CellConfig ReadCellConfig(const std::string& path);

/// As ReadCellConfig, from YAML text; relative paths are resolved against `base_dir`.
CellConfig ParseCellConfig(const std::string& yaml_text, const std::string& source_name,
                           const std::string& base_dir);

/// data/cell/default_cell.yaml under apc::DefaultDataDir().
std::string DefaultCellConfigPath();
/// cell/default_cell.yaml under `data_dir` (the servers' default for their `cell` setting;
/// DefaultCellConfigPath() for the default data folder).
std::string DefaultCellConfigPath(const std::string& data_dir);

/// The static cell's geometry as loaded from a configuration.
struct CellModel {
  CellConfig config;
  TriangleMesh shelf;             ///< In the shelf frame.
  TriangleMesh tote;              ///< In the tote frame.
  TriangleMesh table;             ///< In the table frame (top surface at z = 0).
  std::vector<BinGeometry> bins;  ///< Measured from `shelf`, in the shelf frame, A..L.
  /// The tote's free inner box in the tote frame (its inner walls and floor up to the rim),
  /// measured from `tote` by MeasureToteInner (shelf_bins.h).
  Eigen::AlignedBox3d measured_tote_inner_T;

  /// The bin called `name`; throws std::invalid_argument naming it if unknown.
  const BinGeometry& bin(const std::string& name) const;
  /// The tote's free inner box in the tote frame: measured_tote_inner_T.
  const Eigen::AlignedBox3d& tote_inner_T() const { return measured_tote_inner_T; }
};

/// Loads the meshes and measures the bins and the tote. Throws std::runtime_error on unreadable
/// meshes or a shelf mesh without 12 bins.
CellModel LoadCellModel(const CellConfig& config);

}  // namespace picking::world
