#include "services/simulator/core/sim_world.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <memory>

#include "libs/apc/bins.h"
#include "libs/apc/task.h"
#include "libs/world/mesh_utils.h"
#include "services/simulator/core/physics_layout.h"
#include "services/simulator/core/test/box_penetration.h"

namespace picking::simulator {
namespace {

// The cup (TCP) frame with +z (the approach direction) along `approach_Base`.
Eigen::Isometry3d CupAt(const Eigen::Vector3d& p_Base, const Eigen::Vector3d& approach_Base) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), approach_Base)
                   .toRotationMatrix();
  X.translation() = p_Base;
  return X;
}

class SimWorldTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    models_ = std::make_shared<world::ItemModelLibrary>(
        apc::Catalogue::FromCsvFile(apc::DefaultCataloguePath()));
    cell_ = new world::CellModel(
        world::LoadCellModel(world::ReadCellConfig(world::DefaultCellConfigPath())));
  }
  static void TearDownTestSuite() {
    delete cell_;
    models_.reset();
  }

  void SetUp() override {
    world_ = std::make_unique<SimWorld>(*cell_, models_);
    apc::Task task;
    for (int i = 0; i < apc::kNumBins; ++i) task.bin_contents[apc::BinName(i)] = {};
    task.bin_contents["bin_E"] = {"kleenex_tissue_box"};
    task.bin_contents["bin_K"] = {"rawlings_baseball"};
    world_->LoadTask(task, 3);
    box_id_ = world_->ItemsIn("bin_E").at(0).id;
    ball_id_ = world_->ItemsIn("bin_K").at(0).id;
  }

  Eigen::AlignedBox3d BoxOf(int id) const {
    return world::Bounds(world_->model(id).mesh, world_->item(id).X_BaseItem);
  }

  // Puts the cup 5 cm above the top centre of item `id`, pointing down.
  void CupAbove(int id, double height_m = 0.05) {
    const auto box = BoxOf(id);
    world_->SetTcpPose(
        CupAt(Eigen::Vector3d(box.center().x(), box.center().y(), box.max().z() + height_m),
              -Eigen::Vector3d::UnitZ()));
  }

  static std::shared_ptr<world::ItemModelLibrary> models_;
  static world::CellModel* cell_;
  std::unique_ptr<SimWorld> world_;
  int box_id_ = 0, ball_id_ = 0;
};

std::shared_ptr<world::ItemModelLibrary> SimWorldTest::models_;
world::CellModel* SimWorldTest::cell_ = nullptr;

TEST_F(SimWorldTest, GuardedMoveStopsAtTheForceThreshold) {
  CupAbove(box_id_, 0.05);
  const GuardedMoveResult r = world_->GuardedMove(0.2);
  EXPECT_TRUE(r.contact);
  EXPECT_EQ(r.contact_item_id, box_id_);
  EXPECT_EQ(r.contact_object, "kleenex_tissue_box");
  const double k = world_->options().contact_stiffness_n_per_m;
  const double f = world_->options().contact_force_threshold_n;
  EXPECT_NEAR(r.travelled_m, 0.05 + f / k, 1e-4);
  EXPECT_NEAR(r.force_n, f, 0.2);
  EXPECT_NEAR(r.p_BaseContact.z(), BoxOf(box_id_).max().z(), 1e-4);
  EXPECT_NEAR(world_->X_BaseTcp().translation().z(), BoxOf(box_id_).max().z() - f / k, 1e-4);

  // Nothing within reach: full travel, no force.
  world_->SetTcpPose(CupAt(Eigen::Vector3d(0.3, 0.0, 0.5), Eigen::Vector3d::UnitZ()));
  const GuardedMoveResult up = world_->GuardedMove(0.1);
  EXPECT_FALSE(up.contact);
  EXPECT_DOUBLE_EQ(up.force_n, 0.0);
  EXPECT_NEAR(world_->X_BaseTcp().translation().z(), 0.6, 1e-12);

  // Short of the surface: moves the whole distance with no contact.
  CupAbove(box_id_, 0.05);
  const GuardedMoveResult short_move = world_->GuardedMove(0.03);
  EXPECT_FALSE(short_move.contact);
  EXPECT_NEAR(short_move.travelled_m, 0.03, 1e-12);
}

