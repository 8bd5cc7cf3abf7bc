#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <map>
#include <random>

#include "libs/world/cell_config.h"
#include "services/planner/core/collision_world.h"
#include "services/planner/core/motion_check.h"
#include "services/planner/core/scene.h"

namespace picking::planner {
namespace {

// The real UR10, gripper and cell, and a scan of boxes standing in three bins.
class CollisionTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    kinematics_ = new ur10::Ur10Kinematics(ur10::Ur10Model::Load(PICKING_DATA_DIR "/ur10"));
    robot_ = new RobotGeometry(*kinematics_, GripperGeometry{});
    cell_model_ = new world::CellModel(
        world::LoadCellModel(world::ReadCellConfig(PICKING_DATA_DIR "/cell/default_cell.yaml")));
    cell_ = new StaticCell(*cell_model_);
    ScanScene scene(ScanSceneOptions{});
    std::vector<float> xyz;
    for (const char* name : {"bin_B", "bin_E", "bin_J"}) {
      const Eigen::AlignedBox3d inner = cell_model_->bin(name).inner_S;
      // A 10 x 8 x 12 cm box on the bin floor near the opening, sampled every 3 mm.
      const Eigen::Vector3d c_S(inner.max().x() - 0.12, inner.center().y() + 0.04,
                                inner.min().z() + 0.06);
      const Eigen::Vector3d half(0.05, 0.04, 0.06);
      for (double x = -half.x(); x <= half.x(); x += 0.003) {
        for (double y = -half.y(); y <= half.y(); y += 0.003) {
          for (double z = -half.z(); z <= half.z(); z += 0.003) {
            const bool surface = std::abs(std::abs(x) - half.x()) < 0.003 ||
                                 std::abs(std::abs(y) - half.y()) < 0.003 ||
                                 std::abs(std::abs(z) - half.z()) < 0.003;
            if (!surface) continue;
            const Eigen::Vector3d p =
                cell_model_->config.X_BaseShelf * (c_S + Eigen::Vector3d(x, y, z));
            xyz.insert(xyz.end(), {float(p.x()), float(p.y()), float(p.z())});
          }
        }
      }
    }
    scene.Insert(xyz.data(), xyz.size() / 3, {});
    scan_ = new std::shared_ptr<const ScanObstacles>(scene.Snapshot());
  }

  static ur10::Ur10Kinematics* kinematics_;
  static RobotGeometry* robot_;
  static world::CellModel* cell_model_;
  static StaticCell* cell_;
  static std::shared_ptr<const ScanObstacles>* scan_;
};
ur10::Ur10Kinematics* CollisionTest::kinematics_ = nullptr;
RobotGeometry* CollisionTest::robot_ = nullptr;
world::CellModel* CollisionTest::cell_model_ = nullptr;
StaticCell* CollisionTest::cell_ = nullptr;
std::shared_ptr<const ScanObstacles>* CollisionTest::scan_ = nullptr;

TEST_F(CollisionTest, SpheresEncloseEveryLinkVertex) {
  for (int b = 0; b < 7; ++b) {
    const auto& mesh = robot_->link_mesh(b);
    ASSERT_FALSE(robot_->spheres(b).empty()) << BodyName(b);
    for (const auto& v : mesh.vertices) {
      bool inside = false;
      // In a coarse sphere, and in one of that sphere's leaves.
      bool in_leaf = false;
      for (const auto& s : robot_->spheres(b).coarse) {
        if ((v - s.center_B).norm() > s.radius_m) continue;
        inside = true;
        if (s.num_children == 0) in_leaf = true;
        for (std::uint32_t k = 0; k < s.num_children; ++k) {
          const Sphere& leaf = robot_->spheres(b).fine[s.first_child + k];
          if ((v - leaf.center_B).norm() <= leaf.radius_m) in_leaf = true;
        }
      }
      ASSERT_TRUE(inside) << BodyName(b) << " vertex " << v.transpose();
      ASSERT_TRUE(in_leaf) << BodyName(b) << " vertex " << v.transpose();
    }
  }
  for (int b = 0; b < kNumArmBodies; ++b) {
    float largest = 0.f;
    for (const auto& s : robot_->spheres(b).fine) largest = std::max(largest, s.radius_m);
    std::printf("%s: %zu coarse spheres, %zu fine, largest fine radius %.3f m\n", BodyName(b),
                robot_->spheres(b).size(), robot_->spheres(b).fine.size(), largest);
  }
  std::printf("self-collision pairs:");
  for (const auto& [a, b] : robot_->self_pairs()) std::printf(" %s-%s", BodyName(a), BodyName(b));
  std::printf("\n");
  EXPECT_GE(robot_->num_arm_spheres(), 20u);
  EXPECT_LE(robot_->num_arm_spheres(), 80u);
}

