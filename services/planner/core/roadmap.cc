#include "services/planner/core/roadmap.h"

#include <algorithm>
#include <cmath>
#include <queue>
#include <random>
#include <set>
#include <stdexcept>

namespace picking::planner {
namespace {

bool SameJoints(const JointVector& a, const JointVector& b) {
  return (a - b).cwiseAbs().maxCoeff() < 1e-9;
}

}  // namespace

Roadmap::Roadmap(const MotionChecker& checker, std::vector<NamedPose> named,
                 const RoadmapOptions& options)
    : checker_(checker), named_(std::move(named)), options_(options) {
  const ur10::Ur10Model& model = checker_.checker().robot().kinematics().model();
  for (int j = 0; j < 6; ++j) weights_[j] = checker_.reach_m(j, nullptr);
  Eigen::Array<double, 6, 1> lo = Eigen::Array<double, 6, 1>::Constant(1e9), hi = -lo;
  for (const NamedPose& pose : named_) {
    if (const std::string out = model.PositionLimitViolation(pose.q_rad); !out.empty()) {
      throw std::invalid_argument("named pose '" + pose.name + "': " + out);
    }
    const CollisionReport report = checker_.checker().Check(pose.q_rad);
    if (report.in_collision) {
      throw std::invalid_argument("named pose '" + pose.name + "' collides: " + report.ToString());
    }
    nodes_.push_back(pose.q_rad);
    lo = lo.min(pose.q_rad.array());
    hi = hi.max(pose.q_rad.array());
  }
  if (!named_.empty()) {
    lo = (lo - options_.sample_margin_rad).max(model.min_position_rad().array());
    hi = (hi + options_.sample_margin_rad).min(model.max_position_rad().array());
    std::mt19937 rng(options_.seed);
    int tries = 0;
    while (static_cast<int>(nodes_.size() - named_.size()) < options_.samples &&
           tries++ < 50 * options_.samples) {
      JointVector q;
      for (int j = 0; j < 6; ++j) q[j] = std::uniform_real_distribution<double>(lo[j], hi[j])(rng);
      if (checker_.checker().IsFree(q)) nodes_.push_back(q);
    }
  }
  edges_.resize(nodes_.size());
  for (std::size_t n = 0; n < nodes_.size(); ++n) {
    for (int m : Nearest(nodes_[n], options_.neighbours + 1)) {
      if (m == static_cast<int>(n)) continue;
      const bool known =
          std::any_of(edges_[n].begin(), edges_[n].end(), [&](const Edge& e) { return e.to == m; });
      if (known) continue;
      const double length = Distance(nodes_[n], nodes_[m]);
      edges_[n].push_back({m, length, EdgeState::kUnknown});
      edges_[m].push_back({static_cast<int>(n), length, EdgeState::kUnknown});
    }
  }
}

int Roadmap::CacheNamedPaths() const {
  int cached = 0;
  for (std::size_t i = 0; i < named_.size(); ++i) {
    for (std::size_t j = i + 1; j < named_.size(); ++j) {
      const JointPathResult path = Plan(named_[i].q_rad, named_[j].q_rad);
      if (!path.ok) continue;
      // A free path is free backwards.
      std::lock_guard<std::mutex> lock(mutex_);
      cache_[{named_[j].name, named_[i].name}] = {path.path_rad.rbegin(), path.path_rad.rend()};
      cached += 2;
    }
  }
  return cached;
}

const NamedPose* Roadmap::Find(const std::string& name) const {
  for (const NamedPose& pose : named_) {
    if (pose.name == name) return &pose;
  }
  return nullptr;
}

double Roadmap::Distance(const JointVector& a, const JointVector& b) const {
  return ((a - b).cwiseAbs().cwiseProduct(weights_)).sum();
}

std::vector<int> Roadmap::Nearest(const JointVector& q, int count) const {
  std::vector<std::pair<double, int>> all;
  all.reserve(nodes_.size());
  for (std::size_t n = 0; n < nodes_.size(); ++n) all.emplace_back(Distance(q, nodes_[n]), n);
  const std::size_t k = std::min<std::size_t>(count, all.size());
  std::partial_sort(all.begin(), all.begin() + k, all.end());
  std::vector<int> out;
  for (std::size_t i = 0; i < k; ++i) out.push_back(all[i].second);
  return out;
}

bool Roadmap::EdgeFree(int from, std::size_t edge_index, int* edges_checked,
                       const CarriedItem* carried, CarriedEdges* carried_edges) const {
  const Edge& edge = edges_[from][edge_index];
  if (carried != nullptr) {
    // Blocked for the bare arm is blocked with the item too; free must be checked again.
    if (edge.state == EdgeState::kBlocked) return false;
    const auto key = std::minmax(from, edge.to);
    const auto it = carried_edges->find(key);
    if (it != carried_edges->end()) return it->second;
    ++*edges_checked;
    const bool free = checker_.CheckSegment(nodes_[from], nodes_[edge.to], carried).free;
    (*carried_edges)[key] = free;
    return free;
  }
  if (edge.state == EdgeState::kUnknown) {
    ++*edges_checked;
    const bool free = checker_.CheckSegment(nodes_[from], nodes_[edge.to]).free;
    edge.state = free ? EdgeState::kFree : EdgeState::kBlocked;
    for (const Edge& back : edges_[edge.to]) {
      if (back.to == from) back.state = edge.state;
    }
  }
  return edge.state == EdgeState::kFree;
}

std::vector<JointVector> Roadmap::Shortcut(std::vector<JointVector> path,
                                           const MotionChecker& checker,
                                           const CarriedItem* carried) const {
  std::mt19937 rng(options_.seed + static_cast<std::uint32_t>(path.size()));
  // A short path has few pairs to try, and a blocked pair's check is the costly kind (a long
  // motion walked to where it hits): each pair of the current path is checked once.
  std::set<std::pair<int, int>> blocked;
  for (int attempt = 0; attempt < options_.shortcut_attempts && path.size() > 2; ++attempt) {
    const int n = static_cast<int>(path.size());
    if (static_cast<int>(blocked.size()) == (n - 1) * (n - 2) / 2) break;  // every pair tried
    const int i = std::uniform_int_distribution<int>(0, n - 3)(rng);
    const int j = std::uniform_int_distribution<int>(i + 2, n - 1)(rng);
    if (blocked.count({i, j})) continue;
    if (checker.CheckSegment(path[i], path[j], carried).free) {
      path.erase(path.begin() + i + 1, path.begin() + j);
      blocked.clear();  // the indices moved
    } else {
      blocked.insert({i, j});
    }
  }
  return path;
}

Roadmap::Joins Roadmap::NearestJoins(const JointVector& q) const {
  Joins joins;
  joins.q_rad = q;
  joins.nodes = Nearest(q, 3 * options_.neighbours);
  return joins;
}

bool Roadmap::JoinFree(Joins* joins, int node, const CarriedItem* carried, int* edges_checked,
                       std::string* first_block) const {
  if (std::find(joins->free.begin(), joins->free.end(), node) != joins->free.end()) return true;
  ++*edges_checked;
  const MotionCheckResult check = checker_.CheckSegment(joins->q_rad, nodes_[node], carried);
  if (check.free) {
    joins->free.push_back(node);
    return true;
  }
  if (first_block->empty()) {
    *first_block = check.report.ToString() + " at " +
                   std::to_string(static_cast<int>(100 * check.fraction_free)) + "% of the way";
  }
  joins->nodes.erase(std::find(joins->nodes.begin(), joins->nodes.end(), node));
  return false;
}

std::vector<JointVector> Roadmap::SearchLazily(Joins* start, Joins* goal,
                                               const CarriedItem* carried,
                                               std::chrono::steady_clock::time_point deadline,
                                               int* edges_checked, std::string* why_not) const {
  std::string first_block;
  CarriedEdges carried_edges;
  for (int round = 0; round < 1000; ++round) {
    if (std::chrono::steady_clock::now() > deadline) {
      *why_not = "the call's deadline passed during the roadmap search";
      return {};
    }
    if (start->nodes.empty() || goal->nodes.empty()) {
      *why_not = std::string("no free straight motion joins the ") +
                 (start->nodes.empty() ? "start" : "goal") +
                 " to the roadmap (nearest: " + first_block + ")";
      return {};
    }
    const std::vector<std::pair<int, int>> chain =
        ShortestChain(start->q_rad, goal->q_rad, start->nodes, goal->nodes, carried, carried_edges);
    if (chain.empty()) {
      *why_not = "the roadmap has no free path between start and goal";
      return {};
    }
    if (!JoinFree(start, chain.front().first, carried, edges_checked, &first_block) ||
        !JoinFree(goal, chain.back().first, carried, edges_checked, &first_block)) {
      continue;
    }
    bool blocked = false;
    for (std::size_t i = 1; i < chain.size() && !blocked; ++i) {
      blocked =
          !EdgeFree(chain[i - 1].first, chain[i].second, edges_checked, carried, &carried_edges);
    }
    if (blocked) continue;
    std::vector<JointVector> path = {start->q_rad};
    for (const auto& [v, edge] : chain) path.push_back(nodes_[v]);
    path.push_back(goal->q_rad);
    return path;
  }
  *why_not = "the roadmap search gave up after 1000 rounds of blocked motions";
  return {};
}

std::vector<std::pair<int, int>> Roadmap::ShortestChain(const JointVector& start_rad,
                                                        const JointVector& goal_rad,
                                                        const std::vector<int>& start_nodes,
                                                        const std::vector<int>& goal_nodes,
                                                        const CarriedItem* carried,
                                                        const CarriedEdges& carried_edges) const {
  const int n = static_cast<int>(nodes_.size());
  std::vector<double> g(n, 1e18);
  std::vector<int> parent(n, -1), parent_edge(n, -1);
  using Entry = std::pair<double, int>;
  std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> open;
  for (int s : start_nodes) {
    g[s] = Distance(start_rad, nodes_[s]);
    open.emplace(g[s] + Distance(nodes_[s], goal_rad), s);
  }
  int reached = -1;
  std::vector<bool> is_goal(n, false);
  for (int t : goal_nodes) is_goal[t] = true;
  std::vector<bool> closed(n, false);
  while (!open.empty()) {
    const int u = open.top().second;
    open.pop();
    if (closed[u]) continue;
    closed[u] = true;
    if (is_goal[u]) {
      reached = u;
      break;
    }
    for (std::size_t e = 0; e < edges_[u].size(); ++e) {
      const Edge& edge = edges_[u][e];
      if (edge.state == EdgeState::kBlocked) continue;
      if (carried != nullptr) {
        const auto known = carried_edges.find(std::minmax(u, edge.to));
        if (known != carried_edges.end() && !known->second) continue;
      }
      const double cost = g[u] + edge.length;
      if (cost < g[edge.to]) {
        g[edge.to] = cost;
        parent[edge.to] = u;
        parent_edge[edge.to] = static_cast<int>(e);
        open.emplace(cost + Distance(nodes_[edge.to], goal_rad), edge.to);
      }
    }
  }
  std::vector<std::pair<int, int>> chain;
  for (int v = reached; v >= 0; v = parent[v]) chain.emplace_back(v, parent_edge[v]);
  std::reverse(chain.begin(), chain.end());
  return chain;
}

JointPathResult Roadmap::Plan(const JointVector& start_rad, const JointVector& goal_rad,
                              const MotionChecker* scene_checker,
                              std::chrono::steady_clock::time_point deadline,
                              const CarriedItem* carried) const {
  std::lock_guard<std::mutex> lock(mutex_);
  JointPathResult result;
  const MotionChecker& final_checker = scene_checker ? *scene_checker : checker_;
  // Every motion of a path is checked by the roadmap's checker as it is found (a cached path
  // for the bare arm, as the cache holds): a scene's checker, when given, checks it again.
  auto finish = [&](std::vector<JointVector> path) {
    if (scene_checker == nullptr) {
      result.ok = true;
      result.path_rad = std::move(path);
      return result;
    }
    const MotionCheckResult check = final_checker.CheckPath(path, carried);
    if (!check.free) {
      result.reason = "the path collides with the scene at " +
                      std::to_string(static_cast<int>(100 * check.fraction_free)) +
                      "% of the way: " + check.report.ToString();
      return result;
    }
    result.ok = true;
    result.path_rad = std::move(path);
    return result;
  };
  if (const CollisionReport r = final_checker.checker().Check(start_rad, carried); r.in_collision) {
    result.reason = "the start collides: " + r.ToString();
    return result;
  }
  if (const CollisionReport r = final_checker.checker().Check(goal_rad, carried); r.in_collision) {
    result.reason = "the goal collides: " + r.ToString();
    return result;
  }
  // Cached paths between named poses.
  const NamedPose* from = nullptr;
  const NamedPose* to = nullptr;
  for (const NamedPose& pose : named_) {
    if (SameJoints(pose.q_rad, start_rad)) from = &pose;
    if (SameJoints(pose.q_rad, goal_rad)) to = &pose;
  }
  if (carried != nullptr) from = to = nullptr;  // the cache holds bare-arm paths
  if (from && to) {
    const auto it = cache_.find({from->name, to->name});
    if (it != cache_.end()) {
      result.cached = true;
      return finish(it->second);
    }
  }
  auto remember = [&](const std::vector<JointVector>& path) {
    if (from && to) cache_[{from->name, to->name}] = path;
  };
  ++result.edges_checked;
  if (checker_.CheckSegment(start_rad, goal_rad, carried).free) {
    remember({start_rad, goal_rad});
    return finish({start_rad, goal_rad});
  }
  // Through the roadmap, else two trees grown between start and goal.
  Joins start = NearestJoins(start_rad), goal = NearestJoins(goal_rad);
  std::string why_not;
  std::vector<JointVector> path =
      SearchLazily(&start, &goal, carried, deadline, &result.edges_checked, &why_not);
  if (!path.empty()) {
    path = Shortcut(std::move(path), checker_, carried);
    remember(path);
    return finish(std::move(path));
  }
  if (std::chrono::steady_clock::now() > deadline) {
    result.reason = why_not;
    return result;
  }
  path = ConnectTrees(start_rad, goal_rad, final_checker, carried, deadline);
  if (path.empty()) {
    result.reason = why_not + "; no path either by trees grown from start and goal (" +
                    std::to_string(options_.tree_nodes) + " nodes)";
    return result;
  }
  result.by_trees = true;
  return finish(Shortcut(std::move(path), final_checker, carried));
}

std::vector<JointVector> Roadmap::ConnectTrees(
    const JointVector& start_rad, const JointVector& goal_rad, const MotionChecker& checker,
    const CarriedItem* carried, std::chrono::steady_clock::time_point deadline) const {
  struct Tree {
    std::vector<JointVector> q;
    std::vector<int> parent;
    int Nearest(const JointVector& to, const Roadmap& map) const {
      int best = 0;
      double best_d = map.Distance(q[0], to);
      for (std::size_t i = 1; i < q.size(); ++i) {
        const double d = map.Distance(q[i], to);
        if (d < best_d) best_d = d, best = static_cast<int>(i);
      }
      return best;
    }
  };
  // One step from `from` toward `to`: at most tree_step_rad on any joint.
  auto steer = [&](const JointVector& from, const JointVector& to) -> JointVector {
    const JointVector delta = to - from;
    const double largest = delta.cwiseAbs().maxCoeff();
    return largest <= options_.tree_step_rad ? to
                                             : from + delta * (options_.tree_step_rad / largest);
  };
  const ur10::Ur10Model& model = checker.checker().robot().kinematics().model();
  const Eigen::Array<double, 6, 1> lo =
      (start_rad.array().min(goal_rad.array()) - options_.sample_margin_rad)
          .max(model.min_position_rad().array());
  const Eigen::Array<double, 6, 1> hi =
      (start_rad.array().max(goal_rad.array()) + options_.sample_margin_rad)
          .min(model.max_position_rad().array());
  std::mt19937 rng(options_.seed);
  Tree from_start{{start_rad}, {-1}}, from_goal{{goal_rad}, {-1}};
  Tree* a = &from_start;
  Tree* b = &from_goal;
  // Grows `tree` one step toward `target`; the new node's index, or -1 when blocked.
  auto extend = [&](Tree& tree, const JointVector& target) {
    const int near = tree.Nearest(target, *this);
    const JointVector q = steer(tree.q[near], target);
    if (!checker.CheckSegment(tree.q[near], q, carried).free) return -1;
    tree.q.push_back(q);
    tree.parent.push_back(near);
    return static_cast<int>(tree.q.size()) - 1;
  };
  const auto stop =
      std::min(deadline, std::chrono::steady_clock::now() +
                             std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                 std::chrono::duration<double>(options_.tree_time_s)));
  while (static_cast<int>(from_start.q.size() + from_goal.q.size()) < options_.tree_nodes) {
    if (std::chrono::steady_clock::now() > stop) return {};
    JointVector sample;
    for (int j = 0; j < 6; ++j)
      sample[j] = std::uniform_real_distribution<double>(lo[j], hi[j])(rng);
    const int added = extend(*a, sample);
    if (added >= 0) {
      // The other tree goes straight for the new node, step by step, until blocked.
      const JointVector& target = a->q[added];
      for (int reached = extend(*b, target); reached >= 0; reached = extend(*b, target)) {
        if (!SameJoints(b->q[reached], target)) continue;
        // Met: start's chain up to its meeting node, then goal's chain back from its own.
        std::vector<JointVector> path;
        const Tree& s = (a == &from_start) ? *a : *b;
        const Tree& g = (a == &from_start) ? *b : *a;
        const int s_meet = (a == &from_start) ? added : reached;
        const int g_meet = (a == &from_start) ? reached : added;
        for (int i = s_meet; i >= 0; i = s.parent[i]) path.push_back(s.q[i]);
        std::reverse(path.begin(), path.end());
        for (int i = g.parent[g_meet]; i >= 0; i = g.parent[i]) path.push_back(g.q[i]);
        return path;
      }
    }
    std::swap(a, b);
  }
  return {};
}

}  // namespace picking::planner
