#include "services/robot/core/collision_guard.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <functional>
#include <iostream>

#include "services/robot/core/trajectory.h"

namespace picking::robot {
namespace {

// A tool-down pose in front of the robot, clear of the cell (the robot tests' start).
JointVector StartJoints() {
  JointVector q;
  q << 0.2, -1.6, 1.8, -1.8, -1.57, 0.3;
  return q;
}

// The tool pointing into the shelf (+x of the base), its z axis horizontal.
Eigen::Isometry3d ToolIntoShelf(const Eigen::Vector3d& p_BaseTcp,
                                const Eigen::Isometry3d& X_ToolTcp) {
  Eigen::Matrix3d R_BaseTool;
  R_BaseTool.col(0) = -Eigen::Vector3d::UnitZ();
  R_BaseTool.col(1) = Eigen::Vector3d::UnitY();
  R_BaseTool.col(2) = Eigen::Vector3d::UnitX();
  Eigen::Isometry3d X_BaseTcp = Eigen::Isometry3d::Identity();
  X_BaseTcp.linear() = R_BaseTool;
  X_BaseTcp.translation() = p_BaseTcp;
  return X_BaseTcp * X_ToolTcp.inverse();
}

// The bundled UR10 and cell description with its gripper, as the robot server loads them.
class CollisionGuardTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    kinematics_ = new ur10::Ur10Kinematics(ur10::Ur10Model::Load(PICKING_DATA_DIR "/ur10"));
    const world::CellConfig config =
        world::ReadCellConfig(PICKING_DATA_DIR "/cell/default_cell.yaml");
    cell_ = new world::CellModel(world::LoadCellModel(config));
    gripper_ = new planner::GripperGeometry(planner::GripperGeometry::FromCell(config.gripper));
    guard_ = new CollisionGuard(*kinematics_, *cell_, *gripper_);
  }

  // A point of the board under bin_H (middle column, third row), 15 cm behind the opening and
  // 5 mm below the floor's highest point, in the base frame: a gripper tube (2 cm radius)
  // pointing into the bin there crosses the board's top face wherever it tilts.
  static Eigen::Vector3d BoardPoint() {
    const world::BinGeometry& bin = cell_->bin("bin_H");
    const Eigen::Vector3d p_Shelf(bin.opening_x_m - 0.15, bin.inner_S.center().y(),
                                  bin.floor_max_z_m - 0.005);
    return cell_->config.X_BaseShelf * p_Shelf;
  }
  // 10 cm above the board point and 10 cm outside the opening.
  static Eigen::Vector3d BeforeTheBin() {
    const world::BinGeometry& bin = cell_->bin("bin_H");
    const Eigen::Vector3d p_Shelf(bin.opening_x_m + 0.10, bin.inner_S.center().y(),
                                  bin.floor_max_z_m + 0.10);
    return cell_->config.X_BaseShelf * p_Shelf;
  }

  // Joints with the tcp at `p_BaseTcp`, the tool pointing into the shelf, nearest the start.
  static JointVector JointsAt(const Eigen::Vector3d& p_BaseTcp) {
    std::string reason;
    const auto ik = kinematics_->NearestSolution(ToolIntoShelf(p_BaseTcp, gripper_->X_ToolTcp),
                                                 StartJoints(), std::nullopt, &reason);
    EXPECT_TRUE(ik.has_value()) << "tcp at " << p_BaseTcp.transpose() << ": " << reason;
    return ik ? ik->q_rad : StartJoints();
  }

  static ur10::Ur10Kinematics* kinematics_;
  static world::CellModel* cell_;
  static planner::GripperGeometry* gripper_;
  static CollisionGuard* guard_;
};
ur10::Ur10Kinematics* CollisionGuardTest::kinematics_ = nullptr;
world::CellModel* CollisionGuardTest::cell_ = nullptr;
planner::GripperGeometry* CollisionGuardTest::gripper_ = nullptr;
CollisionGuard* CollisionGuardTest::guard_ = nullptr;

TEST_F(CollisionGuardTest, TheStartIsFreeAndAShortMotionToo) {
  EXPECT_TRUE(guard_->CheckState(StartJoints())) << guard_->CheckState(StartJoints()).reason;
  JointVector target = StartJoints();
  target[0] += 0.3;
  target[3] -= 0.2;
  const SafetyCheck check = guard_->CheckJointMotion(StartJoints(), target);
  EXPECT_TRUE(check) << check.reason;
}

