#include "services/planner/core/motion_planner.h"

#include <gtest/gtest.h>

#include <random>
#include <set>
#include <string>

#include "libs/errors/errors.h"

namespace picking::planner {
namespace {

// One planner over the real cell for all tests (start-up builds grids and the roadmap).
class MotionPlannerTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    apc::Catalogue catalogue =
        apc::Catalogue::FromCsvFile(PICKING_DATA_DIR "/apc2016/items/item_data.csv");
    grasps_ = std::make_shared<const GraspTable>(
        GraspTable::FromYamlFile(PICKING_DATA_DIR "/planner/grasps.yaml", catalogue));
    items_ = std::make_shared<world::ItemModelLibrary>(std::move(catalogue));
    planner_ = MakePlanner(GripperGeometry{}).release();
    articulated_ = MakePlanner(Articulated()).release();
  }
  // The gripper with the tote gripper's head on its servo joint (9 cm, +-90 deg).
  static GripperGeometry Articulated() {
    GripperGeometry articulated;
    articulated.head_length_m = 0.09;
    articulated.max_head_angle_rad = M_PI / 2;
    return articulated;
  }
  static std::unique_ptr<MotionPlanner> MakePlanner(const GripperGeometry& gripper,
                                                    const MotionPlannerOptions& options = {}) {
    const ur10::Ur10Kinematics kinematics(ur10::Ur10Model::Load(PICKING_DATA_DIR "/ur10"));
    const world::CellModel cell =
        world::LoadCellModel(world::ReadCellConfig(PICKING_DATA_DIR "/cell/default_cell.yaml"));
    Eigen::Isometry3d X_ToolCamera = Eigen::Isometry3d::Identity();
    X_ToolCamera.translation() = Eigen::Vector3d(-0.075, 0.06, 0.04);
    return std::make_unique<MotionPlanner>(kinematics, cell, gripper, X_ToolCamera, grasps_, items_,
                                           options);
  }
  static void TearDownTestSuite() {
    delete planner_;
    delete articulated_;
  }

  static const NamedPose& Named(const std::string& name) {
    for (const auto& p : planner_->named_poses()) {
      if (p.name == name) return p;
    }
    throw std::runtime_error("no named pose " + name);
  }

  // An item lying on the floor of `bin`, 12 cm behind the opening, and a scan of it: points
  // on the item's box surface and on the bin's floor.
  // With `wall_gap_m` >= 0 the item lies that far from the bin's side wall at -y instead of
  // in the middle.
  static std::pair<Eigen::Isometry3d, std::vector<float>> ItemInBin(const std::string& bin,
                                                                    const std::string& item,
                                                                    double wall_gap_m = -1.0,
                                                                    double depth_m = 0.12,
                                                                    bool long_side_in = false) {
    const auto& cell = planner_->cell().cell();
    const Eigen::Vector3d size = items_->Get(item)->box_I.sizes();
    const world::BinGeometry& geometry = cell.bin(bin);
    const double y_S = wall_gap_m < 0.0 ? geometry.inner_S.center().y()
                                        : geometry.inner_S.min().y() + 0.5 * size.x() + wall_gap_m;
    const Eigen::Vector3d c_S(geometry.opening_x_m - depth_m, y_S,
                              geometry.floor_max_z_m + 0.5 * size.z() + 0.002);
    // Item frame: long side across the bin (shelf y), middle side along the depth, short
    // side up
    // (`long_side_in`: the long side along the depth, the middle side across.)
    Eigen::Isometry3d X_ShelfItem = Eigen::Isometry3d::Identity();
    if (!long_side_in) {
      X_ShelfItem.linear().col(0) = Eigen::Vector3d::UnitY();
      X_ShelfItem.linear().col(1) = -Eigen::Vector3d::UnitX();
    }
    X_ShelfItem.translation() = c_S;
    const Eigen::Isometry3d X_BaseItem = cell.config.X_BaseShelf * X_ShelfItem;
    std::vector<float> xyz;
    const Eigen::Vector3d half = 0.5 * size;
    for (double x = -half.x(); x <= half.x(); x += 0.004) {
      for (double y = -half.y(); y <= half.y(); y += 0.004) {
        for (double z : {-half.z(), half.z()}) {
          const Eigen::Vector3d p = X_BaseItem * Eigen::Vector3d(x, y, z);
          xyz.insert(xyz.end(), {float(p.x()), float(p.y()), float(p.z())});
        }
      }
    }
    for (double x = geometry.inner_S.min().x(); x < geometry.opening_x_m; x += 0.005) {
      for (double y = geometry.inner_S.min().y(); y < geometry.inner_S.max().y(); y += 0.005) {
        const Eigen::Vector3d p =
            cell.config.X_BaseShelf * Eigen::Vector3d(x, y, geometry.floor_max_z_m - 0.001);
        xyz.insert(xyz.end(), {float(p.x()), float(p.y()), float(p.z())});
      }
    }
    return {X_BaseItem, xyz};
  }

  // A pick of `item` at X_BaseItem in `bin`, from the bin's first scan view.
  static PickRequest PickIn(const std::string& bin, const std::string& item,
                            const Eigen::Isometry3d& X_BaseItem) {
    PickRequest request;
    request.item = item;
    request.X_BaseItem = X_BaseItem;
    request.container = bin;
    request.start_rad = Named("scan/" + bin + "/0").q_rad;
    return request;
  }

