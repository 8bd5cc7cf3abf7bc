#include "services/robot/core/collision_guard.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace picking::robot {
namespace {

// A motion that starts in collision may reach states whose worst sphere is this much deeper
// than at the start: the fast check reports the first colliding leaf sphere of each coarse
// one, so its depth wobbles by a fraction of a leaf from state to state.
constexpr float kStartDepthSlack_m = 0.002f;

std::string JointsText(const JointVector& q_rad) {
  std::ostringstream os;
  os.setf(std::ios::fixed);
  os.precision(3);
  os << "(";
  for (int j = 0; j < ur10::kNumJoints; ++j) os << (j ? ", " : "") << q_rad[j];
  os << ") rad";
  return os.str();
}

std::string Percent(double fraction) {
  std::ostringstream os;
  os.setf(std::ios::fixed);
  os.precision(0);
  os << 100.0 * fraction << "%";
  return os.str();
}

// Where a path stands while it is checked: the start's collision, if any, and whether the
// path is still in it.
struct StartCollision {
  planner::CollisionReport report;
  bool leaving = false;
  Eigen::Vector3d p_BaseTcp_start = Eigen::Vector3d::Zero();
  double travel_m = 0.0;  // the tcp's distance from where it started
  double max_travel_m = 0.0;
  // True if `hit` continues the start's collision no deeper than it began, soon enough.
  bool Continues(const planner::CollisionReport& hit) const {
    return leaving && travel_m <= max_travel_m && hit.body == report.body &&
           hit.obstacle == report.obstacle &&
           hit.clearance_m >= report.clearance_m - kStartDepthSlack_m;
  }
};

}  // namespace

void CollisionGuardOptions::Validate() const {
  if (!std::isfinite(max_travel_m) || max_travel_m <= 0.0) {
    throw std::invalid_argument("CollisionGuardOptions: max_travel_m must be finite and > 0");
  }
  if (!std::isfinite(max_escape_travel_m) || max_escape_travel_m <= 0.0) {
    throw std::invalid_argument(
        "CollisionGuardOptions: max_escape_travel_m must be finite and > 0");
  }
  if (!std::isfinite(cup_contact_m) || cup_contact_m <= 0.0) {
    throw std::invalid_argument("CollisionGuardOptions: cup_contact_m must be finite and > 0");
  }
}

CollisionGuard::CollisionGuard(const ur10::Ur10Kinematics& kinematics, const world::CellModel& cell,
                               const planner::GripperGeometry& gripper,
                               const CollisionGuardOptions& options)
    : options_(options) {
  options_.Validate();
  robot_ = std::make_unique<planner::RobotGeometry>(kinematics, gripper);
  cell_ = std::make_shared<const planner::StaticCell>(cell, options_.cell);
  BuildCheckers();
}

CollisionGuard::CollisionGuard(const CollisionGuard& base, const planner::GripperGeometry& gripper)
    : options_(base.options_),
      robot_(std::make_unique<planner::RobotGeometry>(base.robot_->WithGripper(gripper))),
      cell_(base.cell_) {
  BuildCheckers();
}

void CollisionGuard::BuildCheckers() {
  // No scan: the robot guards against the fixed cell; the planner checks the scanned scene.
  fast_ = std::make_unique<planner::FastChecker>(*robot_, *cell_, nullptr);
  planner::MotionCheckOptions motion;
  motion.max_travel_m = options_.max_travel_m;
  motion.max_step_m = std::max(motion.max_step_m, options_.max_travel_m);
  motion_ = std::make_unique<planner::MotionChecker>(*fast_, motion);
}

CollisionGuard::~CollisionGuard() = default;

std::shared_ptr<const CollisionGuard> CollisionGuard::ForHeadAngle(double head_angle_rad) const {
  if (head_angle_rad == robot_->gripper().head_angle_rad) {
    return std::shared_ptr<const CollisionGuard>(std::shared_ptr<const CollisionGuard>(), this);
  }
  // Validates the angle (finite, within the servo's range) before it is a key.
  const planner::GripperGeometry bent = robot_->gripper().AtHeadAngle(head_angle_rad);
  std::lock_guard<std::mutex> lock(heads_mutex_);
  auto& slot = heads_[head_angle_rad];
  if (!slot) {
    if (heads_.size() > kMaxHeads) {
      // A head that follows gravity turns to ever new angles: start the cache again.
      heads_.clear();
      std::shared_ptr<const CollisionGuard> guard(new CollisionGuard(*this, bent));
      heads_.emplace(head_angle_rad, guard);
      return guard;
    }
    slot.reset(new CollisionGuard(*this, bent));
  }
  return slot;
}

SafetyCheck CollisionGuard::CheckState(const JointVector& q_rad) const {
  if (!q_rad.allFinite()) return SafetyCheck::Fail("joints are not finite");
  const float padding_m = static_cast<float>(0.5 * options_.max_travel_m);
  if (fast_->IsFree(q_rad, nullptr, padding_m)) return SafetyCheck::Ok();
  return Refusal(fast_->Check(q_rad, nullptr, padding_m), q_rad, 0.0, padding_m, false);
}

SafetyCheck CollisionGuard::CheckJointMotion(const JointVector& q_start_rad,
                                             const JointVector& q_end_rad) const {
  return CheckPath({q_start_rad, q_end_rad});
}

int CollisionGuard::StatesOnPath(const std::vector<JointVector>& path_rad) const {
  if (path_rad.empty()) return 0;
  int states = 1;
  for (std::size_t i = 0; i + 1 < path_rad.size(); ++i) {
    states += motion_->StatesOnSegment(path_rad[i], path_rad[i + 1], nullptr) - 1;
  }
  return states;
}

