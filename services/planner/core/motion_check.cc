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
  if (!(options_.max_step_m >= options_.max_travel_m) || !std::isfinite(options_.max_step_m)) {
    throw std::invalid_argument("MotionCheckOptions.max_step_m must be finite and >= max_travel_m");
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
  const double tool = robot.gripper().reach_m() + largest_sphere + 0.2;
  const double wrist = std::abs(dh.d4) + std::abs(dh.d5) + std::abs(dh.d6);
  const double lengths[6] = {std::abs(dh.a2) + std::abs(dh.a3) + wrist + std::abs(dh.d1),
                             std::abs(dh.a2) + std::abs(dh.a3) + wrist,
                             std::abs(dh.a3) + wrist,
                             wrist,
                             std::abs(dh.d5) + std::abs(dh.d6),
                             std::abs(dh.d6)};
  for (int j = 0; j < 6; ++j) reach_arm_m_[j] = lengths[j] + tool;
}

namespace {

// How far the carried item's spheres reach beyond the tcp, metres (0 without an item).
double ItemReach_m(const CarriedItem* carried) {
  double extra = 0.0;
  if (carried) {
    // The farthest corner of the item's spheres from the tcp.
    for (const Sphere& s : carried->spheres_Item.coarse) {
      const Eigen::Vector3d c_Tcp = carried->X_TcpItem * s.center_B.cast<double>();
      extra = std::max(extra, c_Tcp.norm() + s.radius_m);
    }
  }
  return extra;
}

}  // namespace

double MotionChecker::reach_m(int joint, const CarriedItem* carried) const {
  return reach_arm_m_[joint] + ItemReach_m(carried);
}

double MotionChecker::Travel_m(const JointVector& a_rad, const JointVector& b_rad,
                               const CarriedItem* carried) const {
  const double item = ItemReach_m(carried);
  double travel = 0.0;
  for (int j = 0; j < 6; ++j) travel += std::abs(b_rad[j] - a_rad[j]) * (reach_arm_m_[j] + item);
  return travel;
}

int MotionChecker::StatesOnSegment(const JointVector& a_rad, const JointVector& b_rad,
                                   const CarriedItem* carried) const {
  return GridStates(Travel_m(a_rad, b_rad, carried));
}

int MotionChecker::GridStates(double travel_m) const {
  return 1 + static_cast<int>(std::ceil(travel_m / options_.max_travel_m));
}

MotionCheckResult MotionChecker::CheckSegment(const JointVector& a_rad, const JointVector& b_rad,
                                              const CarriedItem* carried) const {
  float slack = -1.f;
  return Walk(a_rad, b_rad, carried, &slack);
}

MotionCheckResult MotionChecker::Walk(const JointVector& a_rad, const JointVector& b_rad,
                                      const CarriedItem* carried, float* slack) const {
  if (!a_rad.allFinite() || !b_rad.allFinite()) {
    throw std::invalid_argument("MotionChecker: non-finite joints");
  }
  const JointVector delta = b_rad - a_rad;
  // The fixed grid: states at k / (states - 1), no point travelling more than max_travel_m
  // between neighbours. Checked states are grid states, so the robot service, which checks
  // every grid state with at most this padding, passes what is planned here.
  const double travel = Travel_m(a_rad, b_rad, carried);
  const int states = GridStates(travel);
  const float padding = static_cast<float>(0.5 * options_.max_travel_m);
  const float cap = static_cast<float>(options_.max_step_m);
  MotionCheckResult result;
  auto fail = [&](int k, const JointVector& q) {
    result.free = false;
    result.fraction_free = states == 1 ? 0.0 : double(std::max(0, k)) / (states - 1);
    result.q_hit_rad = q;
    result.report = checker_.Check(q, carried, padding);
    return result;
  };
  if (*slack < 0.f) {
    *slack = checker_.Slack(a_rad, carried, padding, cap);
    if (*slack < 0.f) return fail(0, a_rad);
  }
  const double grid_ds = states > 1 ? 1.0 / (states - 1) : 1.0;
  int k = 0;
  while (k < states - 1) {
    // Every point within the slack of this state stays clear by the padding: skip the grid
    // states that close (the next grid state otherwise).
    double ds = travel > 0.0 ? *slack / travel : 1.0;
    if (ds >= 2.0 * grid_ds) ds = std::min(ds, TableStep(a_rad + (k * grid_ds) * delta, delta));
    const double rest = 1.0 - k * grid_ds;
    if (ds >= rest) {
      // The rest of the segment lies within the slack, its end too: what is left of the slack
      // carries over to the next segment of a path (a short timed sample step costs nothing).
      *slack -= static_cast<float>(rest * travel);
      return result;
    }
    const int k_next = std::min(states - 1, k + std::max(1, static_cast<int>(ds / grid_ds)));
    const JointVector q = a_rad + (k_next * grid_ds) * delta;
    *slack = checker_.Slack(q, carried, padding, cap);
    if (*slack < 0.f) return fail(k, q);
    k = k_next;
  }
  return result;
}

double MotionChecker::TableStep(const JointVector& q_rad, const JointVector& delta) const {
  // A pair judged by a distance table may close in by its Lipschitz bounds per radian of its
  // two joints: step no farther than its distance allows.
  double ds = 1.0;
  for (const PairDistanceTable& table : checker_.robot().pair_tables()) {
    const double rate = table.lipschitz_u_m * std::abs(delta[table.joint_u]) +
                        table.lipschitz_v_m * std::abs(delta[table.joint_v]);
    if (rate <= 0.0) continue;
    const double d = table.LowerBound(q_rad[table.joint_u], q_rad[table.joint_v]);
    ds = std::min(ds, std::max(0.0, d / rate));
  }
  return ds;
}

MotionCheckResult MotionChecker::CheckPath(const std::vector<JointVector>& path_rad,
                                           const CarriedItem* carried) const {
  MotionCheckResult result;
  if (path_rad.empty()) return result;
  float slack = -1.f;
  if (path_rad.size() == 1) return Walk(path_rad[0], path_rad[0], carried, &slack);
  // Each segment starts where the last one ended: its state is checked once.
  for (std::size_t i = 0; i + 1 < path_rad.size(); ++i) {
    MotionCheckResult segment = Walk(path_rad[i], path_rad[i + 1], carried, &slack);
    if (!segment.free) {
      segment.fraction_free = (i + segment.fraction_free) / (path_rad.size() - 1);
      return segment;
    }
  }
  return result;
}

}  // namespace picking::planner
