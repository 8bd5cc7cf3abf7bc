#include "services/planner/core/scene_store.h"

#include <gtest/gtest.h>

#include "libs/errors/errors.h"

namespace picking::planner {
namespace {

TEST(SceneStoreTest, ScenesExpireAfterTheirLastUse) {
  auto now = std::chrono::steady_clock::time_point{};
  SceneStore store(4, [&] { return now; });
  auto scene = std::make_shared<PlanningScene>();
  scene->container = "bin_A";
  const std::string id = store.Put(scene, 10.0);
  now += std::chrono::seconds(8);
  EXPECT_EQ(store.Get(id)->container, "bin_A");  // pushes the expiry to t = 18 s
  now += std::chrono::seconds(8);
  EXPECT_EQ(store.Get(id)->container, "bin_A");
  now += std::chrono::seconds(11);
  EXPECT_THROW(store.Get(id), NotFoundError);
  EXPECT_THROW(store.Get("scene-unknown"), NotFoundError);
}

TEST(SceneStoreTest, TheOldestSceneMakesRoomAndReplacingKeepsTheId) {
  auto now = std::chrono::steady_clock::time_point{};
  SceneStore store(2, [&] { return now; });
  const std::string a = store.Put(std::make_shared<PlanningScene>(), 60.0);
  const std::string b = store.Put(std::make_shared<PlanningScene>(), 60.0);
  auto updated = std::make_shared<PlanningScene>();
  updated->item = "x";
  EXPECT_EQ(store.Put(updated, 60.0, a), a);
  EXPECT_EQ(store.Get(a)->item, "x");
  const std::string c = store.Put(std::make_shared<PlanningScene>(), 60.0);
  EXPECT_EQ(store.size(), 2u);
  EXPECT_THROW(store.Get(b), NotFoundError);  // b was the oldest
  EXPECT_NO_THROW(store.Get(c));
  EXPECT_THROW(store.Put(updated, 60.0, "scene-gone"), NotFoundError);
  EXPECT_THROW(store.Put(updated, -1.0), std::invalid_argument);
}

}  // namespace
}  // namespace picking::planner
