#include "services/detector/core/preprocess.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "services/detector/core/test/bin_scene_test_util.h"

namespace picking::detector {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

geometry::PointCloud Unorganised(std::vector<Eigen::Vector3f> points) {
  geometry::PointCloud c;
  c.points = std::move(points);
  c.width = static_cast<std::uint32_t>(c.points.size());
  return c;
}

using testing::BinScene;

BinScene MakeBinScene() { return testing::MakeBinScene(/*floor_z_m=*/-0.098, /*with_nan=*/true); }

TEST(PreprocessTest, CropAndWallRemovalKeepOnlyTheItem) {
  const BinScene s = MakeBinScene();
  const geometry::PointCloud cropped = CropToBox(s.cloud, s.bin);
  EXPECT_EQ(cropped.size(), s.cloud.size() - 101);
  for (const auto& p : cropped.points) EXPECT_TRUE(s.bin.Contains(p.cast<double>(), 1e-6));
  WallRemovalOptions walls;
  walls.margin_m = 0.01;
  walls.faces = kAllFaces & ~kFaceMaxY;  // open front
  const geometry::PointCloud item = RemoveBoxWalls(cropped, s.bin, walls);
  EXPECT_EQ(item.size(), s.item_points);
}

TEST(PreprocessTest, OrganisedCloudStaysOrganised) {
  geometry::PointCloud c;
  c.width = 4;
  c.height = 2;
  for (int i = 0; i < 8; ++i) c.points.emplace_back(0.1f * i, 0.0f, 1.0f);
  c.intensities.assign(8, 0.5f);
  OrientedBox box;
  box.X_BaseBox.translation() = Eigen::Vector3d(0.15, 0.0, 1.0);
  box.size_m = Eigen::Vector3d(0.2, 0.1, 0.1);
  const geometry::PointCloud out = CropToBox(c, box);
  ASSERT_EQ(out.size(), 8u);
  EXPECT_EQ(out.height, 2u);
  int finite = 0;
  for (const auto& p : out.points) finite += p.allFinite();
  EXPECT_EQ(finite, 2);  // x = 0.1 and 0.2
  CropOptions drop;
  drop.keep_organized = false;
  const geometry::PointCloud dropped = CropToBox(c, box, drop);
  EXPECT_EQ(dropped.size(), 2u);
  EXPECT_EQ(dropped.intensities.size(), 2u);
}

TEST(PreprocessTest, ClearErrors) {
  const BinScene s = MakeBinScene();
  EXPECT_THROW(CropToBox(geometry::PointCloud{}, s.bin), std::invalid_argument);
  geometry::PointCloud nan_only = Unorganised({Eigen::Vector3f::Constant(kNaN)});
  try {
    CropToBox(nan_only, s.bin);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("NaN"), std::string::npos);
  }
  OrientedBox far = s.bin;
  far.X_BaseBox.translation() += Eigen::Vector3d(5, 0, 0);
  try {
    CropToBox(s.cloud, far);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("outside the cloud's bounds"), std::string::npos);
  }
  CropOptions small;
  small.limits.max_points = 10;
  EXPECT_THROW(CropToBox(s.cloud, s.bin, small), std::invalid_argument);
  OrientedBox flat = s.bin;
  flat.size_m.z() = 0.0;
  EXPECT_THROW(CropToBox(s.cloud, flat), std::invalid_argument);
  geometry::PointCloud bad_channel = s.cloud;
  bad_channel.intensities.assign(3, 0.0f);
  EXPECT_THROW(ValidateCloud(bad_channel), std::invalid_argument);
}

TEST(PreprocessTest, RansacRemovesTheDominantPlane) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> uniform(-0.2f, 0.2f);
  std::normal_distribution<float> noise(0.0f, 0.001f);
  const Eigen::Vector3f n = Eigen::Vector3f(0.1f, -0.2f, 1.0f).normalized();
  const Eigen::Vector3f e1 = n.unitOrthogonal(), e2 = n.cross(e1);
  std::vector<Eigen::Vector3f> points;
  for (int i = 0; i < 3000; ++i)
    points.push_back(0.5f * n + uniform(rng) * e1 + uniform(rng) * e2 + noise(rng) * n);
  for (int i = 0; i < 500; ++i)  // a blob above the plane
    points.push_back(0.6f * n + 0.1f * uniform(rng) * Eigen::Vector3f(1, 1, 1).normalized() +
                     0.1f * uniform(rng) * e1);
  const PlaneRemovalResult r = RemoveDominantPlane(Unorganised(points));
  ASSERT_TRUE(r.removed);
  const Eigen::Vector3d plane_n = r.plane.head<3>();
  EXPECT_GT(std::abs(plane_n.dot(n.cast<double>())), 0.999);
  EXPECT_NEAR(std::abs(r.plane[3]), 0.5, 0.003);
  EXPECT_GE(r.num_inliers, 2950u);
  EXPECT_LE(r.num_inliers, 3000u);
  EXPECT_NEAR(static_cast<double>(r.cloud.size()), 500.0, 10.0);
}