TEST_F(CollisionTest, ReportsWhichBodyHitsWhat) {
  // Stretched straight down through the floor.
  JointVector q;
  q << 0.0, 1.5707963, 0.0, 0.0, 0.0, 0.0;
  const FastChecker fast(*robot_, *cell_, scan_->get());
  const ExactChecker exact(*robot_, *cell_, scan_->get());
  const CollisionReport f = fast.Check(q);
  const CollisionReport e = exact.Check(q);
  EXPECT_TRUE(f.in_collision);
  EXPECT_TRUE(e.in_collision);
  EXPECT_FALSE(f.ToString().empty());
  EXPECT_NE(e.ToString().find("hits"), std::string::npos);
}

// The arm straight up puts the tcp above the robot's workspace box: a collision for both
// checks (the robot service would refuse the motion), named as such.
TEST_F(CollisionTest, TheTcpOutsideTheRobotsWorkspaceIsACollision) {
  JointVector up = JointVector::Zero();
  double best_z = -1.0;
  for (const double wrist_1 : {0.0, -1.5707963, 1.5707963, M_PI}) {
    for (const double wrist_2 : {0.0, -1.5707963, 1.5707963, M_PI}) {
      JointVector q;
      q << 0.0, -1.5707963, 0.0, wrist_1, wrist_2, 0.0;
      const double z = robot_->X_BaseTcp(q).translation().z();
      if (z > best_z) best_z = z, up = q;
    }
  }
  ASSERT_GT(robot_->X_BaseTcp(up).translation().z(), cell_->tcp_workspace_Base().max().z());
  const FastChecker fast(*robot_, *cell_, nullptr);
  const ExactChecker exact(*robot_, *cell_, nullptr);
  EXPECT_FALSE(fast.IsFree(up));
  EXPECT_NE(fast.Check(up).ToString().find("workspace"), std::string::npos);
  EXPECT_NE(exact.Check(up).ToString().find("workspace"), std::string::npos);
  // Without the box, nothing else is hit there.
  StaticCellOptions unbounded;
  unbounded.tcp_workspace_Base.setEmpty();
  const StaticCell open_cell(*cell_model_, unbounded);
  EXPECT_TRUE(FastChecker(*robot_, open_cell, nullptr).IsFree(up));
  EXPECT_FALSE(ExactChecker(*robot_, open_cell, nullptr).Check(up).in_collision);
}

// The planner's box is the robot service's (its settings file, the robot's defaults).
TEST(WorkspaceTest, ThePlannersTcpBoxIsTheRobotServicesSafetyBox) {
  const YAML::Node robot = YAML::LoadFile(PICKING_DATA_DIR "/cell/robot_cell.yaml");
  const StaticCellOptions planner;
  for (int k = 0; k < 3; ++k) {
    EXPECT_DOUBLE_EQ(robot["safety"]["workspace_min_m"][k].as<double>(),
                     planner.tcp_workspace_Base.min()[k]);
    EXPECT_DOUBLE_EQ(robot["safety"]["workspace_max_m"][k].as<double>(),
                     planner.tcp_workspace_Base.max()[k]);
  }
}

