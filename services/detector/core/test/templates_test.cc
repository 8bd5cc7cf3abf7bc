#include "services/detector/core/templates.h"

#include <gtest/gtest.h>

#include <chrono>

#include <cmath>
#include <limits>
#include <random>

#include "libs/geometry/point_cloud_io.h"
#include "services/detector/core/kdtree.h"
#include "services/detector/core/preprocess.h"
#include "services/detector/core/verify.h"

namespace picking::detector {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

world::TriangleMesh BoxMesh(const Eigen::Vector3f& size) {
  world::TriangleMesh mesh;
  const Eigen::Vector3f h = 0.5f * size;
  for (int i = 0; i < 8; ++i)
    mesh.vertices.emplace_back((i & 1) ? h.x() : -h.x(), (i & 2) ? h.y() : -h.y(),
                               (i & 4) ? h.z() : -h.z());
  // Counter-clockwise seen from outside.
  mesh.triangles = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                    {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
  return mesh;
}

// A random rotation from a seeded generator (uniform quaternion).
Eigen::Matrix3d RandomRotation(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  Eigen::Quaterniond q(n(rng), n(rng), n(rng), n(rng));
  return q.normalized().toRotationMatrix();
}

// An organised scene seen by `camera` at X_BaseSensor: the floor z = 0 of the base frame and
// the object `model` (dense points with normals) at X_BaseItem, with seeded depth noise.
struct Scene {
  geometry::PointCloud cloud;
  Eigen::Isometry3d X_BaseSensor;
  PinholeCamera camera{320, 240, 300.0, 300.0, 159.5, 119.5};
};

Scene RenderScene(const geometry::PointCloud& model, double spacing_m,
                  const Eigen::Isometry3d& X_BaseItem, std::uint32_t seed) {
  Scene s;
  // Sensor 0.7 m above the floor, looking down and slightly tilted.
  s.X_BaseSensor = Eigen::Translation3d(0.05, -0.1, 0.7) *
                   Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()) *
                   Eigen::AngleAxisd(0.15, Eigen::Vector3d::UnitX());
  const Eigen::Isometry3d X_SensorItem = s.X_BaseSensor.inverse() * X_BaseItem;
  const RangeImage object = RenderRangeImage(model, X_SensorItem, s.camera, spacing_m);
  std::mt19937 rng(seed);
  std::normal_distribution<float> noise(0.0f, 0.0005f);
  s.cloud.width = s.camera.width();
  s.cloud.height = s.camera.height();
  const Eigen::Vector3d c = s.X_BaseSensor.translation();
  for (int v = 0; v < s.camera.height(); ++v) {
    for (int u = 0; u < s.camera.width(); ++u) {
      const Eigen::Vector3d d_Sensor((u - s.camera.cx()) / s.camera.fx(),
                                     (v - s.camera.cy()) / s.camera.fy(), 1.0);
      const Eigen::Vector3d d = s.X_BaseSensor.linear() * d_Sensor;
      double z = std::numeric_limits<double>::infinity();
      if (d.z() < 0.0) z = -c.z() / d.z();  // floor, in units of the ray's z_Sensor = 1
      const float zo = object.at(u, v);
      if (std::isfinite(zo) && zo < z) z = zo;
      if (!std::isfinite(z)) {
        s.cloud.points.push_back(Eigen::Vector3f::Constant(kNaN));
        continue;
      }
      z += noise(rng);
      s.cloud.points.push_back((s.X_BaseSensor * (d_Sensor * z)).cast<float>());
    }
  }
  return s;
}

// Mean distance from each model point at the estimate to the nearest model point at the
// truth (ADD-S: symmetric objects have several correct poses).
double AddS(const geometry::PointCloud& model, const Eigen::Isometry3d& X_true,
            const Eigen::Isometry3d& X_est) {
  std::vector<Eigen::Vector3f> truth;
  for (const auto& p : model.points) truth.push_back((X_true * p.cast<double>()).cast<float>());
  KdTree tree(truth);
  double sum = 0.0;
  for (const auto& p : model.points) {
    float d_sq = 0.0f;
    tree.Nearest((X_est * p.cast<double>()).cast<float>(), &d_sq);
    sum += std::sqrt(d_sq);
  }
  return sum / model.size();
}

// A random orientation of `model` placed in view of the sensor, its lowest point 5 mm above
// the floor (z = 0).
Eigen::Isometry3d RandomPoseAboveFloor(const geometry::PointCloud& model, std::mt19937& rng) {
  Eigen::Isometry3d X_BaseItem = Eigen::Isometry3d::Identity();
  X_BaseItem.linear() = RandomRotation(rng);
  std::uniform_real_distribution<double> xy(-0.06, 0.06);
  double min_z = std::numeric_limits<double>::infinity();
  for (const auto& p : model.points)
    min_z = std::min(min_z, (X_BaseItem.linear() * p.cast<double>()).z());
  X_BaseItem.translation() = Eigen::Vector3d(0.05 + xy(rng), -0.2 + xy(rng), 0.005 - min_z);
  return X_BaseItem;
}

struct Recovery {
  double add_s_m;
  double translation_error_m;
  double verify_score;
};

Recovery DetectInScene(const geometry::PointCloud& model, double render_spacing_m,
                       std::uint32_t seed, RangeTemplateSet* templates_out = nullptr,
                       int num_views = 1024) {
  TemplateOptions options;
  options.num_views = num_views;
  const RangeTemplateSet templates(model, options);
  std::mt19937 rng(seed);
  const Eigen::Isometry3d X_BaseItem = RandomPoseAboveFloor(model, rng);
  const Scene scene = RenderScene(model, render_spacing_m, X_BaseItem, seed);

  PlaneRemovalOptions plane;
  plane.distance_threshold_m = 0.004;
  const PlaneRemovalResult without_floor = RemoveDominantPlane(scene.cloud, plane);
  EXPECT_TRUE(without_floor.removed);
  ClusterOptions cluster_options;
  cluster_options.tolerance_m = 0.01;
  cluster_options.min_size = 100;
  const auto clusters = EuclideanClusters(without_floor.cloud, cluster_options);
  EXPECT_GE(clusters.size(), 1u);
  const auto matches =
      MatchTemplates(templates, without_floor.cloud, clusters, scene.X_BaseSensor, scene.camera);
  if (matches.empty()) {
    ADD_FAILURE() << "no template match";
    return {1.0, 1.0, 0.0};
  }
  const Eigen::Isometry3d& X_est = matches.front().X_BaseItem;
  const VerificationScene verification(scene.cloud, scene.X_BaseSensor, scene.camera);
  return {AddS(templates.model(), X_BaseItem, X_est),
          (X_est.translation() - X_BaseItem.translation()).norm(),
          Verify(verification, templates.model(), X_est).score};
}

TEST(FibonacciSphereTest, UnitAndUniform) {
  const auto d = FibonacciSphere(1024);
  ASSERT_EQ(d.size(), 1024u);
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  double worst = 0.0;  // largest angle from a random direction to its nearest view
  for (const auto& v : d) {
    EXPECT_NEAR(v.norm(), 1.0, 1e-12);
    sum += v;
  }
  EXPECT_LT(sum.norm() / 1024.0, 1e-3);
  std::mt19937 rng(3);
  std::normal_distribution<double> n(0.0, 1.0);
  for (int k = 0; k < 500; ++k) {
    const Eigen::Vector3d q = Eigen::Vector3d(n(rng), n(rng), n(rng)).normalized();
    double best = -1.0;
    for (const auto& v : d) best = std::max(best, v.dot(q));
    worst = std::max(worst, std::acos(std::min(1.0, best)));
  }
  EXPECT_LT(worst, 5.0 * M_PI / 180.0);
  EXPECT_THROW(FibonacciSphere(0), std::invalid_argument);
}

TEST(RangeTemplateSetTest, BuildsTemplatesWithClosestPoints) {
  const auto model = SampleMeshSurface(BoxMesh({0.1f, 0.06f, 0.03f}), 0.002);
  TemplateOptions options;
  options.num_views = 64;
  const RangeTemplateSet set(model, options);
  ASSERT_EQ(set.templates().size(), 64u);
  EXPECT_NEAR(set.diameter_m(), std::sqrt(0.01 + 0.0036 + 0.0009), 2e-3);
  for (const auto& t : set.templates()) {
    ASSERT_FALSE(t.p_CameraPoints.empty());
    EXPECT_LE(t.p_CameraPoints.size(), 300u);
    // The closest point is no farther than any template point and lies on the model.
    for (const auto& p : t.p_CameraPoints) EXPECT_GE(p.norm(), t.p_CameraClosest.norm() - 1e-6f);
    const Eigen::Vector3d p_Item = t.X_CameraItem.inverse() * t.p_CameraClosest.cast<double>();
    EXPECT_LT(((p_Item.cwiseAbs() - Eigen::Vector3d(0.05, 0.03, 0.015)).cwiseMax(0.0)).norm(),
              3e-3);
    EXPECT_NEAR(t.X_CameraItem.translation().norm(), options.distance_m, 1e-9);
  }
  geometry::PointCloud no_normals = model;
  no_normals.normals.clear();
  EXPECT_THROW(RangeTemplateSet(no_normals, options), std::invalid_argument);
}

TEST(RangeTemplateMatchTest, RecoversBoxPose) {
  const auto model = SampleMeshSurface(BoxMesh({0.1f, 0.06f, 0.03f}), 0.001, 5);
  const double diameter = std::sqrt(0.01 + 0.0036 + 0.0009);
  for (std::uint32_t seed : {11u, 12u}) {
    const Recovery r = DetectInScene(model, 0.001, seed);
    EXPECT_LT(r.add_s_m, 0.1 * diameter) << "seed " << seed;
    EXPECT_LT(r.translation_error_m, 0.1 * diameter) << "seed " << seed;
    EXPECT_GT(r.verify_score, 0.8) << "seed " << seed;
  }
}

TEST(RangeTemplateMatchTest, RecoversScannedEraserPose) {
  // The scanned model's positions only (VoxelDownsample drops its non-finite points).
  geometry::PointCloud model = geometry::ReadPointCloud(std::string(PICKING_TEST_DATA_DIR) +
                                                        "/models/expo_dry_erase_board_eraser.ply");
  model.colors.clear();
  model = VoxelDownsample(model, 0.0015);
  NormalOptions normals;
  normals.orient_outward_from_centroid = true;
  model = EstimateNormals(model, normals);
  Eigen::AlignedBox3d bounds;
  for (const auto& p : model.points) bounds.extend(p.cast<double>());
  const double diameter = bounds.diagonal().norm();
  const Recovery r = DetectInScene(model, 0.0015, 21);
  EXPECT_LT(r.add_s_m, 0.1 * diameter);
  EXPECT_LT(r.translation_error_m, 0.1 * diameter);
  EXPECT_GT(r.verify_score, 0.7);
}

TEST(RangeTemplateMatchTest, NoMatchOnFlatClutter) {
  // A scene cluster that is a flat slab cannot be explained by the box templates well.
  const auto model = SampleMeshSurface(BoxMesh({0.1f, 0.06f, 0.03f}), 0.002);
  TemplateOptions options;
  options.num_views = 128;
  const RangeTemplateSet templates(model, options);
  const auto slab = SampleMeshSurface(BoxMesh({0.25f, 0.2f, 0.005f}), 0.001, 9);
  Eigen::Isometry3d X_BaseSlab = Eigen::Isometry3d::Identity();
  X_BaseSlab.translation() = Eigen::Vector3d(0.05, -0.2, 0.05);
  const Scene scene = RenderScene(slab, 0.001, X_BaseSlab, 4);
  const auto without_floor = RemoveDominantPlane(scene.cloud, {});
  ClusterOptions cluster_options;
  cluster_options.min_size = 100;
  auto clusters = EuclideanClusters(without_floor.cloud, cluster_options);
  ASSERT_FALSE(clusters.empty());
  // The slab is too large for the box and skipped by default; matched anyway, no template
  // explains it. The report says which, and how far the best fit missed.
  TemplateSearchReport skipped;
  EXPECT_TRUE(MatchTemplates(templates, without_floor.cloud, clusters, scene.X_BaseSensor,
                             scene.camera, {}, &skipped)
                  .empty());
  EXPECT_EQ(skipped.clusters, static_cast<int>(clusters.size()));
  EXPECT_EQ(skipped.implausible_clusters, skipped.clusters);
  EXPECT_EQ(skipped.searched_clusters, 0);
  EXPECT_FALSE(std::isfinite(skipped.best_rejected_cost_m));
  TemplateMatchOptions any_size;
  any_size.max_cluster_extent_rel = 100.0;
  TemplateSearchReport searched;
  EXPECT_TRUE(MatchTemplates(templates, without_floor.cloud, clusters, scene.X_BaseSensor,
                             scene.camera, any_size, &searched)
                  .empty());
  EXPECT_GE(searched.searched_clusters, 1);
  EXPECT_GE(searched.best_rejected_cost_m, any_size.max_cost_m);
  EXPECT_TRUE(std::isfinite(searched.best_rejected_cost_m));
  clusters[0].push_back(-1);
  EXPECT_THROW(
      MatchTemplates(templates, without_floor.cloud, clusters, scene.X_BaseSensor, scene.camera),
      std::invalid_argument);
}

// Clusters of an implausible size for the item and a spent time budget give no match;
// the same cluster with a plausible size and time left does.
TEST(RangeTemplateMatchTest, SkipsImplausibleClustersAndStopsAtTheDeadline) {
  // The scene of RecoversBoxPose, seed 11.
  const auto model = SampleMeshSurface(BoxMesh({0.1f, 0.06f, 0.03f}), 0.001, 5);
  const RangeTemplateSet templates(model, TemplateOptions{});
  std::mt19937 rng(11);
  const Eigen::Isometry3d X_BaseItem = RandomPoseAboveFloor(model, rng);
  const Scene scene = RenderScene(model, 0.001, X_BaseItem, 11);
  PlaneRemovalOptions plane;
  plane.distance_threshold_m = 0.004;
  const PlaneRemovalResult without_floor = RemoveDominantPlane(scene.cloud, plane);
  ClusterOptions cluster_options;
  cluster_options.min_size = 100;
  const auto clusters = EuclideanClusters(without_floor.cloud, cluster_options);
  ASSERT_FALSE(clusters.empty());
  const auto match = [&](const TemplateMatchOptions& o) {
    return MatchTemplates(templates, without_floor.cloud, clusters, scene.X_BaseSensor,
                          scene.camera, o);
  };
  const TemplateMatchOptions defaults;
  const auto found = match(defaults);
  ASSERT_FALSE(found.empty());
  EXPECT_LT(AddS(templates.model(), X_BaseItem, found.front().X_BaseItem), 0.012);
  TemplateMatchOptions too_small = defaults;  // The visible box is larger than this.
  too_small.min_cluster_extent_rel = 0.0;
  too_small.max_cluster_extent_rel = 0.1;
  EXPECT_TRUE(match(too_small).empty());
  TemplateMatchOptions too_large = defaults;  // ... and smaller than this.
  too_large.min_cluster_extent_rel = 2.0;
  too_large.max_cluster_extent_rel = 3.0;
  EXPECT_TRUE(match(too_large).empty());
  TemplateMatchOptions late = defaults;
  const auto start = std::chrono::steady_clock::time_point(std::chrono::hours(1000));
  late.clock = BudgetClock::Frozen(start);  // the search's time stands still, past its deadline
  late.deadline = start - std::chrono::seconds(1);
  EXPECT_TRUE(match(late).empty());
  late.deadline = start + std::chrono::seconds(1);  // ... or before it: the whole search
  EXPECT_EQ(match(late).size(), found.size());
  TemplateMatchOptions bad = defaults;
  bad.min_cluster_extent_rel = 2.0;  // above max
  EXPECT_THROW(match(bad), std::invalid_argument);
}

}  // namespace
}  // namespace picking::detector
