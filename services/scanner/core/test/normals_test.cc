#include "services/scanner/core/normals.h"

#include "libs/camera/pinhole_camera.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>

namespace picking::scanner {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// An organised cloud of what a camera sees: a sphere in front of a plane.
geometry::PointCloud RenderCloud(const Eigen::Vector3d& plane_normal, double plane_offset_m,
                                 const Eigen::Vector3d& sphere_center, double sphere_radius_m) {
  const camera::PinholeCamera camera(320, 240, 400.0, 400.0, 159.5, 119.5);
  geometry::PointCloud cloud;
  cloud.width = 320;
  cloud.height = 240;
  cloud.points.resize(320 * 240);
  for (int v = 0; v < 240; ++v) {
    for (int u = 0; u < 320; ++u) {
      const Eigen::Vector3d ray = camera.RayDirection(Eigen::Vector2d(u, v));
      double t = plane_offset_m / plane_normal.dot(ray);
      const Eigen::Vector3d oc = -sphere_center;
      const double b = oc.dot(ray);
      const double disc = b * b - (oc.squaredNorm() - sphere_radius_m * sphere_radius_m);
      if (disc >= 0 && -b - std::sqrt(disc) > 0) t = std::min(t, -b - std::sqrt(disc));
      cloud.points[v * 320 + u] = (t * ray).cast<float>();
    }
  }
  return cloud;
}

TEST(NormalsTest, PlaneAndSphereNormalsFaceTheCamera) {
  const Eigen::Vector3d plane_normal = Eigen::Vector3d(0.3, -0.2, 1.0).normalized();
  const Eigen::Vector3d center(0.05, 0.0, 0.8);
  const double radius = 0.12;
  geometry::PointCloud cloud = RenderCloud(plane_normal, 1.0, center, radius);
  cloud.points[100 * 320 + 10].setConstant(kNaN);  // A hole.
  NormalOptions options;
  options.step = 1;
  const NormalResult result = EstimateNormals(&cloud, options);
  ASSERT_EQ(cloud.normals.size(), cloud.points.size());
  EXPECT_GT(result.num_normals, cloud.points.size() * 95 / 100);
  EXPECT_TRUE(std::isnan(cloud.normals[100 * 320 + 10].x()));

  int plane_checked = 0;
  int sphere_checked = 0;
  for (int v = 2; v < 238; ++v) {
    for (int u = 2; u < 318; ++u) {
      const Eigen::Vector3d p = cloud.points[v * 320 + u].cast<double>();
      const Eigen::Vector3f& n = cloud.normals[v * 320 + u];
      if (std::isnan(p.z()) || std::isnan(n.x())) continue;
      EXPECT_NEAR(n.norm(), 1.0f, 1e-5f);
      EXPECT_LT(n.cast<double>().dot(p), 0.0);  // Towards the camera.
      const double on_sphere = std::abs((p - center).norm() - radius);
      if (std::abs(plane_normal.dot(p) - 1.0) < 1e-6) {
        EXPECT_GT(n.cast<double>().dot(-plane_normal), 0.9999) << u << ", " << v;
        ++plane_checked;
      } else if (on_sphere < 1e-6) {
        // Away from the silhouette, the normal is radial.
        const Eigen::Vector3d radial = (p - center).normalized();
        if (radial.dot(-p.normalized()) > 0.3) {
          EXPECT_GT(n.cast<double>().dot(radial), 0.999) << u << ", " << v;
          ++sphere_checked;
        }
      }
    }
  }
  EXPECT_GT(plane_checked, 20000);
  EXPECT_GT(sphere_checked, 3000);
}

TEST(NormalsTest, DepthJumpsAreNotBridged) {
  // Two fronto-parallel planes at 1.0 m and 1.3 m, split at column 160.
  geometry::PointCloud cloud;
  cloud.width = 320;
  cloud.height = 10;
  for (int v = 0; v < 10; ++v) {
    for (int u = 0; u < 320; ++u) {
      const float z = u < 160 ? 1.0f : 1.3f;
      cloud.points.emplace_back((u - 160) * 0.002f * z, (v - 5) * 0.002f * z, z);
    }
  }
  EstimateNormals(&cloud, NormalOptions{});
  for (int v = 0; v < 10; ++v) {
    for (int u = 0; u < 320; ++u) {
      const Eigen::Vector3f& n = cloud.normals[v * 320 + u];
      ASSERT_FALSE(std::isnan(n.z())) << u << ", " << v;
      EXPECT_NEAR(n.z(), -1.0f, 1e-5f) << u << ", " << v;
    }
  }
}

TEST(NormalsTest, RejectsUnorganisedCloudsAndBadOptions) {
  geometry::PointCloud cloud;
  cloud.points.resize(10, Eigen::Vector3f(0, 0, 1));
  cloud.width = 10;
  cloud.height = 1;
  EXPECT_THROW(EstimateNormals(&cloud), std::invalid_argument);
  cloud.width = 5;
  cloud.height = 3;
  EXPECT_THROW(EstimateNormals(&cloud), std::invalid_argument);
  cloud.height = 2;
  EXPECT_NO_THROW(EstimateNormals(&cloud));
  NormalOptions bad;
  bad.step = 0;
  EXPECT_THROW(EstimateNormals(&cloud, bad), std::invalid_argument);
  bad = NormalOptions{};
  bad.max_depth_jump_m = 0;
  EXPECT_THROW(EstimateNormals(&cloud, bad), std::invalid_argument);
  EXPECT_THROW(EstimateNormals(nullptr), std::invalid_argument);
}

}  // namespace
}  // namespace picking::scanner
