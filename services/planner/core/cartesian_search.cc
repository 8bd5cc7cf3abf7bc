#include "services/planner/core/cartesian_search.h"

#include <cmath>
#include <queue>
#include <sstream>
#include <unordered_set>

namespace picking::planner {
namespace {

struct Node {
  int i = 0, j = 0, k = 0, a = 0, b = 0;  // along, across (y, z), tilts (about y, z)
  int parent = -1;
  double h = 0.0;  // steps to go
  bool evaluated = false;
  JointVector q = JointVector::Zero();
};

std::uint64_t Key(int i, int j, int k, int a, int b) {
  auto u = [](int v) { return static_cast<std::uint64_t>(v + 512) & 0x3ff; };
  return (u(i) << 40) | (u(j) << 30) | (u(k) << 20) | (u(a) << 10) | u(b);
}

// The lattice around the straight line from the start pose to the goal.
struct Lattice {
  Eigen::Vector3d p0, p_goal, y, z;
  Eigen::Quaterniond q0, q_goal;
  int n = 1;  // steps along the line
  double step = 0.02, tilt = 0.087;

  Eigen::Isometry3d Pose(const Node& node) const {
    const double f = double(node.i) / n;
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.translation() = p0 + f * (p_goal - p0) + node.j * step * y + node.k * step * z;
    X.linear() = (Eigen::AngleAxisd(node.a * tilt, y) * Eigen::AngleAxisd(node.b * tilt, z) *
                  q0.slerp(f, q_goal))
                     .toRotationMatrix();
    return X;
  }
  double StepsToGo(const Node& node) const {
    return std::abs(n - node.i) + std::abs(node.j) + std::abs(node.k) +
           0.5 * (std::abs(node.a) + std::abs(node.b));
  }
};

Lattice MakeLattice(const Eigen::Isometry3d& X_start, const Eigen::Isometry3d& X_goal,
                    const CartesianSearchOptions& options) {
  Lattice lattice;
  lattice.p0 = X_start.translation();
  lattice.p_goal = X_goal.translation();
  lattice.q0 = Eigen::Quaterniond(X_start.linear());
  lattice.q_goal = Eigen::Quaterniond(X_goal.linear());
  lattice.step = options.step_m;
  lattice.tilt = options.tilt_step_rad;
  const Eigen::Vector3d d = lattice.p_goal - lattice.p0;
  const double angle = lattice.q0.angularDistance(lattice.q_goal);
  lattice.n = std::max({1, static_cast<int>(std::ceil(d.norm() / options.step_m)),
                        static_cast<int>(std::ceil(angle / (3.0 * options.tilt_step_rad)))});
  const Eigen::Vector3d x =
      d.norm() > 1e-9 ? Eigen::Vector3d(d.normalized()) : Eigen::Vector3d(X_start.linear().col(2));
  lattice.y = x.unitOrthogonal();
  lattice.z = x.cross(lattice.y);
  return lattice;
}

}  // namespace

const char* CartesianFailureName(CartesianFailureKind kind) {
  switch (kind) {
    case CartesianFailureKind::kNone:
      return "none";
    case CartesianFailureKind::kStartInCollision:
      return "start in collision";
    case CartesianFailureKind::kIkUnreachable:
      return "ik unreachable";
    case CartesianFailureKind::kJointJump:
      return "joint jump";
    case CartesianFailureKind::kCollision:
      return "collision";
    case CartesianFailureKind::kBudget:
      return "node budget spent";
    case CartesianFailureKind::kDeadline:
      return "deadline";
  }
  return "unknown";
}

std::string CartesianSearchResult::Describe() const {
  if (ok) return "reached the goal";
  std::ostringstream out;
  out << CartesianFailureName(failure) << " at node " << failed_node << " ("
      << static_cast<int>(std::round(100.0 * fraction_achieved)) << "% of the way)";
  if (!detail.empty()) out << ": " << detail;
  return out.str();
}

CartesianSearchResult SearchCartesianPath(const MotionChecker& checker,
                                          const JointVector& q_start_rad,
                                          const Eigen::Isometry3d& X_BaseTcp_goal,
                                          const CarriedItem* carried,
                                          const CartesianSearchOptions& options) {
  const RobotGeometry& robot = checker.checker().robot();
  const ur10::Ur10Kinematics& kinematics = robot.kinematics();
  const Eigen::Isometry3d X_TcpTool = robot.gripper().X_ToolTcp.inverse();
  CartesianSearchResult result;
  const CollisionReport start_report = checker.checker().Check(q_start_rad, carried);
  if (start_report.in_collision) {
    result.failure = CartesianFailureKind::kStartInCollision;
    result.failed_node = 0;
    result.collision = start_report;
    result.detail = start_report.ToString();
    return result;
  }
  const Lattice lattice = MakeLattice(robot.X_BaseTcp(q_start_rad), X_BaseTcp_goal, options);
  const ur10::Branch branch = kinematics.BranchOf(q_start_rad);

  std::vector<Node> nodes;
  nodes.reserve(options.node_budget * 8 + 16);
  std::unordered_set<std::uint64_t> seen;
  using Entry = std::pair<double, int>;  // (steps to go, node); ties: older first
  std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> open;
  Node root;
  root.evaluated = true;
  root.q = q_start_rad;
  root.h = lattice.StepsToGo(root);
  nodes.push_back(root);
  seen.insert(Key(0, 0, 0, 0, 0));
  open.emplace(root.h, 0);

  int best = 0;  // evaluated node furthest along
  int best_failure_i = -1;
  auto fail = [&](const Node& node, int index, CartesianFailureKind kind, std::string detail,
                  const CollisionReport* report) {
    if (node.i < best_failure_i) return;
    best_failure_i = node.i;
    result.failure = kind;
    result.failed_node = index;
    result.detail = std::move(detail);
    result.collision = report ? *report : CollisionReport{};
  };
  auto expand = [&](int index) {
    const Node parent = nodes[index];
    for (int di = 0; di <= 1; ++di) {
      for (int dj = -1; dj <= 1; ++dj) {
        for (int dk = -1; dk <= 1; ++dk) {
          for (int t = 0; t < 5; ++t) {
            const int da = t == 1 ? 1 : t == 2 ? -1 : 0, db = t == 3 ? 1 : t == 4 ? -1 : 0;
            if (di == 0 && dj == 0 && dk == 0 && t == 0) continue;
            if (t != 0 && (dj != 0 || dk != 0)) continue;  // tilt in place or while advancing
            Node child = parent;
            child.i += di;
            child.j += dj;
            child.k += dk;
            child.a += da;
            child.b += db;
            if (child.i > lattice.n || std::abs(child.j) > options.max_lateral_steps ||
                std::abs(child.k) > options.max_lateral_steps ||
                std::abs(child.a) > options.max_tilt_steps ||
                std::abs(child.b) > options.max_tilt_steps) {
              continue;
            }
            if (!seen.insert(Key(child.i, child.j, child.k, child.a, child.b)).second) continue;
            child.parent = index;
            child.evaluated = false;
            child.h = lattice.StepsToGo(child);
            nodes.push_back(child);
            open.emplace(child.h, static_cast<int>(nodes.size()) - 1);
          }
        }
      }
    }
  };

  int goal = -1;
  expand(0);
  ++result.nodes_expanded;
  while (!open.empty()) {
    if (result.nodes_evaluated >= options.node_budget) {
      if (result.failure == CartesianFailureKind::kNone)
        result.failure = CartesianFailureKind::kBudget;
      result.detail += (result.detail.empty() ? "" : "; ") + std::string("node budget of ") +
                       std::to_string(options.node_budget) + " spent";
      break;
    }
    if (std::chrono::steady_clock::now() > options.deadline) {
      result.failure = CartesianFailureKind::kDeadline;
      result.detail =
          "the call's deadline passed after " + std::to_string(result.nodes_evaluated) + " nodes";
      break;
    }
    const int index = open.top().second;
    open.pop();
    Node& node = nodes[index];
    if (!node.evaluated) {
      ++result.nodes_evaluated;
      const Node& parent = nodes[node.parent];
      const Eigen::Isometry3d X_BaseTcp = lattice.Pose(node);
      std::string reason;
      const auto ik = kinematics.NearestSolution(X_BaseTcp * X_TcpTool, parent.q, branch, &reason);
      if (!ik) {
        fail(
            node, index, CartesianFailureKind::kIkUnreachable,
            "no IK solution on branch " + branch.ToString() + (reason.empty() ? "" : ": " + reason),
            nullptr);
        continue;
      }
      const JointVector dq = (ik->q_rad - parent.q).cwiseAbs();
      int joint = 0;
      if (dq.maxCoeff(&joint) > options.max_joint_step_rad) {
        fail(node, index, CartesianFailureKind::kJointJump,
             std::string(ur10::kJointNames[joint]) + " would jump " + std::to_string(dq[joint]) +
                 " rad",
             nullptr);
        continue;
      }
      const MotionCheckResult motion = checker.CheckSegment(parent.q, ik->q_rad, carried);
      if (!motion.free) {
        fail(node, index, CartesianFailureKind::kCollision, motion.report.ToString(),
             &motion.report);
        continue;
      }
      node.q = ik->q_rad;
      node.evaluated = true;
      if (node.i > nodes[best].i) best = index;
    }
    if (node.i == lattice.n && node.j == 0 && node.k == 0 && node.a == 0 && node.b == 0) {
      goal = index;
      break;
    }
    expand(index);
    ++result.nodes_expanded;
  }
  result.fraction_achieved = double(nodes[best].i) / lattice.n;
  if (goal < 0) {
    if (open.empty() && result.failure == CartesianFailureKind::kNone) {
      result.failure = CartesianFailureKind::kBudget;
      result.detail = "no free node left within the lattice";
    }
    return result;
  }
  for (int n = goal; n >= 0; n = nodes[n].parent) {
    result.path_rad.push_back(nodes[n].q);
    result.X_BaseTcp.push_back(lattice.Pose(nodes[n]));
  }
  std::reverse(result.path_rad.begin(), result.path_rad.end());
  std::reverse(result.X_BaseTcp.begin(), result.X_BaseTcp.end());
  result.ok = true;
  result.failure = CartesianFailureKind::kNone;
  result.detail.clear();
  result.fraction_achieved = 1.0;
  return result;
}

}  // namespace picking::planner
