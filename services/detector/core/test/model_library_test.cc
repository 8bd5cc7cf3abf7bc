#include "services/detector/core/model_library.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include "libs/errors/errors.h"

namespace picking::detector {
namespace {

const std::string kTestData = PICKING_TEST_DATA_DIR;
const std::string kDataDir = PICKING_DATA_DIR;

std::string Expect(const std::string& text) {
  try {
    ModelManifest::Parse(text, "manifest.json", "/m", "/data");
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  ADD_FAILURE() << "no exception for " << text;
  return "";
}

TEST(ModelManifestTest, ParsesSourcesAndMergesTheDetectionConfig) {
  const ModelManifest m = ModelManifest::Parse(R"({
    "version": 1,
    "default": {"preferred": "ppf", "fallbacks": ["range_templates"],
                "thresholds": {"min_score": 0.4}},
    "models": {
      "milk": {"source": "scan:pointclouds/milk.pcd", "preferred": "sift",
               "thresholds": {"min_score": 0.7}},
      "abs": {"source": "scan:/abs/x.ply", "frame": "item", "symmetry": "cylinder-z"},
      "tee": {"source": "shape:box", "fold": [2, 2]},
      "tape": {"source": "shape:cylinder", "axis": "short"},
      "ball": {"source": "shape:sphere"}}})",
                                               "m.json", "/manifests", "/data");
  ASSERT_EQ(m.models().size(), 5u);
  const ModelSpec* milk = m.find("milk");
  ASSERT_NE(milk, nullptr);
  EXPECT_EQ(milk->kind, ModelSourceKind::kScan);
  EXPECT_EQ(milk->scan_path, "/data/pointclouds/milk.pcd");
  EXPECT_EQ(milk->frame, ScanFrame::kFile);
  EXPECT_EQ(milk->symmetry, "none");
  EXPECT_EQ(milk->SourceKindName(), "scan");
  const ModelSpec* abs = m.find("abs");
  ASSERT_NE(abs, nullptr);
  EXPECT_EQ(abs->scan_path, "/abs/x.ply");
  EXPECT_EQ(abs->frame, ScanFrame::kItem);
  EXPECT_EQ(abs->symmetry, "cylinder-z");
  const ModelSpec* tee = m.find("tee");
  ASSERT_NE(tee, nullptr);
  EXPECT_EQ(tee->kind, ModelSourceKind::kShapeBox);
  EXPECT_EQ(tee->fold_long, 2);
  EXPECT_EQ(tee->fold_middle, 2);
  EXPECT_EQ(tee->symmetry, "box");
  EXPECT_EQ(tee->SourceKindName(), "shape");
  const ModelSpec* tape = m.find("tape");
  ASSERT_NE(tape, nullptr);
  EXPECT_FALSE(tape->cylinder_axis_long);
  EXPECT_EQ(tape->symmetry, "cylinder-z");
  EXPECT_EQ(m.find("ball")->kind, ModelSourceKind::kShapeSphere);
  EXPECT_EQ(m.find("nothing"), nullptr);