// Joint vectors with the tcp in and around the shelf's bins and the tote: where the planner
// works and where contacts are close.
std::vector<JointVector> NearContactSamples(const ur10::Ur10Kinematics& kinematics,
                                            const world::CellModel& cell,
                                            const GripperGeometry& gripper, int count,
                                            std::mt19937& rng) {
  std::vector<JointVector> out;
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> tilt(0.0, 0.35);
  std::normal_distribution<double> jitter(0.0, 0.03);
  while (static_cast<int>(out.size()) < count) {
    const auto& bin = cell.bins[static_cast<int>(u(rng) * cell.bins.size()) % cell.bins.size()];
    Eigen::Vector3d p_S =
        bin.inner_S.min() +
        (bin.inner_S.sizes().array() * Eigen::Array3d(u(rng), u(rng), u(rng))).matrix();
    p_S.x() += 0.25 * u(rng);  // also in front of the opening
    const Eigen::Vector3d p_Base = cell.config.X_BaseShelf * p_S;
    // Tool axis into the bin (-x of the shelf frame), tilted at random.
    const Eigen::Vector3d into = cell.config.X_BaseShelf.linear() * -Eigen::Vector3d::UnitX();
    Eigen::Vector3d z = (into + Eigen::Vector3d(tilt(rng), tilt(rng), tilt(rng))).normalized();
    Eigen::Vector3d x = z.unitOrthogonal();
    Eigen::Isometry3d X_BaseTcp = Eigen::Isometry3d::Identity();
    X_BaseTcp.linear() << x, z.cross(x), z;
    X_BaseTcp.linear() =
        X_BaseTcp.linear() *
        Eigen::AngleAxisd(6.283 * u(rng), Eigen::Vector3d::UnitZ()).toRotationMatrix();
    X_BaseTcp.translation() = p_Base;
    const auto ik = kinematics.Solve(X_BaseTcp * gripper.X_ToolTcp.inverse());
    for (const auto& s : ik.solutions) {
      JointVector q = s.q_rad;
      for (int j = 0; j < 6; ++j) q[j] += jitter(rng);
      out.push_back(q);
    }
  }
  out.resize(count);
  return out;
}

// Joint vectors drawn uniformly within the UR10's limits.
std::vector<JointVector> RandomStates(const ur10::Ur10Model& model, int count, std::mt19937& rng) {
  const JointVector lo = model.min_position_rad();
  const JointVector hi = model.max_position_rad();
  std::vector<JointVector> states;
  for (int i = 0; i < count; ++i) {
    JointVector q;
    for (int j = 0; j < 6; ++j) q[j] = std::uniform_real_distribution<double>(lo[j], hi[j])(rng);
    states.push_back(q);
  }
  return states;
}

TEST_F(CollisionTest, FastCheckIsNeverFreeWhereFclCollides) {
  const FastChecker fast(*robot_, *cell_, scan_->get());
  // FCL on every pair: the spheres must not judge themselves.
  const ExactChecker exact(*robot_, *cell_, scan_->get(), /*sphere_broad_phase=*/false);
  std::mt19937 rng(20161);
  std::vector<JointVector> states = RandomStates(kinematics_->model(), 40000, rng);
  const auto near = NearContactSamples(*kinematics_, *cell_model_, robot_->gripper(), 60000, rng);
  states.insert(states.end(), near.begin(), near.end());
  const CarriedItem item = MakeCarriedItem(
      "box",
      Eigen::AlignedBox3d(Eigen::Vector3d(-0.1, -0.06, 0.0), Eigen::Vector3d(0.1, 0.06, 0.08)),
      Eigen::Isometry3d::Identity());
  int exact_hits = 0, fast_hits = 0, missed = 0;
  std::map<std::string, int> false_alarm_by_;
  for (std::size_t i = 0; i < states.size(); ++i) {
    const CarriedItem* carried = (i % 4 == 3) ? &item : nullptr;
    const bool exact_collides = exact.Check(states[i], carried).in_collision;
    const bool fast_free = fast.IsFree(states[i], carried);
    exact_hits += exact_collides;
    fast_hits += !fast_free;
    if (!exact_collides && !fast_free) {
      const CollisionReport r = fast.Check(states[i], carried);
      ++false_alarm_by_[std::string(BodyName(r.body)) + " / " + r.obstacle];
    }
    if (exact_collides && fast_free) {
      ++missed;
      ADD_FAILURE() << "fast check calls free what FCL calls colliding ("
                    << exact.Check(states[i], carried).ToString() << ") at "
                    << states[i].transpose();
      if (missed > 5) break;
    }
  }
  EXPECT_EQ(missed, 0);
  // Both checks see plenty of collisions and plenty of free states, and the fast one is
  // not so conservative that it calls nearly everything colliding.
  EXPECT_GT(exact_hits, 10000);
  EXPECT_LT(exact_hits, 90000);
  const int false_alarms = fast_hits - exact_hits;
  RecordProperty("states", static_cast<int>(states.size()));
  RecordProperty("exact_collisions", exact_hits);
  RecordProperty("fast_false_alarms", false_alarms);
  std::printf(
      "states %zu, FCL collisions %d, fast collisions %d (false alarms %d, %.1f%% of "
      "the free states)\n",
      states.size(), exact_hits, fast_hits, false_alarms,
      100.0 * false_alarms / (states.size() - exact_hits));
  for (const auto& [what, n] : false_alarm_by_)
    std::printf("  false alarm %s: %d\n", what.c_str(), n);
  // Most false alarms are the forearm against the wrist housings, which stay within a
  // centimetre or two of each other over much of the joint space (benchmarks/RESULTS.md).
  EXPECT_LT(false_alarms, static_cast<int>(0.65 * (states.size() - exact_hits)));
}

