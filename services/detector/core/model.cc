#include "services/detector/core/model.h"

#include "services/detector/core/appearance.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <type_traits>
#include <vector>

#include "libs/geometry/temp_path.h"

namespace picking::detector {
namespace {

constexpr char kMagic[8] = {'P', 'K', 'P', 'P', 'F', 'M', 'D', 'L'};

void ValidateOptions(const ObjectModelOptions& o) {
  auto positive = [](float v, const char* name) {
    if (!(v > 0.0f) || !std::isfinite(v)) {
      throw std::invalid_argument(std::string("ObjectModelOptions: ") + name +
                                  " must be positive, got " + std::to_string(v));
    }
  };
  positive(o.sampling_distance_rel, "sampling_distance_rel");
  positive(o.fine_voxel_rel, "fine_voxel_rel");
  positive(o.icp_voxel_rel, "icp_voxel_rel");
  positive(o.normal_radius_rel, "normal_radius_rel");
  positive(o.max_diameter_m, "max_diameter_m");
  if (o.cylinder_symmetry_steps < 1) {
    throw std::invalid_argument("ObjectModelOptions: cylinder_symmetry_steps must be >= 1, got " +
                                std::to_string(o.cylinder_symmetry_steps));
  }
  const auto symmetry = static_cast<int>(o.symmetry);
  if (symmetry < 0 || symmetry > static_cast<int>(ModelSymmetry::kSphere)) {
    throw std::invalid_argument("ObjectModelOptions: symmetry has no valid value");
  }
}

class Writer {
 public:
  explicit Writer(const std::string& path) : path_(path), out_(path, std::ios::binary) {
    if (!out_) throw ModelCacheError("model cache " + path + ": cannot open for writing");
  }
  template <typename T>
  void Pod(const T& v) {
    out_.write(reinterpret_cast<const char*>(&v), sizeof(T));
  }
  template <typename T>
  void Vector(const std::vector<T>& v) {
    Pod<std::uint64_t>(v.size());
    out_.write(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(T));
  }
  void Cloud(const geometry::PointCloud& c) {
    Vector(c.points);
    Vector(c.normals);
    Vector(c.intensities);
  }
  void Finish() {
    out_.flush();
    if (!out_) throw ModelCacheError("model cache " + path_ + ": write failed");
  }

 private:
  std::string path_;
  std::ofstream out_;
};

class Reader {
 public:
  explicit Reader(const std::string& path) : path_(path), in_(path, std::ios::binary) {
    if (!in_) throw ModelCacheError("model cache " + path + ": cannot open");
    in_.seekg(0, std::ios::end);
    remaining_ = static_cast<std::uint64_t>(in_.tellg());
    in_.seekg(0);
  }
  template <typename T>
  T Pod(const char* field) {
    T v{};
    Read(&v, sizeof(T), field);
    return v;
  }
  template <typename T>
  std::vector<T> Vector(const char* field) {
    const auto n = Pod<std::uint64_t>(field);
    if (n > remaining_ / sizeof(T)) {
      throw ModelCacheError("model cache " + path_ + ": field '" + field + "' claims " +
                            std::to_string(n) + " elements, more than the file holds");
    }
    std::vector<T> v(n);
    Read(v.data(), n * sizeof(T), field);
    return v;
  }
  geometry::PointCloud Cloud(const char* field) {
    geometry::PointCloud c;
    c.points = Vector<Eigen::Vector3f>(field);
    c.normals = Vector<Eigen::Vector3f>(field);
    if (c.normals.size() != c.points.size()) {
      throw ModelCacheError("model cache " + path_ + ": field '" + field +
                            "' has mismatched normals");
    }
    c.intensities = Vector<float>(field);
    if (!c.intensities.empty() && c.intensities.size() != c.points.size()) {
      throw ModelCacheError("model cache " + path_ + ": field '" + field +
                            "' has mismatched albedo");
    }
    c.width = static_cast<std::uint32_t>(c.points.size());
    return c;
  }
  void ExpectEnd() {
    if (remaining_ != 0) {
      throw ModelCacheError("model cache " + path_ + ": " + std::to_string(remaining_) +
                            " trailing bytes");
    }
  }
  const std::string& path() const { return path_; }

