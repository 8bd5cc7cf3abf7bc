#pragma once

#include <Eigen/Geometry>

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "libs/geometry/point_cloud.h"
#include "services/detector/core/detection.h"
#include "services/detector/core/model.h"
#include "services/detector/core/sift.h"
#include "services/detector/core/templates.h"

namespace picking::detector {

/// Where an object model's surface comes from.
enum class ModelSourceKind {
  kScan,           ///< A point cloud file (PLY or PCD), e.g. an APC scanned model.
  kShapeBox,       ///< The catalogue item's box, surface sampled.
  kShapeCylinder,  ///< The largest cylinder inside the catalogue box.
  kShapeSphere,    ///< A sphere with the catalogue box's shortest side as diameter.
};

/// Frame of a scanned model's points.
enum class ScanFrame {
  kFile,  ///< The coordinates of the file as they are.
  /// The item frame of libs/world (principal axes of the reconstructed scan, origin at the
  /// centre of its bounding box: long side x, middle y, short z), so detector poses agree with
  /// the simulator's item poses.
  kItem,
};

/// One entry of the model manifest.
struct ModelSpec {
  std::string item;
  ModelSourceKind kind = ModelSourceKind::kScan;
  /// The `source` string as written ("scan:models/x.ply", "shape:box").
  std::string source;
  /// kScan: absolute or working-directory-relative path of the cloud file.
  std::string scan_path;
  ScanFrame frame = ScanFrame::kFile;
  /// kShapeCylinder: axis along the long side (true) or the short side.
  bool cylinder_axis_long = true;
  /// Shapes: soft items stored folded (see world::ItemShape).
  int fold_long = 1;
  int fold_middle = 1;
  /// Free-form symmetry note reported by ListModels ("none", "box", "cylinder-x", ...).
  std::string symmetry = "none";

  /// "scan" or "shape".
  std::string SourceKindName() const;
};

/// The detector's model manifest: which items it knows, how each model is made and how each
/// item is detected (the per-object part is a DetectorConfig).
///
/// File format (JSON):
/// ```
/// {"version": 1,
///  "root": "..",   // optional: base of relative scan paths, relative to the manifest's
///                  // folder; default: the data directory given to LoadFile
///  "default": {"preferred": "ppf", "fallbacks": ["range_templates"],
///              "thresholds": {"min_score": 0.5}},
///  "models": {
///    "milk": {"source": "scan:pointclouds/milk.pcd", "frame": "file", "symmetry": "none",
///             "preferred": "ppf", "thresholds": {"min_score": 0.4}},
///    "dasani_water_bottle": {"source": "shape:cylinder", "axis": "long"},
///    "cherokee_easy_tee_shirt": {"source": "shape:box", "fold": [2, 2]}}}
/// ```
/// Model keys: source ("scan:<path>", "shape:box", "shape:cylinder", "shape:sphere"), frame
/// ("file" or "item", scans only; default "file"), symmetry (default "none" for scans, "box",
/// "cylinder-x" / "cylinder-z", "sphere" for shapes), axis ("long" | "short", cylinders),
/// fold ([n_long, n_middle], shapes). Detection keys (preferred, fallbacks, thresholds,
/// method_thresholds) are those of DetectorConfig and inherit from "default". Unknown keys
/// are errors.
class ModelManifest final {
 public:
  /// Reads a manifest file. Relative scan paths are resolved against "root" (relative to the
  /// file's folder) or, without it, against `data_dir`. Throws std::invalid_argument naming
  /// the file and the field on bad content, or when the file cannot be read.
  static ModelManifest LoadFile(const std::string& path, const std::string& data_dir);
  /// As LoadFile; `source_name` names the text in errors and `manifest_dir` is the folder
  /// "root" is relative to.
  static ModelManifest Parse(const std::string& text, const std::string& source_name,
                             const std::string& manifest_dir, const std::string& data_dir);

  /// Entries sorted by item name.
  const std::vector<ModelSpec>& models() const { return models_; }
  /// The entry of `item`, or nullptr.
  const ModelSpec* find(const std::string& item) const;
  const DetectorConfig& config() const { return config_; }
  const std::string& source_name() const { return source_name_; }

