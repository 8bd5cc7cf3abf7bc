#include "services/planner/core/cartesian_search.h"

#include <gtest/gtest.h>

#include "services/planner/core/scene.h"

namespace picking::planner {
namespace {

class CartesianSearchTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    kinematics_ = new ur10::Ur10Kinematics(ur10::Ur10Model::Load(PICKING_DATA_DIR "/ur10"));
    robot_ = new RobotGeometry(*kinematics_, GripperGeometry{});
    cell_model_ = new world::CellModel(
        world::LoadCellModel(world::ReadCellConfig(PICKING_DATA_DIR "/cell/default_cell.yaml")));
    cell_ = new StaticCell(*cell_model_);
  }

  // The tcp 10 cm in front of bin E's opening, pointing into the bin, and a joint solution.
  static std::pair<JointVector, Eigen::Isometry3d> InFrontOfBinE() {
    const auto& bin = cell_model_->bin("bin_E");
    const Eigen::Isometry3d& X_BaseShelf = cell_model_->config.X_BaseShelf;
    Eigen::Isometry3d X_BaseTcp = Eigen::Isometry3d::Identity();
    const Eigen::Vector3d z = X_BaseShelf.linear() * -Eigen::Vector3d::UnitX();
    const Eigen::Vector3d x = -Eigen::Vector3d::UnitZ();
    X_BaseTcp.linear() << x, z.cross(x), z;
    X_BaseTcp.translation() =
        X_BaseShelf *
        Eigen::Vector3d(bin.opening_x_m + 0.10, bin.inner_S.center().y(), bin.inner_S.center().z());
    JointVector seed;
    seed << M_PI, -2.0, 2.0, -M_PI / 2, -M_PI / 2, 0.0;
    const auto q =
        kinematics_->NearestSolution(X_BaseTcp * robot_->gripper().X_ToolTcp.inverse(), seed);
    EXPECT_TRUE(q.has_value())
        << kinematics_->Solve(X_BaseTcp * robot_->gripper().X_ToolTcp.inverse()).reason << "\n"
        << X_BaseTcp.matrix();
    return {q->q_rad, X_BaseTcp};
  }

  static Eigen::Isometry3d Ahead(const Eigen::Isometry3d& X, double d) {
    Eigen::Isometry3d Y = X;
    Y.translation() += d * X.linear().col(2);
    return Y;
  }

  static ur10::Ur10Kinematics* kinematics_;
  static RobotGeometry* robot_;
  static world::CellModel* cell_model_;
  static StaticCell* cell_;
};
ur10::Ur10Kinematics* CartesianSearchTest::kinematics_ = nullptr;
RobotGeometry* CartesianSearchTest::robot_ = nullptr;
world::CellModel* CartesianSearchTest::cell_model_ = nullptr;
StaticCell* CartesianSearchTest::cell_ = nullptr;

TEST_F(CartesianSearchTest, AFreeLineCostsOneEvaluationPerStep) {
  const FastChecker fast(*robot_, *cell_, nullptr);
  const MotionChecker motion(fast);
  const auto [q0, X0] = InFrontOfBinE();
  const Eigen::Isometry3d X_goal = Ahead(X0, 0.40);
  const CartesianSearchResult result =
      SearchCartesianPath(motion, q0, X_goal, nullptr, CartesianSearchOptions{});
  ASSERT_TRUE(result.ok) << result.Describe();
  EXPECT_EQ(result.path_rad.size(), 21u);
  EXPECT_EQ(result.nodes_evaluated, 20);
  EXPECT_DOUBLE_EQ(result.fraction_achieved, 1.0);
  const Eigen::Isometry3d X_end = robot_->X_BaseTcp(result.path_rad.back());
  EXPECT_LT((X_end.translation() - X_goal.translation()).norm(), 1e-6);
  EXPECT_LT(Eigen::AngleAxisd(X_end.linear().transpose() * X_goal.linear()).angle(), 1e-6);
  for (std::size_t i = 1; i < result.path_rad.size(); ++i) {
    EXPECT_LE((result.path_rad[i] - result.path_rad[i - 1]).cwiseAbs().maxCoeff(), 0.25);
  }
}