 private:
  void Read(void* dst, std::uint64_t bytes, const char* field) {
    if (bytes > remaining_) {
      throw ModelCacheError("model cache " + path_ + ": truncated in field '" + field + "'");
    }
    in_.read(static_cast<char*>(dst), static_cast<std::streamsize>(bytes));
    if (!in_) throw ModelCacheError("model cache " + path_ + ": read error in '" + field + "'");
    remaining_ -= bytes;
  }
  std::string path_;
  std::ifstream in_;
  std::uint64_t remaining_ = 0;
};

void WriteOptions(Writer& w, const ObjectModelOptions& o) {
  w.Pod(o.sampling_distance_rel);
  w.Pod(o.fine_voxel_rel);
  w.Pod(o.icp_voxel_rel);
  w.Pod(o.normal_radius_rel);
  w.Pod<std::uint8_t>(o.use_input_normals);
  w.Pod<std::int32_t>(static_cast<std::int32_t>(o.orientation));
  w.Pod(o.viewpoint);
  w.Pod<std::int32_t>(o.table.angle_bins);
  w.Pod<std::uint8_t>(o.table.store_planar_pairs);
  w.Pod(o.max_diameter_m);
  w.Pod<std::int32_t>(static_cast<std::int32_t>(o.symmetry));
  w.Pod<std::int32_t>(o.cylinder_symmetry_steps);
}

ObjectModelOptions ReadOptions(Reader& r) {
  ObjectModelOptions o;
  o.sampling_distance_rel = r.Pod<float>("sampling_distance_rel");
  o.fine_voxel_rel = r.Pod<float>("fine_voxel_rel");
  o.icp_voxel_rel = r.Pod<float>("icp_voxel_rel");
  o.normal_radius_rel = r.Pod<float>("normal_radius_rel");
  o.use_input_normals = r.Pod<std::uint8_t>("use_input_normals") != 0;
  const auto orientation = r.Pod<std::int32_t>("orientation");
  if (orientation < 0 || orientation > 1) {
    throw ModelCacheError("model cache " + r.path() + ": bad field 'orientation'");
  }
  o.orientation = static_cast<NormalOrientation>(orientation);
  o.viewpoint = r.Pod<Eigen::Vector3f>("viewpoint");
  o.table.angle_bins = r.Pod<std::int32_t>("angle_bins");
  o.table.store_planar_pairs = r.Pod<std::uint8_t>("store_planar_pairs") != 0;
  o.max_diameter_m = r.Pod<float>("max_diameter_m");
  const auto symmetry = r.Pod<std::int32_t>("symmetry");
  if (symmetry < 0 || symmetry > static_cast<std::int32_t>(ModelSymmetry::kSphere)) {
    throw ModelCacheError("model cache " + r.path() + ": bad field 'symmetry'");
  }
  o.symmetry = static_cast<ModelSymmetry>(symmetry);
  o.cylinder_symmetry_steps = r.Pod<std::int32_t>("cylinder_symmetry_steps");
  return o;
}

bool SameOptions(const ObjectModelOptions& a, const ObjectModelOptions& b) {
  return a.sampling_distance_rel == b.sampling_distance_rel &&
         a.fine_voxel_rel == b.fine_voxel_rel && a.icp_voxel_rel == b.icp_voxel_rel &&
         a.normal_radius_rel == b.normal_radius_rel && a.use_input_normals == b.use_input_normals &&
         a.orientation == b.orientation && a.viewpoint == b.viewpoint &&
         a.table.angle_bins == b.table.angle_bins &&
         a.table.store_planar_pairs == b.table.store_planar_pairs &&
         a.max_diameter_m == b.max_diameter_m && a.symmetry == b.symmetry &&
         a.cylinder_symmetry_steps == b.cylinder_symmetry_steps;
}

}  // namespace

std::uint64_t HashCloud(const geometry::PointCloud& cloud) {
  std::uint64_t h = 1469598103934665603ull;
  auto mix = [&h](const void* data, std::size_t bytes) {
    const auto* p = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < bytes; ++i) {
      h ^= p[i];
      h *= 1099511628211ull;
    }
  };
  mix(cloud.points.data(), cloud.points.size() * sizeof(Eigen::Vector3f));
  mix(cloud.normals.data(), cloud.normals.size() * sizeof(Eigen::Vector3f));
  mix(cloud.intensities.data(), cloud.intensities.size() * sizeof(float));
  return h;
}