  // How far a pick's lift moves the cup across the bin (shelf +y) and up, metres: to the last
  // retreat sample before the tcp heads out toward the opening (shelf +x); the lift itself goes
  // up and sideways only.
  static std::pair<double, double> LiftAcrossAndUp(const PickPlan& plan) {
    const Eigen::Isometry3d X_ShelfBase = planner_->cell().cell().config.X_BaseShelf.inverse();
    const Eigen::Vector3d p0_S = X_ShelfBase * plan.grasp.X_BaseTcp.translation();
    double across_m = 0.0, up_m = 0.0;
    for (const TrajectorySample& s : plan.retreat.samples) {
      const Eigen::Vector3d p_S = X_ShelfBase * planner_->robot().X_BaseTcp(s.q_rad).translation();
      if (std::abs(p_S.x() - p0_S.x()) > 0.002) break;
      across_m = p_S.y() - p0_S.y();
      up_m = p_S.z() - p0_S.z();
    }
    return {across_m, up_m};
  }

  static MotionPlanner* planner_;
  static MotionPlanner* articulated_;
  static std::shared_ptr<world::ItemModelLibrary> items_;
  static std::shared_ptr<const GraspTable> grasps_;
};
MotionPlanner* MotionPlannerTest::planner_ = nullptr;
MotionPlanner* MotionPlannerTest::articulated_ = nullptr;
std::shared_ptr<world::ItemModelLibrary> MotionPlannerTest::items_;
std::shared_ptr<const GraspTable> MotionPlannerTest::grasps_;

Deadline Far() { return std::chrono::steady_clock::now() + std::chrono::seconds(30); }

void ExpectWithinLimits(const Trajectory& t, const ur10::Ur10Model& model) {
  ASSERT_FALSE(t.samples.empty());
  for (const auto& s : t.samples) {
    for (int j = 0; j < 6; ++j) {
      EXPECT_LE(std::abs(s.qd_rad_s[j]), model.max_velocity_rad_s()[j] * (1 + 1e-6));
      EXPECT_LE(std::abs(s.qdd_rad_s2[j]), model.max_acceleration_rad_s2()[j] * (1 + 1e-6));
    }
    EXPECT_TRUE(model.WithinPositionLimits(s.q_rad));
  }
}

TEST_F(MotionPlannerTest, EveryNamedPoseExistsAndIsFree) {
  const auto& poses = planner_->named_poses();
  EXPECT_EQ(poses.size(), 1u + 36u + 2u + 3u);
  const FastChecker fast(planner_->robot(), planner_->cell(), nullptr);
  for (const auto& p : poses) EXPECT_TRUE(fast.IsFree(p.q_rad)) << p.name;
}

// A free configuration can sit in a pocket no motion reaches (the top middle bin's high side
// view, first solved with the wrist turned the far way round): each named pose is one the
// roadmap joins to home.
TEST_F(MotionPlannerTest, EveryNamedPoseIsReachedFromHome) {
  EXPECT_TRUE(planner_->unreachable_named_poses().empty());
  for (const auto& p : planner_->named_poses()) {
    SCOPED_TRACE(p.name);
    EXPECT_NO_THROW(planner_->PlanJointMotion(Named("home").q_rad, p.q_rad, 1.0, Far()));
  }
}

TEST_F(MotionPlannerTest, JointMotionsBetweenNamedPosesAreTimedAndFree) {
  const auto& model = planner_->robot().kinematics().model();
  for (const char* goal : {"scan/bin_A/0", "scan/bin_L/2", "above_tote", "table", "verify"}) {
    SCOPED_TRACE(goal);
    const JointMotionPlan plan =
        planner_->PlanJointMotion(Named("home").q_rad, Named(goal).q_rad, 1.0, Far());
    ExpectWithinLimits(plan.trajectory, model);
    EXPECT_LT((plan.trajectory.samples.back().q_rad - Named(goal).q_rad).norm(), 1e-9) << goal;
    EXPECT_LT((plan.trajectory.samples.front().q_rad - Named("home").q_rad).norm(), 1e-9);
  }
  // The second time the path comes from the cache.
  EXPECT_TRUE(
      planner_->PlanJointMotion(Named("home").q_rad, Named("table").q_rad, 0.5, Far()).cached);
}

TEST_F(MotionPlannerTest, PicksABoxFromABinAndReportsItsTrajectories) {
  const auto [X_BaseItem, xyz] = ItemInBin("bin_E", "kleenex_tissue_box");
  const PlanningScene scene =
      planner_->BuildScene("bin_E", xyz.data(), xyz.size() / 3, "kleenex_tissue_box", X_BaseItem);
  EXPECT_GT(scene.stats.points_cut, 0u);
  PickRequest request = PickIn("bin_E", "kleenex_tissue_box", X_BaseItem);
  const PickPlan plan = planner_->PlanPick(request, &scene, Far());
  const auto& model = planner_->robot().kinematics().model();
  ExpectWithinLimits(plan.approach, model);
  ExpectWithinLimits(plan.descend, model);
  ExpectWithinLimits(plan.retreat, model);
  // The descent ends guarded_distance short of the grasp, on the approach line.
  const Eigen::Isometry3d X_end = planner_->robot().X_BaseTcp(plan.descend.samples.back().q_rad);
  const Eigen::Vector3d to_grasp = plan.grasp.X_BaseTcp.translation() - X_end.translation();
  EXPECT_NEAR(to_grasp.norm(), planner_->options().guarded_distance_m, 1e-4);
  EXPECT_GT(to_grasp.normalized().dot(plan.guarded_direction_Base), 0.999);
  // The retreat ends outside the bin, above the pre-grasp pose by the lift (the full lift
  // here: the tissue box has room above it).
  const Eigen::Isometry3d X_out = planner_->robot().X_BaseTcp(plan.retreat.samples.back().q_rad);
  const Eigen::Vector3d p_pre =
      planner_->robot().X_BaseTcp(plan.approach.samples.back().q_rad).translation();
  EXPECT_LT(
      (X_out.translation() - p_pre - Eigen::Vector3d(0, 0, planner_->options().lift_m)).norm(),
      1e-4);
}

