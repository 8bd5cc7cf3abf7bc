#include "services/simulator/core/layout.h"

#include <fcl/fcl.h>
#include <gtest/gtest.h>

#include <memory>

#include "libs/apc/task.h"
#include "libs/world/mesh_utils.h"
#include "services/simulator/core/sim_world.h"

namespace picking::simulator {
namespace {

using Bvh = fcl::BVHModel<fcl::OBBRSSd>;

std::shared_ptr<Bvh> MakeBvh(const world::TriangleMesh& mesh) {
  auto bvh = std::make_shared<Bvh>();
  std::vector<fcl::Vector3d> vertices;
  for (const auto& v : mesh.vertices) vertices.push_back(v.cast<double>());
  std::vector<fcl::Triangle> triangles;
  for (const auto& t : mesh.triangles) triangles.emplace_back(t[0], t[1], t[2]);
  bvh->beginModel();
  bvh->addSubModel(vertices, triangles);
  bvh->endModel();
  return bvh;
}

bool Collide(const std::shared_ptr<Bvh>& a, const Eigen::Isometry3d& X_a,
             const std::shared_ptr<Bvh>& b, const Eigen::Isometry3d& X_b) {
  fcl::CollisionObjectd oa(a, X_a);
  fcl::CollisionObjectd ob(b, X_b);
  fcl::CollisionRequestd request;
  fcl::CollisionResultd result;
  fcl::collide(&oa, &ob, request, result);
  return result.isCollision();
}

class LayoutTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    catalogue_ = new apc::Catalogue(apc::Catalogue::FromCsvFile(apc::DefaultCataloguePath()));
    models_ = std::make_shared<world::ItemModelLibrary>(*catalogue_);
    world_ = new SimWorld(
        world::LoadCellModel(world::ReadCellConfig(world::DefaultCellConfigPath())), models_);
  }
  static void TearDownTestSuite() {
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
};

apc::Catalogue* LayoutTest::catalogue_ = nullptr;
std::shared_ptr<world::ItemModelLibrary> LayoutTest::models_;
SimWorld* LayoutTest::world_ = nullptr;

void CheckLayout(const SimWorld& world, const apc::Task& task) {
  const auto& cell = world.cell();
  const auto shelf = MakeBvh(cell.shelf);
  const auto tote = MakeBvh(cell.tote);
  std::vector<std::shared_ptr<Bvh>> bvhs;
  for (const ItemState& s : world.items()) bvhs.push_back(MakeBvh(world.model(s.id).mesh));
  // Every listed item is there, in its bin.
  std::size_t expected = task.tote_contents.size();
  for (const auto& [bin, items] : task.bin_contents) {
    expected += items.size();
    std::multiset<std::string> want(items.begin(), items.end()), got;
    for (const ItemState& s : world.ItemsIn(bin)) got.insert(s.name);
    EXPECT_EQ(want, got) << bin;
  }
  ASSERT_EQ(world.items().size(), expected);
  const Eigen::Isometry3d X_ShelfBase = cell.config.X_BaseShelf.inverse();
  for (std::size_t i = 0; i < world.items().size(); ++i) {
    const ItemState& s = world.items()[i];
    SCOPED_TRACE(s.name + " in " + s.container);
    EXPECT_EQ(world.ClassifyContainer(world.model(s.id), s.X_BaseItem), s.container);
    if (s.container != kTote) {
      const auto& bin = cell.bin(s.container);
      const Eigen::AlignedBox3d box_S =
          world::Bounds(world.model(s.id).mesh, X_ShelfBase * s.X_BaseItem);
      EXPECT_TRUE(bin.inner_S.contains(box_S))
          << box_S.min().transpose() << " / " << box_S.max().transpose();
      // It rests on something: floor or an item top within a few millimetres.
    } else {
      const Eigen::AlignedBox3d box_T =
          world::Bounds(world.model(s.id).mesh, cell.config.X_BaseTote.inverse() * s.X_BaseItem);
      EXPECT_TRUE(world::Bounds(cell.tote).contains(box_T.center()));
    }
    EXPECT_FALSE(Collide(bvhs[i], s.X_BaseItem, shelf, cell.config.X_BaseShelf));
    EXPECT_FALSE(Collide(bvhs[i], s.X_BaseItem, tote, cell.config.X_BaseTote));
    for (std::size_t j = i + 1; j < world.items().size(); ++j) {
      EXPECT_FALSE(Collide(bvhs[i], s.X_BaseItem, bvhs[j], world.items()[j].X_BaseItem))
          << " and " << world.items()[j].name;
    }
  }
}

TEST_F(LayoutTest, PickAndStowLayoutsFitWithoutIntersections) {
  for (const std::string name :
       {"pick_layout_1", "pick_layout_2", "pick_layout_3", "stow_layout_1"}) {
    SCOPED_TRACE(name);
    const apc::Task task = Task(name);
    world_->LoadTask(task, 42);
    CheckLayout(*world_, task);
  }
}

TEST_F(LayoutTest, ItemsRestOnTheirSupportAndSettleNowhere) {
  world_->LoadTask(Task("pick_layout_1"), 7);
  const SimState before = world_->state();
  // Re-releasing nothing: nothing falls, so every item is supported as placed.
  EXPECT_EQ(world_->SuctionOff(), 0);
  EXPECT_EQ(world_->state().items, before.items);
  EXPECT_TRUE(world_->events().empty());
}

TEST_F(LayoutTest, SameSeedSameLayoutOtherSeedOtherLayout) {
  const apc::Task task = Task("pick_layout_2");
  world_->LoadTask(task, 5);
  const auto a = world_->items();
  world_->LoadTask(task, 5);
  EXPECT_EQ(world_->items(), a);
  world_->LoadTask(task, 6);
  EXPECT_NE(world_->items(), a);
}

TEST_F(LayoutTest, TooManyItemsNameTheBinAndChangeNothing) {
  world_->LoadTask(Task("pick_layout_1"), 1);
  const SimState before = world_->state();
  apc::Task task = Task("pick_layout_1");
  task.bin_contents["bin_F"] = std::vector<std::string>(8, "kleenex_paper_towels");
  try {
    world_->LoadTask(task, 1);
    FAIL() << "no throw";
  } catch (const LayoutError& e) {
    EXPECT_EQ(e.container(), "bin_F");
    EXPECT_NE(std::string(e.what()).find("kleenex_paper_towels"), std::string::npos) << e.what();
  }
  EXPECT_EQ(world_->state(), before);
}

}  // namespace
}  // namespace picking::simulator
