#include "services/detector/core/ppf_cloud.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>

namespace picking::detector {
namespace {

// The half of a sphere's surface facing `viewpoint`, with noise, normals toward the viewpoint.
void AddVisibleSphere(const Eigen::Vector3d& centre, double radius,
                      const Eigen::Vector3d& viewpoint, std::mt19937* rng,
                      geometry::PointCloud* cloud) {
  std::normal_distribution<double> noise(0.0, 0.0003);
  std::normal_distribution<double> normal_noise(0.0, 0.03);
  for (double theta = 0.02; theta < M_PI; theta += 0.04) {
    for (double phi = 0.0; phi < 2.0 * M_PI; phi += 0.04 / std::sin(theta)) {
      const Eigen::Vector3d n(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi),
                              std::cos(theta));
      const Eigen::Vector3d p = centre + (radius + noise(*rng)) * n;
      if (n.dot(viewpoint - p) <= 0.0) continue;
      const Eigen::Vector3d n_noisy =
          (n + Eigen::Vector3d(normal_noise(*rng), normal_noise(*rng), normal_noise(*rng)))
              .normalized();
      cloud->points.push_back(p.cast<float>());
      cloud->normals.push_back(n_noisy.cast<float>());
    }
  }
}

// Two balls of the searched radius, a larger ball and a table: both balls are found, the
// better-supported one first, with their centres to a fraction of a millimetre; what the larger
// ball and the table offer (a ring of the larger ball) comes after them, with far less support.
TEST(VoxelAverageTest, AveragesFiniteIntensitiesOnly) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  geometry::PointCloud cloud;
  cloud.points = {{0.001f, 0.001f, 0.001f}, {0.002f, 0.002f, 0.002f}, {0.011f, 0.001f, 0.001f}};
  cloud.intensities = {nan, 0.6f, nan};
  cloud.width = 3;
  const geometry::PointCloud out = VoxelAverage(cloud, 0.01f);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_FLOAT_EQ(out.intensities[0], 0.6f);
  EXPECT_TRUE(std::isnan(out.intensities[1]));
}

TEST(FindSpheresTest, FindsBallsOfTheRadiusAmongOtherSurfaces) {
  const double radius = 0.037;
  const Eigen::Vector3d viewpoint(0.0, 0.0, 0.6);
  std::mt19937 rng(5);
  geometry::PointCloud cloud;
  const Eigen::Vector3d near_ball(0.05, -0.02, radius);
  const Eigen::Vector3d far_ball(-0.15, 0.1, radius);
  AddVisibleSphere(near_ball, radius, viewpoint, &rng, &cloud);
  const std::size_t near_points = cloud.size();
  AddVisibleSphere(far_ball, radius, viewpoint + Eigen::Vector3d(0.3, 0.0, 0.0), &rng, &cloud);
  AddVisibleSphere(Eigen::Vector3d(0.15, 0.15, 0.06), 0.06, viewpoint, &rng, &cloud);
  for (double x = -0.3; x <= 0.3; x += 0.004) {
    for (double y = -0.3; y <= 0.3; y += 0.004) {
      if ((Eigen::Vector2d(x, y) - near_ball.head<2>()).norm() < radius ||
          (Eigen::Vector2d(x, y) - far_ball.head<2>()).norm() < radius) {
        continue;
      }
      cloud.points.emplace_back(x, y, 0.0);
      cloud.normals.emplace_back(0.0f, 0.0f, 1.0f);
    }
  }
  cloud.width = static_cast<std::uint32_t>(cloud.size());
  const std::vector<SphereFit> spheres = FindSpheres(cloud, radius);
  ASSERT_GE(spheres.size(), 2u);
  for (std::size_t i = 2; i < spheres.size(); ++i) {
    EXPECT_LT(spheres[i].inliers, spheres[1].inliers / 3) << i;
  }
  const bool near_first = (spheres[0].p_Centre - near_ball).norm() < 0.0005;
  EXPECT_LT((spheres[near_first ? 0 : 1].p_Centre - near_ball).norm(), 0.0005);
  EXPECT_LT((spheres[near_first ? 1 : 0].p_Centre - far_ball).norm(), 0.0005);
  EXPECT_GE(spheres[0].inliers, spheres[1].inliers);
  EXPECT_GT(spheres[near_first ? 0 : 1].inliers, near_points / 2);
  // Deterministic.
  const std::vector<SphereFit> again = FindSpheres(cloud, radius);
  ASSERT_EQ(again.size(), spheres.size());
  EXPECT_EQ(again[0].p_Centre, spheres[0].p_Centre);
}

TEST(FindSpheresTest, RejectsBadInput) {
  geometry::PointCloud cloud;
  cloud.points.emplace_back(0.0f, 0.0f, 0.0f);
  cloud.width = 1;
  EXPECT_THROW(FindSpheres(cloud, 0.03), std::invalid_argument);  // no normals
  cloud.normals.emplace_back(0.0f, 0.0f, 1.0f);
  EXPECT_THROW(FindSpheres(cloud, 0.0), std::invalid_argument);
  SphereSearchOptions bad;
  bad.max_spheres = 0;
  EXPECT_THROW(FindSpheres(cloud, 0.03, bad), std::invalid_argument);
  EXPECT_TRUE(FindSpheres(cloud, 0.03).empty());  // too few points for a sphere
}

}  // namespace
}  // namespace picking::detector
