#pragma once

#include <string>
#include <vector>

#include "services/planner/core/collision_world.h"

namespace picking::planner {

/// Options of MotionChecker.
struct MotionCheckOptions {
  /// Largest distance any point of the arm, gripper or item may travel between two checked
  /// states, metres. Each check grows the spheres by half of it, so the swept volume between
  /// the states is covered.
  double max_travel_m = 0.006;
};

/// Where a checked motion first collides.
struct MotionCheckResult {
  bool free = true;
  /// Fraction of the motion (0..1) before the first colliding state.
  double fraction_free = 1.0;
  JointVector q_hit_rad = JointVector::Zero();
  CollisionReport report;  ///< What hits what at q_hit_rad.
};

/// Checks straight joint-space motions continuously with the fast checker: states are spaced
/// so that no point of the moving bodies travels more than `max_travel_m` between two of
/// them (a bound from each joint's reach), and each state's spheres are grown by half that.
/// Thread-safe (const).
class MotionChecker final {
 public:
  MotionChecker(const FastChecker& checker, const MotionCheckOptions& options = {});

  /// Checks the motion from a to b (both included).
  MotionCheckResult CheckSegment(const JointVector& a_rad, const JointVector& b_rad,
                                 const CarriedItem* carried = nullptr) const;
  /// Checks a path of straight segments.
  MotionCheckResult CheckPath(const std::vector<JointVector>& path_rad,
                              const CarriedItem* carried = nullptr) const;
  /// Number of states CheckSegment would test (for budgets and benchmarks).
  int StatesOnSegment(const JointVector& a_rad, const JointVector& b_rad,
                      const CarriedItem* carried) const;

  const FastChecker& checker() const { return checker_; }
  /// Upper bound of the distance any body point travels per radian of joint j, metres.
  double reach_m(int joint, const CarriedItem* carried) const;

 private:
  const FastChecker& checker_;
  MotionCheckOptions options_;
  JointVector reach_arm_m_ = JointVector::Zero();
};

}  // namespace picking::planner
