// Free-space conflicts of a pose (ViewRangeGrid, MeasureAgreement) on a synthetic bin view:
// a box in front of a wall, seen from above its top face so that the top is almost edge-on
// and, as with a real structured-light scan, not measured at all.

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "libs/geometry/point_cloud.h"
#include "services/detector/core/model.h"
#include "services/detector/core/ppf_detector.h"

namespace picking::detector {
namespace {

// Sensor frame: x right, y up, z forward (the viewing direction). The box sits 0.9 m ahead,
// the wall 1.1 m; the sensor is 4.5 cm above the box's top face.
const Eigen::Vector3f kViewpoint(0.0f, 0.1f, 0.0f);
const Eigen::Vector3f kBoxCentre(0.0f, 0.0f, 0.9f);
const Eigen::Vector3f kBoxHalf(0.065f, 0.055f, 0.0575f);
constexpr float kWallZ = 1.1f;
constexpr float kSpacing = 0.001f;

// Slab test: does the segment from the viewpoint to p pass through the box before p?
bool BoxOccludes(const Eigen::Vector3f& p) {
  const Eigen::Vector3f d = p - kViewpoint;
  float t_near = 0.0f, t_far = 1.0f - 1e-4f;
  for (int a = 0; a < 3; ++a) {
    const float lo = kBoxCentre[a] - kBoxHalf[a], hi = kBoxCentre[a] + kBoxHalf[a];
    if (std::abs(d[a]) < 1e-9f) {
      if (kViewpoint[a] < lo || kViewpoint[a] > hi) return false;
      continue;
    }
    float t0 = (lo - kViewpoint[a]) / d[a], t1 = (hi - kViewpoint[a]) / d[a];
    if (t0 > t1) std::swap(t0, t1);
    t_near = std::max(t_near, t0);
    t_far = std::min(t_far, t1);
    if (t_near > t_far) return false;
  }
  return true;
}

// The measured scene: the box's front face and the unoccluded part of the wall; the top face
// (seen at ~87 degrees from its normal) has no points.
geometry::PointCloud MeasuredScene() {
  geometry::PointCloud scene;
  const float front_z = kBoxCentre.z() - kBoxHalf.z();
  for (float x = -kBoxHalf.x(); x <= kBoxHalf.x(); x += kSpacing) {
    for (float y = -kBoxHalf.y(); y <= kBoxHalf.y(); y += kSpacing) {
      scene.points.emplace_back(x, y, front_z);
    }
  }
  for (float x = -0.3f; x <= 0.3f; x += 2 * kSpacing) {
    for (float y = -0.2f; y <= 0.25f; y += 2 * kSpacing) {
      const Eigen::Vector3f p(x, y, kWallZ);
      if (!BoxOccludes(p)) scene.points.push_back(p);
    }
  }
  return scene;
}

// Surface samples of the box (model frame at its centre) with outward normals.
geometry::PointCloud BoxModelCloud() {
  geometry::PointCloud cloud;
  for (int axis = 0; axis < 3; ++axis) {
    const int a = (axis + 1) % 3, b = (axis + 2) % 3;
    for (float sign : {-1.0f, 1.0f}) {
      for (float s = -kBoxHalf[a]; s <= kBoxHalf[a]; s += kSpacing) {
        for (float t = -kBoxHalf[b]; t <= kBoxHalf[b]; t += kSpacing) {
          Eigen::Vector3f p, n = Eigen::Vector3f::Zero();
          p[axis] = sign * kBoxHalf[axis];
          p[a] = s;
          p[b] = t;
          n[axis] = sign;
          cloud.points.push_back(p);
          cloud.normals.push_back(n);
        }
      }
    }
  }
  return cloud;
}

Eigen::Isometry3d At(const Eigen::Vector3f& centre) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = centre.cast<double>();
  return X;
}

TEST(ViewRangeGridTest, MinRangeNearLooksAtNeighbouringCells) {
  // Two points one degree apart at ranges 1 and 2; cells of half a degree.
  const float deg = static_cast<float>(M_PI / 180.0);
  const std::vector<Eigen::Vector3f> points = {
      Eigen::Vector3f(0.0f, 0.0f, 1.0f),
      2.0f * Eigen::Vector3f(std::sin(deg), 0.0f, std::cos(deg))};
  const ViewRangeGrid grid(points, Eigen::Vector3f::Zero(), 0.5f * deg);
  const Eigen::Vector3f far_ray(std::sin(deg), 0.0f, std::cos(deg));
  EXPECT_NEAR(grid.MinRange(far_ray), 2.0f, 1e-5f);
  EXPECT_NEAR(grid.MinRangeNear(far_ray, 0), 2.0f, 1e-5f);
  EXPECT_NEAR(grid.MinRangeNear(far_ray, 2), 1.0f, 1e-5f);
  // Outside the grid: nothing was seen there.
  EXPECT_TRUE(std::isinf(grid.MinRangeNear(Eigen::Vector3f(1.0f, 0.0f, 0.1f), 1)));
}

TEST(FreeSpaceTest, UnmeasuredEdgeOnFaceIsNotAConflict) {
  const ObjectModel model(BoxModelCloud(), ObjectModelOptions{});
  PpfSceneOptions scene_options;
  scene_options.viewpoint = kViewpoint;
  const PpfScene scene = PreparePpfScene(MeasuredScene(), model, scene_options);
  ASSERT_FALSE(scene.view_ranges.empty());
  const float step = model.sampling_distance_m();
  const SceneAgreement truth =
      MeasureAgreement(model, scene, At(kBoxCentre), 0.5f * step, 0.5f, 2.0f * step);
  // The top face faces the sensor (it counts as visible) but was not measured: unsupported,
  // and its cells hold the wall behind the box's silhouette. It must not count as free space.
  EXPECT_GT(truth.visible_points, 0);
  EXPECT_LT(truth.support, 0.9);
  EXPECT_LT(truth.conflict_fraction, 0.02);

  // The same box 20 cm to the side floats in front of the wall: its front face (the side
  // face and the top are seen edge-on there) is in conflict.
  const SceneAgreement beside =
      MeasureAgreement(model, scene, At(kBoxCentre + Eigen::Vector3f(0.2f, 0.0f, 0.0f)),
                       0.5f * step, 0.5f, 2.0f * step);
  EXPECT_LT(beside.support, 0.1);
  EXPECT_GT(beside.conflict_fraction, 0.3);
}

}  // namespace
}  // namespace picking::detector