TEST_F(SimWorldTest, AProbeTellsWhatItTouches) {
  const Eigen::Vector3d down = -Eigen::Vector3d::UnitZ();
  const auto probe = [&](const Eigen::Vector3d& p_Base) {
    return world_->Probe(CupAt(p_Base, down), down, 1.0);
  };
  const auto box = BoxOf(box_id_);
  const ProbeResult item =
      probe(Eigen::Vector3d(box.center().x(), box.center().y(), box.max().z() + 0.05));
  EXPECT_TRUE(item.contact);
  EXPECT_EQ(item.surface, ContactSurface::kItem);
  EXPECT_EQ(item.item_id, box_id_);
  const world::CellConfig& config = cell_->config;
  const ProbeResult shelf = probe(config.X_BaseShelf * cell_->bin("bin_B").inner_S.center());
  EXPECT_TRUE(shelf.contact);
  EXPECT_EQ(shelf.surface, ContactSurface::kShelf);
  EXPECT_EQ(shelf.item_id, 0);
  const ProbeResult tote = probe(config.X_BaseTote * cell_->tote_inner_T().center());
  EXPECT_EQ(tote.surface, ContactSurface::kTote);
  const ProbeResult table = probe(config.X_BaseTable * Eigen::Vector3d(0.0, 0.0, 0.2));
  EXPECT_EQ(table.surface, ContactSurface::kTable);
  const ProbeResult none = world_->Probe(
      CupAt(config.X_BaseTable * Eigen::Vector3d(0.0, 0.0, 0.2), Eigen::Vector3d::UnitZ()),
      Eigen::Vector3d::UnitZ(), 0.1);
  EXPECT_FALSE(none.contact);
  EXPECT_EQ(none.surface, ContactSurface::kNone);
}

TEST_F(SimWorldTest, PickCarryAndDropIntoTheToteIsLogged) {
  CupAbove(box_id_);
  world_->GuardedMove(0.2);
  const SuctionResult seal = world_->SuctionOn();
  ASSERT_TRUE(seal.sealed) << seal.reason;
  EXPECT_EQ(seal.attached_item_id, box_id_);
  EXPECT_LT(seal.flatness_m, 1e-4);
  EXPECT_LT(seal.angle_rad, 1e-3);
  EXPECT_EQ(world_->item(box_id_).container, kGripper);
  const Eigen::Isometry3d X_TcpItem =
      world_->X_BaseTcp().inverse() * world_->item(box_id_).X_BaseItem;

  // Carry it 0.5 m above the tote floor; it follows the cup.
  const Eigen::Vector3d tote_centre = cell_->config.X_BaseTote.translation();
  world_->SetTcpPose(
      CupAt(tote_centre + Eigen::Vector3d(0.0, 0.0, 0.5), -Eigen::Vector3d::UnitZ()));
  const Eigen::Isometry3d carried = world_->item(box_id_).X_BaseItem;
  EXPECT_TRUE((world_->X_BaseTcp() * X_TcpItem).isApprox(carried, 1e-12));
  const double bottom = BoxOf(box_id_).min().z();

  EXPECT_EQ(world_->SuctionOff(), box_id_);
  EXPECT_EQ(world_->attached_item_id(), 0);
  EXPECT_EQ(world_->item(box_id_).container, kTote);
  const auto& events = world_->events();
  ASSERT_GE(events.size(), 3u);
  EXPECT_EQ(events[0].kind, EventKind::kAttached);
  EXPECT_EQ(events[1].kind, EventKind::kReleased);
  EXPECT_EQ(events[1].container, kTote);
  // The tote floor is the highest support under the item.
  const double rest = BoxOf(box_id_).min().z();
  EXPECT_NEAR(events[1].drop_height_m, bottom - rest, 1e-3);
  EXPECT_GT(events[1].drop_height_m, 0.3);
  EXPECT_EQ(events[2].kind, EventKind::kDropped);
  EXPECT_LT(rest - cell_->config.floor_z_m(), 0.03);
  // It rests upright (largest face down).
  EXPECT_NEAR(std::abs(world_->item(box_id_).X_BaseItem.linear()(2, 2)), 1.0, 1e-9);
}

