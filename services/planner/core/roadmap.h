#pragma once

#include <chrono>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "services/planner/core/motion_check.h"

namespace picking::planner {

/// A joint configuration with a name ("home", "scan/bin_A/0", "above_tote", ...).
struct NamedPose {
  std::string name;
  JointVector q_rad = JointVector::Zero();
};

/// The configurations that could serve as one named pose, most preferred first (each
/// collision-free: the IK solutions of the pose and of its fall-back poses).
struct NamedPoseChoices {
  std::string name;
  std::vector<JointVector> q_rad;
};

/// Options of Roadmap.
struct RoadmapOptions {
  /// Random configurations added to the named poses, drawn within the joint-space box around
  /// the named poses grown by `sample_margin_rad` (and inside the joint limits).
  int samples = 800;
  double sample_margin_rad = 0.6;
  /// Each node is joined to this many nearest nodes (edges checked lazily, when a search
  /// first uses them).
  int neighbours = 12;
  /// Shortcut attempts on a found path (seeded).
  int shortcut_attempts = 40;
  /// Where the roadmap cannot be joined or has no free path (a long carried item close to
  /// the shelf, which the roadmap's edges, made for the bare arm, swing into), two trees
  /// grown from start and goal toward each other (RRT-Connect) within the joint box around
  /// both grown by `sample_margin_rad`: at most `tree_nodes` nodes, `tree_step_rad` apart
  /// at most on any joint.
  int tree_nodes = 1500;
  double tree_step_rad = 0.2;
  /// ... and for at most this long (seconds): a place tries several release spots, each of
  /// which may need the trees, within the caller's deadline.
  double tree_time_s = 1.0;
  std::uint32_t seed = 2016;
};

/// Why a joint path could not be planned.
struct JointPathResult {
  bool ok = false;
  std::vector<JointVector> path_rad;  ///< Start, intermediate nodes, goal.
  std::string reason;                 ///< Why not, naming the blocked state.
  bool cached = false;                ///< Served from the cache of named-pose paths.
  bool by_trees = false;              ///< Found by ConnectTrees, not through the roadmap.
  int edges_checked = 0;
};

/// A lazy probabilistic roadmap over the static cell: the named poses and seeded random
/// collision-free configurations, joined to their nearest neighbours by straight joint-space
/// edges that are checked (continuously, MotionChecker) the first time a search uses them.
/// Paths between two named poses are cached. Thread-safe (edge states and the cache behind a
/// mutex).
class Roadmap final {
 public:
  /// `checker` must check the static cell only (no scan) and outlive the roadmap. Throws
  /// std::invalid_argument if a named pose is outside the limits or in collision.
  Roadmap(const MotionChecker& checker, std::vector<NamedPose> named,
          const RoadmapOptions& options = {});

  const std::vector<NamedPose>& named() const { return named_; }
  /// The named pose or nullptr.
  const NamedPose* Find(const std::string& name) const;

  /// A collision-free path from `start` to `goal`: the straight segment if it is free,
  /// otherwise through the roadmap (start and goal joined to their nearest free nodes), then
  /// shortcut. `scene_checker`, if given, also checks the path (e.g. with a scan); a path it
  /// rejects is searched again without the rejected edges. With `carried`, every motion is
  /// checked with the item on the cup (edges free for the bare arm are checked again with it,
  /// for this call only).
  JointPathResult Plan(
      const JointVector& start_rad, const JointVector& goal_rad,
      const MotionChecker* scene_checker = nullptr,
      std::chrono::steady_clock::time_point deadline = std::chrono::steady_clock::time_point::max(),
      const CarriedItem* carried = nullptr) const;

  std::size_t num_nodes() const { return nodes_.size(); }

  /// Plans and caches the path between every two named poses, both ways (the paper's
  /// offline joint paths), so that a request between them only times and validates it.
  /// Pairs the roadmap cannot join are left to the requests (which say why). Returns the
  /// pairs cached.
  int CacheNamedPaths() const;

  /// A path from `start` to `goal` by two trees grown toward each other (RRT-Connect,
  /// seeded: the same request gives the same path), each motion checked by `checker` with
  /// `carried`: start, the trees' nodes, goal. Empty when the trees do not meet within
  /// RoadmapOptions::tree_nodes or by the deadline. Plan's way where the roadmap does not
  /// serve.
  std::vector<JointVector> ConnectTrees(const JointVector& start_rad, const JointVector& goal_rad,
                                        const MotionChecker& checker, const CarriedItem* carried,
                                        std::chrono::steady_clock::time_point deadline) const;

 private:
  enum class EdgeState : std::uint8_t { kUnknown, kFree, kBlocked };
  struct Edge {
    int to;
    double length;
    mutable EdgeState state;
  };
  double Distance(const JointVector& a, const JointVector& b) const;
  std::vector<int> Nearest(const JointVector& q, int count) const;
  /// Edge states with a carried item, for one call: (from, to) -> free.
  using CarriedEdges = std::map<std::pair<int, int>, bool>;
  bool EdgeFree(int from, std::size_t edge_index, int* edges_checked, const CarriedItem* carried,
                CarriedEdges* carried_edges) const;
  std::vector<JointVector> Shortcut(std::vector<JointVector> path, const MotionChecker& checker,
                                    const CarriedItem* carried) const;
  /// The straight motions joining a query (start or goal) to its nearest nodes, checked only
  /// once a chain uses them (most searches use one or two of them).
  struct Joins {
    JointVector q_rad;
    std::vector<int> nodes;  ///< Not known to be blocked.
    std::vector<int> free;   ///< Checked free.
  };
  Joins NearestJoins(const JointVector& q) const;
  /// Whether the motion between `joins.q_rad` and `node` is free; a blocked one leaves
  /// `joins.nodes`, its reason landing in `first_block` if that is empty.
  bool JoinFree(Joins* joins, int node, const CarriedItem* carried, int* edges_checked,
                std::string* first_block) const;
  /// Lazy A* from start to goal: the shortest chain over joins and edges not known to be
  /// blocked, its motions checked, again until one is free. The path (start, nodes, goal),
  /// or empty with `why_not` set.
  std::vector<JointVector> SearchLazily(Joins* start, Joins* goal, const CarriedItem* carried,
                                        std::chrono::steady_clock::time_point deadline,
                                        int* edges_checked, std::string* why_not) const;
  /// A* over the edges not known to be blocked: (node, index of the edge from the previous
  /// node) from a start node to a goal node; empty when none is reachable.
  std::vector<std::pair<int, int>> ShortestChain(const JointVector& start_rad,
                                                 const JointVector& goal_rad,
                                                 const std::vector<int>& start_nodes,
                                                 const std::vector<int>& goal_nodes,
                                                 const CarriedItem* carried,
                                                 const CarriedEdges& carried_edges) const;

  const MotionChecker& checker_;
  std::vector<NamedPose> named_;
  RoadmapOptions options_;
  JointVector weights_ = JointVector::Ones();
  std::vector<JointVector> nodes_;
  std::vector<std::vector<Edge>> edges_;
  mutable std::mutex mutex_;
  mutable std::map<std::pair<std::string, std::string>, std::vector<JointVector>> cache_;
};

}  // namespace picking::planner
