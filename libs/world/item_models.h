#pragma once

#include <Eigen/Geometry>

#include <map>
#include <memory>
#include <mutex>
#include <string>

#include "libs/apc/catalogue.h"
#include "libs/world/item_shapes.h"
#include "libs/world/mesh.h"
#include "libs/world/scanned_model.h"

namespace picking::world {

/// The model of one catalogue item.
struct ItemModel {
  const apc::Item* item = nullptr;  ///< Catalogue entry (owned by the library's catalogue).
  ItemShape shape;
  TriangleMesh mesh;  ///< In the item frame (see MakePrimitiveItemMesh / ScannedModel).
  /// Bounding box of the mesh in the item frame (metres); the item rests stably on its -z face.
  Eigen::AlignedBox3d box_I;
  /// For scanned items, the item frame in the scan file's frame; identity otherwise.
  Eigen::Isometry3d X_ScanItem = Eigen::Isometry3d::Identity();
};

/// Options of ItemModelLibrary. Empty paths select the bundled data.
struct ItemModelLibraryOptions {
  std::string shape_table_path;  ///< Default DefaultShapeTablePath().
  std::string models_dir;        ///< Scans: default <data>/models.
  std::string cache_dir;         ///< Default DefaultModelCacheDir().
  ScanReconstructionOptions scan;
};

/// Models of all catalogue items, built on first use (scans are reconstructed once and then
/// read from the disk cache). Thread-safe; returned models stay valid for the library's life.
class ItemModelLibrary final {
 public:
  /// Reads the shape table (throws ShapeTableError). Scans are not touched until needed.
  ItemModelLibrary(apc::Catalogue catalogue, ItemModelLibraryOptions options = {});

  /// The model of `name`; builds it on first use. Throws apc::UnknownItemError for a name
  /// not in the catalogue, std::runtime_error if a scan cannot be read.
  std::shared_ptr<const ItemModel> Get(const std::string& name) const;

  const apc::Catalogue& catalogue() const { return catalogue_; }
  const ShapeTable& shapes() const { return shapes_; }

 private:
  apc::Catalogue catalogue_;
  ItemModelLibraryOptions options_;
  ShapeTable shapes_;
  mutable std::mutex mutex_;
  mutable std::map<std::string, std::shared_ptr<const ItemModel>> models_;
};

}  // namespace picking::world
