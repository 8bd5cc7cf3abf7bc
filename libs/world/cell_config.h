#pragma once

#include <Eigen/Geometry>

#include <stdexcept>
#include <string>
#include <vector>

#include "libs/world/mesh.h"
#include "libs/world/shelf_bins.h"

namespace picking::world {

/// Thrown for an unreadable or invalid cell configuration. The message names the file and the
/// field (e.g. "shelf.X_BaseShelf.orientation").
class CellConfigError final : public std::runtime_error {
 public:
  CellConfigError(const std::string& source, const std::string& field, const std::string& what);
  const std::string& field() const { return field_; }

 private:
  std::string field_;
};

/// Layout of the static cell. Every pose is in the UR10 base frame (Base), metres, except
/// X_WorldBase. World is the floor frame (z = 0 on the floor, z up).
struct CellConfig {
  std::string source;                                             ///< File it was read from.
  Eigen::Isometry3d X_WorldBase = Eigen::Isometry3d::Identity();  ///< Robot base on the floor.
  Eigen::Isometry3d X_BaseShelf = Eigen::Isometry3d::Identity();  ///< Shelf mesh frame.
  std::string shelf_mesh_path;  ///< Absolute path of the shelf mesh (STL, x out of the bins).
  Eigen::Isometry3d X_BaseTote = Eigen::Isometry3d::Identity();  ///< Tote mesh frame.
  std::string tote_mesh_path;  ///< Absolute path of the tote mesh (STL, z up, floor at z = 0).
  Eigen::Isometry3d X_BaseTable = Eigen::Isometry3d::Identity();  ///< Centre of the table top.
  Eigen::Vector3d table_size_m = Eigen::Vector3d::Zero();         ///< Table length, width, height.

  /// Floor height in the base frame (metres).
  double floor_z_m() const { return X_WorldBase.inverse().translation().z(); }
};

/// Reads a cell configuration (YAML). Layout:
///
///     version: 1
///     robot_base: {X_WorldBase: <pose>}
///     shelf: {X_BaseShelf: <pose>, mesh: <path>}
///     tote:  {X_BaseTote: <pose>, mesh: <path>}
///     table: {X_BaseTable: <pose>, size_m: [l, w, h]}
///
/// where <pose> is `{position: [x, y, z], orientation: [w, x, y, z]}` (metres; a unit
/// quaternion, norm within 1e-3 of 1, normalised on reading). Relative mesh paths are
/// resolved against the YAML file's folder and must exist. Throws CellConfigError naming the
/// file and the field for a missing, mistyped or invalid entry, or an unknown key.
CellConfig ReadCellConfig(const std::string& path);

/// As ReadCellConfig, from YAML text; relative paths are resolved against `base_dir`.
CellConfig ParseCellConfig(const std::string& yaml_text, const std::string& source_name,
                           const std::string& base_dir);

/// data/cell/default_cell.yaml under apc::DefaultDataDir().
std::string DefaultCellConfigPath();

/// The static cell's geometry as loaded from a configuration.
struct CellModel {
  CellConfig config;
  TriangleMesh shelf;             ///< In the shelf frame.
  TriangleMesh tote;              ///< In the tote frame.
  TriangleMesh table;             ///< In the table frame (top surface at z = 0).
  std::vector<BinGeometry> bins;  ///< Measured from `shelf`, in the shelf frame, A..L.

  /// The bin called `name`; throws std::invalid_argument naming it if unknown.
  const BinGeometry& bin(const std::string& name) const;
};

/// Loads the meshes and measures the bins. Throws std::runtime_error on unreadable meshes or a
/// shelf mesh without 12 bins.
CellModel LoadCellModel(const CellConfig& config);

}  // namespace picking::world
