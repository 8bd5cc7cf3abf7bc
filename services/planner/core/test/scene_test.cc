#include "services/planner/core/scene.h"

#include <gtest/gtest.h>

#include <octomap/OcTree.h>

namespace picking::planner {
namespace {

std::vector<float> BoxSurface(const Eigen::Vector3d& centre, const Eigen::Vector3d& half,
                              double step) {
  std::vector<float> xyz;
  for (double x = -half.x(); x <= half.x() + 1e-9; x += step) {
    for (double y = -half.y(); y <= half.y() + 1e-9; y += step) {
      for (double z = -half.z(); z <= half.z() + 1e-9; z += step) {
        const bool surface = std::abs(std::abs(x) - half.x()) < step * 0.5 ||
                             std::abs(std::abs(y) - half.y()) < step * 0.5 ||
                             std::abs(std::abs(z) - half.z()) < step * 0.5;
        if (surface) {
          xyz.insert(xyz.end(),
                     {float(centre.x() + x), float(centre.y() + y), float(centre.z() + z)});
        }
      }
    }
  }
  return xyz;
}

ConvexHull BoxHull(const Eigen::Vector3d& centre, const Eigen::Vector3d& half) {
  std::vector<Eigen::Vector3f> corners;
  for (int i = 0; i < 8; ++i) {
    corners.push_back(
        (centre + Eigen::Vector3d((i & 1) ? half.x() : -half.x(), (i & 2) ? half.y() : -half.y(),
                                  (i & 4) ? half.z() : -half.z()))
            .cast<float>());
  }
  return ComputeConvexHull(corners);
}

TEST(ConvexHullTest, BoxHullHasSixPlanesAndContainsItsInside) {
  const ConvexHull hull = BoxHull(Eigen::Vector3d(1, 2, 3), Eigen::Vector3d(0.1, 0.2, 0.3));
  EXPECT_EQ(hull.planes.size(), 6u);
  EXPECT_TRUE(hull.Contains(Eigen::Vector3d(1.05, 2.1, 3.2), 0.0));
  EXPECT_FALSE(hull.Contains(Eigen::Vector3d(1.15, 2.0, 3.0), 0.0));
  EXPECT_TRUE(hull.Contains(Eigen::Vector3d(1.15, 2.0, 3.0), 0.06));
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(-1, -2, -3);
  EXPECT_TRUE(hull.Transformed(X).Contains(Eigen::Vector3d::Zero(), 0.0));
  EXPECT_THROW(ComputeConvexHull({Eigen::Vector3f::Zero()}), std::invalid_argument);
}

TEST(ScanSceneTest, VoxelsOfPointsMatchOctomapKeys) {
  ScanScene scene(ScanSceneOptions{});
  const std::vector<float> xyz = {0.005f, 0.005f, 0.005f, -0.005f, 0.005f, 0.005f,
                                  0.006f, 0.004f, 0.001f, NAN,     0.f,    0.f};
  const SceneUpdateStats stats = scene.Insert(xyz.data(), 4, {});
  EXPECT_EQ(stats.points_invalid, 1u);
  EXPECT_EQ(stats.voxels_total, 2u);
  const auto obstacles = scene.Snapshot();
  ASSERT_TRUE(obstacles->octree);
  const octomap::OcTreeNode* node = obstacles->octree->search(0.005, 0.005, 0.005);
  ASSERT_NE(node, nullptr);
  EXPECT_TRUE(obstacles->octree->isNodeOccupied(node));
  EXPECT_NE(obstacles->octree->search(-0.005, 0.005, 0.005), nullptr);
  EXPECT_EQ(obstacles->octree->search(0.015, 0.005, 0.005), nullptr);
  EXPECT_LT(obstacles->grid.Clearance(Eigen::Vector3f(0.005f, 0.005f, 0.005f)), 0.f);
}

TEST(ScanSceneTest, PointsOutsideTheRegionAreLeftOut) {
  ScanSceneOptions options;
  options.region_Base = Eigen::AlignedBox3d(Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones());
  ScanScene scene(options);
  const std::vector<float> xyz = {0.5f, 0.5f, 0.5f, 2.f, 0.5f, 0.5f};
  const SceneUpdateStats stats = scene.Insert(xyz.data(), 2, {});
  EXPECT_EQ(stats.points_outside, 1u);
  EXPECT_EQ(scene.num_voxels(), 1u);
}

// MoveIt keeps the voxels of an item cut out of the scan for seconds after the cut
// (moveit/moveit2#3614), so a planner sees the target as an obstacle it must not touch.
// Here the voxels inside a cut-out are free in the very update that brings the cut-out.
TEST(ScanSceneTest, Moveit2_3614_CutOutVoxelsAreFreeInTheSameUpdate) {
  const Eigen::Vector3d item_centre(1.0, 0.2, 0.3), item_half(0.05, 0.04, 0.06);
  const Eigen::Vector3d other_centre(1.0, 0.0, 0.3);
  std::vector<float> xyz = BoxSurface(item_centre, item_half, 0.004);
  const std::vector<float> other = BoxSurface(other_centre, item_half, 0.004);
  xyz.insert(xyz.end(), other.begin(), other.end());

  ScanScene scene(ScanSceneOptions{});
  scene.Insert(xyz.data(), xyz.size() / 3, {});
  const auto before = scene.Snapshot();
  EXPECT_LT(before->grid.Clearance(item_centre.cast<float>() + Eigen::Vector3f(0.05f, 0, 0)), 0.f);

  // A second view of the same scene, now with the target's hull cut out.
  SceneCutOut cut{"target", BoxHull(item_centre, item_half), 0.02};
  const SceneUpdateStats stats = scene.Insert(xyz.data(), xyz.size() / 3, {cut});
  EXPECT_GT(stats.points_cut, 0u);
  EXPECT_GT(stats.voxels_cleared, 0u);
  const auto after = scene.Snapshot();
  for (const Eigen::Vector3f& v : scene.VoxelCentres()) {
    ASSERT_FALSE(cut.hull_Base.Contains(v.cast<double>(), cut.margin_m))
        << "voxel " << v.transpose() << " inside the cut-out is still occupied";
  }
  // The octree agrees: the item's surface is no longer occupied, its neighbour still is.
  const octomap::OcTreeNode* node = after->octree->search(item_centre.x() + item_half.x() - 0.002,
                                                          item_centre.y(), item_centre.z());
  EXPECT_TRUE(node == nullptr || !after->octree->isNodeOccupied(node));
  const octomap::OcTreeNode* kept = after->octree->search(other_centre.x() + item_half.x() - 0.002,
                                                          other_centre.y(), other_centre.z());
  ASSERT_NE(kept, nullptr);
  EXPECT_TRUE(after->octree->isNodeOccupied(kept));
  EXPECT_GT(after->grid.Clearance(item_centre.cast<float>()), 0.f);
}

TEST(ScanSceneTest, RejectsBadOptions) {
  ScanSceneOptions options;
  options.resolution_m = 0.0;
  EXPECT_THROW(ScanScene{options}, std::invalid_argument);
  options.resolution_m = 0.01;
  options.max_extent_m = 1e9;
  EXPECT_THROW(ScanScene{options}, std::invalid_argument);
}

}  // namespace
}  // namespace picking::planner
