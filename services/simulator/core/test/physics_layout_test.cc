#include "services/simulator/core/physics_layout.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <map>
#include <memory>
#include <random>
#include <set>

#include "libs/apc/bins.h"
#include "libs/apc/task.h"
#include "libs/world/mesh_utils.h"
#include "services/simulator/core/sim_world.h"

namespace picking::simulator {
namespace {

// How deep two oriented boxes (half sizes, poses of their centres) interpenetrate: the least
// overlap over the 15 separating axes of two boxes; <= 0 when they are apart.
double BoxPenetration(const Eigen::Vector3d& ha, const Eigen::Isometry3d& Xa,
                      const Eigen::Vector3d& hb, const Eigen::Isometry3d& Xb) {
  const Eigen::Matrix3d A = Xa.linear(), B = Xb.linear();
  const Eigen::Vector3d d = Xb.translation() - Xa.translation();
  std::vector<Eigen::Vector3d> axes;
  for (int i = 0; i < 3; ++i) {
    axes.push_back(A.col(i));
    axes.push_back(B.col(i));
    for (int j = 0; j < 3; ++j) {
      const Eigen::Vector3d c = A.col(i).cross(B.col(j));
      if (c.norm() > 1e-6) axes.push_back(c.normalized());
    }
  }
  double least = std::numeric_limits<double>::infinity();
  for (const Eigen::Vector3d& n : axes) {
    const double ra = (A.transpose() * n).cwiseAbs().dot(ha);
    const double rb = (B.transpose() * n).cwiseAbs().dot(hb);
    least = std::min(least, ra + rb - std::abs(n.dot(d)));
  }
  return least;
}

TEST(BoxPenetrationTest, MeasuresOverlapAndSeparation) {
  const Eigen::Vector3d h(0.1, 0.05, 0.02);
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(0, 0, 0.039);  // 1 mm into the other
  EXPECT_NEAR(BoxPenetration(h, Eigen::Isometry3d::Identity(), h, X), 0.001, 1e-12);
  X.translation() = Eigen::Vector3d(0, 0, 0.045);
  EXPECT_LT(BoxPenetration(h, Eigen::Isometry3d::Identity(), h, X), 0.0);
  // Turned by 45 deg about x, its corner edge dipped 2 mm into the box below.
  X.linear() = Eigen::AngleAxisd(M_PI / 4, Eigen::Vector3d::UnitX()).toRotationMatrix();
  const double reach_z = (0.05 + 0.02) / std::sqrt(2.0);
  X.translation() = Eigen::Vector3d(0, 0, 0.02 + reach_z - 0.002);
  EXPECT_NEAR(BoxPenetration(h, Eigen::Isometry3d::Identity(), h, X), 0.002, 1e-9);
}

class PhysicsLayoutTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    catalogue_ = new apc::Catalogue(apc::Catalogue::FromCsvFile(apc::DefaultCataloguePath()));
    models_ = std::make_shared<world::ItemModelLibrary>(*catalogue_);
    world_ = new SimWorld(
        world::LoadCellModel(world::ReadCellConfig(world::DefaultCellConfigPath())), models_);
    layout_ = new PhysicsLayout(world_->cell(), *models_);
  }
  static void TearDownTestSuite() {
    delete layout_;
    delete world_;
    delete catalogue_;
    models_.reset();
  }
  static apc::Task Task(const std::string& name) {
    return apc::ReadTaskFile(std::string(PICKING_DATA_DIR) + "/apc2016/tasks/" + name + ".json",
                             *catalogue_);
  }

  static apc::Catalogue* catalogue_;
  static std::shared_ptr<world::ItemModelLibrary> models_;
  static SimWorld* world_;
  static PhysicsLayout* layout_;
};

apc::Catalogue* PhysicsLayoutTest::catalogue_ = nullptr;
std::shared_ptr<world::ItemModelLibrary> PhysicsLayoutTest::models_;
SimWorld* PhysicsLayoutTest::world_ = nullptr;
PhysicsLayout* PhysicsLayoutTest::layout_ = nullptr;

// The free box of a container in its own frame (bins: shelf frame; tote: tote frame), and
// that frame in Base.
std::pair<Eigen::Isometry3d, Eigen::AlignedBox3d> ContainerBox(const world::CellModel& cell,
                                                               const std::string& container) {
  if (container == kTote) {
    Eigen::AlignedBox3d box = cell.tote_inner_T(0.0);
    box.max().z() += SettleOptions{}.tote_stack_height_m;
    return {cell.config.X_BaseTote, box};
  }
  return {cell.config.X_BaseShelf, cell.bin(container).inner_S};
}