std::vector<Eigen::Isometry3d> SymmetryRotations(ModelSymmetry symmetry, int cylinder_steps) {
  if (cylinder_steps < 1) {
    throw std::invalid_argument("SymmetryRotations: cylinder_steps must be >= 1, got " +
                                std::to_string(cylinder_steps));
  }
  std::vector<Eigen::Isometry3d> out{Eigen::Isometry3d::Identity()};
  const auto turn = [](double angle, const Eigen::Vector3d& axis) {
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() = Eigen::AngleAxisd(angle, axis).toRotationMatrix();
    return X;
  };
  switch (symmetry) {
    case ModelSymmetry::kNone:
    case ModelSymmetry::kSphere:
      break;
    case ModelSymmetry::kBox:
      for (int axis = 0; axis < 3; ++axis) {
        out.push_back(turn(M_PI, Eigen::Vector3d::Unit(axis)));
      }
      break;
    case ModelSymmetry::kCylinderX:
    case ModelSymmetry::kCylinderZ: {
      const Eigen::Vector3d axis = symmetry == ModelSymmetry::kCylinderX ? Eigen::Vector3d::UnitX()
                                                                         : Eigen::Vector3d::UnitZ();
      const Eigen::Vector3d across = axis.unitOrthogonal();
      for (int flip = 0; flip < 2; ++flip) {
        for (int k = 0; k < cylinder_steps; ++k) {
          if (flip == 0 && k == 0) continue;
          Eigen::Isometry3d X = turn(2.0 * M_PI * k / cylinder_steps, axis);
          if (flip == 1) X = X * turn(M_PI, across);
          out.push_back(X);
        }
      }
      break;
    }
  }
  return out;
}

std::string ToString(ModelSymmetry symmetry) {
  switch (symmetry) {
    case ModelSymmetry::kNone:
      return "none";
    case ModelSymmetry::kBox:
      return "box";
    case ModelSymmetry::kCylinderX:
      return "cylinder-x";
    case ModelSymmetry::kCylinderZ:
      return "cylinder-z";
    case ModelSymmetry::kSphere:
      return "sphere";
  }
  return "none";
}

ModelSymmetry ModelSymmetryFromString(const std::string& name) {
  for (ModelSymmetry s : {ModelSymmetry::kNone, ModelSymmetry::kBox, ModelSymmetry::kCylinderX,
                          ModelSymmetry::kCylinderZ, ModelSymmetry::kSphere}) {
    if (ToString(s) == name) return s;
  }
  throw std::invalid_argument("model symmetry '" + name +
                              "' is not none, box, cylinder-x, cylinder-z or sphere");
}