// An item lying 3 mm from a side wall: its spheres stand up to 5.5 mm proud of its box, so
// the lift draws it away from the wall before the retreat (which could not start otherwise).
TEST_F(MotionPlannerTest, TheLiftDrawsAnItemAwayFromTheWallItLeansOn) {
  const auto [X_BaseItem, xyz] = ItemInBin("bin_E", "kleenex_tissue_box", 0.003);
  const PlanningScene scene =
      planner_->BuildScene("bin_E", xyz.data(), xyz.size() / 3, "kleenex_tissue_box", X_BaseItem);
  PickRequest request = PickIn("bin_E", "kleenex_tissue_box", X_BaseItem);
  const auto [moved_m, lifted_m] = LiftAcrossAndUp(planner_->PlanPick(request, &scene, Far()));
  EXPECT_GT(lifted_m, 0.6 * planner_->options().lift_m - 1e-3);
  EXPECT_NEAR(moved_m, planner_->options().wall_release_m - 0.003, 2e-3);
}

// An item with a neighbour 1 cm beside it (at -y) that stands 9 cm taller: its points within the
// cut-out's margin are gone, but above the item the scan still has them, and a lift straight
// up along it would graze them. The lift draws the item away from the neighbour by up to
// wall_release_m (less the gap the voxels leave).
TEST_F(MotionPlannerTest, TheLiftDrawsAnItemAwayFromATallerNeighbourBesideIt) {
  auto [X_BaseItem, xyz] = ItemInBin("bin_E", "kleenex_tissue_box");
  const auto& cell = planner_->cell().cell();
  const Eigen::Isometry3d X_ShelfBase = cell.config.X_BaseShelf.inverse();
  const Eigen::Vector3d half = 0.5 * items_->Get("kleenex_tissue_box")->box_I.sizes();
  // The item's long side lies across the bin (shelf y), its middle side along the depth.
  const Eigen::Vector3d c_S = X_ShelfBase * X_BaseItem.translation();
  const double floor_z = cell.bin("bin_E").floor_max_z_m;
  const double face_y = c_S.y() - half.x() - 0.01;
  for (double x = c_S.x() - half.y(); x <= c_S.x() + half.y(); x += 0.004) {
    for (double z = floor_z; z <= floor_z + 0.2; z += 0.004) {
      const Eigen::Vector3d p = cell.config.X_BaseShelf * Eigen::Vector3d(x, face_y, z);
      xyz.insert(xyz.end(), {float(p.x()), float(p.y()), float(p.z())});
    }
  }
  const PlanningScene scene =
      planner_->BuildScene("bin_E", xyz.data(), xyz.size() / 3, "kleenex_tissue_box", X_BaseItem);
  PickRequest request = PickIn("bin_E", "kleenex_tissue_box", X_BaseItem);
  const auto [moved_m, lifted_m] = LiftAcrossAndUp(planner_->PlanPick(request, &scene, Far()));
  EXPECT_GT(lifted_m, 0.6 * planner_->options().lift_m - 1e-3);
  // At most wall_release_m from the voxels' enclosing spheres (3.7 mm past a 1 cm cube).
  EXPECT_GT(moved_m, 0.004);
  EXPECT_LT(moved_m, planner_->options().wall_release_m + 0.0037 + 1e-3);
}

// The cup's lip cannot seal on a baseball (its rim stands 3 mm off the ball), wherever it
// touches: every grasp is refused as `no seal` before any search.
TEST_F(MotionPlannerTest, AnItemTheCupCannotSealOnIsRefusedBeforeAnySearch) {
  const auto [X_BaseItem, xyz] = ItemInBin("bin_E", "rawlings_baseball");
  const PlanningScene scene =
      planner_->BuildScene("bin_E", xyz.data(), xyz.size() / 3, "rawlings_baseball", X_BaseItem);
  PickRequest request = PickIn("bin_E", "rawlings_baseball", X_BaseItem);
  try {
    planner_->PlanPick(request, &scene, Far());
    FAIL() << "a pick on a ball was planned";
  } catch (const PlanFailedError& e) {
    ASSERT_FALSE(e.failures().empty());
    for (const PlanFailure& f : e.failures()) {
      EXPECT_EQ(f.kind, FailureKind::kNoSeal) << f.message;
      EXPECT_TRUE(f.before_search);
    }
    EXPECT_NE(std::string(e.what()).find("not flat enough"), std::string::npos) << e.what();
  }
}

