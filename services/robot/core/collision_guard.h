#pragma once

#include <Eigen/Geometry>

#include <map>
#include <memory>
#include <mutex>
#include <vector>

#include "libs/ur10/kinematics.h"
#include "libs/world/cell_config.h"
#include "services/planner/core/collision_world.h"
#include "services/planner/core/motion_check.h"
#include "services/robot/core/safety.h"

namespace picking::robot {

/// Options of CollisionGuard.
struct CollisionGuardOptions {
  /// Largest distance any point of the arm or gripper travels between two checked states,
  /// metres (> 0). Each state's spheres are grown by half of it, so the checked states cover
  /// the swept volume between them. The planner's MotionCheckOptions default: a motion the
  /// planner checked free is checked with the same padding here.
  double max_travel_m = 0.006;
  /// A guarded move's suction cup counts as touching a static surface within this distance
  /// of it, metres (> 0); the contact search steps along the line by this much.
  double cup_contact_m = 0.001;
  /// A motion that starts in collision must be out of it before the tcp is this far from
  /// where it started, metres (> 0): it may leave, not slide along.
  double max_escape_travel_m = 0.05;
  /// The static cell's distance grids and pedestal: the planner's defaults, without the
  /// exact band. The guard checks a few hundred states a motion, so start-up (about 3 s for
  /// the band) matters more than the checks' speed, and its answers are the same without it.
  planner::StaticCellOptions cell = [] {
    planner::StaticCellOptions options;
    options.exact_band_m = 0.0;
    return options;
  }();
  /// @throws std::invalid_argument naming the bad field.
  void Validate() const;
};

/// The robot's last line against crashes: refuses motions whose swept path collides with the
/// static cell (shelf, tote, table, floor, pedestal) or with the arm itself, by the planner's
/// collision world (planner::FastChecker: the arm's and gripper tube's enclosing spheres
/// against the cell's distance grids and the self-collision pairs). Each straight joint-space
/// segment of a path is checked at evenly spaced states, as many as the planner's
/// MotionChecker takes (no point of the arm or gripper moves more than `max_travel_m` between
/// two of them, a bound from each joint's reach), each state's spheres grown by half the
/// travel between two states: the swept volume is covered, and a state the planner checked
/// free (it pads by max_travel_m / 2) is free here too.
///
/// What may touch: the suction cup (the last `cup_length_m` of the gripper) is not a
/// collision body, so the cup on an item or a board is contact, not collision. Items, the
/// scanned scene and a carried item are not in the robot's world: the planner checks those;
/// the robot guards against the fixed cell and the arm.
///
/// A motion may start in collision (after a stop, or a guarded move that pressed the cup
/// onto a board) and leave it: states are allowed to collide only from the start on, only
/// the start's body with the start's obstacle, never deeper than at the start and only
/// within `max_escape_travel_m` of the tcp's start; once a state is free every later one must be.
/// Thread-safe (const).
class CollisionGuard final {
 public:
  /// @param X_ToolTcp, tube and cup: the gripper of the cell description.
  /// @throws std::invalid_argument for bad options or gripper geometry, std::runtime_error
  /// if a link mesh cannot be read.
  CollisionGuard(const ur10::Ur10Kinematics& kinematics, const world::CellModel& cell,
                 const planner::GripperGeometry& gripper,
                 const CollisionGuardOptions& options = {});
  ~CollisionGuard();
  CollisionGuard(const CollisionGuard&) = delete;
  CollisionGuard& operator=(const CollisionGuard&) = delete;

  /// One state, its spheres grown by max_travel_m / 2: refused if it collides.
  SafetyCheck CheckState(const JointVector& q_rad) const;

  /// The straight joint-space motion from `q_start_rad` to `q_end_rad` (a UR movej).
  SafetyCheck CheckJointMotion(const JointVector& q_start_rad, const JointVector& q_end_rad) const;

  /// The polyline through `path_rad` (how both backends interpolate a trajectory's
  /// waypoints). An empty path, or one that does not move, is free (even from a colliding
  /// start: see the class comment).
  SafetyCheck CheckPath(const std::vector<JointVector>& path_rad) const;

  /// How far the suction cup's lip (the tcp) travels from `p_BaseTcp` along `axis_Base`
  /// (unit) before it meets a static surface, at most `max_distance_m` (>= 0): where a guarded
  /// move's intended contact with the cell would stop it.
  double CupTravelToStaticContact(const Eigen::Vector3d& p_BaseTcp,
                                  const Eigen::Vector3d& axis_Base, double max_distance_m) const;

  /// States CheckPath tests on `path_rad` (for budgets and benchmarks).
  int StatesOnPath(const std::vector<JointVector>& path_rad) const;

  /// This guard with the gripper's head at `head_angle_rad` (a gripper with a servo joint):
  /// this guard at its own angle (not owned), else a guard with the bent gripper's bodies
  /// over the same static cell, built once per angle and kept (at most kMaxHeads angles; a
  /// caller keeps its own alive). Throws std::invalid_argument outside the servo's range.
  std::shared_ptr<const CollisionGuard> ForHeadAngle(double head_angle_rad) const;
  static constexpr std::size_t kMaxHeads = 16;

  const planner::RobotGeometry& robot() const { return *robot_; }
  const planner::StaticCell& cell() const { return *cell_; }
  const CollisionGuardOptions& options() const { return options_; }

 private:
  // Half the largest travel of any arm or gripper point between two of the `states` evenly
  // spaced states of the segment a -> b, metres.
  float SegmentPadding_m(const JointVector& a_rad, const JointVector& b_rad, int states) const;
  // The refusal of a path at q_rad (`deeper`: it started in that collision).
  SafetyCheck Refusal(const planner::CollisionReport& hit, const JointVector& q_rad,
                      double fraction, float padding_m, bool deeper) const;
  // Distance from p_Base to the nearest static surface, up to `max_m`.
  double StaticSurfaceDistance(const Eigen::Vector3d& p_Base, double max_m) const;

  // The same cell and options with another gripper.
  CollisionGuard(const CollisionGuard& base, const planner::GripperGeometry& gripper);
  // The fast and motion checkers over robot_ and cell_.
  void BuildCheckers();

  CollisionGuardOptions options_;
  std::unique_ptr<planner::RobotGeometry> robot_;
  std::shared_ptr<const planner::StaticCell> cell_;
  mutable std::mutex heads_mutex_;
  mutable std::map<double, std::shared_ptr<const CollisionGuard>> heads_;
  std::unique_ptr<planner::FastChecker> fast_;
  std::unique_ptr<planner::MotionChecker> motion_;
};

}  // namespace picking::robot
