#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <string>

#include "libs/world/mesh.h"

namespace picking::ur10 {

/// Number of joints of the UR10 (base, shoulder, elbow, wrist 1, wrist 2, wrist 3).
inline constexpr int kNumJoints = 6;

/// A joint vector in radians (positions), rad/s (velocities) or rad/s^2 (accelerations),
/// ordered base (shoulder_pan), shoulder (shoulder_lift), elbow, wrist 1, wrist 2, wrist 3.
using JointVector = Eigen::Matrix<double, kNumJoints, 1>;

/// Joint names in the order of a JointVector, as in joint_limits.yaml.
inline constexpr std::array<const char*, kNumJoints> kJointNames = {
    "shoulder_pan", "shoulder_lift", "elbow_joint", "wrist_1", "wrist_2", "wrist_3"};

/// Factory Denavit-Hartenberg parameters of the UR (standard DH convention,
/// alpha = [pi/2, 0, 0, pi/2, -pi/2, 0]), metres.
struct DhParameters {
  double d1 = 0.0;
  double a2 = 0.0;
  double a3 = 0.0;
  double d4 = 0.0;
  double d5 = 0.0;
  double d6 = 0.0;
};

/// Limits of one joint. Positions in rad, speed in rad/s, acceleration in rad/s^2, effort in Nm.
struct JointLimit {
  double min_position_rad = 0.0;
  double max_position_rad = 0.0;
  double max_velocity_rad_s = 0.0;
  double max_acceleration_rad_s2 = 0.0;
  double max_effort_nm = 0.0;
};

/// The links that carry a collision mesh, in chain order. kBase is fixed to the base frame,
/// link i (1..6) moves with joint i.
enum class Link { kBase = 0, kShoulder, kUpperArm, kForearm, kWrist1, kWrist2, kWrist3 };
inline constexpr int kNumLinks = 7;

/// Options of Ur10Model::Load.
struct Ur10ModelOptions {
  /// Joint acceleration limit used for every joint, rad/s^2. Universal Robots do not publish
  /// joint acceleration limits (joint_limits.yaml: "not publicly available"). 2.5 rad/s^2 is a
  /// conservative planning value: above URScript's movej default (1.4 rad/s^2) and well below
  /// what the controller accepts for a loaded UR10, so planned trajectories are executable.
  double max_acceleration_rad_s2 = 2.5;
};

/// The UR10 model: DH chain, URDF link chain (for the collision meshes), joint limits and the
/// collision mesh files, loaded from the ur_description yaml files in data/ur10/.
///
/// Frames: "Base" is the UR controller's base frame (= ur_description's `base` and
/// `base_link_inertia`: z up along the base joint axis, x pointing backwards from the cable
/// outlet). "Tool" is the flange frame `tool0` of the controller with a zero TCP offset (z out
/// of the flange).
class Ur10Model final {
 public:
  /// Loads default_kinematics.yaml, physical_parameters.yaml, joint_limits.yaml and
  /// visual_parameters.yaml from `data_dir` (e.g. PICKING_DATA_DIR "/ur10").
  /// @throws std::runtime_error naming the file and field on a missing or malformed value.
  static Ur10Model Load(const std::string& data_dir, const Ur10ModelOptions& options = {});

  /// Builds a model from explicit values (tests, calibrated robots). Validates: DH lengths
  /// finite, d4 > 0, d6 > 0, a2 and a3 non-zero; every limit finite with min < max,
  /// velocities and accelerations > 0. @throws std::invalid_argument naming the bad value.
  Ur10Model(const DhParameters& dh, const std::array<JointLimit, kNumJoints>& limits);

  const DhParameters& dh() const { return dh_; }
  const std::array<JointLimit, kNumJoints>& limits() const { return limits_; }
  JointVector min_position_rad() const;
  JointVector max_position_rad() const;
  JointVector max_velocity_rad_s() const;
  JointVector max_acceleration_rad_s2() const;

  /// Replaces the limits (same validation as the constructor).
  void set_limits(const std::array<JointLimit, kNumJoints>& limits);

  /// Pose of link `link`'s URDF frame in its parent link's frame at joint angle 0 (the joint
  /// origin from default_kinematics.yaml); identity for kBase. The joint of links 1..6 rotates
  /// about the z axis of the link frame.
  const Eigen::Isometry3d& X_ParentLink(Link link) const {
    return X_parent_link_[static_cast<int>(link)];
  }
  /// Pose of the URDF wrist_3_link frame's `tool0` child in wrist_3_link (fixed).
  const Eigen::Isometry3d& X_Wrist3Tool() const { return X_wrist3_tool_; }
  /// Pose of the collision mesh of `link` in the URDF link frame.
  const Eigen::Isometry3d& X_LinkMesh(Link link) const {
    return X_link_mesh_[static_cast<int>(link)];
  }
  /// Absolute path of the collision STL of `link` (empty if the model was built without files).
  const std::string& collision_mesh_path(Link link) const {
    return mesh_paths_[static_cast<int>(link)];
  }
  /// Reads the collision STL of `link`, vertices in metres in the mesh frame (see X_LinkMesh).
  /// @throws std::runtime_error if there is no file or it is not a valid STL.
  world::TriangleMesh LoadCollisionMesh(Link link) const;

  /// True if every entry of q is finite and within [min_position, max_position].
  bool WithinPositionLimits(const JointVector& q) const;
  /// Empty if WithinPositionLimits(q); else which joint is out and its range, e.g.
  /// "joint elbow_joint at 3.2 rad is outside [-3.14159, 3.14159] rad".
  std::string PositionLimitViolation(const JointVector& q) const;

 private:
  void ValidateLimits(const std::array<JointLimit, kNumJoints>& limits) const;

  DhParameters dh_;
  std::array<JointLimit, kNumJoints> limits_;
  std::array<Eigen::Isometry3d, kNumLinks> X_parent_link_;
  Eigen::Isometry3d X_wrist3_tool_ = Eigen::Isometry3d::Identity();
  std::array<Eigen::Isometry3d, kNumLinks> X_link_mesh_;
  std::array<std::string, kNumLinks> mesh_paths_;
};

/// Name of a link as in ur_description ("base", "shoulder", "upper_arm", ...).
const char* LinkName(Link link);

/// Reads a binary or ASCII STL file into a mesh (vertices shared where bit-identical).
/// @throws std::runtime_error naming the file on I/O or format errors.
world::TriangleMesh ReadStl(const std::string& path);

/// URDF roll-pitch-yaw rotation: Rz(yaw) * Ry(pitch) * Rx(roll).
Eigen::Matrix3d RotationFromRpy(double roll, double pitch, double yaw);

}  // namespace picking::ur10