// The tube test refuses a grasp before any search; it must only refuse what the shelf's
// mesh really blocks: for seeded random grasps in every bin, a refused one has its tube
// within the sampling gap of the mesh. The solid cylinder is sampled from the lip (in the
// bin's free box) to the flange, every 2 mm along and 15 deg around, on its axis, half
// radius and surface: a tube that ends inside the shelf's solid boards crosses their surface
// on the way (distances to a mesh are unsigned).
TEST_F(MotionPlannerTest, ATubeTheReachTestRefusesTouchesTheShelf) {
  const StaticCell& cell = planner_->cell();
  std::size_t shelf = 0;
  while (cell.grids()[shelf].name != "shelf") ++shelf;
  const GripperGeometry& gripper = planner_->robot().gripper();
  TubeReachOptions options;
  options.lip_to_flange_m = gripper.X_ToolTcp.translation().z();
  options.cup_length_m = gripper.cup_length_m;
  options.tube_radius_m = gripper.tube_radius_m;
  const double r = options.tube_radius_m;
  const float gap = 0.003f;
  std::mt19937 rng(17);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  int refused = 0, reached = 0;
  for (const world::BinGeometry& bin : cell.cell().bins) {
    const GraspContainer container = ShelfBinContainer(cell.cell(), bin.name);
    for (int i = 0; i < 150; ++i) {
      GraspCandidate grasp;
      grasp.surface = "random";
      const Eigen::Vector3d p_Shelf =
          bin.inner_S.min() +
          bin.inner_S.sizes().cwiseProduct(Eigen::Vector3d(u(rng), u(rng), u(rng)));
      grasp.p_BasePoint = cell.cell().config.X_BaseShelf * p_Shelf;
      // Within 75 deg of straight in, any side.
      const double tilt = 75.0 * M_PI / 180.0 * u(rng), turn = 2.0 * M_PI * u(rng);
      const Eigen::Vector3d in_Shelf(-std::cos(tilt), std::sin(tilt) * std::cos(turn),
                                     std::sin(tilt) * std::sin(turn));
      const Eigen::Vector3d a = cell.cell().config.X_BaseShelf.linear() * in_Shelf;
      grasp.approach_Base = a;
      const TubeReachResult reach = CheckTubeReach(container, grasp, options);
      if (reach.reaches) {
        ++reached;
        continue;
      }
      ++refused;
      const Eigen::Vector3d e1 = a.unitOrthogonal(), e2 = a.cross(e1);
      bool touches = false;
      for (double s = 0.0; s <= options.lip_to_flange_m && !touches; s += 0.002) {
        for (const double rho : {0.0, 0.5 * r, r}) {
          for (int k = 0; k < (rho > 0.0 ? 24 : 1) && !touches; ++k) {
            const double phi = k * M_PI / 12.0;
            const Eigen::Vector3d p =
                grasp.p_BasePoint - s * a + rho * (std::cos(phi) * e1 + std::sin(phi) * e2);
            touches = cell.SurfaceDistance(shelf, p.cast<float>(), gap) < gap;
          }
        }
      }
      EXPECT_TRUE(touches) << bin.name << ": " << reach.message;
    }
  }
  EXPECT_GT(refused, 200);
  EXPECT_GT(reached, 200);
}

// A book lying flat 20 cm deep in a bin: the straight tube cannot stand at its top face (the
// reach test refuses it), the articulated gripper bends its head down and keeps the tube
// level, out of the opening.
TEST_F(MotionPlannerTest, ATopFaceDeepInABinTakesTheHeadBent) {
  const std::string item = "laugh_out_loud_joke_book";
  const auto [X_BaseItem, xyz] = ItemInBin("bin_E", item, -1.0, 0.20);
  PickRequest request = PickIn("bin_E", item, X_BaseItem);
  const PlanningScene straight_scene =
      planner_->BuildScene("bin_E", xyz.data(), xyz.size() / 3, item, X_BaseItem);
  try {
    planner_->PlanPick(request, &straight_scene, Far());
    ADD_FAILURE() << "the straight tube reached a top face 20 cm deep";
  } catch (const PlanFailedError& e) {
    bool blocked = false;
    for (const auto& f : e.failures()) blocked |= f.kind == FailureKind::kTubeBlocked;
    EXPECT_TRUE(blocked) << e.what();
  }

  const PlanningScene scene =
      articulated_->BuildScene("bin_E", xyz.data(), xyz.size() / 3, item, X_BaseItem);
  const PickPlan plan = articulated_->PlanPick(request, &scene, Far());
  // Bent by a servo step (30 deg) near the angle between the approach and the opening.
  EXPECT_GE(plan.head_angle_rad, M_PI / 3 - 1e-9);
  EXPECT_NEAR(std::remainder(plan.head_angle_rad, M_PI / 6), 0.0, 1e-9);
  EXPECT_NE(plan.grasp.surface.find("+z face"), std::string::npos) << plan.grasp.surface;
  // The cup points down at the book; the guarded move goes down.
  EXPECT_LT(plan.guarded_direction_Base.z(), -0.9);
  const auto& model = articulated_->robot().kinematics().model();
  ExpectWithinLimits(plan.approach, model);
  ExpectWithinLimits(plan.descend, model);
  ExpectWithinLimits(plan.retreat, model);
  // With the head bent, the descent ends above the grasp with the tube out of the opening,
  // within a servo step of level.
  const RobotGeometry bent = articulated_->robot().WithGripper(
      articulated_->robot().gripper().AtHeadAngle(plan.head_angle_rad));
  const Eigen::Isometry3d X_end = bent.X_BaseTcp(plan.descend.samples.back().q_rad);
  const Eigen::Vector3d to_grasp = plan.grasp.X_BaseTcp.translation() - X_end.translation();
  EXPECT_GT(to_grasp.normalized().dot(plan.guarded_direction_Base), 0.999);
  const Eigen::Isometry3d X_BaseTool =
      bent.kinematics().ForwardKinematics(plan.descend.samples.back().q_rad);
  const Eigen::Vector3d p_joint = X_BaseTool * bent.gripper().p_ToolJoint();
  const Eigen::Vector3d tube = (X_BaseTool.translation() - p_joint).normalized();
  const Eigen::Vector3d out = articulated_->cell().cell().config.X_BaseShelf.linear().col(0);
  EXPECT_GT(tube.dot(out), std::cos(M_PI / 6 + 0.27)) << tube.transpose();  // tilt <= 15 deg
  // Every sample of the pick is free for FCL with the bent head (the item carried on the
  // retreat is checked by the planner itself; here the arm and gripper).
  const ExactChecker exact(bent, articulated_->cell(), scene.obstacles.get());
  for (const Trajectory* t : {&plan.approach, &plan.descend}) {
    for (const auto& sample : t->samples) {
      EXPECT_FALSE(exact.Check(sample.q_rad).in_collision);
    }
  }
  // A head angle outside the servo's range is refused.
  PlaceRequest place;
  place.item = item;
  place.container = "tote";
  place.start_rad = plan.retreat.samples.back().q_rad;
  place.head_angle_rad = 2.0;
  EXPECT_THROW(articulated_->PlanPlace(place, Far()), std::invalid_argument);
  place.head_angle_rad = plan.head_angle_rad;
  place.X_TcpItem = plan.grasp.X_BaseTcp.inverse() * X_BaseItem;
  const PlacePlan placed = articulated_->PlanPlace(place, Far());
  ExpectWithinLimits(placed.trajectory, model);
}

