#include "libs/world/item_models.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <set>

#include "libs/world/mesh_utils.h"
#include "libs/world/ply_mesh_io.h"

namespace picking::world {
namespace {

apc::Catalogue LoadCatalogue() { return apc::Catalogue::FromCsvFile(apc::DefaultCataloguePath()); }

std::string CacheDir() {
  return (std::filesystem::temp_directory_path() / "picking_world_test" /
          ("cache_" + std::to_string(::getpid())))
      .string();
}

TEST(ItemShapesTest, TableCoversItemsAndNamesBadFields) {
  const apc::Catalogue catalogue = LoadCatalogue();
  const ShapeTable table = ShapeTable::FromYamlFile(DefaultShapeTablePath(), catalogue);
  EXPECT_EQ(table.entries().size(), 39u);
  EXPECT_EQ(table.at("rawlings_baseball").kind, ShapeKind::kSphere);
  EXPECT_EQ(table.at("dasani_water_bottle").kind, ShapeKind::kCylinder);
  EXPECT_EQ(table.at("fiskars_scissors_red").kind, ShapeKind::kScan);

  const std::string path = CacheDir() + "_bad_shapes.yaml";
  std::filesystem::create_directories(std::filesystem::path(path).parent_path());
  std::ofstream(path) << "version: 1\nitems:\n  rawlings_baseball: {shape: cube}\n";
  try {
    ShapeTable::FromYamlFile(path, catalogue);
    FAIL() << "no throw";
  } catch (const ShapeTableError& e) {
    EXPECT_NE(std::string(e.what()).find("items.rawlings_baseball.shape"), std::string::npos)
        << e.what();
  }
  std::ofstream(path) << "version: 1\nitems:\n  golden_ball: {shape: sphere}\n";
  EXPECT_THROW(ShapeTable::FromYamlFile(path, catalogue), ShapeTableError);
}

TEST(ItemShapesTest, PrimitivesMatchTheCatalogueSizesAndAreTextured) {
  const apc::Catalogue catalogue = LoadCatalogue();
  const ShapeTable table = ShapeTable::FromYamlFile(DefaultShapeTablePath(), catalogue);
  int primitives = 0;
  for (const apc::Item& item : catalogue.items()) {
    const ItemShape shape = table.at(item.name);
    if (shape.kind == ShapeKind::kScan) continue;
    ++primitives;
    SCOPED_TRACE(item.name);
    const TriangleMesh mesh = MakePrimitiveItemMesh(item, shape);
    ASSERT_NO_THROW(Validate(mesh));
    ASSERT_EQ(mesh.vertex_albedo.size(), mesh.vertices.size());
    const Eigen::Vector3d size = ModelledSize(item, shape);
    const Eigen::AlignedBox3d b = Bounds(mesh);
    EXPECT_LT(b.center().norm(), 1e-3);
    // Long side along x, short along z; within the measured box.
    EXPECT_LE(b.sizes().x(), size.x() + 1e-5);
    EXPECT_LE(b.sizes().y(), size.y() + 1e-5);
    EXPECT_LE(b.sizes().z(), size.z() + 1e-5);
    EXPECT_GE(b.sizes().x(), b.sizes().y() - 1e-3);
    EXPECT_GE(b.sizes().y(), b.sizes().z() - 1e-3);
    EXPECT_GT(SignedVolume(mesh), 0.0);  // outward winding
    if (shape.kind == ShapeKind::kBox) {
      EXPECT_NEAR(SignedVolume(mesh), size.prod(), 1e-3 * size.prod());
    }
    // The texture shows at least two grey levels.
    const std::set<float> levels(mesh.vertex_albedo.begin(), mesh.vertex_albedo.end());
    if (shape.texture != TextureKind::kUniform) EXPECT_GE(levels.size(), 2u);
  }
  EXPECT_EQ(primitives, 33);
  // The folded T-shirt fits a bin floor.
  const ItemShape shirt = table.at("cherokee_easy_tee_shirt");
  EXPECT_LT(ModelledSize(catalogue.at("cherokee_easy_tee_shirt"), shirt).x(), 0.25);
  // A sphere of the baseball's size.
  const TriangleMesh ball =
      MakePrimitiveItemMesh(catalogue.at("rawlings_baseball"), table.at("rawlings_baseball"));
  for (const auto& v : ball.vertices) EXPECT_NEAR(v.norm(), 0.034, 1e-5);
}

TEST(ItemModelsTest, EveryItemHasAModelAndScansAreCachedOnDisk) {
  ItemModelLibraryOptions options;
  options.cache_dir = CacheDir();
  std::filesystem::remove_all(options.cache_dir);
  const ItemModelLibrary library(LoadCatalogue(), options);
  for (const apc::Item& item : library.catalogue().items()) {
    if (library.shapes().at(item.name).kind == ShapeKind::kScan &&
        item.name != "fiskars_scissors_red") {
      continue;  // one scan is enough here; the rest are built the same way
    }
    const auto model = library.Get(item.name);
    EXPECT_FALSE(model->mesh.empty()) << item.name;
    EXPECT_EQ(model->mesh.name, item.name);
  }
  EXPECT_THROW(library.Get("golden_ball"), apc::UnknownItemError);

  const auto scissors = library.Get("fiskars_scissors_red");
  EXPECT_EQ(scissors, library.Get("fiskars_scissors_red"));  // built once
  EXPECT_GT(scissors->mesh.num_triangles(), 2000u);
  ASSERT_EQ(scissors->mesh.vertex_colors.size(), scissors->mesh.vertices.size());
  // Mostly red.
  double r = 0, g = 0;
  for (const auto& c : scissors->mesh.vertex_colors) {
    r += c[0];
    g += c[1];
  }
  EXPECT_GT(r, 1.5 * g);
  // The scan (without the packaging the catalogue box includes) is a flat object: about
  // 9.4 x 7.2 x 1.9 cm, within the catalogue's 13.3 cm long side.
  const Eigen::Vector3d size = scissors->box_I.sizes();
  EXPECT_GT(size.x(), 0.08);
  EXPECT_LT(size.x(), 0.133);
  EXPECT_LT(size.z(), 0.03);
  // The item frame maps the mesh back onto the scan's points.
  const TriangleMesh raw =
      ReadPly(std::string(PICKING_DATA_DIR) + "/models/fiskars_scissors_red.ply");
  const Eigen::AlignedBox3d raw_box = Bounds(raw);
  const Eigen::AlignedBox3d mapped = Bounds(scissors->mesh, scissors->X_ScanItem);
  EXPECT_TRUE(raw_box.contains(mapped.center()));
  EXPECT_LT((raw_box.center() - mapped.center()).norm(), 0.01);
  EXPECT_LT(scissors->box_I.center().norm(), 1e-4);
  EXPECT_GE(size.x(), size.y());
  EXPECT_GE(size.y(), size.z());

  // The cache holds one versioned file; a second library reads it and gets the same mesh.
  std::vector<std::filesystem::path> files;
  for (const auto& e : std::filesystem::directory_iterator(options.cache_dir)) {
    files.push_back(e.path());
  }
  ASSERT_EQ(files.size(), 1u);
  EXPECT_NE(files[0].filename().string().find("fiskars_scissors_red.v1-"), std::string::npos);
  const auto write_time = std::filesystem::last_write_time(files[0]);
  const ItemModelLibrary again(LoadCatalogue(), options);
  const auto cached = again.Get("fiskars_scissors_red");
  EXPECT_EQ(std::filesystem::last_write_time(files[0]), write_time);
  EXPECT_EQ(cached->mesh.triangles, scissors->mesh.triangles);
  ASSERT_EQ(cached->mesh.vertices.size(), scissors->mesh.vertices.size());
  for (std::size_t i = 0; i < cached->mesh.vertices.size(); ++i) {
    EXPECT_TRUE(cached->mesh.vertices[i].isApprox(scissors->mesh.vertices[i], 1e-5));
  }
  std::filesystem::remove_all(options.cache_dir);
}

}  // namespace
}  // namespace picking::world
