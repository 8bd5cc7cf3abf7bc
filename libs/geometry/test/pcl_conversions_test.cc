#include "libs/geometry/pcl_conversions.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include <pcl/io/pcd_io.h>

#include "libs/geometry/point_cloud_io.h"

namespace picking::geometry {
namespace {

PointCloud Sample() {
  PointCloud cloud;
  cloud.width = 2;
  cloud.height = 2;
  cloud.frame_id = "camera";
  const float nan = std::numeric_limits<float>::quiet_NaN();
  cloud.points = {{0.1f, 0.2f, 0.3f}, {nan, nan, nan}, {-1, 2, -3}, {4, 5, 6}};
  cloud.normals = {{0, 0, 1}, {0, 1, 0}, {1, 0, 0}, {0, 0, -1}};
  cloud.colors = {{{1, 2, 3}}, {{4, 5, 6}}, {{7, 8, 9}}, {{255, 0, 128}}};
  return cloud;
}

TEST(PclConversionsTest, XyzRoundTripKeepsOrganisationAndFrame) {
  const PointCloud cloud = Sample();
  const pcl::PointCloud<pcl::PointXYZ> pcl_cloud = ToPclXyz(cloud);
  EXPECT_EQ(pcl_cloud.width, 2u);
  EXPECT_EQ(pcl_cloud.height, 2u);
  EXPECT_EQ(pcl_cloud.header.frame_id, "camera");
  EXPECT_FALSE(pcl_cloud.is_dense);
  EXPECT_EQ(pcl_cloud[2].x, -1.0f);
  const PointCloud back = FromPcl(pcl_cloud);
  EXPECT_EQ(back.width, 2u);
  EXPECT_EQ(back.height, 2u);
  EXPECT_EQ(back.frame_id, "camera");
  EXPECT_EQ(back.points[3], cloud.points[3]);
  EXPECT_TRUE(std::isnan(back.points[1].x()));
  EXPECT_FALSE(back.has_normals());
  EXPECT_FALSE(back.has_colors());
}

TEST(PclConversionsTest, NormalsAndColoursRoundTrip) {
  const PointCloud cloud = Sample();
  const PointCloud with_normals = FromPcl(ToPclPointNormal(cloud));
  EXPECT_EQ(with_normals.normals, cloud.normals);
  const auto rgb = ToPclXyzRgb(cloud);
  EXPECT_EQ(rgb[3].r, 255);
  EXPECT_EQ(rgb[3].b, 128);
  const PointCloud with_colors = FromPcl(rgb);
  EXPECT_EQ(with_colors.colors, cloud.colors);
}

TEST(PclConversionsTest, MissingChannelsAndInconsistentCloudsThrow) {
  PointCloud cloud = Sample();
  cloud.normals.clear();
  EXPECT_THROW(ToPclPointNormal(cloud), std::invalid_argument);
  cloud.colors.clear();
  EXPECT_THROW(ToPclXyzRgb(cloud), std::invalid_argument);
  cloud = Sample();
  cloud.height = 3;
  EXPECT_THROW(ToPclXyz(cloud), std::invalid_argument);
}

TEST(PclConversionsTest, RealSceneMatchesPclsOwnReader) {
  const std::string scene =
      std::string(PICKING_TEST_DATA_DIR) + "/pointclouds/milk_cartoon_all_small_clorox.pcd";
  const auto converted = ToPclXyzRgb(ReadPointCloud(scene));
  pcl::PointCloud<pcl::PointXYZRGB> reference;
  ASSERT_EQ(pcl::io::loadPCDFile(scene, reference), 0);
  ASSERT_EQ(converted.size(), reference.size());
  EXPECT_EQ(converted.width, reference.width);
  for (std::size_t i = 0; i < reference.size(); i += 101) {
    if (std::isnan(reference[i].x)) {
      EXPECT_TRUE(std::isnan(converted[i].x));
      continue;
    }
    EXPECT_EQ(converted[i].x, reference[i].x);
    EXPECT_EQ(converted[i].z, reference[i].z);
    EXPECT_EQ(converted[i].r, reference[i].r);
    EXPECT_EQ(converted[i].g, reference[i].g);
    EXPECT_EQ(converted[i].b, reference[i].b);
  }
}

}  // namespace
}  // namespace picking::geometry