// The stow's verification: an item taken from a bin is set down on the table (not dropped),
// and picked from the table again with a vertical lift.
TEST_F(MotionPlannerTest, AnItemIsSetDownOnTheTableAndPickedFromItAgain) {
  const std::string item = "kleenex_tissue_box";
  const auto [X_BaseItem, xyz] = ItemInBin("bin_E", item);
  const PlanningScene bin_scene =
      planner_->BuildScene("bin_E", xyz.data(), xyz.size() / 3, item, X_BaseItem);
  PickRequest pick;
  pick.item = item;
  pick.X_BaseItem = X_BaseItem;
  pick.container = "bin_E";
  pick.start_rad = Named("scan/bin_E/0").q_rad;
  const PickPlan from_bin = planner_->PlanPick(pick, &bin_scene, Far());

  PlaceRequest place;
  place.item = item;
  place.container = "table";
  place.start_rad = from_bin.retreat.samples.back().q_rad;
  place.X_TcpItem = from_bin.grasp.X_BaseTcp.inverse() * X_BaseItem;
  const PlacePlan placed = planner_->PlanPlace(place, Far());
  const auto& model = planner_->robot().kinematics().model();
  ExpectWithinLimits(placed.trajectory, model);
  EXPECT_NEAR(placed.drop_height_m, 0.02, 1e-6);  // set down, not dropped
  const auto& config = planner_->cell().cell().config;
  const Eigen::Vector3d p_TableRelease =
      config.X_BaseTable.inverse() * placed.X_BaseTcp_release.translation();
  EXPECT_LT(p_TableRelease.head<2>().norm(), 1e-6);  // over the middle of the top

  // Where it lands: the released pose lowered by the drop. A scan of it and the table's top.
  Eigen::Isometry3d X_BaseOnTable = placed.X_BaseTcp_release * place.X_TcpItem;
  X_BaseOnTable.translation().z() -= placed.drop_height_m;
  const Eigen::Vector3d half = 0.5 * items_->Get(item)->box_I.sizes();
  std::vector<float> cloud;
  auto add = [&cloud](const Eigen::Vector3d& p) {
    cloud.insert(cloud.end(), {float(p.x()), float(p.y()), float(p.z())});
  };
  for (double x = -half.x(); x <= half.x(); x += 0.004) {
    for (double y = -half.y(); y <= half.y(); y += 0.004) {
      for (double z : {-half.z(), half.z()}) add(X_BaseOnTable * Eigen::Vector3d(x, y, z));
    }
  }
  for (double x = -0.3; x <= 0.3; x += 0.005) {
    for (double y = -0.3; y <= 0.3; y += 0.005) add(config.X_BaseTable * Eigen::Vector3d(x, y, 0));
  }
  const PlanningScene table_scene =
      planner_->BuildScene("table", cloud.data(), cloud.size() / 3, item, X_BaseOnTable);
  PickRequest again = pick;
  again.container = "table";
  again.X_BaseItem = X_BaseOnTable;
  again.start_rad = Named("verify").q_rad;
  const PickPlan from_table = planner_->PlanPick(again, &table_scene, Far());
  ExpectWithinLimits(from_table.descend, model);
  ExpectWithinLimits(from_table.retreat, model);
  // Down onto its top, then straight up.
  EXPECT_LT(from_table.guarded_direction_Base.z(), -0.95);
  const auto& robot = planner_->robot();
  const Eigen::Vector3d p_grasp = from_table.grasp.X_BaseTcp.translation();
  const Eigen::Vector3d p_lifted =
      robot.X_BaseTcp(from_table.retreat.samples.back().q_rad).translation();
  EXPECT_GT(p_lifted.z() - p_grasp.z(), 0.1);
  EXPECT_LT((p_lifted - p_grasp).head<2>().norm(), 0.02);
}