ObjectModel::ObjectModel(const geometry::PointCloud& cloud_M, const ObjectModelOptions& options)
    : options_(options) {
  ValidateOptions(options);
  if (cloud_M.empty()) throw std::invalid_argument("ObjectModel: the model cloud is empty");
  if (options.use_input_normals && !cloud_M.has_normals()) {
    throw std::invalid_argument("ObjectModel: use_input_normals set but the cloud has no normals");
  }
  CheckCloudChannels(cloud_M, "ObjectModel");
  for (std::size_t i = 0; i < cloud_M.intensities.size(); ++i) {
    const float a = cloud_M.intensities[i];
    if (!(a >= 0.0f && a <= 1.0f)) {
      throw std::invalid_argument("ObjectModel: albedo (intensities[" + std::to_string(i) + "]) " +
                                  std::to_string(a) + " is not in [0, 1]");
    }
  }
  source_hash_ = HashCloud(cloud_M);
  geometry::PointCloud valid = RemoveInvalidPoints(cloud_M);
  if (!options.use_input_normals) valid.normals.clear();
  if (valid.size() < 3) {
    throw std::invalid_argument("ObjectModel: the model cloud has " + std::to_string(valid.size()) +
                                " finite points, need >= 3");
  }
  // Diameter from a coarse voxel grid (error below one coarse voxel) to keep it O(n).
  Eigen::Vector3f lo = valid.points.front(), hi = lo;
  for (const auto& p : valid.points) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  const float box_diagonal = (hi - lo).norm();
  if (!(box_diagonal > 0.0f)) throw std::invalid_argument("ObjectModel: all points coincide");
  if (box_diagonal > 3.0f * options.max_diameter_m) {
    throw std::invalid_argument(
        "ObjectModel: model extent " + std::to_string(box_diagonal) + " m exceeds max_diameter_m " +
        std::to_string(options.max_diameter_m) + " (is the cloud in millimetres?)");
  }
  diameter_m_ = CloudDiameter(VoxelAverage(valid, box_diagonal / 100.0f).points);
  if (diameter_m_ > options.max_diameter_m) {
    throw std::invalid_argument("ObjectModel: model diameter " + std::to_string(diameter_m_) +
                                " m exceeds max_diameter_m " +
                                std::to_string(options.max_diameter_m) +
                                " (is the cloud in millimetres?)");
  }
  sampling_distance_m_ = diameter_m_ * options.sampling_distance_rel;
  fine_ = VoxelAverage(valid, fine_voxel_m());
  if (!options.use_input_normals) {
    PcaNormalOptions normal_options;
    normal_options.radius_m = normal_radius_m();
    normal_options.orientation = options.orientation;
    normal_options.viewpoint = options.viewpoint;
    fine_ = EstimatePcaNormals(fine_, normal_options);
  }
  fine_.colors.clear();
  if (fine_.size() < 3) {
    throw std::invalid_argument(
        "ObjectModel: too few points with normals; the cloud is too "
        "sparse for normal_radius_rel");
  }
  icp_ = VoxelAverage(fine_, diameter_m_ * options.icp_voxel_rel);
  geometry::PointCloud sampled = VoxelAverage(fine_, sampling_distance_m_);
  sampled.intensities.clear();
  if (options.symmetry == ModelSymmetry::kSphere) {
    // A sphere's orientation is not fixed by its shape, so no pose can be checked against
    // its printing.
    fine_.intensities.clear();
    icp_.intensities.clear();
  }
  if (fine_.has_intensities()) MaskEdgeAlbedo();
  table_ = PpfTable(std::move(sampled), diameter_m_, sampling_distance_m_, options.table);
  Finish();
}

void ObjectModel::MaskEdgeAlbedo() {
  // Printed packaging (and the simulator's texture) has a border along every edge, and a
  // scan's intensity is unreliable where the surface bends away: both would correlate for
  // any item of the same shape, so the albedo near sharp edges is left out (NaN).
  const float radius = std::clamp(0.05f * diameter_m_, 0.003f, 0.012f);
  const float min_cos = std::cos(static_cast<float>(M_PI) / 6.0f);
  const KdTree tree(fine_.points);
  std::vector<std::int32_t> neighbours;
  // Opposite-facing neighbours are the other side of a thin wall (a book's covers), not an
  // edge.
  const float max_cos_opposite = -0.7f;
  const auto near_edge = [&](const Eigen::Vector3f& p, const Eigen::Vector3f& n) {
    tree.RadiusSearch(p, radius, &neighbours);
    for (std::int32_t j : neighbours) {
      const float c = fine_.normals[j].dot(n);
      if (c < min_cos && c > max_cos_opposite) return true;
    }
    return false;
  };
  const float nan = std::numeric_limits<float>::quiet_NaN();
  std::vector<float> fine_albedo = fine_.intensities;
  for (std::size_t i = 0; i < fine_.size(); ++i) {
    if (near_edge(fine_.points[i], fine_.normals[i])) fine_albedo[i] = nan;
  }
  for (std::size_t i = 0; i < icp_.size(); ++i) {
    if (near_edge(icp_.points[i], icp_.normals[i])) icp_.intensities[i] = nan;
  }
  fine_.intensities = std::move(fine_albedo);
}

