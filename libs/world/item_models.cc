#include "libs/world/item_models.h"

#include <filesystem>

#include "libs/world/mesh_utils.h"

namespace picking::world {

ItemModelLibrary::ItemModelLibrary(apc::Catalogue catalogue, ItemModelLibraryOptions options)
    : catalogue_(std::move(catalogue)), options_(std::move(options)) {
  if (options_.shape_table_path.empty()) options_.shape_table_path = DefaultShapeTablePath();
  if (options_.models_dir.empty()) {
    options_.models_dir = (std::filesystem::path(apc::DefaultDataDir()) / "models").string();
  }
  shapes_ = ShapeTable::FromYamlFile(options_.shape_table_path, catalogue_);
}

std::shared_ptr<const ItemModel> ItemModelLibrary::Get(const std::string& name) const {
  const apc::Item& item = catalogue_.at(name);  // throws UnknownItemError
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = models_.find(name);
  if (it != models_.end()) return it->second;
  auto model = std::make_shared<ItemModel>();
  model->item = &item;
  model->shape = shapes_.at(name);
  if (model->shape.kind == ShapeKind::kScan) {
    const std::string path =
        (std::filesystem::path(options_.models_dir) / model->shape.scan_file).string();
    ScannedModel scan = LoadScannedModelCached(path, options_.cache_dir, options_.scan);
    model->mesh = std::move(scan.mesh);
    model->X_ScanItem = scan.X_ScanItem;
  } else {
    model->mesh = MakePrimitiveItemMesh(item, model->shape);
  }
  model->mesh.name = name;
  model->box_I = Bounds(model->mesh);
  models_[name] = model;
  return model;
}

}  // namespace picking::world