// A roll of paper towels lying lengthwise in a bin, grasped on its end: drawn straight back
// by the full exit clearance (its 30 cm behind the cup and 25 cm more), the arm would leave
// its reach; it is drawn just out of the opening instead and the roadmap carries it on to
// the tote.
TEST_F(MotionPlannerTest, ALongItemIsDrawnJustOutOfTheOpening) {
  const std::string item = "kleenex_paper_towels";
  const std::string bin = "bin_D";
  const auto [X_BaseItem, box_xyz] = ItemInBin(bin, item, -1.0, 0.17, /*long_side_in=*/true);
  // The roll is a cylinder about its long side: the scan has no points on its box's edges.
  const double radius_m = 0.5 * items_->Get(item)->box_I.sizes().y();
  std::vector<float> xyz;
  for (std::size_t i = 0; i + 2 < box_xyz.size(); i += 3) {
    const Eigen::Vector3d p_Item =
        X_BaseItem.inverse() * Eigen::Vector3d(box_xyz[i], box_xyz[i + 1], box_xyz[i + 2]);
    const bool on_box =
        (p_Item.cwiseAbs() - 0.5 * items_->Get(item)->box_I.sizes()).maxCoeff() > -0.003;
    if (on_box && p_Item.tail<2>().norm() > radius_m + 0.001) continue;
    xyz.insert(xyz.end(), box_xyz.begin() + i, box_xyz.begin() + i + 3);
  }
  PickRequest request;
  request.item = item;
  request.X_BaseItem = X_BaseItem;
  request.container = bin;
  request.start_rad = Named("scan/" + bin + "/0").q_rad;
  const PlanningScene scene =
      articulated_->BuildScene(bin, xyz.data(), xyz.size() / 3, item, X_BaseItem);
  const PickPlan plan = articulated_->PlanPick(request, &scene, Far());
  ASSERT_NE(plan.grasp.surface.find("end"), std::string::npos) << plan.grasp.surface;
  PlaceRequest place;
  place.item = item;
  place.container = "tote";
  place.start_rad = plan.retreat.samples.back().q_rad;
  place.head_angle_rad = plan.head_angle_rad;
  place.X_TcpItem = plan.grasp.X_BaseTcp.inverse() * X_BaseItem;
  const PlacePlan placed = articulated_->PlanPlace(place, Far());
  ExpectWithinLimits(placed.trajectory, articulated_->robot().kinematics().model());
  // Drawn only by the full clearance, it has no way out.
  MotionPlannerOptions full_only;
  full_only.item_short_exit_clearance_m = full_only.item_exit_clearance_m;
  const std::unique_ptr<MotionPlanner> planner = MakePlanner(Articulated(), full_only);
  EXPECT_THROW(planner->PlanPlace(place, Far()), PlanFailedError);
}

// A book whose back lies under a neighbour's overhang (a slab of scan 4 cm above it over
// its back 3 cm and on to the bin's back): lifting it straight up would press it into the
// overhang, so the lift slides it out toward the opening just above the floor first, then
// lifts it clear.
TEST_F(MotionPlannerTest, AnItemUnderAnOverhangIsSlidOutBeforeTheLift) {
  const std::string item = "i_am_a_bunny_book";
  auto [X_BaseItem, xyz] = ItemInBin("bin_E", item, -1.0, 0.14);
  const auto& cell = articulated_->cell().cell();
  const world::BinGeometry& geometry = cell.bin("bin_E");
  const Eigen::Vector3d size = items_->Get(item)->box_I.sizes();
  const Eigen::Vector3d c_S = cell.config.X_BaseShelf.inverse() * X_BaseItem.translation();
  const double back_x_S = c_S.x() - 0.5 * size.y();  // the item's middle side along the depth
  const double top_z_S = c_S.z() + 0.5 * size.z();
  for (double x = geometry.inner_S.min().x(); x < back_x_S + 0.03; x += 0.004) {
    for (double y = c_S.y() - 0.12; y < c_S.y() + 0.12; y += 0.004) {
      const Eigen::Vector3d p = cell.config.X_BaseShelf * Eigen::Vector3d(x, y, top_z_S + 0.04);
      xyz.insert(xyz.end(), {float(p.x()), float(p.y()), float(p.z())});
    }
  }
  const PlanningScene scene =
      articulated_->BuildScene("bin_E", xyz.data(), xyz.size() / 3, item, X_BaseItem);
  PickRequest request = PickIn("bin_E", item, X_BaseItem);
  const PickPlan plan = articulated_->PlanPick(request, &scene, Far());
  // By the time the cup has risen 3 cm above the grasp (where the book's back would meet
  // the overhang) it has come out toward the opening (shelf +x) by 3 cm.
  const RobotGeometry bent = articulated_->robot().WithGripper(
      articulated_->robot().gripper().AtHeadAngle(plan.head_angle_rad));
  const Eigen::Isometry3d X_ShelfBase = cell.config.X_BaseShelf.inverse();
  const Eigen::Vector3d p0_S = X_ShelfBase * plan.grasp.X_BaseTcp.translation();
  double out_m = 0.0;
  for (const TrajectorySample& s : plan.retreat.samples) {
    const Eigen::Vector3d p_S = X_ShelfBase * bent.X_BaseTcp(s.q_rad).translation();
    if (p_S.z() - p0_S.z() > 0.03) break;
    out_m = std::max(out_m, p_S.x() - p0_S.x());
  }
  EXPECT_GT(out_m, 0.03);
  ExpectWithinLimits(plan.retreat, articulated_->robot().kinematics().model());
  // The book is 4 mm thick: the guarded move's overshoot past its face is cut short of the
  // floor, so the robot's own check of the move's path passes.
  const double overshoot_m = plan.guarded_distance_m - plan.contact_distance_m;
  EXPECT_LT(overshoot_m, articulated_->options().guarded_overshoot_m);
  const Eigen::Isometry3d X_end = bent.X_BaseTcp(plan.descend.samples.back().q_rad);
  Eigen::Isometry3d X_deepest = X_end;
  X_deepest.translation() += plan.guarded_distance_m * plan.guarded_direction_Base;
  const auto q_deepest = bent.kinematics().NearestSolution(
      X_deepest * bent.gripper().X_ToolTcp.inverse(), plan.descend.samples.back().q_rad);
  ASSERT_TRUE(q_deepest);
  const FastChecker cell_only(bent, articulated_->cell(), nullptr);
  EXPECT_TRUE(MotionChecker(cell_only, articulated_->options().motion)
                  .CheckSegment(plan.descend.samples.back().q_rad, q_deepest->q_rad)
                  .free);

  // Without the slides the item is wedged under the overhang, and the failure says where.
  MotionPlannerOptions straight_up = articulated_->options();
  straight_up.slide_out_m.clear();
  const auto lift_only = MakePlanner(Articulated(), straight_up);
  const PlanningScene same =
      lift_only->BuildScene("bin_E", xyz.data(), xyz.size() / 3, item, X_BaseItem);
  try {
    lift_only->PlanPick(request, &same, Far());
    ADD_FAILURE() << "the book was lifted straight into the overhang";
  } catch (const PlanFailedError& e) {
    EXPECT_NE(std::string(e.what()).find("did not touch at the grasp"), std::string::npos)
        << e.what();
  }
}

