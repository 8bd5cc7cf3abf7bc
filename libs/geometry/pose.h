#pragma once

#include <Eigen/Geometry>

#include <string_view>

namespace picking::geometry {

/// Default tolerance of ValidatePose: max |R^T R - I| entry and |det R - 1|.
inline constexpr double kRotationTolerance = 1e-6;
/// Largest accepted deviation of a quaternion's norm from 1 before it is normalised.
inline constexpr double kQuaternionNormTolerance = 1e-3;

/// True when `X_AB` is a rigid transform: finite entries, last row (0 0 0 1), rotation
/// orthonormal with determinant +1 within `tolerance`.
bool IsValidPose(const Eigen::Isometry3d& X_AB, double tolerance = kRotationTolerance);

/// Throws std::invalid_argument naming `field_name` (and what is wrong: NaN/inf entry,
/// non-orthonormal or reflecting rotation, bad last row) unless IsValidPose(X_AB, tolerance).
void ValidatePose(const Eigen::Isometry3d& X_AB, std::string_view field_name,
                  double tolerance = kRotationTolerance);

/// Builds X_AB from the position p_AB (metres) and the orientation quaternion q_AB.
/// The quaternion is normalised; it must be finite with a norm within
/// kQuaternionNormTolerance of 1, else std::invalid_argument naming `field_name` and its
/// .position or .orientation. The one check of a pose's quaternion (proto_convert uses it).
Eigen::Isometry3d FromTranslationQuaternion(const Eigen::Vector3d& p_AB,
                                            const Eigen::Quaterniond& q_AB,
                                            std::string_view field_name = "pose");

/// Position and unit quaternion of a pose; the quaternion has w >= 0 (one of the two
/// equivalent signs, chosen so that equal rotations give equal quaternions).
struct TranslationQuaternion {
  Eigen::Vector3d p_AB = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_AB = Eigen::Quaterniond::Identity();
};

/// Splits X_AB into its position and canonical unit quaternion. X_AB should be valid
/// (ValidatePose); the rotation is read as is.
TranslationQuaternion ToTranslationQuaternion(const Eigen::Isometry3d& X_AB);

/// Interpolates between two poses of the same frame B in A: position linearly, orientation by
/// spherical linear interpolation along the shorter arc. t = 0 gives X_AB0, t = 1 gives
/// X_AB1; t outside [0, 1] extrapolates. Throws std::invalid_argument when t is not finite.
Eigen::Isometry3d Interpolate(const Eigen::Isometry3d& X_AB0, const Eigen::Isometry3d& X_AB1,
                              double t);

/// |p_AB1 - p_AB0| in metres.
double TranslationDistance(const Eigen::Isometry3d& X_AB0, const Eigen::Isometry3d& X_AB1);

/// Angle in radians, in [0, pi], of the rotation taking the orientation of X_AB0 to that of
/// X_AB1 (the geodesic distance on SO(3)).
double RotationAngle(const Eigen::Isometry3d& X_AB0, const Eigen::Isometry3d& X_AB1);

/// Translation and rotation error of an estimate against a reference.
struct PoseError {
  double translation_m = 0.0;
  double rotation_rad = 0.0;
};
PoseError ComputePoseError(const Eigen::Isometry3d& X_AB_estimate,
                           const Eigen::Isometry3d& X_AB_reference);

}  // namespace picking::geometry