TEST_F(SimWorldTest, LowPlacementIsNotADropAndOutsideIsRecorded) {
  CupAbove(box_id_);
  world_->GuardedMove(0.2);
  ASSERT_TRUE(world_->SuctionOn().sealed);
  // Over the table, 5 cm above its top: a gentle placement.
  const double h = BoxOf(box_id_).max().z() - world_->X_BaseTcp().translation().z();
  const double height = BoxOf(box_id_).sizes().z();
  const Eigen::Vector3d table_top = cell_->config.X_BaseTable.translation();
  world_->SetTcpPose(
      CupAt(table_top + Eigen::Vector3d(0, 0, height + 0.05 - h), -Eigen::Vector3d::UnitZ()));
  world_->SuctionOff();
  EXPECT_EQ(world_->item(box_id_).container, kTable);
  EXPECT_NEAR(world_->events().back().drop_height_m, 0.05, 2e-3);
  for (const Event& e : world_->events()) EXPECT_NE(e.kind, EventKind::kDropped);

  // Pick it again and let go between robot and shelf: it lands on the floor, outside.
  CupAbove(box_id_);
  world_->GuardedMove(0.2);
  ASSERT_TRUE(world_->SuctionOn().sealed);
  world_->SetTcpPose(CupAt(Eigen::Vector3d(0.5, 0.0, 0.0), -Eigen::Vector3d::UnitZ()));
  world_->SuctionOff();
  EXPECT_EQ(world_->item(box_id_).container, kOutside);
  EXPECT_EQ(world_->events().back().kind, EventKind::kOutside);
  EXPECT_EQ(world_->ItemsIn(kOutside).size(), 1u);
}

TEST_F(SimWorldTest, NoSealOnARoundOrTiltedSurface) {
  CupAbove(ball_id_, 0.03);
  world_->GuardedMove(0.1);
  const SuctionResult ball = world_->SuctionOn();
  EXPECT_FALSE(ball.sealed);
  EXPECT_GT(ball.flatness_m, world_->options().seal_flatness_tolerance_m);
  EXPECT_EQ(world_->attached_item_id(), 0);
  EXPECT_EQ(world_->item(ball_id_).container, "bin_K");
  world_->SuctionOff();

  // Tilted by 40 degrees about the shelf-facing axis onto the flat box top.
  const auto box = BoxOf(box_id_);
  const Eigen::Vector3d approach =
      Eigen::AngleAxisd(40.0 * M_PI / 180.0, Eigen::Vector3d::UnitX()) * -Eigen::Vector3d::UnitZ();
  world_->SetTcpPose(CupAt(
      box.center() + Eigen::Vector3d(0, 0, 0.5 * box.sizes().z()) - 0.03 * approach, approach));
  world_->GuardedMove(0.1);
  const SuctionResult tilted = world_->SuctionOn();
  EXPECT_FALSE(tilted.sealed);
  EXPECT_LT(tilted.flatness_m, 1e-3);
  EXPECT_NEAR(tilted.angle_rad, 40.0 * M_PI / 180.0, 0.02);
  EXPECT_NE(tilted.reason.find("tilted"), std::string::npos) << tilted.reason;
  EXPECT_EQ(world_->events().size(), 0u);

  // Held 2 cm above the box top: the lip does not touch.
  world_->SuctionOff();
  CupAbove(box_id_, 0.02);
  const SuctionResult away = world_->SuctionOn();
  EXPECT_FALSE(away.sealed);
  EXPECT_NE(away.reason.find("touch"), std::string::npos) << away.reason;
}

// An item standing in the tote above its rim (a roll on end, the top of a pile) is in the
// tote; beside the tote at the same height it is not.
TEST_F(SimWorldTest, AnItemStandingOutAboveTheTotesRimIsInTheTote) {
  const Eigen::AlignedBox3d inner_T = cell_->tote_inner_T();
  Eigen::Isometry3d X_BaseItem =
      cell_->config.X_BaseTote *
      Eigen::Translation3d(inner_T.center().x(), inner_T.center().y(), inner_T.max().z() + 0.1);
  X_BaseItem.translation() -= X_BaseItem.linear() * world_->model(box_id_).box_I.center();
  world_->SetItemPose(box_id_, X_BaseItem);
  EXPECT_EQ(world_->item(box_id_).container, kTote);
  X_BaseItem.translation().y() += inner_T.sizes().y();  // beside it
  world_->SetItemPose(box_id_, X_BaseItem);
  EXPECT_NE(world_->item(box_id_).container, kTote);
}

