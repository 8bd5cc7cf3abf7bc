#include "services/detector/core/model.h"

#include <gtest/gtest.h>

#include <unistd.h>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <string>

#include "services/detector/core/test/ppf_test_util.h"

namespace picking::detector {
namespace {

std::string TempPath(const std::string& name) {
  return ::testing::TempDir() + "/model_test_" + std::to_string(::getpid()) + "_" + name;
}

class ModelTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    milk_ = new geometry::PointCloud(testing::LoadPcd(testing::PointCloudPath("milk.pcd")));
  }
  static void TearDownTestSuite() { delete milk_; }
  static geometry::PointCloud* milk_;
};
geometry::PointCloud* ModelTest::milk_ = nullptr;

TEST_F(ModelTest, BuildsNormalsSamplingAndDiameter) {
  const ObjectModel model(*milk_, ObjectModelOptions{});
  // The carton's bounding box is about 0.15 x 0.25 x 0.18 m.
  EXPECT_GT(model.diameter_m(), 0.25f);
  EXPECT_LT(model.diameter_m(), 0.36f);
  EXPECT_FLOAT_EQ(model.sampling_distance_m(),
                  ObjectModelOptions{}.sampling_distance_rel * model.diameter_m());
  const geometry::PointCloud& sampled = model.table().sampled_model();
  EXPECT_GT(sampled.size(), 100u);
  EXPECT_LT(sampled.size(), model.fine_cloud().size());
  ASSERT_EQ(model.fine_cloud().normals.size(), model.fine_cloud().size());
  for (const auto& n : model.fine_cloud().normals) EXPECT_NEAR(n.norm(), 1.0f, 1e-4f);
  EXPECT_FALSE(model.table().entries().empty());
}

TEST_F(ModelTest, CacheRoundTrip) {
  const ObjectModel model(*milk_, ObjectModelOptions{});
  const std::string path = TempPath("roundtrip.ppfm");
  model.Save(path);
  const ObjectModel loaded = ObjectModel::Load(path);
  EXPECT_EQ(loaded.diameter_m(), model.diameter_m());
  EXPECT_EQ(loaded.sampling_distance_m(), model.sampling_distance_m());
  EXPECT_EQ(loaded.source_hash(), model.source_hash());
  EXPECT_EQ(loaded.fine_cloud().points, model.fine_cloud().points);
  EXPECT_EQ(loaded.icp_cloud().normals, model.icp_cloud().normals);
  EXPECT_EQ(loaded.table().offsets(), model.table().offsets());
  ASSERT_EQ(loaded.table().entries().size(), model.table().entries().size());
  for (std::size_t i = 0; i < model.table().entries().size(); i += 97) {
    EXPECT_EQ(loaded.table().entries()[i].model_reference,
              model.table().entries()[i].model_reference);
    EXPECT_EQ(loaded.table().entries()[i].alpha_m_rad, model.table().entries()[i].alpha_m_rad);
  }
  std::remove(path.c_str());
}

TEST_F(ModelTest, WrongVersionTruncatedAndMissingFilesAreClearErrors) {
  const ObjectModel model(*milk_, ObjectModelOptions{});
  const std::string path = TempPath("version.ppfm");
  model.Save(path);
  {
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(8);
    const std::uint32_t other = ObjectModel::kCacheVersion + 1;
    f.write(reinterpret_cast<const char*>(&other), sizeof(other));
  }
  try {
    ObjectModel::Load(path);
    FAIL() << "no exception";
  } catch (const ModelCacheError& e) {
    EXPECT_NE(std::string(e.what()).find("version"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
  }
  // LoadOrBuild rebuilds and rewrites a stale cache, then loads it.
  bool rebuilt = false;
  ObjectModel::LoadOrBuild(path, *milk_, ObjectModelOptions{}, &rebuilt);
  EXPECT_TRUE(rebuilt);
  ObjectModel::LoadOrBuild(path, *milk_, ObjectModelOptions{}, &rebuilt);
  EXPECT_FALSE(rebuilt);
  // Other options rebuild.
  ObjectModelOptions other;
  other.sampling_distance_rel = 0.03f;
  ObjectModel::LoadOrBuild(path, *milk_, other, &rebuilt);
  EXPECT_TRUE(rebuilt);

  // Truncated file.
  const std::string truncated = TempPath("truncated.ppfm");
  {
    std::ifstream in(path, std::ios::binary);
    std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    std::ofstream out(truncated, std::ios::binary);
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size() / 2));
  }
  EXPECT_THROW(ObjectModel::Load(truncated), ModelCacheError);
  EXPECT_THROW(ObjectModel::Load(TempPath("missing.ppfm")), ModelCacheError);
  std::remove(path.c_str());
  std::remove(truncated.c_str());
}