TEST_F(MotionPlannerTest, AnItemBehindAWallHasATypedFailure) {
  // The item pose is inside the shelf's side wall between bins D and E: every grasp fails,
  // each with a stage and a kind, before any search.
  const auto& cell = planner_->cell().cell();
  const auto& d = cell.bin("bin_D");
  const auto& e = cell.bin("bin_E");
  Eigen::Isometry3d X_ShelfItem = Eigen::Isometry3d::Identity();
  X_ShelfItem.translation() =
      Eigen::Vector3d(d.opening_x_m - 0.2, 0.5 * (d.inner_S.max().y() + e.inner_S.min().y()),
                      d.floor_max_z_m + 0.05);
  PickRequest request;
  request.item = "dove_beauty_bar";
  request.X_BaseItem = cell.config.X_BaseShelf * X_ShelfItem;
  request.container = "bin_E";
  request.start_rad = Named("scan/bin_E/0").q_rad;
  try {
    planner_->PlanPick(request, nullptr, Far());
    FAIL() << "planned into a wall";
  } catch (const PlanFailedError& error) {
    ASSERT_FALSE(error.failures().empty());
    for (const PlanFailure& f : error.failures()) {
      EXPECT_NE(f.stage, FailureStage::kUnspecified) << f.message;
      EXPECT_NE(f.kind, FailureKind::kUnspecified) << f.message;
      EXPECT_FALSE(f.message.empty());
      // Refused before any search (the tube test, the goal poses): no search node.
      EXPECT_EQ(f.node, -1) << f.message;
    }
  }
}

TEST(PlanFailureNames, EveryStageAndKindHasItsOwnName) {
  std::set<std::string> stages, kinds;
  for (int i = 0; i <= static_cast<int>(FailureStage::kSearch); ++i) {
    stages.insert(FailureStageName(static_cast<FailureStage>(i)));
  }
  for (int i = 0; i <= static_cast<int>(FailureKind::kStartInCollision); ++i) {
    kinds.insert(FailureKindName(static_cast<FailureKind>(i)));
  }
  EXPECT_EQ(stages.size(), static_cast<std::size_t>(FailureStage::kSearch) + 1);
  EXPECT_EQ(kinds.size(), static_cast<std::size_t>(FailureKind::kStartInCollision) + 1);
  EXPECT_EQ(stages.count("unknown") + kinds.count("unknown"), 0u);
  // The words the messages have always used.
  EXPECT_STREQ(FailureStageName(FailureStage::kPreGrasp), "pre-grasp");
  EXPECT_STREQ(FailureStageName(FailureStage::kJointMotion), "joint motion");
  EXPECT_STREQ(FailureKindName(FailureKind::kIkUnreachable), "ik unreachable");
  EXPECT_STREQ(FailureKindName(FailureKind::kNodeBudgetSpent), "node budget spent");
  EXPECT_STREQ(FailureKindName(FailureKind::kSearchBudgetSpent), "search budget spent");
}

TEST_F(MotionPlannerTest, ASpentSearchBudgetIsATypedRefusalNotATimeout) {
  // A planner whose search budget is spent before the first grasp's search: the call ends
  // well within its own deadline with a typed "no plan" the caller can act on.
  MotionPlannerOptions hurried = planner_->options();
  hurried.search_time_budget_s = 1e-9;
  const auto planner = MakePlanner(GripperGeometry{}, hurried);
  const auto [X_BaseItem, xyz] = ItemInBin("bin_E", "kleenex_tissue_box");
  const PlanningScene scene =
      planner->BuildScene("bin_E", xyz.data(), xyz.size() / 3, "kleenex_tissue_box", X_BaseItem);
  PickRequest request = PickIn("bin_E", "kleenex_tissue_box", X_BaseItem);
  try {
    planner->PlanPick(request, &scene, Far());
    FAIL() << "planned with no search budget";
  } catch (const PlanFailedError& error) {
    bool spent = false;
    for (const PlanFailure& f : error.failures())
      spent |= f.kind == FailureKind::kSearchBudgetSpent;
    EXPECT_TRUE(spent) << error.what();
  }
  // The default budget plans the same pick.
  EXPECT_NO_THROW(planner_->PlanPick(request, &scene, Far()));
}