// A bin whose board is tilted by 5 degrees and rises 2 cm above the box's bottom, with a
// 4 cm high box and a 1.5 cm thin flat item on it: the floor goes, both items stay, and the
// flat item's top is not taken for the floor although it is the larger plane.
TEST(PreprocessTest, BoxFloorFollowsATiltedBoardBelowFlatItems) {
  OrientedBox bin;
  bin.X_BaseBox =
      Eigen::Translation3d(1.0, 0.2, 0.8) * Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ());
  bin.size_m = Eigen::Vector3d(0.4, 0.3, 0.25);
  const double tilt = 5.0 * M_PI / 180.0;
  const auto floor_z = [&](double x) { return -0.125 + 0.02 + std::tan(tilt) * x; };
  std::mt19937 rng(3);
  std::normal_distribution<float> noise(0.0f, 0.0003f);
  geometry::PointCloud cloud;
  std::size_t num_items = 0;
  const auto add = [&](const Eigen::Vector3d& p_Box, const Eigen::Vector3d& n_Box, bool item) {
    cloud.points.push_back((bin.X_BaseBox * p_Box).cast<float>() +
                           Eigen::Vector3f::Constant(noise(rng)));
    cloud.normals.push_back((bin.X_BaseBox.linear() * n_Box).cast<float>());
    num_items += item ? 1 : 0;
  };
  const Eigen::Vector3d up(-std::sin(tilt), 0.0, std::cos(tilt));
  for (double x = -0.19; x <= 0.19; x += 0.003) {
    for (double y = -0.14; y <= 0.14; y += 0.003) {
      const bool under_flat = x < 0.1 && y < 0.1;  // The flat item hides most of the board.
      const bool under_box = x > 0.12 && y > 0.05;
      if (!under_flat && !under_box) add({x, y, floor_z(x)}, up, false);
      if (under_flat) add({x, y, floor_z(0.1) + 0.015}, Eigen::Vector3d::UnitZ(), true);
      if (under_box && x < 0.17) add({x, y, floor_z(0.17) + 0.04}, Eigen::Vector3d::UnitZ(), true);
    }
  }
  cloud.width = static_cast<std::uint32_t>(cloud.size());
  const PlaneRemovalResult r = RemoveBoxFloor(cloud, bin);
  ASSERT_TRUE(r.removed);
  EXPECT_EQ(r.cloud.size(), num_items);
  const Eigen::Vector3d n_Base = bin.X_BaseBox.linear() * up;
  EXPECT_GT(r.plane.head<3>().dot(n_Base), std::cos(1.0 * M_PI / 180.0));
  // Without a floor candidate nothing is removed; bad options are refused.
  geometry::PointCloud high = cloud;
  for (auto& p : high.points)
    p += (bin.X_BaseBox.linear() * Eigen::Vector3d(0, 0, 0.1)).cast<float>();
  EXPECT_FALSE(RemoveBoxFloor(high, bin).removed);
  FloorRemovalOptions bad;
  bad.max_iterations = 0;
  EXPECT_THROW(RemoveBoxFloor(cloud, bin, bad), std::invalid_argument);
}

