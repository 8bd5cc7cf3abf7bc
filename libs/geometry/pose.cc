#include "libs/geometry/pose.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>

namespace picking::geometry {
namespace {

// Empty when valid, else what is wrong.
std::string Problem(const Eigen::Isometry3d& X, double tolerance) {
  const Eigen::Matrix4d& m = X.matrix();
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) {
      if (!std::isfinite(m(r, c))) {
        std::ostringstream s;
        s << "entry (" << r << ", " << c << ") is " << m(r, c);
        return s.str();
      }
    }
  }
  if (m(3, 0) != 0.0 || m(3, 1) != 0.0 || m(3, 2) != 0.0 || m(3, 3) != 1.0) {
    return "last row is not (0 0 0 1)";
  }
  const Eigen::Matrix3d R = X.linear();
  const double orthonormality =
      (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (orthonormality > tolerance) {
    std::ostringstream s;
    s << "rotation is not orthonormal (max |R^T R - I| = " << orthonormality << ", tolerance "
      << tolerance << ")";
    return s.str();
  }
  const double det = R.determinant();
  if (std::abs(det - 1.0) > tolerance) {
    std::ostringstream s;
    s << "rotation has determinant " << det << " (a reflection, not a rotation)";
    return s.str();
  }
  return "";
}

}  // namespace

bool IsValidPose(const Eigen::Isometry3d& X_AB, double tolerance) {
  return Problem(X_AB, tolerance).empty();
}

void ValidatePose(const Eigen::Isometry3d& X_AB, std::string_view field_name, double tolerance) {
  const std::string problem = Problem(X_AB, tolerance);
  if (!problem.empty()) {
    throw std::invalid_argument(std::string(field_name) + ": invalid pose: " + problem);
  }
}

Eigen::Isometry3d FromTranslationQuaternion(const Eigen::Vector3d& p_AB,
                                            const Eigen::Quaterniond& q_AB,
                                            std::string_view field_name) {
  if (!p_AB.allFinite()) {
    throw std::invalid_argument(std::string(field_name) + ".position is not finite");
  }
  if (!q_AB.coeffs().allFinite()) {
    throw std::invalid_argument(std::string(field_name) + ".orientation is not finite");
  }
  const double norm = q_AB.norm();
  if (std::abs(norm - 1.0) > kQuaternionNormTolerance) {
    std::ostringstream s;
    s << field_name << ".orientation must be a unit quaternion (w, x, y, z); its norm is " << norm
      << " (within " << kQuaternionNormTolerance << " of 1)";
    throw std::invalid_argument(s.str());
  }
  Eigen::Isometry3d X_AB = Eigen::Isometry3d::Identity();
  X_AB.linear() = q_AB.normalized().toRotationMatrix();
  X_AB.translation() = p_AB;
  return X_AB;
}

TranslationQuaternion ToTranslationQuaternion(const Eigen::Isometry3d& X_AB) {
  TranslationQuaternion result;
  result.p_AB = X_AB.translation();
  Eigen::Quaterniond q(X_AB.linear());
  q.normalize();
  if (q.w() < 0.0) q.coeffs() = -q.coeffs();
  result.q_AB = q;
  return result;
}

Eigen::Isometry3d Interpolate(const Eigen::Isometry3d& X_AB0, const Eigen::Isometry3d& X_AB1,
                              double t) {
  if (!std::isfinite(t)) throw std::invalid_argument("Interpolate: t is not finite");
  const Eigen::Quaterniond q0(X_AB0.linear());
  const Eigen::Quaterniond q1(X_AB1.linear());
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  // Eigen's slerp takes the shorter arc.
  X.linear() = q0.normalized().slerp(t, q1.normalized()).normalized().toRotationMatrix();
  X.translation() = (1.0 - t) * X_AB0.translation() + t * X_AB1.translation();
  return X;
}

double TranslationDistance(const Eigen::Isometry3d& X_AB0, const Eigen::Isometry3d& X_AB1) {
  return (X_AB1.translation() - X_AB0.translation()).norm();
}

double RotationAngle(const Eigen::Isometry3d& X_AB0, const Eigen::Isometry3d& X_AB1) {
  const Eigen::Matrix3d R = X_AB0.linear().transpose() * X_AB1.linear();
  // atan2 of |axis * sin| and cos is accurate near 0 and pi, unlike acos of the trace.
  const double cos_angle = 0.5 * (R.trace() - 1.0);
  const Eigen::Vector3d axis_sin(R(2, 1) - R(1, 2), R(0, 2) - R(2, 0), R(1, 0) - R(0, 1));
  return std::atan2(0.5 * axis_sin.norm(), cos_angle);
}

PoseError ComputePoseError(const Eigen::Isometry3d& X_AB_estimate,
                           const Eigen::Isometry3d& X_AB_reference) {
  return {TranslationDistance(X_AB_estimate, X_AB_reference),
          RotationAngle(X_AB_estimate, X_AB_reference)};
}

}  // namespace picking::geometry
