#include "libs/camera/pinhole_camera.h"

#include <gtest/gtest.h>

#include <random>
#include <stdexcept>

namespace picking::camera {
namespace {

// A 1280 x 1024 camera with an 8 mm lens like the scanner's, with noticeable distortion.
PinholeCamera DistortedCamera() {
  Distortion d;
  d.k1 = -0.12;
  d.k2 = 0.08;
  d.p1 = 0.0012;
  d.p2 = -0.0008;
  d.k3 = -0.01;
  return PinholeCamera(1280, 1024, 1520.0, 1518.0, 645.3, 508.7, d);
}

TEST(PinholeCameraTest, ProjectOfUnprojectIsIdentityOverTheImage) {
  const PinholeCamera camera = DistortedCamera();
  double max_error_px = 0.0;
  for (int v = 0; v < camera.height(); v += 7) {
    for (int u = 0; u < camera.width(); u += 7) {
      const Eigen::Vector2d uv(u, v);
      for (double depth_m : {0.3, 1.7}) {
        const Eigen::Vector3d p_CameraPoint = camera.Unproject(uv) * depth_m;
        const auto back = camera.Project(p_CameraPoint);
        ASSERT_TRUE(back.has_value());
        max_error_px = std::max(max_error_px, (*back - uv).norm());
      }
    }
  }
  EXPECT_LT(max_error_px, 1e-8);
}

TEST(PinholeCameraTest, UnprojectOfProjectIsTheSameRay) {
  const PinholeCamera camera = DistortedCamera();
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> lateral(-0.35, 0.35);
  std::uniform_real_distribution<double> depth(0.4, 2.0);
  for (int i = 0; i < 1000; ++i) {
    const Eigen::Vector3d p(lateral(rng), lateral(rng) * 0.8, depth(rng));
    const auto uv = camera.Project(p);
    ASSERT_TRUE(uv.has_value());
    if (!camera.Contains(*uv)) continue;
    const Eigen::Vector3d ray = camera.RayDirection(*uv);
    EXPECT_NEAR(ray.dot(p.normalized()), 1.0, 1e-12);
  }
}

TEST(PinholeCameraTest, RayTableMatchesUnproject) {
  const PinholeCamera camera(64, 48, 50.0, 52.0, 31.0, 24.5,
                             Distortion{-0.2, 0.05, 0.001, 0.002, 0.0});
  const RayTable table = camera.ComputeRayTable();
  ASSERT_EQ(table.width, 64);
  ASSERT_EQ(table.height, 48);
  ASSERT_EQ(table.xy.size(), 64u * 48u);
  for (int v = 0; v < 48; ++v) {
    for (int u = 0; u < 64; ++u) {
      const Eigen::Vector3d ray = camera.Unproject(Eigen::Vector2d(u, v));
      EXPECT_NEAR(table.xy[v * 64 + u].x(), ray.x(), 1e-6);
      EXPECT_NEAR(table.xy[v * 64 + u].y(), ray.y(), 1e-6);
    }
  }
}

TEST(PinholeCameraTest, WithoutDistortionProjectIsTheIntrinsicMatrix) {
  const PinholeCamera camera(912, 1140, 1200.0, 1210.0, 456.0, 1100.0);
  const Eigen::Vector3d p(0.1, -0.2, 1.5);
  const Eigen::Vector3d h = camera.K() * p;
  const auto uv = camera.Project(p);
  ASSERT_TRUE(uv.has_value());
  EXPECT_NEAR(uv->x(), h.x() / h.z(), 1e-12);
  EXPECT_NEAR(uv->y(), h.y() / h.z(), 1e-12);
  EXPECT_FALSE(camera.Project(Eigen::Vector3d(0.1, 0.1, -1.0)).has_value());
  EXPECT_FALSE(camera.Project(Eigen::Vector3d(0.1, 0.1, 0.0)).has_value());
  EXPECT_TRUE(camera.Contains(Eigen::Vector2d(-0.5, 1139.5)));
  EXPECT_FALSE(camera.Contains(Eigen::Vector2d(912.0, 0.0)));
}

TEST(PinholeCameraTest, RejectsInvalidParameters) {
  EXPECT_THROW(PinholeCamera(0, 10, 1, 1, 0, 0), std::invalid_argument);
  EXPECT_THROW(PinholeCamera(10, -1, 1, 1, 0, 0), std::invalid_argument);
  EXPECT_THROW(PinholeCamera(10, 10, 0, 1, 0, 0), std::invalid_argument);
  EXPECT_THROW(PinholeCamera(10, 10, 1, -2, 0, 0), std::invalid_argument);
  EXPECT_THROW(PinholeCamera(10, 10, 1, 1, std::nan(""), 0), std::invalid_argument);
  EXPECT_THROW(PinholeCamera(10, 10, 1, 1, 0, 0, Distortion{std::nan(""), 0, 0, 0, 0}),
               std::invalid_argument);
  // Strong barrel distortion folds over inside this wide image.
  try {
    PinholeCamera(1280, 1024, 400.0, 400.0, 640.0, 512.0, Distortion{-0.9, 0.0, 0.0, 0.0, 0.0});
    FAIL() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("not invertible"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace picking::camera
