#pragma once

#include <Eigen/Geometry>

#include <chrono>
#include <string>
#include <vector>

#include "services/planner/core/motion_check.h"
#include "services/planner/core/plan_failure.h"

namespace picking::planner {

/// Options of SearchCartesianPath.
struct CartesianSearchOptions {
  /// Lattice step along and across the line, metres (the paper's 2 cm).
  double step_m = 0.02;
  /// Tilt step about the two axes across the line, radians.
  double tilt_step_rad = 5.0 * M_PI / 180.0;
  /// How far a node may leave the straight line: lateral steps and tilt steps each way.
  int max_lateral_steps = 3;
  int max_tilt_steps = 3;
  /// Nodes evaluated (IK + collision check of the move from the parent) before giving up.
  int node_budget = 1500;
  /// Largest change of any joint between a node and its parent, radians: a bigger jump means
  /// a branch flip or a pass near a singularity.
  double max_joint_step_rad = 0.25;
  /// The search stops when this time point passes.
  std::chrono::steady_clock::time_point deadline = std::chrono::steady_clock::time_point::max();
};

/// The outcome of a search, with what stopped it when it failed.
struct CartesianSearchResult {
  bool ok = false;
  std::vector<JointVector> path_rad;         ///< From the start to the goal.
  std::vector<Eigen::Isometry3d> X_BaseTcp;  ///< The tcp pose of each path node.
  int nodes_expanded = 0;
  int nodes_evaluated = 0;
  /// Fraction of the straight distance to the goal covered by the best node reached.
  double fraction_achieved = 0.0;
  /// Why it ended without reaching the goal (kUnspecified when it reached it): kStartInCollision,
  /// kIkUnreachable (the best node's next pose toward the goal), kJointJump (its IK solution
  /// on the start's branch), kCollision (the move toward it), kNodeBudgetSpent, kDeadline.
  FailureKind failure = FailureKind::kUnspecified;
  /// Index (evaluation order) of the node whose move failed, and what happened there: the
  /// joint that jumped, the IK reason, or which body hit what.
  int failed_node = -1;
  std::string detail;
  CollisionReport collision;
  /// E.g. "collision at node 12 (45% of the way): forearm hits shelf".
  std::string Describe() const;
};

/// Greedy best-first search over a lattice of tcp poses from the start configuration's pose
/// to `X_BaseTcp_goal`: steps of `step_m` along the line and across it, and small tilts,
/// the node closest to the goal first. A node is kept when it has an IK solution on the
/// start's branch within `max_joint_step_rad` of its parent's joints and the joint motion
/// from the parent is collision-free for `checker` (continuous check). Nodes are evaluated
/// lazily, when they are taken from the queue, so a free straight line costs one evaluation
/// per step. The goal node has the goal's exact pose.
CartesianSearchResult SearchCartesianPath(const MotionChecker& checker,
                                          const JointVector& q_start_rad,
                                          const Eigen::Isometry3d& X_BaseTcp_goal,
                                          const CarriedItem* carried,
                                          const CartesianSearchOptions& options);

}  // namespace picking::planner
