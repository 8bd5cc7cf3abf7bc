#include "services/detector/core/model_library.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>
#include <stdexcept>
#include <utility>

#include "libs/apc/catalogue.h"
#include "libs/errors/errors.h"
#include "libs/geometry/point_cloud_io.h"
#include "libs/world/item_shapes.h"
#include "libs/world/scanned_model.h"
#include "services/detector/core/appearance.h"
#include "services/detector/core/ppf_cloud.h"
#include "services/detector/core/verify.h"

namespace picking::detector {
namespace {

using Json = nlohmann::json;
namespace fs = std::filesystem;

[[noreturn]] void Fail(const std::string& source, const std::string& field,
                       const std::string& what) {
  throw std::invalid_argument(source + ": field '" + field + "': " + what);
}

std::size_t LineOf(const std::string& text, std::size_t byte) {
  byte = std::min(byte, text.size());
  return 1 + static_cast<std::size_t>(std::count(text.begin(), text.begin() + byte, '\n'));
}

const std::set<std::string> kConfigKeys = {"preferred", "fallbacks", "thresholds",
                                           "method_thresholds", "time_budget_s"};
const std::set<std::string> kModelKeys = {"source", "frame", "symmetry", "axis", "fold"};

std::string GetString(const Json& node, const std::string& key, const std::string& source,
                      const std::string& path) {
  const Json& value = node.at(key);
  if (!value.is_string()) Fail(source, path + "." + key, "expected a string");
  return value.get<std::string>();
}

ModelSpec ParseModel(const std::string& item, const Json& node, const std::string& source,
                     const fs::path& root) {
  const std::string path = "models." + item;
  if (!node.is_object()) Fail(source, path, "expected an object");
  for (const auto& [key, value] : node.items()) {
    (void)value;
    if (kConfigKeys.count(key) == 0 && kModelKeys.count(key) == 0) {
      Fail(source, path + "." + key, "unknown key");
    }
  }
  if (!node.contains("source")) Fail(source, path + ".source", "missing");
  ModelSpec spec;
  spec.item = item;
  spec.source = GetString(node, "source", source, path);
  const std::string& s = spec.source;
  if (s.rfind("scan:", 0) == 0) {
    spec.kind = ModelSourceKind::kScan;
    const std::string file = s.substr(5);
    if (file.empty()) Fail(source, path + ".source", "'scan:' needs a file path");
    const fs::path p(file);
    spec.scan_path = (p.is_absolute() ? p : root / p).lexically_normal().string();
  } else if (s == "shape:box") {
    spec.kind = ModelSourceKind::kShapeBox;
    spec.symmetry = "box";
  } else if (s == "shape:cylinder") {
    spec.kind = ModelSourceKind::kShapeCylinder;
    spec.symmetry = "cylinder-x";
  } else if (s == "shape:sphere") {
    spec.kind = ModelSourceKind::kShapeSphere;
    spec.symmetry = "sphere";
  } else {
    Fail(source, path + ".source",
         "'" + s + "' is not scan:<path>, shape:box, shape:cylinder or shape:sphere");
  }
  const bool is_shape = spec.kind != ModelSourceKind::kScan;
  if (node.contains("frame")) {
    if (is_shape) Fail(source, path + ".frame", "only scans have a frame setting");
    const std::string frame = GetString(node, "frame", source, path);
    if (frame == "file") {
      spec.frame = ScanFrame::kFile;
    } else if (frame == "item") {
      spec.frame = ScanFrame::kItem;
    } else {
      Fail(source, path + ".frame", "'" + frame + "' is not 'file' or 'item'");
    }
  }
  if (node.contains("axis")) {
    if (spec.kind != ModelSourceKind::kShapeCylinder) {
      Fail(source, path + ".axis", "only shape:cylinder has an axis");
    }
    const std::string axis = GetString(node, "axis", source, path);
    if (axis != "long" && axis != "short") {
      Fail(source, path + ".axis", "'" + axis + "' is not 'long' or 'short'");
    }
    spec.cylinder_axis_long = axis == "long";
    spec.symmetry = spec.cylinder_axis_long ? "cylinder-x" : "cylinder-z";
  }
  if (node.contains("fold")) {
    if (!is_shape) Fail(source, path + ".fold", "only shapes can be folded");
    const Json& fold = node["fold"];
    if (!fold.is_array() || fold.size() != 2 || !fold[0].is_number_integer() ||
        !fold[1].is_number_integer() || fold[0].get<int>() < 1 || fold[1].get<int>() < 1) {
      Fail(source, path + ".fold", "expected [n_long, n_middle], integers >= 1");
    }
    spec.fold_long = fold[0].get<int>();
    spec.fold_middle = fold[1].get<int>();
  }
  if (node.contains("symmetry")) {
    spec.symmetry = GetString(node, "symmetry", source, path);
    if (spec.symmetry.empty()) Fail(source, path + ".symmetry", "empty");
  }
  return spec;
}

geometry::PointCloud ShapeCloud(const ModelSpec& spec, const ModelLibraryOptions& options) {
  const std::string catalogue_path =
      options.catalogue_path.empty() ? apc::DefaultCataloguePath() : options.catalogue_path;
  const apc::Catalogue catalogue = apc::Catalogue::FromCsvFile(catalogue_path);
  const apc::Item* item = catalogue.find(spec.item);
  if (item == nullptr) {
    throw std::runtime_error("model '" + spec.item + "': source '" + spec.source +
                             "' needs a catalogue item of that name (catalogue " + catalogue_path +
                             ")");
  }
  world::ItemShape shape;
  switch (spec.kind) {
    case ModelSourceKind::kShapeBox:
      shape.kind = world::ShapeKind::kBox;
      break;
    case ModelSourceKind::kShapeCylinder:
      shape.kind = world::ShapeKind::kCylinder;
      break;
    case ModelSourceKind::kShapeSphere:
      shape.kind = world::ShapeKind::kSphere;
      break;
    case ModelSourceKind::kScan:
      throw std::logic_error("ShapeCloud: not a shape");
  }
  shape.axis_along_long_side = spec.cylinder_axis_long;
  shape.fold_long = spec.fold_long;
  shape.fold_middle = spec.fold_middle;
  // The printed texture (albedo, pattern) as the simulator paints it, from the shape table.
  std::string table_path = options.shape_table_path;
  if (table_path.empty()) {
    const std::string default_path = world::DefaultShapeTablePath();
    if (fs::exists(default_path)) table_path = default_path;
  }
  if (!table_path.empty()) {
    const world::ItemShape painted =
        world::ShapeTable::FromYamlFile(table_path, catalogue).at(spec.item);
    shape.albedo = painted.albedo;
    shape.pattern_albedo = painted.pattern_albedo;
    shape.texture = painted.texture;
    shape.pattern_period_m = painted.pattern_period_m;
  }
  const world::TriangleMesh mesh = world::MakePrimitiveItemMesh(*item, shape);
  return SampleTexturedMeshSurface(mesh, options.shape_spacing_m, /*seed=*/1);
}

std::string SafeFileName(const std::string& item) {
  std::string out;
  for (char c : item) {
    out += (std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-') ? c : '_';
  }
  return out;
}

bool ChainHas(const ObjectConfig& config, Method method) {
  const auto order = config.Order();
  return std::find(order.begin(), order.end(), method) != order.end();
}

}  // namespace

std::string ModelSpec::SourceKindName() const {
  return kind == ModelSourceKind::kScan ? "scan" : "shape";
}

ModelManifest ModelManifest::LoadFile(const std::string& path, const std::string& data_dir) {
  std::ifstream in(path);
  if (!in) throw std::invalid_argument("model manifest '" + path + "': cannot read the file");
  std::stringstream text;
  text << in.rdbuf();
  const fs::path dir = fs::absolute(fs::path(path)).parent_path();
  return Parse(text.str(), path, dir.string(), data_dir);
}

ModelManifest ModelManifest::Parse(const std::string& text, const std::string& source_name,
                                   const std::string& manifest_dir, const std::string& data_dir) {
  Json root;
  try {
    root = Json::parse(text);
  } catch (const Json::parse_error& e) {
    throw std::invalid_argument(source_name + ":" + std::to_string(LineOf(text, e.byte)) +
                                ": invalid JSON: " + e.what());
  }
  if (!root.is_object()) Fail(source_name, "", "expected a JSON object");
  for (const auto& [key, value] : root.items()) {
    (void)value;
    if (key != "version" && key != "root" && key != "default" && key != "models") {
      Fail(source_name, key, "unknown key");
    }
  }
  if (root.contains("version") &&
      (!root["version"].is_number_integer() || root["version"].get<int>() != 1)) {
    Fail(source_name, "version", "only version 1 is understood");
  }
  fs::path base = fs::path(data_dir);
  if (root.contains("root")) {
    if (!root["root"].is_string()) Fail(source_name, "root", "expected a path string");
    const fs::path r(root["root"].get<std::string>());
    base = r.is_absolute() ? r : fs::path(manifest_dir) / r;
  }
  if (!root.contains("models") || !root["models"].is_object() || root["models"].empty()) {
    Fail(source_name, "models", "expected a non-empty object of item -> model");
  }

  ModelManifest manifest;
  manifest.source_name_ = source_name;
  // The detection part goes through DetectorConfig's own parser (one format, one set of
  // rules for inheritance and validation).
  Json config = Json::object();
  if (root.contains("default")) config["default"] = root["default"];
  config["objects"] = Json::object();
  for (const auto& [item, node] : root["models"].items()) {
    if (item.empty()) Fail(source_name, "models", "empty item name");
    manifest.models_.push_back(ParseModel(item, node, source_name, base));
    Json object = Json::object();
    for (const auto& [key, value] : node.items()) {
      if (kConfigKeys.count(key) != 0) object[key] = value;
    }
    config["objects"][item] = object;
  }
  try {
    manifest.config_ = DetectorConfig::Parse(config.dump(), source_name);
  } catch (const std::exception& e) {
    throw std::invalid_argument(std::string(e.what()) +
                                " (detection settings: 'objects.<item>' is 'models.<item>')");
  }
  return manifest;
}

const ModelSpec* ModelManifest::find(const std::string& item) const {
  for (const auto& m : models_) {
    if (m.item == item) return &m;
  }
  return nullptr;
}

std::string DefaultDetectorCacheDir() {
  if (const char* env = std::getenv("PICKING_CACHE_DIR"); env != nullptr && *env != '\0') {
    return (fs::path(env) / "detector").string();
  }
  if (const char* home = std::getenv("HOME"); home != nullptr && *home != '\0') {
    return (fs::path(home) / ".cache" / "picking" / "detector").string();
  }
  return (fs::temp_directory_path() / "picking-cache" / "detector").string();
}

geometry::PointCloud ModelSourceCloud(const ModelSpec& spec, const ModelLibraryOptions& options) {
  if (spec.kind != ModelSourceKind::kScan) return ShapeCloud(spec, options);
  geometry::PointCloud cloud = geometry::ReadPointCloud(spec.scan_path);
  if (cloud.empty()) {
    throw std::runtime_error("model '" + spec.item + "': '" + spec.scan_path + "' has no points");
  }
  // Models are unorganised; channels this detector does not use are dropped.
  cloud.width = static_cast<std::uint32_t>(cloud.size());
  cloud.height = 1;
  cloud.intensities.clear();
  IntensitiesFromColors(&cloud);  // The scan's colour is its albedo.
  if (spec.frame == ScanFrame::kItem) {
    const std::string cache_dir =
        (fs::path(options.cache_dir.empty() ? DefaultDetectorCacheDir() : options.cache_dir) /
         "scans")
            .string();
    const world::ScannedModel scanned = world::LoadScannedModelCached(spec.scan_path, cache_dir);
    const Eigen::Isometry3f X_ItemScan = scanned.X_ScanItem.inverse().cast<float>();
    for (auto& p : cloud.points) p = X_ItemScan * p;
    for (auto& n : cloud.normals) n = X_ItemScan.linear() * n;
  }
  return cloud;
}

std::vector<SiftView> RenderSiftViews(const geometry::PointCloud& model, int num_views,
                                      int view_size_px) {
  const bool colours = model.has_colors() && model.colors.size() == model.points.size();
  const bool albedo = model.has_intensities() && model.intensities.size() == model.points.size();
  if (!colours && !albedo) {
    throw std::invalid_argument("RenderSiftViews: the model has no colours or albedo");
  }
  if (num_views < 1) throw std::invalid_argument("RenderSiftViews: num_views must be >= 1");
  if (view_size_px < 32) throw std::invalid_argument("RenderSiftViews: view_size_px must be >= 32");
  Eigen::Vector3f centre = Eigen::Vector3f::Zero();
  std::size_t n = 0;
  for (const auto& p : model.points) {
    if (!p.allFinite()) continue;
    centre += p;
    ++n;
  }
  if (n == 0) throw std::invalid_argument("RenderSiftViews: the model has no finite point");
  centre /= static_cast<float>(n);
  float radius = 0.0f;
  for (const auto& p : model.points) {
    if (p.allFinite()) radius = std::max(radius, (p - centre).norm());
  }
  if (!(radius > 0.0f)) throw std::invalid_argument("RenderSiftViews: the model is a point");
  const float pixel_m = 2.0f * radius / static_cast<float>(view_size_px);
  const double spacing_m = MeanPointSpacing(model);
  // Each point covers a square of about its own spacing, so the surface has no holes.
  const int splat = std::max(0, static_cast<int>(std::ceil(0.75 * spacing_m / pixel_m)) - 1);
  const int size = view_size_px;
  const float nan = std::numeric_limits<float>::quiet_NaN();

  std::vector<SiftView> views;
  const std::vector<Eigen::Vector3d> directions = FibonacciSphere(num_views);
  for (std::size_t vi = 0; vi < directions.size(); ++vi) {
    // Orthographic view looking along -d (from outside the model toward its centre).
    const Eigen::Vector3f d = directions[vi].cast<float>();
    const Eigen::Vector3f helper =
        std::abs(d.z()) < 0.9f ? Eigen::Vector3f::UnitZ() : Eigen::Vector3f::UnitX();
    const Eigen::Vector3f right = helper.cross(d).normalized();
    const Eigen::Vector3f down = d.cross(right).normalized();
    std::vector<float> depth(static_cast<std::size_t>(size) * size,
                             std::numeric_limits<float>::infinity());
    std::vector<int> owner(depth.size(), -1);
    for (std::size_t i = 0; i < model.points.size(); ++i) {
      const Eigen::Vector3f q = model.points[i] - centre;
      if (!q.allFinite()) continue;
      const float z = radius - q.dot(d);  // Distance from the image plane, >= 0.
      const int u = static_cast<int>(std::lround(q.dot(right) / pixel_m + 0.5f * (size - 1)));
      const int v = static_cast<int>(std::lround(q.dot(down) / pixel_m + 0.5f * (size - 1)));
      for (int dv = -splat; dv <= splat; ++dv) {
        for (int du = -splat; du <= splat; ++du) {
          const int uu = u + du;
          const int vv = v + dv;
          if (uu < 0 || vv < 0 || uu >= size || vv >= size) continue;
          const std::size_t k = static_cast<std::size_t>(vv) * size + uu;
          if (z < depth[k]) {
            depth[k] = z;
            owner[k] = static_cast<int>(i);
          }
        }
      }
    }
    SiftView view;
    view.name = "view_" + std::to_string(vi);
    view.image.width = size;
    view.image.height = size;
    view.image.pixels.assign(depth.size(), 128);  // Mid grey: weak edges at the silhouette.
    view.p_ItemPixel.assign(depth.size(), Eigen::Vector3f::Constant(nan));
    for (std::size_t k = 0; k < depth.size(); ++k) {
      if (owner[k] < 0) continue;
      const float grey =
          255.0f * (colours ? ColorLuma(model.colors[owner[k]]) : model.intensities[owner[k]]);
      view.image.pixels[k] = static_cast<std::uint8_t>(
          std::clamp(std::isfinite(grey) ? std::lround(grey) : 128L, 0L, 255L));
      view.p_ItemPixel[k] = model.points[owner[k]];
    }
    views.push_back(std::move(view));
  }
  return views;
}

struct ModelLibrary::Slot {
  std::mutex mutex;  // Held while building: one build per item.
  std::shared_ptr<const LoadedModel> model;
};

ModelLibrary::ModelLibrary(ModelManifest manifest, ModelLibraryOptions options)
    : manifest_(std::move(manifest)), options_(std::move(options)) {
  if (!(options_.shape_spacing_m > 0.0)) {
    throw std::invalid_argument("ModelLibrary: shape_spacing_m must be positive");
  }
  if (options_.sift_views < 1) throw std::invalid_argument("ModelLibrary: sift_views must be >= 1");
  if (options_.sift_view_size_px < 32) {
    throw std::invalid_argument("ModelLibrary: sift_view_size_px must be >= 32");
  }
  if (options_.cache_dir.empty()) options_.cache_dir = DefaultDetectorCacheDir();
  for (const auto& spec : manifest_.models()) slots_[spec.item] = std::make_unique<Slot>();
}

ModelLibrary::~ModelLibrary() = default;

namespace {
// The error for an item the manifest does not name. The name is the caller's and may be
// any length: it is quoted cut, so that the status stays readable.
NotFoundError UnknownItem(const std::string& item, const std::string& manifest) {
  constexpr std::size_t kMaxQuoted = 64;
  const std::string quoted = item.size() <= kMaxQuoted ? item : item.substr(0, kMaxQuoted) + "...";
  return NotFoundError("unknown item '" + quoted + "': not in the model manifest " + manifest);
}
}  // namespace

ObjectConfig ModelLibrary::ConfigFor(const std::string& item) const {
  return manifest_.config().ForItem(item);
}

std::shared_ptr<const LoadedModel> ModelLibrary::GetIfLoaded(const std::string& item) const {
  const auto it = slots_.find(item);
  if (it == slots_.end()) {
    throw UnknownItem(item, manifest_.source_name());
  }
  std::unique_lock<std::mutex> lock(it->second->mutex, std::try_to_lock);
  if (!lock.owns_lock()) return nullptr;  // Being built right now.
  return it->second->model;
}

std::shared_ptr<const LoadedModel> ModelLibrary::Get(const std::string& item) const {
  const auto it = slots_.find(item);
  if (it == slots_.end()) {
    throw UnknownItem(item, manifest_.source_name());
  }
  std::lock_guard<std::mutex> lock(it->second->mutex);
  if (!it->second->model) {
    try {
      it->second->model = Build(*manifest_.find(item));
    } catch (const std::exception& e) {
      // A model that cannot be built is the server's problem, not the caller's input.
      throw std::runtime_error("model '" + item + "' (" + manifest_.find(item)->source +
                               ") cannot be built: " + e.what());
    }
  }
  return it->second->model;
}

void ModelLibrary::LoadAll() const {
  for (const auto& spec : manifest_.models()) Get(spec.item);
}

std::shared_ptr<const LoadedModel> ModelLibrary::Build(const ModelSpec& spec) const {
  const auto start = std::chrono::steady_clock::now();
  auto loaded = std::make_shared<LoadedModel>();
  loaded->spec = spec;
  loaded->config = ConfigFor(spec.item);
  geometry::PointCloud cloud = ModelSourceCloud(spec, options_);
  loaded->source_points = cloud.size();

  // The PPF model: trained once, then read from the versioned cache (rebuilt when the source
  // cloud, the options or the format changed).
  std::error_code ec;
  fs::create_directories(options_.cache_dir, ec);
  if (ec) {
    throw std::runtime_error("model cache folder '" + options_.cache_dir +
                             "' cannot be created: " + ec.message());
  }
  const std::string cache_path =
      (fs::path(options_.cache_dir) /
       (SafeFileName(spec.item) + ".ppf.v" + std::to_string(ObjectModel::kCacheVersion) + ".bin"))
          .string();
  // Geometry and albedo (the shape's texture, a scan's colour luma); colours stay with the
  // SIFT views.
  geometry::PointCloud geometry_only = cloud;
  geometry_only.colors.clear();
  ObjectModelOptions object_options = options_.object;
  try {
    object_options.symmetry = ModelSymmetryFromString(spec.symmetry);
  } catch (const std::invalid_argument&) {
    object_options.symmetry = ModelSymmetry::kNone;  // A free-form note: no turns tried.
  }
  if (spec.kind != ModelSourceKind::kScan) {
    // Sampled shapes carry exact outward face normals.
    object_options.use_input_normals = true;
  } else {
    geometry_only.normals.clear();
  }
  bool rebuilt = false;
  loaded->object = std::make_shared<const ObjectModel>(
      ObjectModel::LoadOrBuild(cache_path, geometry_only, object_options, &rebuilt));
  loaded->object_from_cache = !rebuilt;

  if (ChainHas(loaded->config, Method::kRangeTemplates)) {
    loaded->templates =
        std::make_shared<const RangeTemplateSet>(loaded->object->icp_cloud(), options_.templates);
  }
  if (ChainHas(loaded->config, Method::kSift) && (cloud.has_colors() || cloud.has_intensities())) {
    try {
      loaded->sift = std::make_shared<const SiftModel>(
          RenderSiftViews(cloud, options_.sift_views, options_.sift_view_size_px));
    } catch (const std::invalid_argument&) {
      // No view has a usable feature (an untextured model): the SIFT method finds nothing.
      loaded->sift = nullptr;
    }
  }
  loaded->build_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return loaded;
}

}  // namespace picking::detector