// The exact check's broad phase only skips FCL queries that the enclosing spheres prove
// clear: with and without it, FCL gives the same answer on random, near-contact and carrying
// states, and the broad phase leaves most of the queries out.
TEST_F(CollisionTest, SphereBroadPhaseGivesFclsAnswer) {
  const ExactChecker culled(*robot_, *cell_, scan_->get());
  const ExactChecker full(*robot_, *cell_, scan_->get(), /*sphere_broad_phase=*/false);
  const FastChecker fast(*robot_, *cell_, scan_->get());
  std::mt19937 rng(2016);
  std::vector<JointVector> states = RandomStates(kinematics_->model(), 2000, rng);
  const auto near = NearContactSamples(*kinematics_, *cell_model_, robot_->gripper(), 6000, rng);
  states.insert(states.end(), near.begin(), near.end());
  const CarriedItem item = MakeCarriedItem(
      "box",
      Eigen::AlignedBox3d(Eigen::Vector3d(-0.1, -0.06, 0.0), Eigen::Vector3d(0.1, 0.06, 0.08)),
      Eigen::Isometry3d::Identity());
  int collisions = 0, mismatches = 0;
  std::size_t pairs_total = 0, pairs_near = 0;
  for (std::size_t i = 0; i < states.size(); ++i) {
    const CarriedItem* carried = (i % 3 == 2) ? &item : nullptr;
    const CollisionReport a = culled.Check(states[i], carried);
    const CollisionReport b = full.Check(states[i], carried);
    collisions += b.in_collision;
    if (a.in_collision != b.in_collision) {
      ++mismatches;
      ADD_FAILURE() << "broad phase: " << (a.in_collision ? a.ToString() : "free")
                    << ", FCL on every pair: " << (b.in_collision ? b.ToString() : "free") << " at "
                    << states[i].transpose();
      if (mismatches > 5) break;
    }
    BodyPoses X;
    robot_->ComputePoses(states[i], carried, &X);
    const Proximity p = fast.Near(states[i], X, carried);
    const int bodies = carried ? kNumBodies : kNumArmBodies;
    for (int body = 1; body < bodies; ++body) {
      pairs_total += fast.num_obstacles();
      pairs_near += __builtin_popcount(p.near_obstacles[body]);
    }
  }
  EXPECT_EQ(mismatches, 0);
  EXPECT_GT(collisions, 1000);
  EXPECT_LT(collisions, 7000);
  std::printf("states %zu, collisions %d; body-obstacle pairs left to FCL: %.1f%%\n", states.size(),
              collisions, 100.0 * pairs_near / pairs_total);
  EXPECT_LT(pairs_near, pairs_total / 4);
}

