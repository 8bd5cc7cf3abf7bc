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
  /// Where the bodies are farther from everything, checked states are spaced by their slack
  /// (conservative advancement), up to this travel, metres (>= max_travel_m).
  double max_step_m = 0.06;
};

/// Where a checked motion first collides.
struct MotionCheckResult {
  bool free = true;
  /// Fraction of the motion (0..1) before the first colliding state.
  double fraction_free = 1.0;
  JointVector q_hit_rad = JointVector::Zero();
  CollisionReport report;  ///< What hits what at q_hit_rad.
};

/// Checks straight joint-space motions continuously with the fast checker, on a grid of
/// states spaced so that no point of the moving bodies travels more than `max_travel_m`
/// between two of them (a bound from each joint's reach). Each checked state must be free
/// with its spheres grown by half of that; from a state whose slack (FastChecker::Slack) is
/// s, the grid states within s of travel are clear by that padding and skipped (conservative
/// advancement, up to `max_step_m`; self pairs judged by a distance table bound the skip
/// through their joints), otherwise the next grid state is checked. Thread-safe (const).
class MotionChecker final {
 public:
  MotionChecker(const FastChecker& checker, const MotionCheckOptions& options = {});

  /// Checks the motion from a to b (both included).
  MotionCheckResult CheckSegment(const JointVector& a_rad, const JointVector& b_rad,
                                 const CarriedItem* carried = nullptr) const;
  /// Checks a path of straight segments.
  MotionCheckResult CheckPath(const std::vector<JointVector>& path_rad,
                              const CarriedItem* carried = nullptr) const;
  /// Number of grid states of the segment: the most CheckSegment tests (for budgets).
  int StatesOnSegment(const JointVector& a_rad, const JointVector& b_rad,
                      const CarriedItem* carried) const;

  const FastChecker& checker() const { return checker_; }
  /// Upper bound of the distance any body point travels on the straight motion a -> b, metres.
  double Travel_m(const JointVector& a_rad, const JointVector& b_rad,
                  const CarriedItem* carried) const;
  /// Upper bound of the distance any body point travels per radian of joint j, metres.
  double reach_m(int joint, const CarriedItem* carried) const;

 private:
  /// States of the fixed grid on a motion whose points travel at most `travel_m`.
  int GridStates(double travel_m) const;
  /// CheckSegment from a state whose slack is known (`*slack` >= 0; the state itself is not
  /// checked again) or not (`*slack` < 0); leaves a slack of the end state in `*slack` (its
  /// own, or what is left of an earlier state's when the end lies within it).
  MotionCheckResult Walk(const JointVector& a_rad, const JointVector& b_rad,
                         const CarriedItem* carried, float* slack) const;

  /// The largest step (fraction of `delta`) from q_rad that the self pairs with a distance
  /// table allow.
  double TableStep(const JointVector& q_rad, const JointVector& delta) const;

  const FastChecker& checker_;
  MotionCheckOptions options_;
  JointVector reach_arm_m_ = JointVector::Zero();
};

}  // namespace picking::planner
