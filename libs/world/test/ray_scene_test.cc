#include "libs/world/ray_scene.h"

#include <gtest/gtest.h>

#include <cmath>

#include "libs/world/mesh_utils.h"

namespace picking::world {
namespace {

TEST(RaySceneTest, HitsNearestPlacedMeshAndSkipsIgnoredObject) {
  RayScene scene;
  const TriangleMesh box = MakeBox({0.2, 0.2, 0.2});
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

TEST(RaySceneTest, CastAllReturnsEverySurfaceAlongTheRayInOrder) {
  RayScene scene;
  const TriangleMesh box = MakeBox({0.2, 0.2, 0.2});
  scene.Add(1, box, Eigen::Isometry3d(Eigen::Translation3d(1.0, 0.0, 0.0)));
  scene.Add(2, box, Eigen::Isometry3d(Eigen::Translation3d(2.0, 0.0, 0.0)));
  EXPECT_THROW(scene.CastAll({0, 0, 0}, {1, 0, 0}), std::logic_error);
  scene.Commit();
  // Through the middle of the faces, i.e. through the edge the two triangles of each face
  // share: one hit per face.
  const auto hits = scene.CastAll({0, 0, 0}, {3, 0, 0});
  ASSERT_EQ(hits.size(), 4u);
  const double expected[] = {0.9, 1.1, 1.9, 2.1};
  const int objects[] = {1, 1, 2, 2};
  for (int i = 0; i < 4; ++i) {
    EXPECT_NEAR(hits[i].distance_m, expected[i], 1e-6);
    EXPECT_EQ(hits[i].object_id, objects[i]);
    EXPECT_TRUE(hits[i].p_BaseHit.isApprox(Eigen::Vector3d(expected[i], 0, 0), 1e-6));
    EXPECT_NEAR(std::abs(hits[i].n_Base.x()), 1.0, 1e-6);
  }
  EXPECT_TRUE(hits[1].n_Base.isApprox(Eigen::Vector3d::UnitX(), 1e-6));  // leaving box 1
  const auto window = scene.CastAll({0, 0, 0}, {1, 0, 0}, 2.0, 1.0);
  ASSERT_EQ(window.size(), 2u);
  EXPECT_NEAR(window[0].distance_m, 1.1, 1e-6);
  EXPECT_NEAR(window[1].distance_m, 1.9, 1e-6);
  EXPECT_TRUE(scene.CastAll({0, 0, 0}, {0, 1, 0}).empty());
  EXPECT_THROW(scene.CastAll({0, 0, 0}, {0, 0, 0}), std::invalid_argument);
}

TEST(RaySceneTest, DoubleHitDistancesAreAsExactAsTheVertices) {
  // A face at x = 1 - 0.1f seen from x = 0.3 + 1e-9: single precision rounds the origin and
  // the distance (about 1e-8 m off); kDouble recomputes it on the hit triangle.
  const TriangleMesh box = MakeBox({0.2, 0.2, 0.2});
  const Eigen::Isometry3d X_BaseBox(Eigen::Translation3d(1.0, 0.0, 0.0));
  const Eigen::Vector3d origin(0.3 + 1e-9, 0.013, 0.021);
  const double front = 1.0 + static_cast<double>(-0.1f) - origin.x();
  const double back = 1.0 + static_cast<double>(0.1f) - origin.x();
  RayScene exact(HitDistance::kDouble);
  exact.Add(1, box, X_BaseBox);
  exact.Commit();
  const auto hit = exact.Cast(origin, {2, 0, 0}, 10.0);
  ASSERT_TRUE(hit);
  EXPECT_NEAR(hit->distance_m, front, 1e-15);
  EXPECT_NEAR(hit->p_BaseHit.x(), origin.x() + front, 1e-15);
  EXPECT_TRUE(hit->n_Base.isApprox(-Eigen::Vector3d::UnitX(), 1e-6));
  const auto hits = exact.CastAll(origin, {1, 0, 0});
  ASSERT_EQ(hits.size(), 2u);
  EXPECT_NEAR(hits[0].distance_m, front, 1e-15);
  EXPECT_NEAR(hits[1].distance_m, back, 1e-15);
  EXPECT_FALSE(exact.Cast(origin, {1, 0, 0}, 0.5));
  RayScene single;
  single.Add(1, box, X_BaseBox);
  single.Commit();
  const auto rounded = single.Cast(origin, {1, 0, 0}, 10.0);
  ASSERT_TRUE(rounded);
  EXPECT_NEAR(rounded->distance_m, front, 1e-6);
  EXPECT_NE(rounded->distance_m, front);
}

}  // namespace
}  // namespace picking::world