TEST_F(CollisionGuardTest, AMotionIntoAShelfBoardIsRefusedNamingTheLinkAndTheShelf) {
  const JointVector q_board = JointsAt(BoardPoint());
  const SafetyCheck check = guard_->CheckJointMotion(StartJoints(), q_board);
  ASSERT_FALSE(check);
  EXPECT_NE(check.reason.find("hits shelf"), std::string::npos) << check.reason;
  EXPECT_NE(check.reason.find("swept path collides"), std::string::npos) << check.reason;
  // The same target short of the opening is free.
  const SafetyCheck before = guard_->CheckJointMotion(StartJoints(), JointsAt(BeforeTheBin()));
  EXPECT_TRUE(before) << before.reason;
}

TEST_F(CollisionGuardTest, AWaypointInsideTheBoardRefusesTheWholeTrajectory) {
  const JointVector q_before = JointsAt(BeforeTheBin());
  const SafetyCheck check =
      guard_->CheckPath({StartJoints(), q_before, JointsAt(BoardPoint()), q_before});
  ASSERT_FALSE(check);
  EXPECT_NE(check.reason.find("hits shelf"), std::string::npos) << check.reason;
}

TEST_F(CollisionGuardTest, AFoldedArmIsRefusedNamingBothLinks) {
  JointVector folded = StartJoints();
  folded[4] = -3.0;  // wrist_2 turns wrist_3 into the forearm
  const SafetyCheck check = guard_->CheckJointMotion(StartJoints(), folded);
  ASSERT_FALSE(check);
  EXPECT_NE(check.reason.find("hits self: "), std::string::npos) << check.reason;
}

TEST_F(CollisionGuardTest, AMotionMayLeaveTheCollisionItStartsInButNotGoDeeper) {
  const JointVector q_board = JointsAt(BoardPoint());
  ASSERT_FALSE(guard_->CheckState(q_board));
  // Not moving is not refused.
  EXPECT_TRUE(guard_->CheckPath({q_board}));
  // Straight back out along the tool axis.
  LinearMoveOptions options;
  options.X_ToolTcp = gripper_->X_ToolTcp;
  const Eigen::Isometry3d X_BaseTcp = kinematics_->ForwardKinematics(q_board) * gripper_->X_ToolTcp;
  auto line_to = [&](const Eigen::Vector3d& shift_Base) {
    Eigen::Isometry3d X_goal = X_BaseTcp;
    X_goal.translation() += shift_Base;
    const LinearMoveResult line =
        SampleLinearPath(*kinematics_, q_board, X_goal, options, 0.005, 0.02);
    EXPECT_TRUE(line.ok) << line.reason;
    std::vector<JointVector> path;
    for (const auto& p : line.trajectory.points) path.push_back(p.q_rad);
    return path;
  };
  // Straight up off the board.
  const SafetyCheck out = guard_->CheckPath(line_to(Eigen::Vector3d(0.0, 0.0, 0.04)));
  EXPECT_TRUE(out) << out.reason;
  // Down into the board.
  const SafetyCheck deeper = guard_->CheckPath(line_to(Eigen::Vector3d(0.0, 0.0, -0.02)));
  ASSERT_FALSE(deeper);
  EXPECT_NE(deeper.reason.find("does not get out"), std::string::npos) << deeper.reason;
  // Sliding along the board, no deeper, for longer than the escape allows.
  const SafetyCheck along = guard_->CheckPath(line_to(Eigen::Vector3d(0.0, 0.10, 0.0)));
  ASSERT_FALSE(along);
  EXPECT_NE(along.reason.find("does not get out"), std::string::npos) << along.reason;
}