TEST_F(SimWorldTest, ItemOnTopFallsWhenTheItemBelowIsPulledOut) {
  // A book lying on the tissue box.
  const int book = world_->AddItem("i_am_a_bunny_book", "bin_H", 1);
  const auto box = BoxOf(box_id_);
  Eigen::Isometry3d X_book = world_->item(book).X_BaseItem;
  X_book.translation().x() += box.center().x() - BoxOf(book).center().x();
  X_book.translation().y() += box.center().y() - BoxOf(book).center().y();
  X_book.translation().z() += box.max().z() + 0.0005 - BoxOf(book).min().z();
  world_->SetItemPose(book, X_book);
  EXPECT_EQ(world_->item(book).container, "bin_E");

  // Grip the box's front face (approach toward the shelf, -x of the base is out of the bin).
  const Eigen::Vector3d front(box.min().x(), box.center().y(), box.min().z() + 0.03);
  world_->SetTcpPose(CupAt(front - Eigen::Vector3d(0.05, 0, 0), Eigen::Vector3d::UnitX()));
  const GuardedMoveResult touch = world_->GuardedMove(0.2);
  ASSERT_TRUE(touch.contact);
  EXPECT_EQ(touch.contact_item_id, box_id_);
  ASSERT_TRUE(world_->SuctionOn().sealed);
  EXPECT_EQ(world_->item(book).container, "bin_E");  // still resting on the box
  // Pull the box out of the bin.
  Eigen::Isometry3d X = world_->X_BaseTcp();
  X.translation().x() -= 0.4;
  world_->SetTcpPose(X);
  const Event& fell = world_->events().back();
  EXPECT_EQ(fell.kind, EventKind::kFell);
  EXPECT_EQ(fell.item_id, book);
  EXPECT_NEAR(fell.drop_height_m, box.sizes().z(), 3e-3);
  EXPECT_EQ(world_->item(book).container, "bin_E");
  EXPECT_NEAR(BoxOf(book).min().z(), box.min().z(), 0.02);  // back on the bin floor
}

// Puts item `id` on top of item `below`, centred over it, `gap_m` above its top.
void StackOn(SimWorld* world, int id, int below, double gap_m = 0.0005) {
  const auto bounds = [&](int i) {
    return world::Bounds(world->model(i).mesh, world->item(i).X_BaseItem);
  };
  Eigen::Isometry3d X = world->item(id).X_BaseItem;
  X.translation().x() += bounds(below).center().x() - bounds(id).center().x();
  X.translation().y() += bounds(below).center().y() - bounds(id).center().y();
  X.translation().z() += bounds(below).max().z() + gap_m - bounds(id).min().z();
  world->SetItemPose(id, X);
}

