#pragma once

#include <memory>

#include "libs/apc/catalogue.h"
#include "services/viewer/core/viewer_model.h"

namespace picking::viewer {

/// The bundled cell, UR10 and item models, loaded once for every test.
inline const ViewerModel& BundledModel() {
  static const ViewerModel* model = [] {
    const std::string data = PICKING_DATA_DIR;
    world::ItemModelLibraryOptions options;
    options.shape_table_path = data + "/items/shapes.yaml";
    options.models_dir = data + "/models";
    auto items = std::make_shared<const world::ItemModelLibrary>(
        apc::Catalogue::FromCsvFile(data + "/apc2016/items/item_data.csv"), options);
    return new ViewerModel(
        world::LoadCellModel(world::ReadCellConfig(data + "/cell/default_cell.yaml")),
        ur10::Ur10Kinematics(ur10::Ur10Model::Load(data + "/ur10")), items);
  }();
  return *model;
}

}  // namespace picking::viewer