// A shelf bin as the scanner sees it after the floor band was cut away: the board rises by
// 5 degrees from the box's bottom at the front toward the back and is visible only where it
// is more than 1 cm high; a 3.3 cm flat item covers the low front part (its top is the larger
// upward plane) and a 1.2 cm thin item lies on the visible board. Normals carry about a
// degree of noise. Both items stay whole and only board points go.
TEST(PreprocessTest, BoxFloorKeepsFlatItemsOverAHiddenFrontBoard) {
  OrientedBox bin;
  bin.X_BaseBox =
      Eigen::Translation3d(0.9, -0.3, 1.1) * Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitZ());
  bin.size_m = Eigen::Vector3d(0.44, 0.27, 0.23);
  const double tilt = 5.0 * M_PI / 180.0;
  const double bottom = -0.115;
  const auto floor_z = [&](double x) { return bottom + std::tan(tilt) * (x + 0.21); };
  std::mt19937 rng(11);
  std::normal_distribution<double> noise(0.0, 0.0003);
  std::normal_distribution<double> tilt_noise(0.0, 0.015);
  geometry::PointCloud cloud;
  std::size_t num_items = 0;
  const auto add = [&](const Eigen::Vector3d& p_Box, const Eigen::Vector3d& n_Box, bool item) {
    const Eigen::Vector3d n =
        (n_Box + Eigen::Vector3d(tilt_noise(rng), tilt_noise(rng), 0.0)).normalized();
    cloud.points.push_back(
        (bin.X_BaseBox * (p_Box + Eigen::Vector3d(0.0, 0.0, noise(rng)))).cast<float>());
    cloud.normals.push_back((bin.X_BaseBox.linear() * n).cast<float>());
    num_items += item ? 1 : 0;
  };
  const Eigen::Vector3d up(-std::sin(tilt), 0.0, std::cos(tilt));
  for (double x = -0.2; x <= 0.2; x += 0.002) {
    for (double y = -0.125; y <= 0.125; y += 0.002) {
      const bool flat = x < -0.05 && std::abs(y) < 0.1;
      const bool thin = x > 0.09 && x < 0.15 && y > 0.0 && y < 0.08;
      if (flat) {
        add({x, y, bottom + 0.033}, Eigen::Vector3d::UnitZ(), true);
      } else if (thin) {
        add({x, y, floor_z(0.15) + 0.012}, Eigen::Vector3d::UnitZ(), true);
      } else if (floor_z(x) > bottom + 0.01) {
        add({x, y, floor_z(x)}, up, false);
      }
    }
  }
  // The flat item's side toward the back, from where it meets the board.
  for (double y = -0.1; y <= 0.1; y += 0.002) {
    for (double z = floor_z(-0.05) + 0.006; z <= bottom + 0.032; z += 0.002) {
      add({-0.05, y, z}, Eigen::Vector3d::UnitX(), true);
    }
  }
  cloud.width = static_cast<std::uint32_t>(cloud.size());
  const PlaneRemovalResult r = RemoveBoxFloor(cloud, bin);
  ASSERT_TRUE(r.removed);
  EXPECT_EQ(r.cloud.size(), num_items);
  EXPECT_EQ(r.num_inliers, cloud.size() - num_items);
  const Eigen::Vector3d n_Base = bin.X_BaseBox.linear() * up;
  EXPECT_GT(r.plane.head<3>().dot(n_Base), std::cos(1.0 * M_PI / 180.0));
  // Organised input stays organised, removed points become NaN.
  FloorRemovalOptions organised;
  organised.keep_organized = true;
  geometry::PointCloud grid = cloud;
  grid.width = static_cast<std::uint32_t>(cloud.size());
  grid.height = 1;
  const PlaneRemovalResult o = RemoveBoxFloor(grid, bin, organised);
  std::size_t finite = 0;
  for (const auto& p : o.cloud.points) finite += p.allFinite() ? 1 : 0;
  EXPECT_EQ(finite, num_items);
  FloorRemovalOptions bad;
  bad.max_planes = 0;
  EXPECT_THROW(RemoveBoxFloor(cloud, bin, bad), std::invalid_argument);
  bad = FloorRemovalOptions{};
  bad.normal_threshold_rad = 0.0;
  EXPECT_THROW(RemoveBoxFloor(cloud, bin, bad), std::invalid_argument);
}