  // Detection settings: milk overrides, the others inherit the default.
  const ObjectConfig milk_config = m.config().ForItem("milk");
  EXPECT_EQ(milk_config.preferred, Method::kSift);
  ASSERT_EQ(milk_config.fallbacks.size(), 1u);
  EXPECT_EQ(milk_config.fallbacks[0], Method::kRangeTemplates);
  EXPECT_DOUBLE_EQ(milk_config.thresholds.min_score, 0.7);
  const ObjectConfig tee_config = m.config().ForItem("tee");
  EXPECT_EQ(tee_config.preferred, Method::kPpf);
  EXPECT_DOUBLE_EQ(tee_config.thresholds.min_score, 0.4);
}

TEST(ModelManifestTest, RootIsRelativeToTheManifestFolder) {
  const ModelManifest m = ModelManifest::Parse(
      R"({"root": "..", "models": {"milk": {"source": "scan:pointclouds/milk.pcd"}}})", "m.json",
      "/repo/tests/data/detector", "/data");
  EXPECT_EQ(m.find("milk")->scan_path, "/repo/tests/data/pointclouds/milk.pcd");
}

TEST(ModelManifestTest, BadContentNamesTheField) {
  EXPECT_NE(Expect("{").find("manifest.json:1"), std::string::npos);
  EXPECT_NE(Expect(R"({"models": {}})").find("'models'"), std::string::npos);
  EXPECT_NE(Expect(R"({"modles": {}})").find("'modles'"), std::string::npos);
  EXPECT_NE(Expect(R"({"models": {"a": {"source": "mesh:x"}}})").find("models.a.source"),
            std::string::npos);
  EXPECT_NE(Expect(R"({"models": {"a": {}}})").find("models.a.source"), std::string::npos);
  EXPECT_NE(
      Expect(R"({"models": {"a": {"source": "shape:box", "colour": 1}}})").find("models.a.colour"),
      std::string::npos);
  EXPECT_NE(Expect(R"({"models": {"a": {"source": "shape:box", "frame": "item"}}})")
                .find("models.a.frame"),
            std::string::npos);
  EXPECT_NE(
      Expect(R"({"models": {"a": {"source": "shape:box", "axis": "long"}}})").find("models.a.axis"),
      std::string::npos);
  EXPECT_NE(
      Expect(R"({"models": {"a": {"source": "shape:box", "fold": [0, 1]}}})").find("models.a.fold"),
      std::string::npos);
  EXPECT_NE(Expect(R"({"models": {"a": {"source": "shape:box", "preferred": "hough"}}})")
                .find("preferred"),
            std::string::npos);
  EXPECT_NE(Expect(R"({"version": 2, "models": {"a": {"source": "shape:box"}}})").find("version"),
            std::string::npos);
  EXPECT_THROW(ModelManifest::LoadFile("/no/such/manifest.json", "/data"), std::invalid_argument);
}

TEST(ModelManifestTest, BundledManifestCoversTheCatalogue) {
  const ModelManifest m = ModelManifest::LoadFile(kDataDir + "/detector/models.json", kDataDir);
  EXPECT_EQ(m.models().size(), 39u);
  for (const ModelSpec& spec : m.models()) {
    if (spec.kind == ModelSourceKind::kScan) {
      EXPECT_TRUE(std::filesystem::is_regular_file(spec.scan_path)) << spec.scan_path;
    }
  }
}

class ModelLibraryTest : public ::testing::Test {
 protected:
  void SetUp() override {
    cache_dir_ = ::testing::TempDir() + "/model_library_test_" +
                 ::testing::UnitTest::GetInstance()->current_test_info()->name();
    std::filesystem::remove_all(cache_dir_);
  }
  void TearDown() override { std::filesystem::remove_all(cache_dir_); }

  ModelLibraryOptions Options() const {
    ModelLibraryOptions options;
    options.cache_dir = cache_dir_;
    options.catalogue_path = kDataDir + "/apc2016/items/item_data.csv";
    return options;
  }

  static ModelManifest TestManifest() {
    return ModelManifest::LoadFile(kTestData + "/detector/models.json", kDataDir);
  }

  std::string cache_dir_;
};

TEST_F(ModelLibraryTest, BuildsOnFirstUseAndReadsTheCacheAfterARestart) {
  double diameter = 0.0;
  {
    const ModelLibrary library(TestManifest(), Options());
    EXPECT_EQ(library.GetIfLoaded("milk"), nullptr);
    const auto milk = library.Get("milk");
    ASSERT_NE(milk, nullptr);
    EXPECT_FALSE(milk->object_from_cache);
    EXPECT_EQ(library.GetIfLoaded("milk"), milk);
    EXPECT_EQ(library.Get("milk"), milk);  // Built once.
    EXPECT_EQ(milk->source_points, 13704u);
    diameter = milk->object->diameter_m();
    EXPECT_GT(diameter, 0.15);
    EXPECT_LT(diameter, 0.4);
    EXPECT_TRUE(milk->object->icp_cloud().has_normals());
    // PPF only: no templates or SIFT views were asked for.
    EXPECT_EQ(milk->templates, nullptr);
    EXPECT_EQ(milk->sift, nullptr);
  }
  const ModelLibrary restarted(TestManifest(), Options());
  const auto milk = restarted.Get("milk");
  EXPECT_TRUE(milk->object_from_cache);
  EXPECT_FLOAT_EQ(milk->object->diameter_m(), diameter);
}

TEST_F(ModelLibraryTest, UnknownItemIsNotFound) {
  const ModelLibrary library(TestManifest(), Options());
  EXPECT_THROW(library.Get("no_such_item"), NotFoundError);
  EXPECT_THROW(library.GetIfLoaded("no_such_item"), NotFoundError);
}

TEST_F(ModelLibraryTest, UnreadableSourceIsAnErrorNamingTheItem) {
  const ModelLibrary library(
      ModelManifest::Parse(R"({"models": {"ghost": {"source": "scan:none.ply"}}})", "m.json", "/m",
                           "/no/such/dir"),
      Options());
  try {
    library.Get("ghost");
    FAIL() << "no exception";
  } catch (const NotFoundError&) {
    FAIL() << "a broken model is not an unknown item";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("ghost"), std::string::npos) << e.what();
  }
}