void ObjectModel::Finish() {
  albedo_stddev_ = 0.0f;
  if (fine_.has_intensities()) {
    double sum = 0.0, sum_sq = 0.0, n = 0.0;
    for (float a : fine_.intensities) {
      if (!std::isfinite(a)) continue;
      sum += a;
      sum_sq += static_cast<double>(a) * a;
      n += 1.0;
    }
    n = std::max(n, 1.0);
    albedo_stddev_ =
        static_cast<float>(std::sqrt(std::max(0.0, sum_sq / n - (sum / n) * (sum / n))));
  }
  fine_tree_ = KdTree(fine_.points);
  fine_patches_.clear();
  fine_patches_.reserve(fine_.size());
  for (std::size_t i = 0; i < fine_.size(); ++i) {
    fine_patches_.push_back(fine_.has_normals() ? SurfacePatch(fine_.normals[i]) : 255);
  }
  symmetries_ = SymmetryRotations(options_.symmetry, options_.cylinder_symmetry_steps);
}

void ObjectModel::Save(const std::string& path) const {
  const std::string tmp = geometry::TemporaryPathBeside(path);
  {
    Writer w(tmp);
    w.Pod(kMagic);
    w.Pod(kCacheVersion);
    WriteOptions(w, options_);
    w.Pod(diameter_m_);
    w.Pod(sampling_distance_m_);
    w.Pod(source_hash_);
    w.Cloud(fine_);
    w.Cloud(icp_);
    w.Cloud(table_.sampled_model());
    w.Vector(table_.offsets());
    w.Vector(table_.entries());
    w.Finish();
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    throw ModelCacheError("model cache " + path + ": cannot rename the written file into place");
  }
}

ObjectModel ObjectModel::Load(const std::string& path) {
  Reader r(path);
  char magic[8];
  for (char& c : magic) c = r.Pod<char>("magic");
  if (std::memcmp(magic, kMagic, sizeof(kMagic)) != 0) {
    throw ModelCacheError("model cache " + path + ": not a PPF model cache (bad magic)");
  }
  const auto version = r.Pod<std::uint32_t>("version");
  if (version != kCacheVersion) {
    throw ModelCacheError("model cache " + path + ": format version " + std::to_string(version) +
                          ", this build reads version " + std::to_string(kCacheVersion) +
                          "; rebuild the model");
  }
  ObjectModel m;
  m.options_ = ReadOptions(r);
  m.diameter_m_ = r.Pod<float>("diameter_m");
  m.sampling_distance_m_ = r.Pod<float>("sampling_distance_m");
  m.source_hash_ = r.Pod<std::uint64_t>("source_hash");
  m.fine_ = r.Cloud("fine_cloud");
  m.icp_ = r.Cloud("icp_cloud");
  geometry::PointCloud sampled = r.Cloud("sampled_cloud");
  auto offsets = r.Vector<std::uint32_t>("offsets");
  auto entries = r.Vector<PpfTable::Entry>("entries");
  r.ExpectEnd();
  try {
    ValidateOptions(m.options_);
    m.table_ = PpfTable(std::move(sampled), m.diameter_m_, m.sampling_distance_m_,
                        m.options_.table.angle_bins, m.options_.table.store_planar_pairs,
                        std::move(offsets), std::move(entries));
    if (m.icp_.has_intensities() != m.fine_.has_intensities()) {
      throw std::invalid_argument("the fine and ICP clouds disagree on the albedo channel");
    }
    m.Finish();
  } catch (const std::invalid_argument& e) {
    throw ModelCacheError("model cache " + path + ": inconsistent: " + e.what());
  }
  return m;
}

ObjectModel ObjectModel::LoadOrBuild(const std::string& path, const geometry::PointCloud& cloud_M,
                                     const ObjectModelOptions& options, bool* rebuilt) {
  try {
    ObjectModel m = Load(path);
    if (m.source_hash_ == HashCloud(cloud_M) && SameOptions(m.options_, options)) {
      if (rebuilt != nullptr) *rebuilt = false;
      return m;
    }
  } catch (const ModelCacheError&) {
    // Missing, stale or corrupt: rebuilt below.
  }
  ObjectModel m(cloud_M, options);
  m.Save(path);
  if (rebuilt != nullptr) *rebuilt = true;
  return m;
}

}  // namespace picking::detector
