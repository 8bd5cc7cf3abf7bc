#pragma once

#include <Eigen/Core>

#include <map>
#include <stdexcept>
#include <string>

#include "libs/apc/catalogue.h"
#include "libs/world/mesh.h"

namespace picking::world {

/// Geometric primitive used for an item.
enum class ShapeKind { kBox, kCylinder, kSphere, kScan };

/// Procedural albedo pattern painted on an item's surface.
enum class TextureKind {
  kUniform,  ///< `albedo` everywhere.
  kStripes,  ///< Bands of `albedo` / `pattern_albedo`, `pattern_period_m` wide, along the
             ///< first surface direction.
  kChecker,  ///< Squares of `pattern_period_m`.
  kBlocks,   ///< A printed-package look: a border and a few rectangles of `pattern_albedo`
             ///< per face, placed by a generator seeded with the item id.
};

/// How one item is modelled. Sizes come from the catalogue (long / middle / short side).
struct ItemShape {
  ShapeKind kind = ShapeKind::kBox;
  /// Cylinder axis: along the item's long side (true; e.g. a bottle lying down) or its short
  /// side (false; e.g. a roll of tape).
  bool axis_along_long_side = true;
  /// A soft item folded for storage: the long and middle sides are divided by these factors
  /// and the short side multiplied by their product (e.g. a T-shirt folded twice).
  int fold_long = 1;
  int fold_middle = 1;
  float albedo = 0.6f;
  float pattern_albedo = 0.2f;
  TextureKind texture = TextureKind::kBlocks;
  double pattern_period_m = 0.02;
  std::string scan_file;  ///< kScan: file name of the coloured point cloud in the models dir.
};

/// Thrown for an invalid shape table; the message names the file and the field.
class ShapeTableError final : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Shape per item name, read from data/items/shapes.yaml:
///
///     version: 1
///     items:
///       rawlings_baseball: {shape: sphere, albedo: 0.85, texture: stripes, period_m: 0.03}
///       dasani_water_bottle: {shape: cylinder, axis: long, ...}
///       fiskars_scissors_red: {shape: scan, file: fiskars_scissors_red.ply, ...}
///       cherokee_easy_tee_shirt: {shape: box, fold: [2, 2], ...}
///
/// Keys: shape (box|cylinder|sphere|scan), axis (long|short), fold ([n_long, n_middle]),
/// albedo and pattern_albedo (in [0, 1]), texture (uniform|stripes|checker|blocks), period_m
/// (> 0), file (scan only). Items not listed are boxes with the defaults of ItemShape.
class ShapeTable final {
 public:
  /// Reads and validates the table against `catalogue` (every key must be an item). Throws
  /// ShapeTableError naming the file and field.
  static ShapeTable FromYamlFile(const std::string& path, const apc::Catalogue& catalogue);

  /// The shape of `item` (the defaults for an unlisted item).
  ItemShape at(const std::string& item) const;
  const std::map<std::string, ItemShape>& entries() const { return entries_; }

 private:
  std::map<std::string, ItemShape> entries_;
};

/// data/items/shapes.yaml under apc::DefaultDataDir().
std::string DefaultShapeTablePath();

/// Box dimensions (metres) of the item as modelled: long, middle, short side after folding.
Eigen::Vector3d ModelledSize(const apc::Item& item, const ItemShape& shape);

/// Builds the textured primitive mesh of an item in its item frame: the origin at the centre of
/// its bounding box, the long side along x, middle along y, short along z (so resting on the
/// largest face means z up). Cylinders have the largest diameter that fits the box; a sphere
/// the smallest side as diameter. Faces are divided into cells of about 1 cm with their own
/// vertices, each cell carrying one albedo from the texture (per-vertex albedo).
/// Throws std::invalid_argument for kScan (see ScannedItemMesh) or bad dimensions.
TriangleMesh MakePrimitiveItemMesh(const apc::Item& item, const ItemShape& shape);

}  // namespace picking::world
