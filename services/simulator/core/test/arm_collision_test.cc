#include "services/simulator/core/arm_collision.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <memory>

#include "libs/world/mesh_utils.h"

namespace picking::simulator {
namespace {

class ArmCollisionTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    cell_ = new world::CellModel(
        world::LoadCellModel(world::ReadCellConfig(world::DefaultCellConfigPath())));
    kinematics_ =
        new ur10::Ur10Kinematics(ur10::Ur10Model::Load(std::string(PICKING_DATA_DIR) + "/ur10"));
    checker_ = new ArmCollisionChecker(*cell_, *kinematics_);
  }
  static void TearDownTestSuite() {
    delete checker_;
    delete kinematics_;
    delete cell_;
  }
  static world::CellModel* cell_;
  static ur10::Ur10Kinematics* kinematics_;
  static ArmCollisionChecker* checker_;
};
world::CellModel* ArmCollisionTest::cell_ = nullptr;
ur10::Ur10Kinematics* ArmCollisionTest::kinematics_ = nullptr;
ArmCollisionChecker* ArmCollisionTest::checker_ = nullptr;

const ur10::JointVector kHome =
    (ur10::JointVector() << 0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0).finished();

TEST_F(ArmCollisionTest, HomePoseIsFree) {
  const ArmCollision c = checker_->Check(kHome);
  EXPECT_FALSE(c.in_collision) << c.detail;
  EXPECT_TRUE(c.detail.empty());
}

TEST_F(ArmCollisionTest, ArmStretchedIntoThePodsBaseHitsTheShelf) {
  // Turned toward the shelf and stretched out at the height of the base: the flange is at
  // x = 1.18 m, z = 0.01 m, inside the pod's solid base below the lowest bins.
  const ur10::JointVector q = (ur10::JointVector() << M_PI, 0, 0, 0, 0, 0).finished();
  const ArmCollision c = checker_->Check(q);
  EXPECT_TRUE(c.in_collision);
  EXPECT_NE(c.detail.find("hits shelf"), std::string::npos) << c.detail;
}

TEST_F(ArmCollisionTest, GripperReachingIntoABinIsFreeUntilItMeetsTheBackWall) {
  // Cup axis along +x of base, through the middle of bin_E's opening.
  const world::BinGeometry& bin = cell_->bin("bin_E");
  const Eigen::Vector3d c_Base = cell_->config.X_BaseShelf * bin.inner_S.center();
  const Eigen::Vector3d opening_Base =
      cell_->config.X_BaseShelf *
      Eigen::Vector3d(bin.opening_x_m, bin.inner_S.center().y(), bin.inner_S.center().z());
  Eigen::Isometry3d X_BaseTcp = Eigen::Isometry3d::Identity();
  X_BaseTcp.linear() = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitY()).toRotationMatrix();
  EXPECT_TRUE(checker_->gripper().X_ToolTcp.isApprox(cell_->config.gripper.X_ToolTcp));
  auto check_at = [&](double x) {
    X_BaseTcp.translation() = Eigen::Vector3d(x, c_Base.y(), c_Base.z());
    const Eigen::Isometry3d X_BaseTool = X_BaseTcp * checker_->gripper().X_ToolTcp.inverse();
    const auto q = kinematics_->NearestSolution(X_BaseTool, kHome);
    EXPECT_TRUE(q.has_value());
    return q ? checker_->Check(q->q_rad) : ArmCollision{};
  };
  const double back_x = 2.0 * c_Base.x() - opening_Base.x();
  EXPECT_FALSE(check_at(opening_Base.x() + 0.1).in_collision);
  const ArmCollision deep = check_at(back_x + 0.05);  // the cup through the back wall
  EXPECT_TRUE(deep.in_collision);
  EXPECT_EQ(deep.detail, "gripper hits shelf");
}