// The head on its joint, turned a quarter turn: the gripper is the tube to the joint and the
// head to the cup, each a prism in FCL; its spheres hold both cylinders, and the spheres'
// broad phase still gives FCL's answer.
TEST_F(CollisionTest, ABentHeadIsTwoCylindersForBothChecks) {
  GripperGeometry articulated;
  articulated.head_length_m = 0.09;
  articulated.max_head_angle_rad = M_PI / 2;
  const GripperGeometry bent_gripper = articulated.AtHeadAngle(M_PI / 2);
  EXPECT_TRUE(bent_gripper.bent());
  EXPECT_FALSE(articulated.bent());
  EXPECT_THROW(articulated.AtHeadAngle(2.0), std::invalid_argument);
  EXPECT_TRUE(bent_gripper.AtHeadAngle(0.0).X_ToolTcp.isApprox(articulated.X_ToolTcp));
  const RobotGeometry bent = robot_->WithGripper(bent_gripper);
  // Points on both cylinders' surfaces and the knuckle lie in the gripper's spheres.
  const Eigen::Vector3d p_J = bent_gripper.p_ToolJoint();
  const Eigen::Vector3d z_Tcp = bent_gripper.X_ToolTcp.linear().col(2);
  auto in_spheres = [&](const Eigen::Vector3d& p) {
    for (const Sphere& s : bent.spheres(kBodyTool).coarse) {
      if ((s.center_B.cast<double>() - p).norm() <= s.radius_m) return true;
    }
    return false;
  };
  const double r = bent_gripper.tube_radius_m;
  int outside = 0;
  for (int k = 0; k < 24; ++k) {
    const double a = 2.0 * M_PI * k / 24;
    for (int i = 0; i <= 20; ++i) {
      const double t = i / 20.0;
      const Eigen::Vector3d d1 = p_J.normalized();
      const Eigen::Vector3d ring1 =
          r * (std::cos(a) * d1.unitOrthogonal() + std::sin(a) * d1.cross(d1.unitOrthogonal()));
      const Eigen::Vector3d ring2 = r * (std::cos(a) * z_Tcp.unitOrthogonal() +
                                         std::sin(a) * z_Tcp.cross(z_Tcp.unitOrthogonal()));
      outside += !in_spheres(t * p_J + ring1);
      outside += !in_spheres(p_J + t * (bent_gripper.head_length_m - 0.02) * z_Tcp + ring2);
      outside += !in_spheres(p_J + t * ring1.normalized() * r);  // the knuckle
    }
  }
  EXPECT_EQ(outside, 0);
  // The gripper is paired with the links it may now reach.
  const auto& pairs = bent.self_pairs();
  EXPECT_NE(
      std::find(pairs.begin(), pairs.end(), std::make_pair(int(kBodyUpperArm), int(kBodyTool))),
      pairs.end());

  const ExactChecker culled(bent, *cell_, scan_->get());
  const ExactChecker full(bent, *cell_, scan_->get(), /*sphere_broad_phase=*/false);
  const FastChecker fast(bent, *cell_, scan_->get());
  std::mt19937 rng(2017);
  std::vector<JointVector> states = RandomStates(kinematics_->model(), 1000, rng);
  const auto near = NearContactSamples(*kinematics_, *cell_model_, bent_gripper, 4000, rng);
  states.insert(states.end(), near.begin(), near.end());
  int collisions = 0, mismatches = 0, missed = 0;
  for (const JointVector& q : states) {
    const CollisionReport a = culled.Check(q, nullptr);
    const CollisionReport b = full.Check(q, nullptr);
    collisions += b.in_collision;
    mismatches += a.in_collision != b.in_collision;
    missed += b.in_collision && fast.IsFree(q, nullptr);
  }
  EXPECT_EQ(mismatches, 0);
  EXPECT_EQ(missed, 0);
  EXPECT_GT(collisions, 500);
  EXPECT_LT(collisions, 4500);
}

