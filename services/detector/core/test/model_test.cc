#include "services/detector/core/model.h"

#include <gtest/gtest.h>

#include <unistd.h>
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

}  // namespace
}  // namespace picking::detector