TEST_F(ModelTest, BadCloudsThrow) {
  EXPECT_THROW(ObjectModel(geometry::PointCloud{}, ObjectModelOptions{}), std::invalid_argument);
  geometry::PointCloud nan_cloud;
  nan_cloud.points.assign(50, Eigen::Vector3f::Constant(std::numeric_limits<float>::quiet_NaN()));
  EXPECT_THROW(ObjectModel(nan_cloud, ObjectModelOptions{}), std::invalid_argument);
  // The milk carton in millimetres is far above any pickable item's size.
  geometry::PointCloud millimetres = *milk_;
  for (auto& p : millimetres.points) p *= 1000.0f;
  try {
    ObjectModel(millimetres, ObjectModelOptions{});
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("max_diameter_m"), std::string::npos) << e.what();
  }
  ObjectModelOptions bad;
  bad.sampling_distance_rel = -1.0f;
  EXPECT_THROW(ObjectModel(*milk_, bad), std::invalid_argument);
  ObjectModelOptions input_normals;
  input_normals.use_input_normals = true;
  EXPECT_THROW(ObjectModel(*milk_, input_normals), std::invalid_argument);
  // Too fine a sampling gives more sampled points than the table accepts.
  ObjectModelOptions too_fine;
  too_fine.sampling_distance_rel = 0.002f;
  too_fine.fine_voxel_rel = 0.002f;
  EXPECT_THROW(ObjectModel(*milk_, too_fine), std::invalid_argument);
}

TEST_F(ModelTest, AlbedoChannelIsKeptAveragedAndCached) {
  // The carton with a printed half: albedo 0.8 for x < centre, 0.2 beyond.
  geometry::PointCloud painted = *milk_;
  float lo = std::numeric_limits<float>::max(), hi = -lo;
  for (const auto& p : painted.points) {
    if (!p.allFinite()) continue;
    lo = std::min(lo, p.x());
    hi = std::max(hi, p.x());
  }
  const float mid = 0.5f * (lo + hi);
  for (const auto& p : painted.points) painted.intensities.push_back(p.x() < mid ? 0.8f : 0.2f);
  ObjectModelOptions options;
  options.symmetry = ModelSymmetry::kBox;
  const ObjectModel model(painted, options);
  ASSERT_TRUE(model.has_albedo());
  ASSERT_EQ(model.fine_cloud().intensities.size(), model.fine_cloud().size());
  ASSERT_EQ(model.icp_cloud().intensities.size(), model.icp_cloud().size());
  EXPECT_GT(model.albedo_stddev(), 0.2f);
  EXPECT_EQ(model.symmetries().size(), 4u);
  // Away from the paint's boundary and the carton's edges the albedo is the painted one.
  int checked = 0, masked = 0;
  for (std::size_t i = 0; i < model.fine_cloud().size(); ++i) {
    const float a = model.fine_cloud().intensities[i];
    const float x = model.fine_cloud().points[i].x();
    if (!std::isfinite(a)) {
      ++masked;
      continue;
    }
    if (std::abs(x - mid) < 0.01f) continue;
    EXPECT_NEAR(a, x < mid ? 0.8f : 0.2f, 1e-4f);
    ++checked;
  }
  EXPECT_GT(checked, static_cast<int>(model.fine_cloud().size() / 3));
  // The edges' albedo is left out, but most of the surface is kept.
  EXPECT_GT(masked, 0);
  EXPECT_LT(masked, static_cast<int>(model.fine_cloud().size() / 2));
  // A different albedo is a different source.
  EXPECT_NE(model.source_hash(), ObjectModel(*milk_, options).source_hash());

  const std::string path = TempPath("albedo.ppfm");
  model.Save(path);
  const ObjectModel loaded = ObjectModel::Load(path);
  std::remove(path.c_str());
  ASSERT_EQ(loaded.fine_cloud().intensities.size(), model.fine_cloud().intensities.size());
  for (std::size_t i = 0; i < model.fine_cloud().size(); ++i) {
    const float a = model.fine_cloud().intensities[i], b = loaded.fine_cloud().intensities[i];
    ASSERT_TRUE((std::isnan(a) && std::isnan(b)) || a == b) << i;
  }
  EXPECT_EQ(loaded.albedo_stddev(), model.albedo_stddev());
  EXPECT_EQ(loaded.options().symmetry, ModelSymmetry::kBox);
  EXPECT_EQ(loaded.symmetries().size(), 4u);
  EXPECT_EQ(loaded.fine_tree().size(), loaded.fine_cloud().size());
}

