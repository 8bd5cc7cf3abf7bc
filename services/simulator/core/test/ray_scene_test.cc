#include "services/simulator/core/ray_scene.h"

#include <gtest/gtest.h>

#include "libs/world/mesh_utils.h"

namespace picking::simulator {
namespace {

TEST(RaySceneTest, HitsNearestPlacedMeshAndSkipsIgnoredObject) {
  RayScene scene;
  const world::TriangleMesh box = world::MakeBox({0.2, 0.2, 0.2});
  scene.Add(1, box, Eigen::Isometry3d(Eigen::Translation3d(1.0, 0.0, 0.0)));
  scene.Add(2, box, Eigen::Isometry3d(Eigen::Translation3d(2.0, 0.0, 0.0)));
  EXPECT_THROW(scene.Cast({0, 0, 0}, {1, 0, 0}, 10.0), std::logic_error);
  scene.Commit();
  const auto hit = scene.Cast({0, 0, 0}, {2, 0, 0}, 10.0);
  ASSERT_TRUE(hit);
  EXPECT_EQ(hit->object_id, 1);
  EXPECT_NEAR(hit->distance_m, 0.9, 1e-6);
  EXPECT_TRUE(hit->n_Base.isApprox(-Eigen::Vector3d::UnitX(), 1e-6));
  const auto skip = scene.Cast({0, 0, 0}, {1, 0, 0}, 10.0, 1);
  ASSERT_TRUE(skip);
  EXPECT_EQ(skip->object_id, 2);
  EXPECT_NEAR(skip->distance_m, 1.9, 1e-6);
  EXPECT_FALSE(scene.Cast({0, 0, 0}, {1, 0, 0}, 0.5));
  EXPECT_FALSE(scene.Cast({0, 0, 0}, {0, 1, 0}, 10.0));
  EXPECT_THROW(scene.Cast({0, 0, 0}, {0, 0, 0}, 1.0), std::invalid_argument);
  EXPECT_THROW(scene.Add(3, box, Eigen::Isometry3d::Identity()), std::logic_error);
}

}  // namespace
}  // namespace picking::simulator
