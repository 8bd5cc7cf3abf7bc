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
#include "services/simulator/core/test/box_penetration.h"

namespace picking::simulator {
namespace {

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
    Eigen::AlignedBox3d box = cell.tote_inner_T();
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

// How far an item moved between two poses: its box centre's shift and its turn.
std::pair<double, double> Moved(const world::ItemModel& model, const Eigen::Isometry3d& X_before,
                                const Eigen::Isometry3d& X_after) {
  const double shift = (X_after * model.box_I.center() - X_before * model.box_I.center()).norm();
  const double turn = Eigen::AngleAxisd(X_after.linear() * X_before.linear().transpose()).angle();
  return {shift, turn};
}

// Every item of pick_layout_1's bins taken away in turn, tidy and settled: the items it did
// not support keep their poses exactly; those it did settle, come to rest inside the bin
// (or leave it over the lip) and enter no other item by more than 1 mm; the same poses on
// every run.
TEST_F(PhysicsLayoutTest, TakingAnyItemAwayLeavesTheRestConsistent) {
  const apc::Task task = Task("pick_layout_1");
  for (const LayoutMode mode : {LayoutMode::kTidy, LayoutMode::kSettled}) {
    LayoutOptions options;
    options.mode = mode;
    world_->LoadTask(task, 5, options);
    int loose = 0, fell = 0;
    for (const auto& [bin, names] : task.bin_contents) {
      std::vector<PlacedItem> all;
      for (const ItemState& s : world_->ItemsIn(bin)) all.push_back({s.name, bin, s.X_BaseItem});
      for (std::size_t r = 0; r < all.size(); ++r) {
        SCOPED_TRACE(std::string(mode == LayoutMode::kTidy ? "tidy " : "settled ") + bin +
                     " without " + all[r].name);
        std::vector<PlacedItem> items = all;
        items.erase(items.begin() + r);
        const RestResult rest = layout_->Resettle(bin, items, all[r]);
        EXPECT_TRUE(rest.at_rest);
        ASSERT_EQ(rest.items.size(), items.size());
        std::vector<Eigen::Vector3d> half;
        std::vector<Eigen::Isometry3d> X_BaseBox;
        for (std::size_t i = 0; i < items.size(); ++i) {
          const auto model = models_->Get(items[i].name);
          half.push_back(0.5 * model->box_I.sizes());
          X_BaseBox.push_back(rest.items[i].X_BaseItem *
                              Eigen::Translation3d(model->box_I.center()));
          if (!rest.loose[i]) {
            EXPECT_EQ(rest.items[i].X_BaseItem.matrix(), items[i].X_BaseItem.matrix());
            continue;
          }
          ++loose;
          fell += (X_BaseBox.back().translation() - items[i].X_BaseItem * model->box_I.center())
                      .norm() > 0.005;
          if (!rest.left_container[i]) {
            EXPECT_EQ(world_->ClassifyContainer(*model, rest.items[i].X_BaseItem), bin)
                << items[i].name;
          }
        }
        for (std::size_t i = 0; i < items.size(); ++i) {
          for (std::size_t j = 0; j < items.size(); ++j) {
            if (!rest.loose[i] || i == j || rest.left_container[i]) continue;
            EXPECT_LE(BoxPenetration(half[i], X_BaseBox[i], half[j], X_BaseBox[j]), 0.001)
                << items[i].name << " and " << items[j].name;
          }
        }
        const RestResult again = layout_->Resettle(bin, items, all[r]);
        for (std::size_t i = 0; i < items.size(); ++i) {
          EXPECT_EQ(again.items[i].X_BaseItem.matrix(), rest.items[i].X_BaseItem.matrix());
        }
      }
    }
    std::printf("%s: %d items lost their support, %d of them moved more than 5 mm\n",
                mode == LayoutMode::kTidy ? "tidy" : "settled", loose, fell);
    EXPECT_GT(loose, 0);
  }
}

// An item let go over the tote falls straight down until it first touches something (the
// drop height), lands on the items already there without entering them, and stays in the
// tote.
TEST_F(PhysicsLayoutTest, AReleasedItemFallsOntoThePile) {
  const world::CellModel& cell = world_->cell();
  const Eigen::AlignedBox3d& tote_T = cell.tote_inner_T();
  const auto box = models_->Get("kleenex_tissue_box");
  // Over the empty tote, its lowest point 0.25 m above the floor: it falls 0.25 m.
  Eigen::Isometry3d X_TBox = Eigen::Isometry3d::Identity();
  X_TBox.translation() = tote_T.center();
  X_TBox.translation().z() = tote_T.min().z() + 0.25 + 0.5 * box->box_I.sizes().z();
  const Eigen::Isometry3d X_BaseItem =
      cell.config.X_BaseTote * X_TBox * Eigen::Translation3d(-box->box_I.center());
  const RestResult empty = layout_->Release("tote", {{box->item->name, "tote", X_BaseItem}}, 0);
  EXPECT_NEAR(empty.drop_height_m, 0.25, 0.0015);
  EXPECT_EQ(empty.release_lift_m, 0.0);
  EXPECT_TRUE(empty.at_rest);
  EXPECT_NEAR((empty.items[0].X_BaseItem * box->box_I.center()).z(),
              (cell.config.X_BaseTote * X_TBox.translation()).z() - 0.25, 0.002);

  // Onto a settled pile of six items; then once more where its box overlaps one of them.
  const std::vector<std::string> pile = {
      "crayola_24_ct", "dove_beauty_bar",          "expo_dry_erase_board_eraser",
      "jane_eyre_dvd", "laugh_out_loud_joke_book", "staples_index_cards"};
  std::vector<PlacedItem> items = layout_->SettleIn("tote", pile, {}, 9).items;
  double top_z = -1.0;
  for (const PlacedItem& p : items) {
    top_z = std::max(top_z, world::Bounds(models_->Get(p.name)->mesh, p.X_BaseItem).max().z());
  }
  for (const bool overlapping : {false, true}) {
    SCOPED_TRACE(overlapping ? "overlapping" : "above");
    std::vector<PlacedItem> with = items;
    Eigen::Isometry3d X = X_BaseItem;
    const double lowest_z = top_z + 0.1;
    X.translation().z() += lowest_z - world::Bounds(box->mesh, X_BaseItem).min().z();
    if (overlapping) {
      // Its centre at the first item's centre.
      X.translation() +=
          with[0].X_BaseItem * models_->Get(with[0].name)->box_I.center() - X * box->box_I.center();
    }
    with.push_back({box->item->name, "tote", X});
    const RestResult r = layout_->Release("tote", with, with.size() - 1);
    EXPECT_TRUE(r.at_rest);
    EXPECT_EQ(r.release_lift_m > 0.0, overlapping);
    if (!overlapping) {
      EXPECT_GE(r.drop_height_m, 0.1 - 0.002);
      // It met the pile before the floor.
      const double floor_z = (cell.config.X_BaseTote * tote_T.min()).z();
      EXPECT_LT(r.drop_height_m, lowest_z - floor_z - 0.005);
    }
    std::vector<Eigen::Vector3d> half;
    std::vector<Eigen::Isometry3d> X_BaseBox;
    for (const PlacedItem& p : r.items) {
      const auto model = models_->Get(p.name);
      half.push_back(0.5 * model->box_I.sizes());
      X_BaseBox.push_back(p.X_BaseItem * Eigen::Translation3d(model->box_I.center()));
      EXPECT_EQ(world_->ClassifyContainer(*model, p.X_BaseItem), kTote) << p.name;
    }
    for (std::size_t i = 0; i + 1 < half.size(); ++i) {
      EXPECT_LE(BoxPenetration(half.back(), X_BaseBox.back(), half[i], X_BaseBox[i]), 0.001)
          << r.items[i].name;
    }
  }
}

TEST_F(PhysicsLayoutTest, ASettleFromPosesRefusesBadInput) {
  const std::vector<PlacedItem> items = layout_->SettleIn("bin_A", {"crayola_24_ct"}, {}, 1).items;
  std::vector<PlacedItem> nan = items;
  nan[0].X_BaseItem.translation().z() = std::numeric_limits<double>::quiet_NaN();
  try {
    layout_->Resettle("bin_A", nan, items[0]);
    FAIL() << "no throw";
  } catch (const LayoutError& e) {
    EXPECT_EQ(e.container(), "bin_A");
    EXPECT_NE(std::string(e.what()).find("crayola_24_ct"), std::string::npos) << e.what();
  }
  std::vector<PlacedItem> unknown = items;
  unknown[0].name = "golden_ball";
  EXPECT_THROW(layout_->Resettle("bin_A", unknown, items[0]), apc::UnknownItemError);
  EXPECT_THROW(layout_->Resettle("bin_A", items, unknown[0]), apc::UnknownItemError);
  EXPECT_THROW(layout_->Resettle("bin_A", items, nan[0]), LayoutError);
  EXPECT_THROW(layout_->Resettle("bin_Q", items, items[0]), LayoutError);
  EXPECT_THROW(layout_->Release("bin_A", items, 1), std::out_of_range);
  EXPECT_TRUE(layout_->Resettle("bin_A", {}, items[0]).items.empty());
}

// Releases go to the physics only where the whole box is over a container.
TEST_F(PhysicsLayoutTest, ContainerUnderAReleasedBox) {
  const world::CellModel& cell = world_->cell();
  const Eigen::Vector3d half(0.05, 0.04, 0.03);
  const Eigen::AlignedBox3d& tote_T = cell.tote_inner_T();
  const auto at = [](const Eigen::Isometry3d& X_BaseFrame, const Eigen::Vector3d& p_Frame) {
    return Eigen::Isometry3d(Eigen::Translation3d(X_BaseFrame * p_Frame));
  };
  const Eigen::Vector3d above_tote(tote_T.center().x(), tote_T.center().y(),
                                   tote_T.max().z() + 0.3);
  EXPECT_EQ(layout_->ContainerUnder(half, at(cell.config.X_BaseTote, above_tote)), "tote");
  const Eigen::Vector3d on_rim(tote_T.max().x(), tote_T.center().y(), tote_T.max().z() + 0.1);
  EXPECT_FALSE(layout_->ContainerUnder(half, at(cell.config.X_BaseTote, on_rim)));
  EXPECT_EQ(layout_->ContainerUnder(
                half, at(cell.config.X_BaseShelf, cell.bin("bin_E").inner_S.center())),
            "bin_E");
  EXPECT_FALSE(layout_->ContainerUnder(half, at(cell.config.X_BaseTable, {0, 0, 0.2})));
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
