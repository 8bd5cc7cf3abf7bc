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
  // A line that is a whole number of steps long up to rounding (a 0.40 m line between poses
  // from forward kinematics measures 20.000000000001 steps of 2 cm) takes that many, not one
  // more.
  constexpr double kRoundingSteps = 1e-9;
  lattice.n = std::max(
      {1, static_cast<int>(std::ceil(d.norm() / options.step_m - kRoundingSteps)),
       static_cast<int>(std::ceil(angle / (3.0 * options.tilt_step_rad) - kRoundingSteps))});
  const Eigen::Vector3d x =
      d.norm() > 1e-9 ? Eigen::Vector3d(d.normalized()) : Eigen::Vector3d(X_start.linear().col(2));
  lattice.y = x.unitOrthogonal();
  lattice.z = x.cross(lattice.y);
  return lattice;
}

}  // namespace

std::string CartesianSearchResult::Describe() const {
  if (ok) return "reached the goal";
  std::ostringstream out;
  out << FailureKindName(failure) << " at node " << failed_node << " ("
      << static_cast<int>(std::round(100.0 * fraction_achieved)) << "% of the way)";
  if (!detail.empty()) out << ": " << detail;
  return out.str();
}

namespace {

// One search: the lattice's nodes, the queue, and the result being filled in.
class Search {
 public:
  Search(const MotionChecker& checker, const CarriedItem* carried,
         const CartesianSearchOptions& options, const Lattice& lattice, const JointVector& q_start)
      : checker_(checker),
        kinematics_(checker.checker().robot().kinematics()),
        X_TcpTool_(checker.checker().robot().gripper().X_ToolTcp.inverse()),
        carried_(carried),
        options_(options),
        lattice_(lattice),
        branch_(kinematics_.BranchOf(q_start)) {
    nodes_.reserve(options.node_budget * 8 + 16);
    Node root;
    root.evaluated = true;
    root.q = q_start;
    root.h = lattice_.StepsToGo(root);
    nodes_.push_back(root);
    seen_.insert(Key(0, 0, 0, 0, 0));
  }

  CartesianSearchResult Run() {
    Expand(0);
    int goal = -1;
    while (!open_.empty() && !OutOfBudgetOrTime()) {
      const int index = open_.top().second;
      open_.pop();
      if (!nodes_[index].evaluated && !Evaluate(index)) continue;
      const Node& node = nodes_[index];
      if (node.i == lattice_.n && node.j == 0 && node.k == 0 && node.a == 0 && node.b == 0) {
        goal = index;
        break;
      }
      Expand(index);
    }
    result_.fraction_achieved = double(nodes_[best_].i) / lattice_.n;
    if (goal < 0) {
      if (open_.empty() && result_.failure == FailureKind::kUnspecified) {
        result_.failure = FailureKind::kNodeBudgetSpent;
        result_.detail = "no free node left within the lattice";
      }
      return result_;
    }
    return Path(goal);
  }

 private:
  using Entry = std::pair<double, int>;  // (steps to go, node); ties: older first

  bool OutOfBudgetOrTime() {
    if (result_.nodes_evaluated >= options_.node_budget) {
      if (result_.failure == FailureKind::kUnspecified) {
        result_.failure = FailureKind::kNodeBudgetSpent;
      }
      result_.detail += (result_.detail.empty() ? "" : "; ") + std::string("node budget of ") +
                        std::to_string(options_.node_budget) + " spent";
      return true;
    }
    if (std::chrono::steady_clock::now() > options_.deadline) {
      result_.failure = FailureKind::kDeadline;
      result_.detail =
          "the call's deadline passed after " + std::to_string(result_.nodes_evaluated) + " nodes";
      return true;
    }
    return false;
  }

  // Queues the unseen neighbours of node `index` within the lattice's bounds: a step along,
  // across (both ways, both axes) or both, or a tilt in place or while advancing.
  void Expand(int index) {
    ++result_.nodes_expanded;
    const Node parent = nodes_[index];
    for (int di = 0; di <= 1; ++di) {
      for (int dj = -1; dj <= 1; ++dj) {
        for (int dk = -1; dk <= 1; ++dk) {
          for (int t = 0; t < 5; ++t) {
            if (di == 0 && dj == 0 && dk == 0 && t == 0) continue;
            if (t != 0 && (dj != 0 || dk != 0)) continue;
            Node child = parent;
            child.i += di;
            child.j += dj;
            child.k += dk;
            child.a += t == 1 ? 1 : t == 2 ? -1 : 0;
            child.b += t == 3 ? 1 : t == 4 ? -1 : 0;
            if (child.i > lattice_.n || std::abs(child.j) > options_.max_lateral_steps ||
                std::abs(child.k) > options_.max_lateral_steps ||
                std::abs(child.a) > options_.max_tilt_steps ||
                std::abs(child.b) > options_.max_tilt_steps) {
              continue;
            }
            if (!seen_.insert(Key(child.i, child.j, child.k, child.a, child.b)).second) continue;
            child.parent = index;
            child.evaluated = false;
            child.h = lattice_.StepsToGo(child);
            nodes_.push_back(child);
            open_.emplace(child.h, static_cast<int>(nodes_.size()) - 1);
          }
        }
      }
    }
  }