TEST_F(ModelLibraryTest, ShapeModelHasTheCatalogueBoxAndRangeTemplates) {
  const ModelLibrary library(TestManifest(), Options());
  const ModelSpec& spec = *library.manifest().find("crayola_24_ct");
  const geometry::PointCloud cloud = ModelSourceCloud(spec, library.options());
  ASSERT_FALSE(cloud.empty());
  ASSERT_TRUE(cloud.has_normals());
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(1e9f), hi = -lo;
  for (const auto& p : cloud.points) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  // Catalogue: 9.5 x 7.0 x 2.5 cm (long, middle, short), centred, long side along x.
  const Eigen::Vector3f size = hi - lo;
  EXPECT_NEAR(size.x(), 0.095, 0.004);
  EXPECT_NEAR(size.y(), 0.070, 0.004);
  EXPECT_NEAR(size.z(), 0.025, 0.004);
  EXPECT_LT(((hi + lo) / 2).norm(), 0.003);

  const auto model = library.Get("crayola_24_ct");
  ASSERT_NE(model->templates, nullptr);  // range_templates is its fallback.
  EXPECT_FALSE(model->templates->templates().empty());
}

TEST_F(ModelLibraryTest, ScannedApcModelIsInTheItemFrameWithSiftViewsAndTemplates) {
  const ModelLibrary library(ModelManifest::LoadFile(kDataDir + "/detector/models.json", kDataDir),
                             Options());
  const auto eraser = library.Get("expo_dry_erase_board_eraser");
  // Item frame of libs/world: centred on the bounding box, long side along x, short along z.
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(1e9f), hi = -lo;
  for (const auto& p : eraser->object->fine_cloud().points) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  const Eigen::Vector3f size = hi - lo;
  EXPECT_LT(((hi + lo) / 2).norm(), 0.01);
  EXPECT_GT(size.x(), size.y());
  EXPECT_GT(size.y(), size.z());
  // The scan is coloured and its chain has SIFT and range templates as fallbacks.
  ASSERT_NE(eraser->sift, nullptr);
  EXPECT_GT(eraser->sift->num_features(), 50u);
  ASSERT_NE(eraser->templates, nullptr);
}

TEST_F(ModelLibraryTest, ShapeModelsCarryTheSimulatorsPrintedTextureAsAlbedo) {
  const ModelLibrary library(ModelManifest::LoadFile(kDataDir + "/detector/models.json", kDataDir),
                             Options());
  // data/items/shapes.yaml: staples_index_cards {albedo: 0.9, pattern_albedo: 0.3, blocks}.
  const geometry::PointCloud cloud =
      ModelSourceCloud(*library.manifest().find("staples_index_cards"), library.options());
  ASSERT_EQ(cloud.intensities.size(), cloud.size());
  std::size_t base = 0, print = 0;
  for (float a : cloud.intensities) {
    base += std::abs(a - 0.9f) < 1e-5f ? 1 : 0;
    print += std::abs(a - 0.3f) < 1e-5f ? 1 : 0;
  }
  EXPECT_EQ(base + print, cloud.size());
  EXPECT_GT(print, cloud.size() / 10);
  EXPECT_GT(base, cloud.size() / 10);

  const auto model = library.Get("staples_index_cards");
  ASSERT_TRUE(model->object->has_albedo());
  EXPECT_GT(model->object->albedo_stddev(), 0.1f);
  EXPECT_EQ(model->object->options().symmetry, ModelSymmetry::kBox);
  EXPECT_EQ(library.Get("dasani_water_bottle")->object->options().symmetry,
            ModelSymmetry::kCylinderX);
  EXPECT_EQ(library.Get("scotch_duct_tape")->object->options().symmetry, ModelSymmetry::kCylinderZ);

  // Another shape table: a uniform texture gives a uniform albedo.
  const std::string table = cache_dir_ + "/shapes.yaml";
  std::filesystem::create_directories(cache_dir_);
  std::ofstream(table) << "version: 1\nitems:\n  staples_index_cards: {shape: box, albedo: 0.5, "
                          "texture: uniform}\n";
  ModelLibraryOptions options = Options();
  options.shape_table_path = table;
  const geometry::PointCloud plain =
      ModelSourceCloud(*library.manifest().find("staples_index_cards"), options);
  for (float a : plain.intensities) ASSERT_NEAR(a, 0.5f, 1e-6f);
  options.shape_table_path = cache_dir_ + "/missing.yaml";
  EXPECT_THROW(ModelSourceCloud(*library.manifest().find("staples_index_cards"), options),
               std::exception);
}