TEST_F(MotionPlannerTest, BadRequestsAreRefused) {
  PickRequest request;
  request.item = "dove_beauty_bar";
  request.container = "bin_E";
  request.start_rad = Named("home").q_rad;
  request.X_BaseItem.translation() = Eigen::Vector3d(1.0, 0.0, 0.5);
  PickRequest nan = request;
  nan.start_rad[2] = NAN;
  EXPECT_THROW(planner_->PlanPick(nan, nullptr, Far()), std::invalid_argument);
  PickRequest unknown = request;
  unknown.item = "no_such_item";
  EXPECT_THROW(planner_->PlanPick(unknown, nullptr, Far()), NotFoundError);
  PickRequest bin = request;
  bin.container = "bin_Z";
  EXPECT_THROW(planner_->PlanPick(bin, nullptr, Far()), NotFoundError);
  PickRequest outside = request;
  outside.start_rad[2] = 4.0;  // the elbow allows +-pi
  EXPECT_THROW(planner_->PlanPick(outside, nullptr, Far()), PreconditionError);
  PickRequest colliding = request;
  colliding.start_rad << 0.0, 1.5707963, 0.0, 0.0, 0.0, 0.0;  // down through the floor
  EXPECT_THROW(planner_->PlanPick(colliding, nullptr, Far()), PreconditionError);
  PickRequest late = request;
  EXPECT_THROW(planner_->PlanPick(late, nullptr, std::chrono::steady_clock::now()), TimeoutError);
  EXPECT_THROW(planner_->PlanJointMotion(request.start_rad, colliding.start_rad, 1.0, Far()),
               std::invalid_argument);
}

}  // namespace
}  // namespace picking::planner

namespace picking::planner {
namespace {

// Items let go over the tote land on spots of their own, each with the item's footprint
// inside the walls, the six spots apart from each other.
TEST(ToteReleaseSpotsTest, SpotsLieInsideTheToteApartFromEachOther) {
  const Eigen::Vector2d tote(0.56, 0.36);
  const double margin = 0.06;
  const std::vector<Eigen::Vector2d> spots = ToteReleaseSpots(tote, margin);
  ASSERT_EQ(spots.size(), 6u);
  for (std::size_t i = 0; i < spots.size(); ++i) {
    EXPECT_LE(std::abs(spots[i].x()), 0.5 * tote.x() - margin + 1e-12);
    EXPECT_LE(std::abs(spots[i].y()), 0.5 * tote.y() - margin + 1e-12);
    for (std::size_t j = 0; j < i; ++j) EXPECT_GT((spots[i] - spots[j]).norm(), 0.08);
  }
  // An item as wide as the tote: every spot is its centre line.
  for (const Eigen::Vector2d& s : ToteReleaseSpots(tote, 0.3)) EXPECT_TRUE(s.isZero());
}

// A detected pose off by up to 2 cm and a few degrees puts an item on the table partly
// inside its top: it is still picked (it rests on the top, which the lift lets it leave).
TEST_F(MotionPlannerTest, AnItemSeenSlightlyInsideTheTableTopIsPickedFromIt) {
  const std::string item = "kleenex_tissue_box";
  const auto& config = planner_->cell().cell().config;
  const Eigen::Vector3d half = 0.5 * items_->Get(item)->box_I.sizes();
  for (const auto& [sink_m, tilt_deg] :
       {std::pair{0.0, 0.0}, {0.006, 3.0}, {0.015, 0.0}, {0.02, 2.0}}) {
    SCOPED_TRACE("sunk " + std::to_string(sink_m) + " m, tilted " + std::to_string(tilt_deg));
    Eigen::Isometry3d X_BaseItem = config.X_BaseTable;
    X_BaseItem.translate(Eigen::Vector3d(0.0, 0.0, half.z() - sink_m));
    X_BaseItem.rotate(Eigen::AngleAxisd(tilt_deg * M_PI / 180.0, Eigen::Vector3d::UnitX()));
    std::vector<float> cloud;
    auto add = [&cloud](const Eigen::Vector3d& p) {
      cloud.insert(cloud.end(), {float(p.x()), float(p.y()), float(p.z())});
    };
    for (double x = -half.x(); x <= half.x(); x += 0.004) {
      for (double y = -half.y(); y <= half.y(); y += 0.004) {
        add(X_BaseItem * Eigen::Vector3d(x, y, half.z()));
      }
    }
    for (double x = -0.3; x <= 0.3; x += 0.005) {
      for (double y = -0.3; y <= 0.3; y += 0.005)
        add(config.X_BaseTable * Eigen::Vector3d(x, y, 0));
    }
    const PlanningScene scene =
        planner_->BuildScene("table", cloud.data(), cloud.size() / 3, item, X_BaseItem);
    PickRequest pick;
    pick.item = item;
    pick.container = "table";
    pick.X_BaseItem = X_BaseItem;
    pick.start_rad = Named("verify").q_rad;
    try {
      const PickPlan plan = planner_->PlanPick(pick, &scene, Far());
      EXPECT_LT(plan.guarded_direction_Base.z(), -0.95);
    } catch (const PlanFailedError& e) {
      ADD_FAILURE() << e.what();
    }
  }
}

}  // namespace
}  // namespace picking::planner