// The slack is a lower bound: every state whose body points all lie within the slack of a
// checked state's stays free with the same padding (self pairs with a distance table aside:
// the motion check bounds their step through their joints), and its sign is IsFree's.
TEST_F(CollisionTest, SlackIsHowFarEveryPointMayMove) {
  const FastChecker fast(*robot_, *cell_, scan_->get());
  const MotionChecker motion(fast);
  std::mt19937 rng(7);
  const auto states = NearContactSamples(*kinematics_, *cell_model_, robot_->gripper(), 3000, rng);
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const float padding = 0.003f, cap = 0.05f;
  int positive = 0, moved = 0;
  for (const JointVector& q : states) {
    const float slack = fast.Slack(q, nullptr, padding, cap);
    ASSERT_EQ(slack >= 0.f, fast.IsFree(q, nullptr, padding)) << q.transpose();
    EXPECT_LE(slack, cap);
    if (slack <= 0.f) continue;
    ++positive;
    // A random joint direction scaled so that no point travels farther than the slack.
    JointVector dq;
    for (int j = 0; j < 6; ++j) dq[j] = gauss(rng);
    double travel = 0.0;
    for (int j = 0; j < 6; ++j) travel += std::abs(dq[j]) * motion.reach_m(j, nullptr);
    const JointVector q2 = q + dq * (slack * u(rng) / travel);
    const CollisionReport r = fast.Check(q2, nullptr, padding);
    if (!r.in_collision) continue;
    const bool table_pair = r.obstacle.rfind("self: ", 0) == 0 && [&] {
      for (int b = 0; b < kNumBodies; ++b) {
        if (r.obstacle == std::string("self: ") + BodyName(b)) {
          return robot_->pair_table(std::min(r.body, b), std::max(r.body, b)) != nullptr;
        }
      }
      return false;
    }();
    if (table_pair) continue;
    ++moved;
    ADD_FAILURE() << "moved within the slack (" << slack << " m) into " << r.ToString();
    if (moved > 5) break;
  }
  EXPECT_GT(positive, 500);
}

// The motion check spaces its states by their slack; a motion it calls free is free for FCL
// at every state sampled four times more densely than the fixed spacing (the broad-phase
// exact check, which gives FCL's answers: SphereBroadPhaseGivesFclsAnswer).
TEST_F(CollisionTest, MotionsCheckedByTheirSlackAreFreeForFcl) {
  const FastChecker fast(*robot_, *cell_, scan_->get());
  const MotionChecker motion(fast);
  const ExactChecker exact(*robot_, *cell_, scan_->get());
  std::mt19937 rng(11);
  const auto near = NearContactSamples(*kinematics_, *cell_model_, robot_->gripper(), 3000, rng);
  std::vector<JointVector> starts;
  for (const JointVector& q : near) {
    if (fast.IsFree(q, nullptr, 0.003f)) starts.push_back(q);
  }
  ASSERT_GT(starts.size(), 300u);
  int free_motions = 0, blocked = 0, dense_states = 0;
  for (std::size_t i = 0; i + 1 < starts.size() && i < 600; i += 2) {
    // From a free state near the shelf toward another, a few centimetres to decimetres.
    const JointVector a = starts[i];
    const JointVector b = a + (starts[i + 1] - a) * (i % 4 == 0 ? 0.05 : 0.3);
    const MotionCheckResult result = motion.CheckSegment(a, b);
    if (!result.free) {
      ++blocked;
      continue;
    }
    ++free_motions;
    const int n = 4 * motion.StatesOnSegment(a, b, nullptr);
    for (int k = 0; k <= n; ++k) {
      const JointVector q = a + (b - a) * (double(k) / n);
      ++dense_states;
      const CollisionReport r = exact.Check(q);
      ASSERT_FALSE(r.in_collision)
          << "a free motion hits at " << double(k) / n << ": " << r.ToString();
    }
  }
  std::printf("motions: %d free (%d states checked by FCL), %d blocked\n", free_motions,
              dense_states, blocked);
  EXPECT_GT(free_motions, 60);
  EXPECT_GT(blocked, 20);
}