// The robot takes the lowest item of a three-high stack: the cup seals on its front face and
// pulls it out of the bin. The two items above settle by physics onto what is left: lower,
// on the bin floor or on each other, apart, inside the bin, each with a kFell event giving
// how far its centre fell; the item beside the stack does not move.
TEST_F(SimWorldTest, PickingTheLowestItemOfAStackLetsTheItemsAboveSettle) {
  const int book = world_->AddItem("i_am_a_bunny_book", "bin_E", 1);
  const int dvd = world_->AddItem("jane_eyre_dvd", "bin_H", 1);
  const int beside = world_->AddItem("dove_beauty_bar", "bin_E", 2);
  StackOn(world_.get(), book, box_id_);
  StackOn(world_.get(), dvd, book);
  ASSERT_EQ(world_->ItemsIn("bin_E").size(), 4u);
  const std::vector<ItemState> before = world_->items();
  const Eigen::AlignedBox3d box = BoxOf(box_id_);

  // The cup on the tissue box's front face, 3 cm above its bottom, pressing toward the shelf.
  const Eigen::Vector3d front(box.min().x(), box.center().y(), box.min().z() + 0.03);
  world_->SetTcpPose(CupAt(front - Eigen::Vector3d(0.05, 0, 0), Eigen::Vector3d::UnitX()));
  ASSERT_EQ(world_->GuardedMove(0.2).contact_item_id, box_id_);
  ASSERT_EQ(world_->SuctionOn().attached_item_id, box_id_);
  // Out of the bin in 1 cm steps, as the arm would draw it.
  for (int step = 0; step < 40; ++step) {
    Eigen::Isometry3d X = world_->X_BaseTcp();
    X.translation().x() -= 0.01;
    world_->SetTcpPose(X);
  }
  EXPECT_EQ(world_->item(box_id_).container, kGripper);

  std::map<int, double> fell;  // item id: drop height
  for (const Event& e : world_->events()) {
    if (e.kind == EventKind::kFell) fell[e.item_id] = e.drop_height_m;
    EXPECT_NE(e.kind, EventKind::kOutside) << e.item_name;
  }
  EXPECT_EQ(fell.size(), 2u);
  const world::BinGeometry& bin = cell_->bin("bin_E");
  const Eigen::Isometry3d X_ShelfBase = cell_->config.X_BaseShelf.inverse();
  const double floor_z = (cell_->config.X_BaseShelf * bin.inner_S.min()).z();
  for (const int id : {book, dvd}) {
    SCOPED_TRACE(world_->item(id).name);
    const world::ItemModel& m = world_->model(id);
    const ItemState& then =
        *std::find_if(before.begin(), before.end(), [&](const ItemState& s) { return s.id == id; });
    const double centre_fall = (then.X_BaseItem * m.box_I.center()).z() -
                               (world_->item(id).X_BaseItem * m.box_I.center()).z();
    EXPECT_GT(centre_fall, 0.05);  // the tissue box is about 10 cm tall
    ASSERT_EQ(fell.count(id), 1u);
    EXPECT_NEAR(fell[id], centre_fall, 1e-9);
    EXPECT_EQ(world_->item(id).container, "bin_E");
    // Inside the bin's free box, but for 1 cm.
    const Eigen::AlignedBox3d b_S =
        world::Bounds(m.mesh, X_ShelfBase * world_->item(id).X_BaseItem);
    const Eigen::AlignedBox3d grown(bin.inner_S.min() - Eigen::Vector3d::Constant(0.01),
                                    bin.inner_S.max() + Eigen::Vector3d::Constant(0.01));
    EXPECT_TRUE(grown.contains(b_S)) << b_S.min().transpose() << " " << b_S.max().transpose();
    EXPECT_LT(BoxOf(id).min().z(), floor_z + 0.05);  // down on the floor or on the book
  }
  // The item beside the stack did not move; nothing left in the bin interpenetrates.
  const ItemState& beside_then = *std::find_if(before.begin(), before.end(),
                                               [&](const ItemState& s) { return s.id == beside; });
  EXPECT_EQ(world_->item(beside).X_BaseItem.matrix(), beside_then.X_BaseItem.matrix());
  const std::vector<ItemState> left = world_->ItemsIn("bin_E");
  ASSERT_EQ(left.size(), 3u);
  for (std::size_t i = 0; i < left.size(); ++i) {
    for (std::size_t j = i + 1; j < left.size(); ++j) {
      const world::ItemModel& a = world_->model(left[i].id);
      const world::ItemModel& b = world_->model(left[j].id);
      EXPECT_LE(BoxPenetration(0.5 * a.box_I.sizes(),
                               left[i].X_BaseItem * Eigen::Translation3d(a.box_I.center()),
                               0.5 * b.box_I.sizes(),
                               left[j].X_BaseItem * Eigen::Translation3d(b.box_I.center())),
                0.001)
          << left[i].name << " and " << left[j].name;
    }
  }
  // They rest: each fallen item lies on the bin floor or touches an item left there.
  for (const int id : {book, dvd}) {
    const world::ItemModel& m = world_->model(id);
    const Eigen::Isometry3d X_BaseBox =
        world_->item(id).X_BaseItem * Eigen::Translation3d(m.box_I.center());
    const double floor_max_z =
        (cell_->config.X_BaseShelf * Eigen::Vector3d(0, 0, bin.floor_max_z_m)).z();
    bool supported = BoxOf(id).min().z() < floor_max_z + 0.003;
    for (const ItemState& s : left) {
      const world::ItemModel& o = world_->model(s.id);
      supported = supported ||
                  (s.id != id &&
                   BoxPenetration(0.5 * m.box_I.sizes(), X_BaseBox, 0.5 * o.box_I.sizes(),
                                  s.X_BaseItem * Eigen::Translation3d(o.box_I.center())) > -0.002);
    }
    EXPECT_TRUE(supported) << world_->item(id).name;
  }
}

