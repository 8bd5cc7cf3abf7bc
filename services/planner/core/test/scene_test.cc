#include "services/planner/core/scene.h"

#include <gtest/gtest.h>

#include <octomap/OcTree.h>

#include "services/planner/core/voxel_contacts.h"

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

// A box beside a neighbour's voxels, on a floor of voxels: the neighbour's side touches it;
// drawing it away from the neighbour keeps only old contacts, lifting it along the
// neighbour's side makes new ones, and so does sliding it along the floor of voxels (a
// voxel says only that a surface lies somewhere in it). The snapshot carries the voxels.
TEST(VoxelContactsTest, TellsContactsAMotionKeepsFromNewOnes) {
  ScanScene scene(ScanSceneOptions{});
  std::vector<float> xyz;
  for (double x = -0.3; x <= 0.0; x += 0.004) {
    for (double y = -0.2; y <= 0.2; y += 0.004) {
      xyz.insert(xyz.end(), {float(x), float(y), 0.196f});  // a floor, under a second box
    }
  }
  for (double y = -0.2; y <= 0.2; y += 0.004) {
    for (double z = 0.0; z <= 0.06; z += 0.004) {
      xyz.insert(xyz.end(), {0.094f, float(y), float(z)});  // a neighbour's face
    }
  }
  scene.Insert(xyz.data(), xyz.size() / 3, {});
  const auto obstacles = scene.Snapshot();
  ASSERT_EQ(obstacles->voxel_centres_Base.size(), scene.num_voxels());
  const VoxelContacts contacts(obstacles->voxel_centres_Base, obstacles->voxel_m, 0.002);
  const Eigen::AlignedBox3d box_Item(Eigen::Vector3d(-0.09, -0.05, 0.0),
                                     Eigen::Vector3d(0.09, 0.05, 0.03));
  Eigen::Isometry3d X_BaseItem = Eigen::Isometry3d::Identity();
  const std::vector<int> touched = contacts.Touching(X_BaseItem, box_Item);
  ASSERT_FALSE(touched.empty());
  for (const int i : touched) EXPECT_GT(contacts.centre(i).x(), 0.09f);
  // Drawn 3 cm away from the neighbour: nothing new.
  X_BaseItem.translation() = Eigen::Vector3d(-0.03, 0.0, 0.002);
  EXPECT_EQ(contacts.NewContact(X_BaseItem, box_Item, touched), -1);
  // Lifted 4 cm along the neighbour's side: its higher voxels are new.
  X_BaseItem.translation() = Eigen::Vector3d(0.0, 0.0, 0.04);
  const int hit = contacts.NewContact(X_BaseItem, box_Item, touched);
  ASSERT_GE(hit, 0);
  EXPECT_GT(contacts.centre(hit).z(), 0.035f);
  // A box on the floor of voxels, slid along it 4 mm above the floor's points.
  Eigen::Isometry3d X_BaseOther = Eigen::Isometry3d::Identity();
  X_BaseOther.translation() = Eigen::Vector3d(-0.15, 0.0, 0.197);
  const std::vector<int> under = contacts.Touching(X_BaseOther, box_Item);
  ASSERT_FALSE(under.empty());
  X_BaseOther.translation() += Eigen::Vector3d(-0.04, 0.0, 0.004);
  EXPECT_GE(contacts.NewContact(X_BaseOther, box_Item, under), 0);
  // A voxel above the floor's clears it.
  X_BaseOther.translation().z() += 0.01;
  EXPECT_EQ(contacts.NewContact(X_BaseOther, box_Item, under), -1);
  EXPECT_THROW(VoxelContacts({}, 0.0, 0.0), std::invalid_argument);
  EXPECT_THROW(VoxelContacts({}, 0.01, -1.0), std::invalid_argument);
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
