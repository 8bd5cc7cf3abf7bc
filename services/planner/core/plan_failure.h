#pragma once

namespace picking::planner {

/// Where a planning attempt failed (PlanFailure::stage).
enum class FailureStage {
  kUnspecified,
  kStart,        ///< The start state, with the gripper's head bent for the grasp.
  kGrasps,       ///< Computing the item's grasp candidates.
  kPreGrasp,     ///< The pre-grasp pose: its IK and collisions.
  kDescend,      ///< The descent to the grasp and the guarded move.
  kRetreat,      ///< The lift off the support and the retreat out of the container.
  kApproach,     ///< The joint motion from the start to the pre-grasp.
  kPlace,        ///< A place's release pose and the motion to it.
  kJointMotion,  ///< A joint motion between two states.
  kSearch,       ///< The pick's search as a whole (its time budget).
};

/// Why a planning attempt failed (PlanFailure::kind).
enum class FailureKind {
  kUnspecified,
  kCollision,          ///< A pose or a motion collides.
  kIkUnreachable,      ///< A pose has no IK solution (on the branch kept).
  kJointJump,          ///< The cartesian search's next IK solution jumps joints.
  kNodeBudgetSpent,    ///< The cartesian search's node budget ran out.
  kDeadline,           ///< The call's deadline passed during a search.
  kNoGrasp,            ///< The item has no grasp candidate.
  kNoPath,             ///< No collision-free joint path.
  kTiming,             ///< The path could not be time-parametrised.
  kTubeBlocked,        ///< The gripper's tube at the grasp crosses the container (CheckTubeReach).
  kSearchBudgetSpent,  ///< The pick's search time budget ran out.
  kStartInCollision,   ///< The cartesian search's start collides.
  kNoSeal,             ///< The cup cannot seal on the item's model at or near the grasp.
};

/// The stage's name in messages: "start", "grasps", "pre-grasp", "descend", "retreat",
/// "approach", "place", "joint motion", "search" ("unspecified").
const char* FailureStageName(FailureStage stage);

/// The kind's name in messages: "collision", "ik unreachable", "joint jump", "node budget
/// spent", "deadline", "no grasp", "no path", "timing", "tube blocked", "search budget
/// spent", "start in collision", "no seal" ("unspecified").
const char* FailureKindName(FailureKind kind);

}  // namespace picking::planner