TEST_F(CartesianSearchTest, GoesAroundAnObstacleOnTheLine) {
  const auto [q0, X0] = InFrontOfBinE();
  // A 6 x 6 cm post of voxels across the line, 15 cm ahead, standing on the bin floor.
  const auto& bin = cell_model_->bin("bin_E");
  std::vector<float> xyz;
  const Eigen::Vector3d p = Ahead(X0, 0.30).translation();
  for (double dy = -0.03; dy <= 0.03; dy += 0.005) {
    for (double dx = -0.03; dx <= 0.03; dx += 0.005) {
      for (double z = (cell_model_->config.X_BaseShelf * bin.inner_S.min()).z(); z < p.z() + 0.02;
           z += 0.005) {
        xyz.insert(xyz.end(), {float(p.x() + dx), float(p.y() + dy), float(z)});
      }
    }
  }
  ScanScene scene(ScanSceneOptions{});
  scene.Insert(xyz.data(), xyz.size() / 3, {});
  const auto scan = scene.Snapshot();
  const FastChecker fast(*robot_, *cell_, scan.get());
  const MotionChecker motion(fast);
  // Straight ahead is blocked: the best node stops before the post, and says why.
  CartesianSearchOptions straight;
  straight.max_lateral_steps = straight.max_tilt_steps = 0;
  const Eigen::Isometry3d X_goal = Ahead(X0, 0.30);
  const CartesianSearchResult blocked =
      SearchCartesianPath(motion, q0, Ahead(X0, 0.4), nullptr, straight);
  EXPECT_FALSE(blocked.ok);
  EXPECT_EQ(blocked.failure, FailureKind::kCollision) << blocked.Describe();
  EXPECT_GT(blocked.fraction_achieved, 0.2);
  EXPECT_LT(blocked.fraction_achieved, 0.8);
  EXPECT_EQ(blocked.collision.obstacle, "scan");
  EXPECT_NE(blocked.Describe().find("hits scan"), std::string::npos) << blocked.Describe();
  // With lateral steps the search passes the post to a goal beside it.
  Eigen::Isometry3d X_beside = Ahead(X0, 0.35);
  X_beside.translation().y() += 0.09;
  const CartesianSearchResult around =
      SearchCartesianPath(motion, q0, X_beside, nullptr, CartesianSearchOptions{});
  EXPECT_TRUE(around.ok) << around.Describe();
  (void)X_goal;
}

TEST_F(CartesianSearchTest, UnreachableAndCollidingStartsAreTyped) {
  const FastChecker fast(*robot_, *cell_, nullptr);
  const MotionChecker motion(fast);
  const auto [q0, X0] = InFrontOfBinE();
  CartesianSearchOptions options;
  options.max_lateral_steps = options.max_tilt_steps = 0;
  Eigen::Isometry3d X_far = X0;
  X_far.translation() = Eigen::Vector3d(-2.5, 0.0, 0.3);
  const CartesianSearchResult far = SearchCartesianPath(motion, q0, X_far, nullptr, options);
  EXPECT_FALSE(far.ok);
  EXPECT_NE(far.failure, FailureKind::kUnspecified);
  EXPECT_LT(far.fraction_achieved, 1.0);
  EXPECT_FALSE(far.Describe().empty());

  JointVector down;
  down << 0.0, 1.5707963, 0.0, 0.0, 0.0, 0.0;
  const CartesianSearchResult start = SearchCartesianPath(motion, down, X0, nullptr, options);
  EXPECT_EQ(start.failure, FailureKind::kStartInCollision);
  EXPECT_FALSE(start.collision.obstacle.empty());
}

TEST_F(CartesianSearchTest, StopsAtTheDeadline) {
  const FastChecker fast(*robot_, *cell_, nullptr);
  const MotionChecker motion(fast);
  const auto [q0, X0] = InFrontOfBinE();
  CartesianSearchOptions options;
  options.deadline = std::chrono::steady_clock::now();
  const CartesianSearchResult result =
      SearchCartesianPath(motion, q0, Ahead(X0, 0.3), nullptr, options);
  EXPECT_EQ(result.failure, FailureKind::kDeadline);
}

}  // namespace
}  // namespace picking::planner