TEST_F(CollisionGuardTest, TheCupMeetsTheBinFloorWhereTheBoardIs) {
  const world::BinGeometry& bin = cell_->bin("bin_H");
  const double height_m = 0.10;
  const Eigen::Vector3d p_Shelf(bin.inner_S.center().x(), bin.inner_S.center().y(),
                                bin.inner_S.min().z() + height_m);
  const Eigen::Vector3d p_BaseTcp = cell_->config.X_BaseShelf * p_Shelf;
  const double down_m = guard_->CupTravelToStaticContact(p_BaseTcp, -Eigen::Vector3d::UnitZ(), 0.3);
  // The floor under the bin's centre lies at or a little above its lowest point.
  EXPECT_LE(down_m, height_m + 0.002);
  EXPECT_GT(down_m, height_m - 0.03);
  // Upward the bin is open for longer than 5 cm: the full distance.
  EXPECT_EQ(guard_->CupTravelToStaticContact(p_BaseTcp, Eigen::Vector3d::UnitZ(), 0.05), 0.05);
}

// Not a pass/fail figure (the machine is shared): how long the checks of typical motions take.
TEST_F(CollisionGuardTest, ReportsTheCheckTimes) {
  auto time_ms = [](const std::function<void()>& f) {
    const auto start = std::chrono::steady_clock::now();
    f();
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
        .count();
  };
  JointVector short_target = StartJoints();
  short_target[0] += 0.3;
  short_target[3] -= 0.2;
  JointVector long_target = StartJoints();
  long_target[0] -= 1.5;
  long_target[1] += 0.4;
  for (const auto& [name, target] :
       {std::make_pair("short", short_target), std::make_pair("long", long_target)}) {
    bool free = false;
    const double ms = time_ms([&, t = target] {
      for (int i = 0; i < 10; ++i) free = guard_->CheckJointMotion(StartJoints(), t).ok;
    });
    std::cout << name << " MoveJoints check: " << guard_->StatesOnPath({StartJoints(), target})
              << " states, " << ms / 10.0 << " ms" << std::endl;
    EXPECT_TRUE(free);
  }
}

TEST(CollisionGuardOptionsTest, Validates) {
  CollisionGuardOptions options;
  options.max_travel_m = 0.0;
  EXPECT_THROW(options.Validate(), std::invalid_argument);
  options = {};
  options.cup_contact_m = std::nan("");
  EXPECT_THROW(options.Validate(), std::invalid_argument);
}

// The default cell's gripper has a head on a servo joint: turned down inside a bin, it meets
// the board the straight tube passes over.
TEST_F(CollisionGuardTest, TheHeadIsCheckedWhereItIsTurned) {
  ASSERT_GT(gripper_->head_length_m, 0.0);
  EXPECT_EQ(guard_->ForHeadAngle(0.0).get(), guard_);
  const double quarter = 0.5 * M_PI;
  const auto turned = guard_->ForHeadAngle(quarter);
  EXPECT_EQ(guard_->ForHeadAngle(quarter), turned);  // built once
  EXPECT_THROW(guard_->ForHeadAngle(2.0), std::invalid_argument);
  EXPECT_THROW(guard_->ForHeadAngle(std::nan("")), std::invalid_argument);
  // The tcp 4 cm above the board, 15 cm into bin_H: the straight tube is clear of the board,
  // the head turned down a quarter (one of the two signs) goes through it.
  // The tool into the shelf with its x axis (the head's joint axis) level.
  Eigen::Isometry3d X_BaseTcp = Eigen::Isometry3d::Identity();
  X_BaseTcp.linear() << Eigen::Vector3d::UnitY(), Eigen::Vector3d::UnitZ(),
      Eigen::Vector3d::UnitX();
  X_BaseTcp.translation() = BoardPoint() + Eigen::Vector3d(0.0, 0.0, 0.045);
  const auto ik =
      kinematics_->NearestSolution(X_BaseTcp * gripper_->X_ToolTcp.inverse(), StartJoints());
  ASSERT_TRUE(ik.has_value());
  const JointVector q = ik->q_rad;
  EXPECT_TRUE(guard_->CheckState(q)) << guard_->CheckState(q).reason;
  const SafetyCheck up = turned->CheckState(q);
  const SafetyCheck down = guard_->ForHeadAngle(-quarter)->CheckState(q);
  EXPECT_NE(up.ok, down.ok) << up.reason << " / " << down.reason;
  EXPECT_NE((up.ok ? down : up).reason.find("gripper hits shelf"), std::string::npos)
      << (up.ok ? down : up).reason;
}

}  // namespace
}  // namespace picking::robot