TEST_F(ModelLibraryTest, ScannedModelAlbedoIsTheColourLuma) {
  const ModelLibrary library(ModelManifest::LoadFile(kDataDir + "/detector/models.json", kDataDir),
                             Options());
  const geometry::PointCloud cloud =
      ModelSourceCloud(*library.manifest().find("dove_beauty_bar"), library.options());
  ASSERT_TRUE(cloud.has_colors());
  ASSERT_EQ(cloud.intensities.size(), cloud.size());
  for (std::size_t i = 0; i < cloud.size(); i += 101) {
    const auto& c = cloud.colors[i];
    EXPECT_NEAR(cloud.intensities[i], (0.299f * c[0] + 0.587f * c[1] + 0.114f * c[2]) / 255.0f,
                1e-5f);
  }
  const auto model = library.Get("dove_beauty_bar");
  EXPECT_TRUE(model->object->has_albedo());
  EXPECT_GT(model->object->albedo_stddev(), 0.02f);
  EXPECT_EQ(model->object->options().symmetry, ModelSymmetry::kNone);
  // A scan without colours (the PCL milk carton) has no albedo.
  const ModelLibrary test_library(TestManifest(), Options());
  EXPECT_FALSE(test_library.Get("milk")->object->has_albedo());
}

TEST_F(ModelLibraryTest, ShapeModelsGetSiftViewsOfTheirPrinting) {
  // A catalogue box with SIFT in its chain: the views show the printed blocks.
  const ModelManifest manifest = ModelManifest::Parse(
      R"({"models": {"staples_index_cards": {"source": "shape:box", "preferred": "ppf",
                                             "fallbacks": ["sift"]}}})",
      "m.json", kDataDir, kDataDir);
  const ModelLibrary library(manifest, Options());
  const auto model = library.Get("staples_index_cards");
  ASSERT_NE(model->sift, nullptr);
  EXPECT_GT(model->sift->num_features(), 20u);
}

TEST(RenderSiftViewsTest, PixelsShowTheModelPointsTheyStore) {
  // A textured square 10 cm wide in the z = 0 plane with random grey blocks.
  geometry::PointCloud model;
  std::mt19937 rng(3);
  std::uniform_int_distribution<int> grey(0, 255);
  std::vector<int> block(100);
  for (int& b : block) b = grey(rng);
  for (int i = 0; i < 200; ++i) {
    for (int j = 0; j < 200; ++j) {
      model.points.emplace_back(i * 0.0005f - 0.05f, j * 0.0005f - 0.05f, 0.0f);
      const auto g = static_cast<std::uint8_t>(block[(i / 20) * 10 + j / 20]);
      model.colors.push_back({g, g, g});
    }
  }
  model.width = static_cast<std::uint32_t>(model.points.size());
  const std::vector<SiftView> views = RenderSiftViews(model, 4, 128);
  ASSERT_EQ(views.size(), 4u);
  std::size_t covered = 0;
  for (const SiftView& view : views) {
    ASSERT_EQ(view.image.pixels.size(), 128u * 128u);
    ASSERT_EQ(view.p_ItemPixel.size(), view.image.pixels.size());
    for (std::size_t k = 0; k < view.p_ItemPixel.size(); ++k) {
      const Eigen::Vector3f& p = view.p_ItemPixel[k];
      if (!p.allFinite()) continue;
      ++covered;
      // The stored point lies on the square and the pixel has its colour.
      EXPECT_NEAR(p.z(), 0.0f, 1e-6f);
      const int i = static_cast<int>(std::lround((p.x() + 0.05f) / 0.0005f));
      const int j = static_cast<int>(std::lround((p.y() + 0.05f) / 0.0005f));
      EXPECT_EQ(view.image.pixels[k], block[(i / 20) * 10 + j / 20]);
    }
  }
  EXPECT_GT(covered, 1000u);
  // The same texture as an albedo (a shape model's printing) renders the same grey levels.
  geometry::PointCloud albedo_model = model;
  albedo_model.colors.clear();
  for (const auto& c : model.colors) albedo_model.intensities.push_back(c[0] / 255.0f);
  const std::vector<SiftView> albedo_views = RenderSiftViews(albedo_model, 4, 128);
  ASSERT_EQ(albedo_views.size(), views.size());
  for (std::size_t v = 0; v < views.size(); ++v) {
    EXPECT_EQ(albedo_views[v].image.pixels, views[v].image.pixels);
  }
  geometry::PointCloud grey_model = model;
  grey_model.colors.clear();
  EXPECT_THROW(RenderSiftViews(grey_model, 4, 128), std::invalid_argument);
  EXPECT_THROW(RenderSiftViews(model, 0, 128), std::invalid_argument);
}

}  // namespace
}  // namespace picking::detector