// A carried item's spheres: blocks of its box's surface cubes, each block's sphere around
// its cubes, the cubes around every point of the box's surface.
TEST_F(CollisionTest, ACarriedItemsSpheresEncloseItsSurfaceInBlocks) {
  const Eigen::AlignedBox3d box(Eigen::Vector3d(-0.14, -0.065, 0.0),
                                Eigen::Vector3d(0.14, 0.065, 0.13));
  const CarriedItem item = MakeCarriedItem("towels", box, Eigen::Isometry3d::Identity());
  const SphereTree& tree = item.spheres_Item;
  EXPECT_GT(tree.coarse.size(), 8u);
  std::size_t children = 0;
  for (const Sphere& c : tree.coarse) {
    ASSERT_GT(c.num_children, 0u);
    for (std::uint32_t k = 0; k < c.num_children; ++k) {
      const Sphere& f = tree.fine[c.first_child + k];
      EXPECT_LE((f.center_B - c.center_B).norm() + f.radius_m, c.radius_m);
    }
    children += c.num_children;
  }
  EXPECT_EQ(children, tree.fine.size());
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int i = 0; i < 5000; ++i) {
    // A point on a random face of the box.
    Eigen::Vector3d p =
        box.min() + box.sizes().cwiseProduct(Eigen::Vector3d(u(rng), u(rng), u(rng)));
    const int axis = i % 3;
    p[axis] = (i / 3) % 2 ? box.max()[axis] : box.min()[axis];
    const bool covered = std::any_of(tree.fine.begin(), tree.fine.end(), [&](const Sphere& f) {
      return (f.center_B.cast<double>() - p).norm() <= f.radius_m;
    });
    ASSERT_TRUE(covered) << p.transpose();
  }
}

// A state whose spheres touch nothing flags nothing; a state with the tool in a shelf wall
// flags the gripper and the shelf.
TEST_F(CollisionTest, ProximityFlagsOnlyWhatTheSpheresTouch) {
  const FastChecker fast(*robot_, *cell_, scan_->get());
  JointVector home;
  home << 3.14159, -2.0, 2.0, -1.5708, -1.5708, 0.0;
  BodyPoses X;
  robot_->ComputePoses(home, nullptr, &X);
  ASSERT_TRUE(fast.IsFree(home));
  const Proximity clear = fast.Near(home, X, nullptr);
  for (int b = 0; b < kNumBodies; ++b) EXPECT_EQ(clear.near_obstacles[b], 0u) << BodyName(b);
  // The tcp in the middle of the shelf's divider between bin_D and bin_E.
  const auto& d = cell_model_->bin("bin_D");
  const auto& e = cell_model_->bin("bin_E");
  const Eigen::Vector3d p_S(d.inner_S.max().x() - 0.1,
                            0.5 * (d.inner_S.max().y() + e.inner_S.min().y()),
                            d.inner_S.center().z());
  Eigen::Isometry3d X_BaseTcp = Eigen::Isometry3d::Identity();
  const Eigen::Vector3d z = cell_model_->config.X_BaseShelf.linear() * -Eigen::Vector3d::UnitX();
  const Eigen::Vector3d x = Eigen::Vector3d::UnitZ().cross(z).normalized();
  X_BaseTcp.linear() << x, z.cross(x), z;
  X_BaseTcp.translation() = cell_model_->config.X_BaseShelf * p_S;
  const auto ik =
      kinematics_->NearestSolution(X_BaseTcp * robot_->gripper().X_ToolTcp.inverse(), home);
  ASSERT_TRUE(ik.has_value());
  robot_->ComputePoses(ik->q_rad, nullptr, &X);
  const Proximity hit = fast.Near(ik->q_rad, X, nullptr);
  int shelf = -1;
  for (std::size_t g = 0; g < cell_->grids().size(); ++g) {
    if (cell_->grids()[g].name == "shelf") shelf = kObstacleFirstMesh + static_cast<int>(g);
  }
  ASSERT_GE(shelf, 0);
  EXPECT_TRUE(hit.near_obstacles[kBodyTool] & (1u << shelf));
  const ExactChecker exact(*robot_, *cell_, scan_->get());
  EXPECT_TRUE(exact.Check(ik->q_rad).in_collision);
}

}  // namespace
}  // namespace picking::planner