TEST_F(ModelTest, AlbedoOutsideTheUnitRangeIsRejected) {
  geometry::PointCloud painted = *milk_;
  painted.intensities.assign(painted.size(), 0.5f);
  painted.intensities[7] = 1.5f;
  try {
    ObjectModel model(painted, ObjectModelOptions{});
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("intensities[7]"), std::string::npos) << e.what();
  }
  painted.intensities.pop_back();
  EXPECT_THROW(ObjectModel(painted, ObjectModelOptions{}), std::invalid_argument);
  ObjectModelOptions options;
  options.cylinder_symmetry_steps = 0;
  EXPECT_THROW(ObjectModel(*milk_, options), std::invalid_argument);
}

TEST(SymmetryRotationsTest, MapTheShapesOntoThemselves) {
  EXPECT_EQ(SymmetryRotations(ModelSymmetry::kNone, 36).size(), 1u);
  EXPECT_EQ(SymmetryRotations(ModelSymmetry::kSphere, 36).size(), 1u);
  const auto box = SymmetryRotations(ModelSymmetry::kBox, 36);
  ASSERT_EQ(box.size(), 4u);
  EXPECT_TRUE(box[0].isApprox(Eigen::Isometry3d::Identity()));
  // A box's corner goes to a corner: every coordinate keeps its magnitude.
  const Eigen::Vector3d corner(0.1, 0.05, 0.02);
  for (const auto& X : box) {
    EXPECT_TRUE((X * corner).cwiseAbs().isApprox(corner, 1e-12));
    EXPECT_NEAR(X.translation().norm(), 0.0, 1e-12);
  }
  const auto cylinder = SymmetryRotations(ModelSymmetry::kCylinderX, 12);
  ASSERT_EQ(cylinder.size(), 24u);
  // Points on a cylinder along x stay on it (same radius, same |x|).
  const Eigen::Vector3d rim(0.08, 0.03, 0.0);
  for (const auto& X : cylinder) {
    const Eigen::Vector3d q = X * rim;
    EXPECT_NEAR(std::abs(q.x()), 0.08, 1e-12);
    EXPECT_NEAR(q.tail<2>().norm(), 0.03, 1e-12);
  }
  const auto upright = SymmetryRotations(ModelSymmetry::kCylinderZ, 4);
  ASSERT_EQ(upright.size(), 8u);
  for (const auto& X : upright) EXPECT_NEAR(std::abs((X * rim).z()), 0.0, 1e-12);
  EXPECT_THROW(SymmetryRotations(ModelSymmetry::kBox, 0), std::invalid_argument);
  EXPECT_EQ(ModelSymmetryFromString("cylinder-z"), ModelSymmetry::kCylinderZ);
  EXPECT_EQ(ToString(ModelSymmetry::kBox), "box");
  EXPECT_THROW(ModelSymmetryFromString("cone"), std::invalid_argument);
}

}  // namespace
}  // namespace picking::detector