// A tidy pile loses nothing to a pick beside it: only what the picked item held moves.
TEST_F(SimWorldTest, APickMovesNothingItDidNotHold) {
  const apc::Task task = apc::ReadTaskFile(
      apc::DefaultDataDir() + "/apc2016/tasks/pick_layout_1.json", models_->catalogue());
  world_->LoadTask(task, 11);
  const std::vector<ItemState> bin = world_->ItemsIn("bin_H");
  ASSERT_GT(bin.size(), 2u);
  // The item with the largest footprint, from above.
  const auto footprint = [&](const ItemState& s) {
    const Eigen::Vector3d size = BoxOf(s.id).sizes();
    return size.x() * size.y();
  };
  const ItemState target = *std::max_element(
      bin.begin(), bin.end(),
      [&](const ItemState& a, const ItemState& b) { return footprint(a) < footprint(b); });
  CupAbove(target.id, 0.03);
  world_->GuardedMove(0.1);
  const SuctionResult seal = world_->SuctionOn();
  ASSERT_EQ(seal.attached_item_id, target.id) << seal.reason << " " << target.name;
  for (int step = 0; step < 30; ++step) {
    Eigen::Isometry3d X = world_->X_BaseTcp();
    X.translation() += Eigen::Vector3d(-0.01, 0.0, 0.003);
    world_->SetTcpPose(X);
  }
  for (const Event& e : world_->events()) EXPECT_NE(e.kind, EventKind::kFell) << e.item_name;
  for (const ItemState& s : bin) {
    if (s.id == target.id) continue;
    EXPECT_EQ(world_->item(s.id).X_BaseItem.matrix(), s.X_BaseItem.matrix()) << s.name;
  }
}

TEST_F(SimWorldTest, BadRequestsThrowAndChangeNothing) {
  CupAbove(box_id_);
  world_->GuardedMove(0.2);
  world_->SuctionOn();
  const SimState before = world_->state();
  Eigen::Isometry3d nan = Eigen::Isometry3d::Identity();
  nan.translation().x() = std::nan("");
  Eigen::Isometry3d scaled = Eigen::Isometry3d::Identity();
  scaled.linear() *= 2.0;
  EXPECT_THROW(world_->SetTcpPose(nan), std::invalid_argument);
  EXPECT_THROW(world_->SetTcpPose(scaled), std::invalid_argument);
  EXPECT_THROW(world_->SetItemPose(999, Eigen::Isometry3d::Identity()), std::out_of_range);
  EXPECT_THROW(world_->SetItemPose(ball_id_, nan), std::invalid_argument);
  EXPECT_THROW(world_->SetItemPose(box_id_, Eigen::Isometry3d::Identity()), std::invalid_argument);
  EXPECT_THROW(world_->ItemsIn("bin_Q"), std::invalid_argument);
  EXPECT_THROW(world_->item(0), std::out_of_range);
  EXPECT_THROW(world_->AddItem("golden_ball", "bin_A", 1), apc::UnknownItemError);
  EXPECT_THROW(world_->AddItem("kleenex_tissue_box", "bin_Q", 1), LayoutError);
  EXPECT_THROW(world_->GuardedMove(-0.1), std::invalid_argument);
  EXPECT_THROW(world_->GuardedMove(std::nan("")), std::invalid_argument);
  EXPECT_THROW(world_->SetJointPositions(ur10::JointVector::Zero()), std::logic_error);
  apc::Task bad;
  for (int i = 0; i < apc::kNumBins; ++i) bad.bin_contents[apc::BinName(i)] = {};
  bad.bin_contents["bin_A"] = {"golden_ball"};
  EXPECT_THROW(world_->LoadTask(bad, 1), apc::UnknownItemError);
  bad.bin_contents["bin_A"] = std::vector<std::string>(10, "kleenex_paper_towels");
  EXPECT_THROW(world_->LoadTask(bad, 1), LayoutError);
  EXPECT_EQ(world_->state(), before);
}

