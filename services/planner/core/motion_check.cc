#include "services/planner/core/motion_check.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace picking::planner {

MotionChecker::MotionChecker(const FastChecker& checker, const MotionCheckOptions& options)
    : checker_(checker), options_(options) {
  if (!(options_.max_travel_m > 0.0) || !std::isfinite(options_.max_travel_m)) {
    throw std::invalid_argument("MotionCheckOptions.max_travel_m must be finite and > 0");
  }
  // A point of a body downstream of joint j moves at most |dq_j| times its distance from
  // joint j's axis, which is at most the distance from joint j's origin to the point. Bound
  // it by the lengths of the chain after joint j, the gripper and the largest sphere.
  const RobotGeometry& robot = checker_.robot();
  const ur10::DhParameters& dh = robot.kinematics().model().dh();
  double largest_sphere = 0.0;
  for (int b = 0; b < kNumArmBodies; ++b) {
    for (const Sphere& s : robot.spheres(b).coarse) {
      largest_sphere = std::max(largest_sphere, static_cast<double>(s.radius_m));
    }
  }
  // 0.2 m of slack for the link housings that reach past their frames (the elbow and
  // shoulder caps).
  const double tool = robot.gripper().X_ToolTcp.translation().norm() + largest_sphere + 0.2;
  const double wrist = std::abs(dh.d4) + std::abs(dh.d5) + std::abs(dh.d6);
  const double lengths[6] = {std::abs(dh.a2) + std::abs(dh.a3) + wrist + std::abs(dh.d1),
                             std::abs(dh.a2) + std::abs(dh.a3) + wrist,
                             std::abs(dh.a3) + wrist,
                             wrist,
                             std::abs(dh.d5) + std::abs(dh.d6),
                             std::abs(dh.d6)};
  for (int j = 0; j < 6; ++j) reach_arm_m_[j] = lengths[j] + tool;
}

double MotionChecker::reach_m(int joint, const CarriedItem* carried) const {
  double extra = 0.0;
  if (carried) {
    // The farthest corner of the item's spheres from the tcp.
    for (const Sphere& s : carried->spheres_Item.coarse) {
      const Eigen::Vector3d c_Tcp = carried->X_TcpItem * s.center_B.cast<double>();
      extra = std::max(extra, c_Tcp.norm() + s.radius_m);
    }
  }
  return reach_arm_m_[joint] + extra;
}

int MotionChecker::StatesOnSegment(const JointVector& a_rad, const JointVector& b_rad,
                                   const CarriedItem* carried) const {
  double travel = 0.0;
  for (int j = 0; j < 6; ++j) travel += std::abs(b_rad[j] - a_rad[j]) * reach_m(j, carried);
  return 1 + static_cast<int>(std::ceil(travel / options_.max_travel_m));
}

MotionCheckResult MotionChecker::CheckSegment(const JointVector& a_rad, const JointVector& b_rad,
                                              const CarriedItem* carried) const {
  if (!a_rad.allFinite() || !b_rad.allFinite()) {
    throw std::invalid_argument("MotionChecker: non-finite joints");
  }
  const int states = StatesOnSegment(a_rad, b_rad, carried);
  const float padding = static_cast<float>(0.5 * options_.max_travel_m);
  MotionCheckResult result;
  for (int i = 0; i < states; ++i) {
    const double t = states == 1 ? 1.0 : double(i) / (states - 1);
    const JointVector q = a_rad + t * (b_rad - a_rad);
    if (!checker_.IsFree(q, carried, padding)) {
      result.free = false;
      result.fraction_free = states == 1 ? 0.0 : double(std::max(0, i - 1)) / (states - 1);
      result.q_hit_rad = q;
      result.report = checker_.Check(q, carried, padding);
      return result;
    }
  }
  return result;
}

MotionCheckResult MotionChecker::CheckPath(const std::vector<JointVector>& path_rad,
                                           const CarriedItem* carried) const {
  MotionCheckResult result;
  if (path_rad.empty()) return result;
  if (path_rad.size() == 1) return CheckSegment(path_rad[0], path_rad[0], carried);
  for (std::size_t i = 0; i + 1 < path_rad.size(); ++i) {
    MotionCheckResult segment = CheckSegment(path_rad[i], path_rad[i + 1], carried);
    if (!segment.free) {
      segment.fraction_free = (i + segment.fraction_free) / (path_rad.size() - 1);
      return segment;
    }
  }
  return result;
}

}  // namespace picking::planner