  // IK continuous with the parent and a free motion from it; false (with the failure kept
  // if it is the furthest so far) when the node is unusable.
  bool Evaluate(int index) {
    ++result_.nodes_evaluated;
    Node& node = nodes_[index];
    const Node& parent = nodes_[node.parent];
    std::string reason;
    const auto ik =
        kinematics_.NearestSolution(lattice_.Pose(node) * X_TcpTool_, parent.q, branch_, &reason);
    if (!ik) {
      return Fail(
          node, index, FailureKind::kIkUnreachable,
          "no IK solution on branch " + branch_.ToString() + (reason.empty() ? "" : ": " + reason),
          nullptr);
    }
    const JointVector dq = (ik->q_rad - parent.q).cwiseAbs();
    int joint = 0;
    if (dq.maxCoeff(&joint) > options_.max_joint_step_rad) {
      return Fail(node, index, FailureKind::kJointJump,
                  std::string(ur10::kJointNames[joint]) + " would jump " +
                      std::to_string(dq[joint]) + " rad",
                  nullptr);
    }
    const MotionCheckResult motion = checker_.CheckSegment(parent.q, ik->q_rad, carried_);
    if (!motion.free) {
      return Fail(node, index, FailureKind::kCollision, motion.report.ToString(), &motion.report);
    }
    node.q = ik->q_rad;
    node.evaluated = true;
    if (node.i > nodes_[best_].i) best_ = index;
    return true;
  }

  bool Fail(const Node& node, int index, FailureKind kind, std::string detail,
            const CollisionReport* report) {
    if (node.i >= best_failure_i_) {
      best_failure_i_ = node.i;
      result_.failure = kind;
      result_.failed_node = index;
      result_.detail = std::move(detail);
      result_.collision = report ? *report : CollisionReport{};
    }
    return false;
  }

  CartesianSearchResult Path(int goal) {
    for (int n = goal; n >= 0; n = nodes_[n].parent) {
      result_.path_rad.push_back(nodes_[n].q);
      result_.X_BaseTcp.push_back(lattice_.Pose(nodes_[n]));
    }
    std::reverse(result_.path_rad.begin(), result_.path_rad.end());
    std::reverse(result_.X_BaseTcp.begin(), result_.X_BaseTcp.end());
    result_.ok = true;
    result_.failure = FailureKind::kUnspecified;
    result_.detail.clear();
    result_.fraction_achieved = 1.0;
    return result_;
  }

  const MotionChecker& checker_;
  const ur10::Ur10Kinematics& kinematics_;
  const Eigen::Isometry3d X_TcpTool_;
  const CarriedItem* carried_;
  const CartesianSearchOptions& options_;
  const Lattice& lattice_;
  const ur10::Branch branch_;
  std::vector<Node> nodes_;
  std::unordered_set<std::uint64_t> seen_;
  std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> open_;
  CartesianSearchResult result_;
  int best_ = 0;             // evaluated node furthest along
  int best_failure_i_ = -1;  // how far along the kept failure is
};

}  // namespace

CartesianSearchResult SearchCartesianPath(const MotionChecker& checker,
                                          const JointVector& q_start_rad,
                                          const Eigen::Isometry3d& X_BaseTcp_goal,
                                          const CarriedItem* carried,
                                          const CartesianSearchOptions& options) {
  const CollisionReport start_report = checker.checker().Check(q_start_rad, carried);
  if (start_report.in_collision) {
    CartesianSearchResult result;
    result.failure = FailureKind::kStartInCollision;
    result.failed_node = 0;
    result.collision = start_report;
    result.detail = start_report.ToString();
    return result;
  }
  const Lattice lattice =
      MakeLattice(checker.checker().robot().X_BaseTcp(q_start_rad), X_BaseTcp_goal, options);
  return Search(checker, carried, options, lattice, q_start_rad).Run();
}

}  // namespace picking::planner
