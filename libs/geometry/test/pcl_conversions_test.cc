#include "libs/geometry/pcl_conversions.h"

#include <gtest/gtest.h>

#include <limits>
#include <stdexcept>

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

TEST(PclConversionsTest, XyzKeepsOrganisationAndFrame) {
  const PointCloud cloud = Sample();
  const pcl::PointCloud<pcl::PointXYZ> pcl_cloud = ToPclXyz(cloud);
  EXPECT_EQ(pcl_cloud.width, 2u);
  EXPECT_EQ(pcl_cloud.height, 2u);
  EXPECT_EQ(pcl_cloud.header.frame_id, "camera");
  EXPECT_FALSE(pcl_cloud.is_dense);
  EXPECT_EQ(pcl_cloud[2].x, -1.0f);
}

TEST(PclConversionsTest, InconsistentCloudsThrow) {
  PointCloud cloud = Sample();
  cloud.height = 3;
  EXPECT_THROW(ToPclXyz(cloud), std::invalid_argument);
}

}  // namespace
}  // namespace picking::geometry