// The head bent down a quarter turn: the tube ends at the joint and the head hangs from it,
// so it meets the bin's floor where the straight tube, level, passes over it.
TEST_F(ArmCollisionTest, ABentHeadIsCheckedWhereItHangs) {
  world::CellModel cell = *cell_;
  cell.config.gripper.head_length_m = 0.09;
  cell.config.gripper.max_head_angle_rad = M_PI / 2;
  const ArmCollisionChecker checker(cell, *kinematics_);
  const world::BinGeometry& bin = cell.bin("bin_E");
  // The flange level with the bin's middle, the tube along +x of base into the bin, the
  // joint 5 cm above the floor: a quarter turn of the head points the cup at the floor.
  const Eigen::Vector3d floor_Base =
      cell.config.X_BaseShelf *
      Eigen::Vector3d(bin.opening_x_m - 0.12, bin.inner_S.center().y(), bin.floor_max_z_m);
  const Eigen::Vector3d p_Joint = floor_Base + Eigen::Vector3d(0.0, 0.0, 0.05);
  Eigen::Isometry3d X_BaseTool = Eigen::Isometry3d::Identity();
  // The flange's x axis (the head's joint axis) level, across the tube.
  X_BaseTool.linear() = (Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitY()) *
                         Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()))
                            .toRotationMatrix();
  X_BaseTool.translation() = p_Joint - X_BaseTool.linear() * cell.config.gripper.p_ToolJoint();
  const auto q = kinematics_->NearestSolution(X_BaseTool, kHome);
  ASSERT_TRUE(q.has_value());
  const ArmCollision straight = checker.Check(q->q_rad, nullptr, 0.0);
  EXPECT_FALSE(straight.in_collision) << straight.detail;
  // Which way the head turns: toward base -z at one sign of the angle.
  const double down =
      (X_BaseTool * cell.config.gripper.X_ToolTcpAt(M_PI / 2)).translation().z() < p_Joint.z()
          ? M_PI / 2
          : -M_PI / 2;
  const ArmCollision bent = checker.Check(q->q_rad, nullptr, down);
  EXPECT_TRUE(bent.in_collision);
  EXPECT_EQ(bent.detail, "gripper hits shelf");
  // Turned up instead, it stays clear of the 0.2 m-high bin's ceiling.
  EXPECT_FALSE(checker.Check(q->q_rad, nullptr, -down).in_collision);
  // Outside the servo's range, or any turn of a straight gripper, is refused.
  EXPECT_THROW(checker.Check(q->q_rad, nullptr, 2.0), std::invalid_argument);
  world::CellModel straight_cell = *cell_;
  straight_cell.config.gripper.head_length_m = 0.0;
  straight_cell.config.gripper.max_head_angle_rad = 0.0;
  const ArmCollisionChecker straight_checker(straight_cell, *kinematics_);
  EXPECT_THROW(straight_checker.Check(q->q_rad, nullptr, 0.3), std::invalid_argument);
}

TEST_F(ArmCollisionTest, CarriedItemIsChecked) {
  const world::TriangleMesh box = world::MakeBox(Eigen::Vector3d(0.1, 0.1, 0.1));
  CarriedItem item;
  item.id = 7;
  item.name = "test_box";
  item.mesh = &box;
  // Resting in the tote's floor plane: it intersects the tote's bottom.
  item.X_BaseItem = cell_->config.X_BaseTote;
  ArmCollision c = checker_->Check(kHome, &item);
  EXPECT_TRUE(c.in_collision);
  EXPECT_EQ(c.detail, "carried item test_box hits tote");
  // In free air above the robot.
  item.X_BaseItem = Eigen::Translation3d(0.0, 0.0, 2.0) * Eigen::Isometry3d::Identity();
  c = checker_->Check(kHome, &item);
  EXPECT_FALSE(c.in_collision) << c.detail;
}

TEST_F(ArmCollisionTest, BadInputThrows) {
  ur10::JointVector q = kHome;
  q[3] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(checker_->Check(q), std::invalid_argument);
  CarriedItem empty;
  EXPECT_THROW(checker_->Check(kHome, &empty), std::invalid_argument);
  world::CellModel bad = *cell_;
  bad.config.gripper.tube_radius_m = 0.0;
  EXPECT_THROW(ArmCollisionChecker(bad, *kinematics_), std::invalid_argument);
  bad.config.gripper = cell_->config.gripper;
  bad.config.gripper.cup_length_m = -0.01;
  EXPECT_THROW(ArmCollisionChecker(bad, *kinematics_), std::invalid_argument);
  bad.config.gripper = cell_->config.gripper;
  bad.config.gripper.X_ToolTcp.linear() *= 1.1;
  EXPECT_THROW(ArmCollisionChecker(bad, *kinematics_), std::invalid_argument);
}

}  // namespace
}  // namespace picking::simulator