 private:
  std::vector<ModelSpec> models_;
  DetectorConfig config_;
  std::string source_name_;
};

/// Options of ModelLibrary.
struct ModelLibraryOptions {
  /// On-disk cache of the built models; empty: DefaultDetectorCacheDir().
  std::string cache_dir;
  /// The APC catalogue (item box sizes, for shape models); empty: apc::DefaultCataloguePath().
  std::string catalogue_path;
  ObjectModelOptions object;
  /// Surface sampling of shape models, metres.
  double shape_spacing_m = 0.002;
  /// The shape table (world::ShapeTable) whose texture (albedo, pattern) shape models carry
  /// as their albedo; empty: world::DefaultShapeTablePath() when that file exists, else the
  /// defaults of world::ItemShape.
  std::string shape_table_path;
  /// Range templates (built when range_templates is in the item's chain).
  TemplateOptions templates;
  /// SIFT views (built when sift is in the item's chain and the model has colours, or an
  /// albedo: shape models carry their printed texture): the textured model is rendered from
  /// this many directions spread over the sphere.
  int sift_views = 12;
  /// Pixels across the model's diameter in a SIFT view.
  int sift_view_size_px = 320;
};

/// An object model ready for detection. Frames: the item frame I, metres.
struct LoadedModel {
  ModelSpec spec;
  ObjectConfig config;
  /// Fine and ICP clouds with normals, PPF table (see model.h).
  std::shared_ptr<const ObjectModel> object;
  /// Range templates; null when range_templates is not in the item's chain.
  std::shared_ptr<const RangeTemplateSet> templates;
  /// SIFT views; null when sift is not in the chain or the model has no colours or albedo,
  /// or too little texture.
  std::shared_ptr<const SiftModel> sift;
  /// Number of points of the source cloud (scan) or surface sample (shape).
  std::size_t source_points = 0;
  bool object_from_cache = false;  ///< The PPF model came from the disk cache.
  double build_s = 0.0;            ///< Wall-clock time to build or load, seconds.
};

/// `$PICKING_CACHE_DIR/detector` when set, else `$HOME/.cache/picking/detector`, else
/// `<system temp dir>/picking-cache/detector`.
std::string DefaultDetectorCacheDir();

/// The detector's object models, built on first use from the manifest and cached on disk
/// (the PPF model through ObjectModel::LoadOrBuild, keyed by the source cloud and options),
/// so the first request for an item after a restart reads the cache instead of training.
/// Thread-safe: concurrent requests for different items build in parallel, for one item once.
class ModelLibrary final {
 public:
  /// Reads the catalogue only when a shape model is needed. Throws std::invalid_argument on
  /// invalid options.
  ModelLibrary(ModelManifest manifest, ModelLibraryOptions options = {});
  ~ModelLibrary();
  ModelLibrary(const ModelLibrary&) = delete;
  ModelLibrary& operator=(const ModelLibrary&) = delete;

  /// The model of `item`, built (or loaded from the cache) on first use. Throws NotFoundError
  /// (libs/errors) for an item not in the manifest, std::runtime_error when its source
  /// cannot be read or the model cannot be built (a later call tries again).
  std::shared_ptr<const LoadedModel> Get(const std::string& item) const;
  /// The model when it is already built, else nullptr (never builds). Throws NotFoundError
  /// for an item not in the manifest.
  std::shared_ptr<const LoadedModel> GetIfLoaded(const std::string& item) const;
  /// Builds every model of the manifest (e.g. before serving). Throws as Get.
  void LoadAll() const;

  const ModelManifest& manifest() const { return manifest_; }
  const ModelLibraryOptions& options() const { return options_; }
  /// The item's detection configuration (manifest default for what it does not set).
  ObjectConfig ConfigFor(const std::string& item) const;

 private:
  struct Slot;
  std::shared_ptr<const LoadedModel> Build(const ModelSpec& spec) const;

  ModelManifest manifest_;
  ModelLibraryOptions options_;
  std::map<std::string, std::unique_ptr<Slot>> slots_;
};

/// The model surface points for `spec` in its item frame (scan read from file and moved
/// into the item frame when requested; shapes sampled from the catalogue box), with the
/// surface albedo in `intensities` (a shape's printed texture from the shape table, a scan's
/// colour luma; none for a scan without colours). Exposed for tests. Throws std::runtime_error when
/// the file or catalogue cannot be read.
geometry::PointCloud ModelSourceCloud(const ModelSpec& spec, const ModelLibraryOptions& options);

/// SIFT views of a textured model (points in the item frame with normals and colours, or an
/// albedo in [0, 1] in `intensities`, as shape models have it): a point-splat rendering from
/// `num_views` directions on a Fibonacci sphere, grey levels the colour luma (or 255 *
/// albedo), each pixel storing the model point it shows. Throws std::invalid_argument for a
/// model without colours and albedo, or bad sizes.
std::vector<SiftView> RenderSiftViews(const geometry::PointCloud& model, int num_views,
                                      int view_size_px);

}  // namespace picking::detector
