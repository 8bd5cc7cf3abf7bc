#include "services/planner/core/roadmap.h"

#include <gtest/gtest.h>

#include <random>

#include "libs/world/cell_config.h"
#include "services/planner/core/collision_world.h"

namespace picking::planner {
namespace {

// The default cell's static obstacles and the UR10 with the straight gripper, checked fast.
struct DefaultCell {
  explicit DefaultCell(const StaticCellOptions& options)
      : kinematics(ur10::Ur10Model::Load(PICKING_DATA_DIR "/ur10")),
        robot(kinematics, GripperGeometry{}),
        cell(
            world::LoadCellModel(world::ReadCellConfig(PICKING_DATA_DIR "/cell/default_cell.yaml")),
            options),
        fast(robot, cell, nullptr),
        motion(fast) {}
  const ur10::Ur10Kinematics kinematics;
  const RobotGeometry robot;
  const StaticCell cell;
  const FastChecker fast;
  const MotionChecker motion;
};

// Two trees grown between free states whose straight motion is blocked by the cell: they
// meet for at least half of the pairs, every motion free, and the same request gives the
// same path.
TEST(RoadmapTest, TreesFromStartAndGoalGoAroundWhatBlocksTheStraightMotion) {
  // The trees around obstacles only: without the robot's workspace box, which cuts off
  // part of the random pairs' space (CollisionTest tests the box).
  StaticCellOptions obstacles_only;
  obstacles_only.tcp_workspace_Base.setEmpty();
  const DefaultCell scene(obstacles_only);
  const FastChecker& fast = scene.fast;
  const MotionChecker& motion = scene.motion;
  const Roadmap roadmap(motion, {});
  // A box carried on the cup, as a place carries an item.
  const CarriedItem item = MakeCarriedItem(
      "box",
      Eigen::AlignedBox3d(Eigen::Vector3d(-0.1, -0.04, 0.0), Eigen::Vector3d(0.1, 0.04, 0.06)),
      Eigen::Isometry3d::Identity());
  // Free states around the arm reaching toward the shelf (base joint toward +x, the shelf).
  std::mt19937 rng(7);
  const JointVector centre = (JointVector() << 0.0, -1.6, 1.6, -1.6, -1.57, 0.0).finished();
  auto draw = [&] {
    for (;;) {
      JointVector q = centre;
      for (int j = 0; j < 6; ++j) q[j] += std::uniform_real_distribution<double>(-1.2, 1.2)(rng);
      if (fast.IsFree(q, &item)) return q;
    }
  };
  int pairs = 0, found = 0;
  const auto far = std::chrono::steady_clock::now() + std::chrono::minutes(5);
  while (pairs < 8) {
    const JointVector start = draw(), goal = draw();
    if (motion.CheckSegment(start, goal, &item).free) continue;  // nothing to go around
    ++pairs;
    const std::vector<JointVector> path = roadmap.ConnectTrees(start, goal, motion, &item, far);
    if (path.empty()) continue;
    ++found;
    ASSERT_GE(path.size(), 3u);
    EXPECT_TRUE((path.front() - start).isZero(0.0));
    EXPECT_TRUE((path.back() - goal).isZero(0.0));
    EXPECT_TRUE(motion.CheckPath(path, &item).free);
    const std::vector<JointVector> again = roadmap.ConnectTrees(start, goal, motion, &item, far);
    ASSERT_EQ(again.size(), path.size());
    for (std::size_t i = 0; i < path.size(); ++i) EXPECT_TRUE((again[i] - path[i]).isZero(0.0));
  }
  // Pairs drawn 2.4 rad apart on six joints are not always joined inside the box the trees
  // sample (start and goal grown by 0.6 rad); four times as many nodes join no more of them.
  EXPECT_GE(found, pairs / 2) << "of " << pairs << " blocked pairs";
  // A deadline already passed: no path, at once.
  EXPECT_TRUE(roadmap
                  .ConnectTrees(draw(), draw(), motion, &item,
                                std::chrono::steady_clock::now() - std::chrono::seconds(1))
                  .empty());
}

// Every two named poses get a path at once, both ways: the later requests find them cached,
// free, from start to goal, the way back the way there reversed.
TEST(RoadmapTest, PathsBetweenNamedPosesArePlannedAheadBothWays) {
  const DefaultCell scene(StaticCellOptions{});
  const MotionChecker& motion = scene.motion;
  // Arm poses toward the shelf, the tote side and up: some straight motions between them
  // pass through the shelf or the pedestal and need the roadmap.
  const std::vector<NamedPose> named = {
      {"ahead", (JointVector() << 0.0, -1.9, 1.9, -1.57, -1.57, 0.0).finished()},
      {"left", (JointVector() << 1.4, -1.7, 1.5, -1.4, -1.57, 0.0).finished()},
      {"right", (JointVector() << -1.4, -1.7, 1.5, -1.4, -1.57, 0.0).finished()},
      {"up", (JointVector() << 0.0, -1.57, 0.3, -1.57, -1.57, 0.0).finished()}};
  RoadmapOptions options;
  options.samples = 300;
  const Roadmap roadmap(motion, named, options);
  EXPECT_EQ(roadmap.CacheNamedPaths(), 12);
  for (const NamedPose& a : named) {
    for (const NamedPose& b : named) {
      if (&a == &b) continue;
      const JointPathResult there = roadmap.Plan(a.q_rad, b.q_rad);
      const JointPathResult back = roadmap.Plan(b.q_rad, a.q_rad);
      ASSERT_TRUE(there.ok && back.ok) << a.name << " - " << b.name;
      EXPECT_TRUE(there.cached && back.cached);
      EXPECT_EQ(there.edges_checked, 0);
      EXPECT_TRUE((there.path_rad.front() - a.q_rad).isZero(0.0));
      EXPECT_TRUE((there.path_rad.back() - b.q_rad).isZero(0.0));
      EXPECT_TRUE(motion.CheckPath(there.path_rad).free);
      ASSERT_EQ(there.path_rad.size(), back.path_rad.size());
      for (std::size_t i = 0; i < there.path_rad.size(); ++i) {
        EXPECT_TRUE((there.path_rad[i] - back.path_rad[back.path_rad.size() - 1 - i]).isZero(0.0));
      }
    }
  }
}

}  // namespace
}  // namespace picking::planner