// pick_layout_1 settled by physics: every item in its container, the same poses for the
// same seed, not the tidy layout; a bin that cannot hold its items is refused and the world
// is left as it was.
TEST_F(SimWorldTest, ASettledLayoutKeepsEveryItemInItsContainer) {
  const apc::Task task = apc::ReadTaskFile(
      apc::DefaultDataDir() + "/apc2016/tasks/pick_layout_1.json", models_->catalogue());
  LayoutOptions settled;
  settled.mode = LayoutMode::kSettled;
  world_->LoadTask(task, 7, settled);
  for (const auto& [bin, items] : task.bin_contents) {
    EXPECT_EQ(world_->ItemsIn(bin).size(), items.size()) << bin;
  }
  EXPECT_EQ(world_->ItemsIn("tote").size(), task.tote_contents.size());
  const std::vector<ItemState> first = world_->items();
  world_->LoadTask(task, 7, settled);
  ASSERT_EQ(world_->items().size(), first.size());
  for (std::size_t i = 0; i < first.size(); ++i) {
    EXPECT_EQ(world_->items()[i].X_BaseItem.matrix(), first[i].X_BaseItem.matrix());
  }
  world_->LoadTask(task, 7);
  int moved = 0;
  for (std::size_t i = 0; i < first.size(); ++i) {
    moved += !world_->items()[i].X_BaseItem.isApprox(first[i].X_BaseItem, 1e-6);
  }
  EXPECT_GT(moved, 0);
  const SimState before = world_->state();
  apc::Task overfull;
  for (int i = 0; i < apc::kNumBins; ++i) overfull.bin_contents[apc::BinName(i)] = {};
  overfull.bin_contents["bin_F"] = std::vector<std::string>(8, "kleenex_paper_towels");
  EXPECT_THROW(world_->LoadTask(overfull, 1, settled), LayoutError);
  EXPECT_EQ(world_->state(), before);
  EXPECT_EQ(LayoutModeFromString("settled"), LayoutMode::kSettled);
  EXPECT_THROW(LayoutModeFromString("stacked"), std::invalid_argument);
}

TEST_F(SimWorldTest, SceneMeshesFollowTheItems) {
  const auto objects = world_->SceneMeshes();
  const auto names = world_->SceneNames();
  ASSERT_EQ(objects.size(), 3u + world_->items().size());
  ASSERT_EQ(names.size(), objects.size());
  EXPECT_EQ(names[0], "shelf");
  EXPECT_EQ(objects[0].mesh, &world_->cell().shelf);
  EXPECT_TRUE(objects[0].X_BaseObject.isApprox(cell_->config.X_BaseShelf));
  for (std::size_t i = 0; i < world_->items().size(); ++i) {
    EXPECT_EQ(names[3 + i], world_->items()[i].name);
    EXPECT_EQ(objects[3 + i].mesh, &world_->model(world_->items()[i].id).mesh);
    EXPECT_TRUE(objects[3 + i].X_BaseObject.isApprox(world_->items()[i].X_BaseItem));
  }
}