// A level mailer, 1 cm thick, covers the low back of a board tilted by 5 degrees and rests on
// it where the board is highest under it. Its top plane crosses the board's plane a few
// millimetres above where the board is seen: it is still an item's top, not a second floor.
TEST(PreprocessTest, BoxFloorKeepsALevelFlatItemOnATiltedBoard) {
  OrientedBox bin;
  bin.X_BaseBox = Eigen::Translation3d(1.0, 0.3, 0.85) * Eigen::Isometry3d::Identity();
  bin.size_m = Eigen::Vector3d(0.44, 0.27, 0.27);
  const double tilt = 5.0 * M_PI / 180.0;
  const double bottom = -0.135;
  const auto floor_z = [&](double x) { return bottom + 0.01 + std::tan(tilt) * x; };
  const double item_end = 0.05;  // The item covers x < item_end.
  const double item_top = floor_z(item_end) + 0.01;
  std::mt19937 rng(17);
  std::normal_distribution<double> noise(0.0, 0.0003);
  geometry::PointCloud cloud;
  std::size_t num_items = 0;
  const Eigen::Vector3d up(-std::sin(tilt), 0.0, std::cos(tilt));
  for (double x = -0.21; x <= 0.21; x += 0.002) {
    for (double y = -0.125; y <= 0.125; y += 0.002) {
      const bool item = x < item_end;
      const Eigen::Vector3d p(x, y, (item ? item_top : floor_z(x)) + noise(rng));
      cloud.points.push_back((bin.X_BaseBox * p).cast<float>());
      cloud.normals.push_back((item ? Eigen::Vector3d::UnitZ() : up).cast<float>());
      num_items += item ? 1 : 0;
    }
  }
  cloud.width = static_cast<std::uint32_t>(cloud.size());
  const PlaneRemovalResult r = RemoveBoxFloor(cloud, bin);
  ASSERT_TRUE(r.removed);
  EXPECT_EQ(r.cloud.size(), num_items);
  EXPECT_GT(r.plane.head<3>().dot(up), std::cos(1.0 * M_PI / 180.0));
}

TEST(PreprocessTest, VoxelDownsampleAveragesPerVoxel) {
  geometry::PointCloud c = Unorganised({{0.001f, 0.001f, 0.001f},
                                        {0.003f, 0.003f, 0.003f},
                                        {0.011f, 0.001f, 0.001f},
                                        {kNaN, 0.0f, 0.0f}});
  c.intensities = {0.2f, 0.4f, 1.0f, 0.0f};
  const geometry::PointCloud out = VoxelDownsample(c, 0.01);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_TRUE(out.points[0].isApprox(Eigen::Vector3f(0.002f, 0.002f, 0.002f)));
  EXPECT_FLOAT_EQ(out.intensities[0], 0.3f);
  EXPECT_FLOAT_EQ(out.intensities[1], 1.0f);
  EXPECT_THROW(VoxelDownsample(c, 0.0), std::invalid_argument);

  // A NaN intensity (not measurable there) is left out of its voxel's mean; a voxel with
  // no finite one stays NaN.
  c.intensities = {kNaN, 0.4f, kNaN, 0.0f};
  const geometry::PointCloud partly = VoxelDownsample(c, 0.01);
  ASSERT_EQ(partly.size(), 2u);
  EXPECT_FLOAT_EQ(partly.intensities[0], 0.4f);
  EXPECT_TRUE(std::isnan(partly.intensities[1]));
}

TEST(PreprocessTest, NormalsOfASphereFaceTheViewpointOrOutward) {
  std::vector<Eigen::Vector3f> points;
  for (int i = 0; i < 2000; ++i) {
    const double z = 1.0 - (2.0 * i + 1.0) / 2000.0, r = std::sqrt(1 - z * z);
    const double phi = 2.399963 * i;
    points.emplace_back(0.1 * r * std::cos(phi), 0.1 * r * std::sin(phi), 0.1 * z);
  }
  NormalOptions outward;
  outward.orient_outward_from_centroid = true;
  const geometry::PointCloud out = EstimateNormals(Unorganised(points), outward);
  for (std::size_t i = 0; i < out.size(); ++i)
    EXPECT_GT(out.normals[i].dot(out.points[i].normalized()), 0.99f);
  NormalOptions view;
  view.p_BaseViewpoint = Eigen::Vector3d(0, 0, 2);
  const geometry::PointCloud towards = EstimateNormals(Unorganised(points), view);
  for (std::size_t i = 0; i < towards.size(); ++i)
    EXPECT_GE(towards.normals[i].dot(Eigen::Vector3f(0, 0, 2) - towards.points[i]), 0.0f);
}

