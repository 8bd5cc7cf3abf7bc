#include "services/planner/core/plan_failure.h"

namespace picking::planner {

const char* FailureStageName(FailureStage stage) {
  switch (stage) {
    case FailureStage::kUnspecified:
      return "unspecified";
    case FailureStage::kStart:
      return "start";
    case FailureStage::kGrasps:
      return "grasps";
    case FailureStage::kPreGrasp:
      return "pre-grasp";
    case FailureStage::kDescend:
      return "descend";
    case FailureStage::kRetreat:
      return "retreat";
    case FailureStage::kApproach:
      return "approach";
    case FailureStage::kPlace:
      return "place";
    case FailureStage::kJointMotion:
      return "joint motion";
    case FailureStage::kSearch:
      return "search";
  }
  return "unknown";
}

const char* FailureKindName(FailureKind kind) {
  switch (kind) {
    case FailureKind::kUnspecified:
      return "unspecified";
    case FailureKind::kCollision:
      return "collision";
    case FailureKind::kIkUnreachable:
      return "ik unreachable";
    case FailureKind::kJointJump:
      return "joint jump";
    case FailureKind::kNodeBudgetSpent:
      return "node budget spent";
    case FailureKind::kDeadline:
      return "deadline";
    case FailureKind::kNoGrasp:
      return "no grasp";
    case FailureKind::kNoPath:
      return "no path";
    case FailureKind::kTiming:
      return "timing";
    case FailureKind::kTubeBlocked:
      return "tube blocked";
    case FailureKind::kSearchBudgetSpent:
      return "search budget spent";
    case FailureKind::kStartInCollision:
      return "start in collision";
    case FailureKind::kNoSeal:
      return "no seal";
  }
  return "unknown";
}

}  // namespace picking::planner