TEST_F(SimWorldTest, JointPositionsPlaceTheCupByForwardKinematicsAndTheCellsTcp) {
  auto kinematics = std::make_shared<ur10::Ur10Kinematics>(
      ur10::Ur10Model::Load(std::string(PICKING_DATA_DIR) + "/ur10"));
  // A gripper of its own: the TCP 0.3 m out and turned about the flange's z axis.
  world::CellModel cell = *cell_;
  cell.config.gripper.X_ToolTcp =
      Eigen::Translation3d(0.0, 0.01, 0.3) * Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitZ());
  SimWorld world(cell, models_, SimOptions{}, kinematics);
  EXPECT_TRUE(world.X_ToolTcp().isApprox(cell.config.gripper.X_ToolTcp, 1e-15));
  ur10::JointVector q;
  q << 0.1, -1.2, 1.4, -0.2, 1.5707963, 0.3;
  world.SetJointPositions(q);
  const Eigen::Isometry3d X_BaseTool = kinematics->ForwardKinematics(q);
  EXPECT_TRUE(world.X_BaseTcp().isApprox(X_BaseTool * cell.config.gripper.X_ToolTcp, 1e-12));
  EXPECT_TRUE(world.X_BaseTool().isApprox(X_BaseTool, 1e-12));
  ASSERT_TRUE(world.state().q_rad.has_value());
  EXPECT_EQ(*world.state().q_rad, q);

  // The default cell's gripper: the cup 0.35 m along the flange's z axis.
  SimWorld default_world(*cell_, models_, SimOptions{}, kinematics);
  default_world.SetJointPositions(q);
  EXPECT_NEAR((default_world.X_BaseTcp().translation() - X_BaseTool.translation()).norm(), 0.35,
              1e-12);
  EXPECT_TRUE(default_world.X_BaseTcp().linear().isApprox(X_BaseTool.linear(), 1e-12));

  world::CellModel bad = *cell_;
  bad.config.gripper.X_ToolTcp.linear() *= 2.0;
  EXPECT_THROW(SimWorld(bad, models_, SimOptions{}, kinematics), std::invalid_argument);
}

TEST_F(SimWorldTest, TurningTheHeadMovesTheCupAboutItsJoint) {
  auto kinematics = std::make_shared<ur10::Ur10Kinematics>(
      ur10::Ur10Model::Load(std::string(PICKING_DATA_DIR) + "/ur10"));
  world::CellModel cell = *cell_;
  cell.config.gripper.head_length_m = 0.09;
  cell.config.gripper.max_head_angle_rad = M_PI / 2;
  SimWorld world(cell, models_, SimOptions{}, kinematics);
  ur10::JointVector q;
  q << 0.1, -1.2, 1.4, -0.2, 1.5707963, 0.3;
  world.SetJointPositions(q);
  const Eigen::Isometry3d X_BaseTool = kinematics->ForwardKinematics(q);
  world.SetHeadAngle(M_PI / 2);
  EXPECT_EQ(world.head_angle_rad(), M_PI / 2);
  EXPECT_EQ(world.state().head_angle_rad, M_PI / 2);
  // The flange and joints stay; the cup is the head's length from the joint, its axis
  // across the tube.
  EXPECT_TRUE(world.X_BaseTool().isApprox(X_BaseTool, 1e-12));
  ASSERT_TRUE(world.state().q_rad.has_value());
  EXPECT_EQ(*world.state().q_rad, q);
  const Eigen::Vector3d p_Joint = X_BaseTool * cell.config.gripper.p_ToolJoint();
  EXPECT_NEAR((world.X_BaseTcp().translation() - p_Joint).norm(), 0.09, 1e-12);
  EXPECT_NEAR(world.X_BaseTcp().linear().col(2).dot(X_BaseTool.linear().col(2)), 0.0, 1e-12);
  // Later joint positions keep the head's angle.
  world.SetJointPositions(q);
  EXPECT_TRUE(
      world.X_BaseTcp().isApprox(X_BaseTool * cell.config.gripper.X_ToolTcpAt(M_PI / 2), 1e-12));
  // Out of range, NaN, or any turn of the straight gripper: refused, nothing changes.
  const SimState before = world.state();
  EXPECT_THROW(world.SetHeadAngle(2.0), std::invalid_argument);
  EXPECT_THROW(world.SetHeadAngle(std::nan("")), std::invalid_argument);
  EXPECT_EQ(world.state(), before);
  world::CellModel straight_cell = *cell_;
  straight_cell.config.gripper.head_length_m = 0.0;
  straight_cell.config.gripper.max_head_angle_rad = 0.0;
  SimWorld straight(straight_cell, models_, SimOptions{}, kinematics);
  EXPECT_THROW(straight.SetHeadAngle(0.2), std::invalid_argument);
}

}  // namespace
}  // namespace picking::simulator