float CollisionGuard::SegmentPadding_m(const JointVector& a_rad, const JointVector& b_rad,
                                       int states) const {
  if (states < 2) return 0.f;
  return static_cast<float>(0.5 * motion_->Travel_m(a_rad, b_rad, nullptr) / (states - 1));
}

SafetyCheck CollisionGuard::CheckPath(const std::vector<JointVector>& path_rad) const {
  if (path_rad.empty()) return SafetyCheck::Ok();
  for (std::size_t i = 0; i < path_rad.size(); ++i) {
    if (!path_rad[i].allFinite()) {
      return SafetyCheck::Fail("path point " + std::to_string(i) + " is not finite");
    }
  }
  // A lone state is checked with the full padding; on a segment every state is padded by
  // half the largest travel between two of its states (at most max_travel_m / 2), which
  // covers the swept volume and is never more than the planner's padding at the same states.
  const float lone_padding_m = static_cast<float>(0.5 * options_.max_travel_m);
  const int first_states =
      path_rad.size() > 1 ? motion_->StatesOnSegment(path_rad[0], path_rad[1], nullptr) : 1;
  const float start_padding_m =
      first_states > 1 ? SegmentPadding_m(path_rad[0], path_rad[1], first_states) : lone_padding_m;
  StartCollision start;
  if (!fast_->IsFree(path_rad.front(), nullptr, start_padding_m)) {
    start.report = fast_->Check(path_rad.front(), nullptr, start_padding_m);
    start.leaving = true;
    start.max_travel_m = options_.max_escape_travel_m;
    start.p_BaseTcp_start = robot_->X_BaseTcp(path_rad.front()).translation();
  }
  const int total = StatesOnPath(path_rad);
  int index = 0;                              // states passed so far, the start included
  float checked_padding_m = start_padding_m;  // padding the segment's first state had
  for (std::size_t s = 0; s + 1 < path_rad.size(); ++s) {
    const JointVector& a = path_rad[s];
    const JointVector& b = path_rad[s + 1];
    const int states = motion_->StatesOnSegment(a, b, nullptr);
    if (states < 2) continue;  // no motion
    const float padding_m = SegmentPadding_m(a, b, states);
    // State 0 is the previous segment's end; again only if it had less padding.
    for (int i = checked_padding_m >= padding_m ? 1 : 0; i < states; ++i) {
      if (i > 0) ++index;
      const JointVector q = a + (double(i) / (states - 1)) * (b - a);
      if (fast_->IsFree(q, nullptr, padding_m)) {
        start.leaving = false;
        continue;
      }
      const planner::CollisionReport hit = fast_->Check(q, nullptr, padding_m);
      if (start.leaving) {
        start.travel_m = (robot_->X_BaseTcp(q).translation() - start.p_BaseTcp_start).norm();
      }
      if (start.Continues(hit)) continue;
      return Refusal(hit, q, double(index) / std::max(1, total - 1), padding_m, start.leaving);
    }
    checked_padding_m = padding_m;
  }
  return SafetyCheck::Ok();
}

SafetyCheck CollisionGuard::Refusal(const planner::CollisionReport& hit, const JointVector& q_rad,
                                    double fraction, float padding_m, bool deeper) const {
  std::ostringstream os;
  os.precision(3);
  os << (deeper ? "the path starts in collision and does not get out of it (only the start's "
                  "link may leave the start's obstacle, never deeper and within a few cm)"
                : "the swept path collides")
     << " " << Percent(fraction) << " of the way, at joints " << JointsText(q_rad) << ": "
     << hit.ToString() << " (sphere clearance " << hit.clearance_m << " m with " << padding_m
     << " m padding)";
  return SafetyCheck::Fail(os.str());
}

double CollisionGuard::StaticSurfaceDistance(const Eigen::Vector3d& p_Base, double max_m) const {
  double distance = std::max(0.0, p_Base.z() - cell_->floor_z_m());
  const Eigen::AlignedBox3d& pedestal = cell_->pedestal_Base();
  if (!pedestal.isEmpty())
    distance = std::min(distance, std::sqrt(pedestal.squaredExteriorDistance(p_Base)));
  const Eigen::Vector3f p = p_Base.cast<float>();
  const auto& grids = cell_->grids();
  for (std::size_t g = 0; g < grids.size(); ++g) {
    // The grid's bound first; the mesh's triangles only where it cannot tell.
    if (grids[g].grid.Clearance(p) >= max_m) continue;
    distance = std::min(distance, double(cell_->SurfaceDistance(g, p, float(max_m))));
  }
  return std::min(distance, max_m);
}

double CollisionGuard::CupTravelToStaticContact(const Eigen::Vector3d& p_BaseTcp,
                                                const Eigen::Vector3d& axis_Base,
                                                double max_distance_m) const {
  if (!p_BaseTcp.allFinite() || !axis_Base.allFinite() || !std::isfinite(max_distance_m) ||
      max_distance_m < 0.0) {
    throw std::invalid_argument("CupTravelToStaticContact: non-finite or negative input");
  }
  const double step_m = options_.cup_contact_m;
  // Steps no longer than the contact distance cannot jump over a surface: a crossing passes
  // within half a step of it.
  for (double s = 0.0;; s = std::min(s + step_m, max_distance_m)) {
    const Eigen::Vector3d p = p_BaseTcp + s * axis_Base;
    if (StaticSurfaceDistance(p, 2.0 * step_m) <= step_m) return s;
    if (s >= max_distance_m) return max_distance_m;
  }
}

}  // namespace picking::robot