// Every item of `task` is there once, in its container (its centre by the simulator's own
// classification, its box within the container's free box but for 1 cm), and no two boxes
// interpenetrate by more than 1 mm.
void CheckSettled(const world::CellModel& cell, const world::ItemModelLibrary& models,
                  const SimWorld& world, const apc::Task& task, const SettleResult& result) {
  std::map<std::string, std::multiset<std::string>> want, got;
  for (const auto& [bin, items] : task.bin_contents) {
    if (!items.empty()) want[bin].insert(items.begin(), items.end());
  }
  if (!task.tote_contents.empty()) {
    want[kTote].insert(task.tote_contents.begin(), task.tote_contents.end());
  }
  std::vector<Eigen::Vector3d> half;
  std::vector<Eigen::Isometry3d> X_BaseBox;
  for (const PlacedItem& p : result.items) {
    SCOPED_TRACE(p.container + " " + p.name);
    got[p.container].insert(p.name);
    const auto model = models.Get(p.name);
    half.push_back(0.5 * model->box_I.sizes());
    X_BaseBox.push_back(p.X_BaseItem * Eigen::Translation3d(model->box_I.center()));
    EXPECT_EQ(world.ClassifyContainer(*model, p.X_BaseItem), p.container);
    const auto [X_BaseC, box_C] = ContainerBox(cell, p.container);
    const Eigen::AlignedBox3d grown(box_C.min() - Eigen::Vector3d::Constant(0.0101),
                                    box_C.max() + Eigen::Vector3d::Constant(0.0101));
    for (int corner = 0; corner < 8; ++corner) {
      const Eigen::Vector3d p_Box((corner & 1 ? 1 : -1) * half.back().x(),
                                  (corner & 2 ? 1 : -1) * half.back().y(),
                                  (corner & 4 ? 1 : -1) * half.back().z());
      EXPECT_TRUE(grown.contains(X_BaseC.inverse() * X_BaseBox.back() * p_Box)) << corner;
    }
  }
  EXPECT_EQ(got, want);
  for (std::size_t i = 0; i < result.items.size(); ++i) {
    for (std::size_t j = i + 1; j < result.items.size(); ++j) {
      EXPECT_LE(BoxPenetration(half[i], X_BaseBox[i], half[j], X_BaseBox[j]), 0.001)
          << result.items[i].name << " in " << result.items[i].container << " and "
          << result.items[j].name << " in " << result.items[j].container;
    }
  }
}

TEST_F(PhysicsLayoutTest, OfficialLayoutsSettle) {
  for (const std::string name : {"pick_layout_1", "pick_layout_2", "pick_layout_3", "stow_layout_1",
                                 "apc2016_pick_layout_sample", "apc2016_stow_layout_sample",
                                 "apc2016_pick_output_sample", "apc2016_stow_output_sample"}) {
    SCOPED_TRACE(name);
    const apc::Task task = Task(name);
    const SettleResult result = layout_->Settle(task, 42);
    CheckSettled(world_->cell(), *models_, *world_, task, result);
    EXPECT_LE(result.max_penetration_m, 0.002);
  }
}

TEST_F(PhysicsLayoutTest, ItemsStackAndTurnUnlikeTheTidyPlanner) {
  // pick_layout_1's bin_H holds 9 items: settled, some rest on others or not on a big face.
  const SettleResult r =
      layout_->SettleIn("bin_H", Task("pick_layout_1").bin_contents.at("bin_H"), {}, 3);
  const world::BinGeometry& bin = world_->cell().bin("bin_H");
  const double floor_Base =
      (world_->cell().config.X_BaseShelf * Eigen::Vector3d(0, 0, bin.inner_S.min().z())).z();
  int stacked = 0, on_end = 0;
  for (const PlacedItem& p : r.items) {
    const auto model = models_->Get(p.name);
    if (world::Bounds(model->mesh, p.X_BaseItem).min().z() > floor_Base + 0.03) ++stacked;
    if (std::abs(p.X_BaseItem.linear().col(2).z()) < 0.7) ++on_end;
  }
  EXPECT_GT(stacked + on_end, 0);
}

TEST_F(PhysicsLayoutTest, OverfilledBinIsRefusedNamingBinAndItem) {
  apc::Task task = Task("pick_layout_1");
  task.bin_contents["bin_F"] = std::vector<std::string>(8, "kleenex_paper_towels");
  try {
    layout_->Settle(task, 1);
    FAIL() << "no throw";
  } catch (const LayoutError& e) {
    EXPECT_EQ(e.container(), "bin_F");
    EXPECT_NE(std::string(e.what()).find("kleenex_paper_towels"), std::string::npos) << e.what();
  }
}