TEST(PreprocessTest, EuclideanClustersBySizeAndGap) {
  std::vector<Eigen::Vector3f> points;
  for (int i = 0; i < 200; ++i) points.emplace_back(0.002f * (i % 20), 0.002f * (i / 20), 0.0f);
  for (int i = 0; i < 100; ++i)
    points.emplace_back(0.5f + 0.002f * (i % 10), 0.002f * (i / 10), 0.0f);
  for (int i = 0; i < 5; ++i) points.emplace_back(-0.5f, 0.002f * i, 0.0f);
  points.push_back(Eigen::Vector3f::Constant(kNaN));
  ClusterOptions options;
  options.tolerance_m = 0.005;
  options.min_size = 10;
  const auto clusters = EuclideanClusters(Unorganised(points), options);
  ASSERT_EQ(clusters.size(), 2u);
  EXPECT_EQ(clusters[0].size(), 200u);
  EXPECT_EQ(clusters[1].size(), 100u);
  EXPECT_EQ(clusters[1].front(), 200);
  options.max_size = 150;
  EXPECT_EQ(EuclideanClusters(Unorganised(points), options).size(), 1u);
  options.min_size = 200;
  EXPECT_THROW(EuclideanClusters(Unorganised(points), options), std::invalid_argument);
}

// Clusters grown over voxel representatives equal the exact ones when the gaps between
// clusters are much larger than a voxel; sizes count the original points.
TEST(PreprocessTest, SubsampledEuclideanClustersMatchTheExactOnes) {
  std::vector<Eigen::Vector3f> points;
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> jitter(-0.0002f, 0.0002f);
  for (int i = 0; i < 3600; ++i)  // a dense 6 cm patch, 1 mm spacing
    points.emplace_back(0.001f * (i % 60) + jitter(rng), 0.001f * (i / 60) + jitter(rng), 0.0f);
  for (int i = 0; i < 900; ++i)  // 3 cm away, a 3 cm patch
    points.emplace_back(0.09f + 0.001f * (i % 30), 0.001f * (i / 30), jitter(rng));
  for (int i = 0; i < 6; ++i) points.emplace_back(-0.1f, 0.001f * i, 0.0f);  // too small
  points.push_back(Eigen::Vector3f::Constant(kNaN));
  ClusterOptions exact;
  exact.tolerance_m = 0.01;
  exact.min_size = 20;
  ClusterOptions voxels = exact;
  voxels.subsample_voxel_m = 0.003;
  const auto a = EuclideanClusters(Unorganised(points), exact);
  const auto b = EuclideanClusters(Unorganised(points), voxels);
  ASSERT_EQ(a.size(), 2u);
  EXPECT_EQ(a, b);
  EXPECT_EQ(b[0].size(), 3600u);
  EXPECT_EQ(b[1].size(), 900u);
  // The representatives: members of their cluster, one per voxel of the subsampling.
  std::vector<std::vector<int>> reps;
  EXPECT_EQ(EuclideanClusters(Unorganised(points), voxels, &reps), b);
  ASSERT_EQ(reps.size(), b.size());
  for (std::size_t c = 0; c < b.size(); ++c) {
    std::set<std::tuple<int, int, int>> cells;
    for (int i : reps[c]) {
      EXPECT_TRUE(std::binary_search(b[c].begin(), b[c].end(), i));
      const Eigen::Vector3f cell = (points[i] / 0.003f).array().floor();
      EXPECT_TRUE(cells.emplace(int(cell.x()), int(cell.y()), int(cell.z())).second)
          << "two representatives in one voxel";
    }
    EXPECT_LT(reps[c].size(), b[c].size() / 4);
    EXPECT_GT(reps[c].size(), 0u);
  }
  // Without subsampling every member stands for itself.
  EXPECT_EQ(EuclideanClusters(Unorganised(points), exact, &reps), a);
  EXPECT_EQ(reps, a);
  voxels.max_size = 1000;  // in points, not voxels
  const auto small = EuclideanClusters(Unorganised(points), voxels, &reps);
  ASSERT_EQ(reps.size(), 1u);
  EXPECT_TRUE(std::binary_search(small[0].begin(), small[0].end(), reps[0].front()));
  ASSERT_EQ(small.size(), 1u);
  EXPECT_EQ(small[0].size(), 900u);
  voxels.subsample_voxel_m = 0.01;  // not below the tolerance
  EXPECT_THROW(EuclideanClusters(Unorganised(points), voxels), std::invalid_argument);
}

}  // namespace
}  // namespace picking::detector
