#include "services/scanner/core/merge.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

namespace picking::scanner {
namespace {

const float kNan = std::numeric_limits<float>::quiet_NaN();

geometry::PointCloud Organised(int width, int height, float z, const std::string& frame) {
  geometry::PointCloud cloud;
  cloud.width = width;
  cloud.height = height;
  cloud.frame_id = frame;
  for (int v = 0; v < height; ++v) {
    for (int u = 0; u < width; ++u) {
      cloud.points.emplace_back(0.01f * u, 0.01f * v, z);
      cloud.normals.emplace_back(0.f, 0.f, -1.f);
      cloud.intensities.push_back(0.5f);
    }
  }
  cloud.points[1] = Eigen::Vector3f(kNan, kNan, kNan);
  return cloud;
}

TEST(MergeTest, TransformMovesPointsAndNormalsAndKeepsNan) {
  geometry::PointCloud cloud = Organised(3, 2, 1.0f, "camera");
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitX()).toRotationMatrix();
  X.translation() = Eigen::Vector3d(1, 2, 3);
  TransformCloud(X, "base", &cloud);
  EXPECT_EQ(cloud.frame_id, "base");
  EXPECT_TRUE(std::isnan(cloud.points[1].x()));
  // (0, 0, 1) -> R * (0, 0, 1) + t = (0, -1, 0) + (1, 2, 3).
  EXPECT_NEAR(cloud.points[0].x(), 1.0, 1e-6);
  EXPECT_NEAR(cloud.points[0].y(), 1.0, 1e-6);
  EXPECT_NEAR(cloud.points[0].z(), 3.0, 1e-6);
  EXPECT_NEAR(cloud.normals[0].y(), 1.0, 1e-6);
  Eigen::Isometry3d bad = Eigen::Isometry3d::Identity();
  bad.linear() *= 2.0;
  EXPECT_THROW(TransformCloud(bad, "base", &cloud), std::invalid_argument);
}

TEST(MergeTest, StackingOrganisedViewsKeepsThemOrganised) {
  const auto merged = MergeClouds({Organised(4, 3, 1.0f, "base"), Organised(4, 2, 2.0f, "base")});
  EXPECT_EQ(merged.cloud.width, 4u);
  EXPECT_EQ(merged.cloud.height, 5u);
  EXPECT_EQ(merged.cloud.size(), 20u);
  EXPECT_EQ(merged.num_points, 18u);
  EXPECT_TRUE(merged.cloud.has_normals());
  EXPECT_TRUE(merged.cloud.has_intensities());
  EXPECT_FLOAT_EQ(merged.cloud.points[12].z(), 2.0f);
}

TEST(MergeTest, StackingDifferentWidthsDropsNanAndUnorganises) {
  geometry::PointCloud b = Organised(2, 2, 2.0f, "base");
  b.intensities.clear();
  const auto merged = MergeClouds({Organised(4, 3, 1.0f, "base"), b});
  EXPECT_EQ(merged.cloud.height, 1u);
  EXPECT_EQ(merged.cloud.size(), 14u);  // 12 + 4 minus one NaN each.
  EXPECT_EQ(merged.num_points, 14u);
  EXPECT_FALSE(merged.cloud.has_intensities());  // Only one view had them.
  EXPECT_TRUE(merged.cloud.has_normals());
}

TEST(MergeTest, VoxelMergeAveragesPointsOfAllViews) {
  // Two noisy samplings of the same 10 cm square: the voxel means lie between them.
  std::mt19937 rng(7);
  std::normal_distribution<float> noise(0.f, 0.0002f);
  std::vector<geometry::PointCloud> views(2);
  for (int k = 0; k < 2; ++k) {
    views[k].frame_id = "base";
    for (int i = 0; i < 100; ++i) {
      for (int j = 0; j < 100; ++j) {
        views[k].points.emplace_back(0.001f * i + 0.0005f, 0.001f * j + 0.0005f,
                                     0.505f + (k == 0 ? -0.001f : 0.001f) + noise(rng));
        views[k].normals.emplace_back(0.f, 0.f, 1.f);
      }
    }
    views[k].width = static_cast<std::uint32_t>(views[k].points.size());
  }
  MergeOptions options;
  options.voxel_m = 0.01;
  const auto merged = MergeClouds(views, options);
  EXPECT_EQ(merged.num_points, 100u);  // 10 x 10 voxels of 1 cm.
  for (std::size_t i = 0; i < merged.cloud.size(); ++i) {
    EXPECT_NEAR(merged.cloud.points[i].z(), 0.505, 1e-4);
    EXPECT_NEAR(merged.cloud.normals[i].z(), 1.0, 1e-6);
  }
  options.min_points_per_voxel = 201;
  EXPECT_EQ(MergeClouds(views, options).num_points, 0u);
}

TEST(MergeTest, RefusesBadInput) {
  EXPECT_THROW(MergeClouds({}), std::invalid_argument);
  EXPECT_THROW(MergeClouds({Organised(2, 2, 1, "base"), Organised(2, 2, 1, "camera")}),
               std::invalid_argument);
  MergeOptions options;
  options.voxel_m = -1;
  EXPECT_THROW(MergeClouds({Organised(2, 2, 1, "base")}, options), std::invalid_argument);
  geometry::PointCloud broken = Organised(2, 2, 1, "base");
  broken.normals.pop_back();
  EXPECT_THROW(MergeClouds({broken}), std::invalid_argument);
}

TEST(MergeTest, CropKeepsOrganisationOrRemovesPoints) {
  geometry::PointCloud cloud = Organised(5, 2, 1.0f, "base");
  const std::size_t kept =
      CropToBox(Eigen::Vector3d(0.015, -1, 0), Eigen::Vector3d(1, 1, 2), &cloud);
  EXPECT_EQ(kept, 6u);  // u = 2, 3, 4 of both rows.
  EXPECT_EQ(cloud.size(), 10u);
  EXPECT_TRUE(std::isnan(cloud.points[0].x()));
  EXPECT_TRUE(std::isnan(cloud.normals[0].x()));
  EXPECT_FALSE(std::isnan(cloud.points[2].x()));

  geometry::PointCloud flat =
      MergeClouds({Organised(5, 2, 1.0f, "base"), Organised(3, 2, 1.0f, "base")}).cloud;
  EXPECT_EQ(CropToBox(Eigen::Vector3d(0.015, -1, 0), Eigen::Vector3d(1, 1, 2), &flat), 8u);
  EXPECT_EQ(flat.size(), 8u);
  EXPECT_EQ(flat.width, 8u);
  EXPECT_THROW(CropToBox(Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0, 1, 1), &flat),
               std::invalid_argument);
}

}  // namespace
}  // namespace picking::scanner