TEST_F(PhysicsLayoutTest, BadInputIsRefused) {
  apc::Task task = Task("pick_layout_1");
  task.bin_contents["bin_C"].push_back("no_such_item");
  EXPECT_THROW(layout_->Settle(task, 1), apc::UnknownItemError);
  EXPECT_THROW(layout_->SettleIn("bin_Z", {"crayola_24_ct"}, {}, 1), LayoutError);
  PlacedItem nan{"crayola_24_ct", "bin_A", Eigen::Isometry3d::Identity()};
  nan.X_BaseItem.translation().x() = std::numeric_limits<double>::quiet_NaN();
  try {
    layout_->SettleIn("bin_A", {"dove_beauty_bar"}, {nan}, 1);
    FAIL() << "no throw";
  } catch (const LayoutError& e) {
    EXPECT_EQ(e.container(), "bin_A");
    EXPECT_NE(std::string(e.what()).find("crayola_24_ct"), std::string::npos) << e.what();
  }
  SettleOptions bad;
  bad.time_step_s = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(PhysicsLayout(world_->cell(), *models_, bad), std::invalid_argument);
}

TEST_F(PhysicsLayoutTest, ExistingItemsAreObstacles) {
  // A dropped item lands beside or on a fixed one, never in it.
  const SettleResult first = layout_->SettleIn("bin_E", {"kleenex_tissue_box"}, {}, 4);
  const SettleResult second =
      layout_->SettleIn("bin_E", {"crayola_24_ct", "dove_beauty_bar"}, first.items, 4);
  ASSERT_EQ(second.items.size(), 2u);
  SettleResult all = second;
  all.items.push_back(first.items.front());
  apc::Task task;
  for (const auto& bin : world_->cell().bins) task.bin_contents[bin.name] = {};
  task.bin_contents["bin_E"] = {"crayola_24_ct", "dove_beauty_bar", "kleenex_tissue_box"};
  CheckSettled(world_->cell(), *models_, *world_, task, all);
}

// A random dense task: every bin gets 5 to 10 items and the tote 6 to 12, drawn from the
// catalogue while their boxes fill at most `fill` of the container's free volume.
apc::Task RandomDenseTask(const world::CellModel& cell, const world::ItemModelLibrary& models,
                          double fill, std::mt19937* rng) {
  std::vector<std::string> names;
  for (const apc::Item& item : models.catalogue().items()) names.push_back(item.name);
  std::uniform_int_distribution<std::size_t> pick(0, names.size() - 1);
  const auto draw = [&](int max_count, double volume_m3) {
    std::uniform_int_distribution<int> count(max_count / 2, max_count);
    const int n = count(*rng);
    std::vector<std::string> out;
    double used = 0.0;
    for (int tries = 0; tries < 200 && static_cast<int>(out.size()) < n; ++tries) {
      const std::string& name = names[pick(*rng)];
      const double v = models.Get(name)->box_I.volume();
      if (used + v > fill * volume_m3) continue;
      used += v;
      out.push_back(name);
    }
    return out;
  };
  apc::Task task;
  task.kind = apc::TaskKind::kStow;
  for (const auto& bin : cell.bins) task.bin_contents[bin.name] = draw(10, bin.inner_S.volume());
  task.tote_contents = draw(12, cell.tote_inner_T().volume());
  return task;
}

// The soak: 30 random dense tasks (about 90 items each) in the default test command; the
// issue's full count with `PICKING_SETTLE_SOAK=1000 build/tests/test_simulator_physics_layout_test
// --gtest_filter=*RandomDense*` (about 9 min on the 2-core dev machine; beyond CTest's 300 s).
TEST_F(PhysicsLayoutTest, RandomDenseLayoutsSettleRepeatably) {
  const char* env = std::getenv("PICKING_SETTLE_SOAK");
  const int count = env ? std::atoi(env) : 30;
  ASSERT_GT(count, 0) << "PICKING_SETTLE_SOAK must be a positive count";
  std::mt19937 rng(2016);
  int items = 0, retries = 0;
  double deepest = 0.0;
  for (int k = 0; k < count; ++k) {
    const apc::Task task = RandomDenseTask(world_->cell(), *models_, 0.2, &rng);
    SCOPED_TRACE("layout " + std::to_string(k));
    const SettleResult a = layout_->Settle(task, k);
    CheckSettled(world_->cell(), *models_, *world_, task, a);
    items += static_cast<int>(a.items.size());
    retries += a.retries;
    deepest = std::max(deepest, a.max_penetration_m);
    // The same seed gives the same poses, bit for bit.
    const SettleResult b = layout_->Settle(task, k);
    ASSERT_EQ(a.items.size(), b.items.size());
    for (std::size_t i = 0; i < a.items.size(); ++i) {
      EXPECT_EQ(a.items[i].X_BaseItem.matrix(), b.items[i].X_BaseItem.matrix()) << i;
    }
    if (HasFailure()) break;
  }
  std::printf("soak: %d layouts, %d items, %d container retries, deepest contact %.2g m\n", count,
              items, retries, deepest);
}

}  // namespace
}  // namespace picking::simulator
