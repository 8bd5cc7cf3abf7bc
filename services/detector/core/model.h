#pragma once

#include <Eigen/Geometry>

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include "libs/geometry/point_cloud.h"
#include "services/detector/core/kdtree.h"
#include "services/detector/core/ppf.h"
#include "services/detector/core/ppf_cloud.h"

namespace picking::detector {

/// Rotational symmetry of a model's shape about its frame's origin (the catalogue
/// primitives: origin at the centre of the bounding box, axes along the box sides).
enum class ModelSymmetry {
  kNone,       ///< No symmetry used (scanned models).
  kBox,        ///< A box: the identity and the three 180 degree turns about x, y and z.
  kCylinderX,  ///< A cylinder along x: turns about x in steps, and the same turned end over end.
  kCylinderZ,  ///< A cylinder along z.
  kSphere,     ///< A sphere: every rotation; only the identity is tried.
};

/// The rotations R_MM' that map the model's shape onto itself (identity first); a pose
/// X_SM of the model is as good as X_SM * R_MM' geometrically. Cylinders turn about their axis
/// in `cylinder_steps` (>= 1) equal steps, each also turned end over end (2 * steps
/// rotations). Throws std::invalid_argument for cylinder_steps < 1.
std::vector<Eigen::Isometry3d> SymmetryRotations(ModelSymmetry symmetry, int cylinder_steps);

/// "none", "box", "cylinder-x", "cylinder-z", "sphere" (the manifest's spelling).
std::string ToString(ModelSymmetry symmetry);
/// Inverse of ToString. Throws std::invalid_argument naming the bad value.
ModelSymmetry ModelSymmetryFromString(const std::string& name);

/// How an ObjectModel is derived from a model cloud. Lengths relative to the model diameter.
struct ObjectModelOptions {
  /// PPF sampling distance and distance step (Drost's tau_d), fraction of the diameter.
  /// 0.05 is Drost's default: on the simulated shelf bins and the PCL milk scene it finds as
  /// many true poses as 0.03 and votes several times faster (benchmarks/RESULTS.md).
  float sampling_distance_rel = 0.05f;
  /// Voxel of the fine cloud used for normals, fraction of the diameter.
  float fine_voxel_rel = 0.01f;
  /// Voxel of the cloud used by ICP and verification, fraction of the diameter.
  float icp_voxel_rel = 0.015f;
  /// Radius of the normal plane fit, fraction of the diameter.
  float normal_radius_rel = 0.035f;
  /// Keep the input normals instead of estimating them (input must have unit normals).
  bool use_input_normals = false;
  /// Sign of estimated normals: outward from the centroid suits closed or convex models.
  NormalOrientation orientation = NormalOrientation::kOutwardFromCentroid;
  Eigen::Vector3f viewpoint = Eigen::Vector3f::Zero();  ///< For kTowardViewpoint, metres.
  PpfTableOptions table;
  /// Models larger than this are rejected (a cloud in millimetres, or a whole scene).
  float max_diameter_m = 2.0f;
  /// Symmetry of the shape; hypotheses are also tried turned by its rotations, and the
  /// model's appearance (albedo) picks among them.
  ModelSymmetry symmetry = ModelSymmetry::kNone;
  /// Steps of a turn about a cylinder's axis tried for its appearance (>= 1).
  int cylinder_symmetry_steps = 36;
};

/// Thrown when a model cache file cannot be used: missing, truncated, another format
/// version or corrupt. what() names the file and the field.
class ModelCacheError final : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// A known object as the detector uses it: in the model frame M, metres. Holds the fine
/// cloud with normals, a coarser cloud for ICP and verification, and the PPF table trained
/// on the sampled cloud. When the input cloud has intensities they are the surface's albedo
/// (reflectance in [0, 1]: a primitive's printed texture, a scan's colour luma); the fine and
/// ICP clouds then carry it, voxel-averaged, in their `intensities`, NaN within about 5 % of
/// the diameter (3-12 mm) of a sharp edge (normals more than 30 degrees apart): a printed
/// border along the edges, which every package has, says nothing about which item it is. A
/// sphere (ModelSymmetry::kSphere) keeps no albedo: its shape does not fix its orientation.
class ObjectModel final {
 public:
  /// File format version of Save / Load; bumped whenever the layout or the meaning of a
  /// stored field changes.
  static constexpr std::uint32_t kCacheVersion = 2;

  /// Builds from a model cloud (points in M, metres; normals used only with
  /// use_input_normals; intensities, when present, the albedo in [0, 1]). Throws
  /// std::invalid_argument for an empty cloud, a cloud with no finite point, too few points for
  /// normals, a diameter above max_diameter_m, invalid options, albedo outside [0, 1] or too many
  /// sampled points.
  ObjectModel(const geometry::PointCloud& cloud_M, const ObjectModelOptions& options);

  /// Writes a versioned binary cache. Throws ModelCacheError when the file cannot be written.
  void Save(const std::string& path) const;

  /// Reads a cache written by Save. Throws ModelCacheError (file, field) when the file is
  /// missing, truncated, of another version or inconsistent.
  static ObjectModel Load(const std::string& path);

  /// Loads `path` when it holds a model of this version built from the same cloud with the
  /// same options; otherwise builds the model and rewrites the cache. `rebuilt` (optional)
  /// tells which happened.
  static ObjectModel LoadOrBuild(const std::string& path, const geometry::PointCloud& cloud_M,
                                 const ObjectModelOptions& options, bool* rebuilt = nullptr);

  const ObjectModelOptions& options() const { return options_; }
  float diameter_m() const { return diameter_m_; }
  float sampling_distance_m() const { return sampling_distance_m_; }
  float fine_voxel_m() const { return diameter_m_ * options_.fine_voxel_rel; }
  float normal_radius_m() const { return diameter_m_ * options_.normal_radius_rel; }
  /// Fingerprint (FNV-1a) of the input cloud the model was built from.
  std::uint64_t source_hash() const { return source_hash_; }
  const geometry::PointCloud& fine_cloud() const { return fine_; }
  const geometry::PointCloud& icp_cloud() const { return icp_; }
  const PpfTable& table() const { return table_; }
  /// True when the clouds carry the surface albedo in `intensities`.
  bool has_albedo() const { return fine_.has_intensities(); }
  /// Standard deviation of the fine cloud's finite albedo (0 without albedo): below a few percent
  /// the texture is uniform and says nothing about a pose.
  float albedo_stddev() const { return albedo_stddev_; }
  /// Search tree over fine_cloud().points (albedo look-ups at model-frame positions).
  const KdTree& fine_tree() const { return fine_tree_; }
  /// SurfacePatch (appearance.h) of each fine_cloud() normal: the faces the appearance
  /// comparison takes apart.
  const std::vector<std::uint8_t>& fine_patches() const { return fine_patches_; }
  /// SymmetryRotations(options().symmetry, options().cylinder_symmetry_steps).
  const std::vector<Eigen::Isometry3d>& symmetries() const { return symmetries_; }

 private:
  void MaskEdgeAlbedo();
  void Finish();

  ObjectModel() = default;

  ObjectModelOptions options_;
  float diameter_m_ = 0.0f;
  float sampling_distance_m_ = 0.0f;
  std::uint64_t source_hash_ = 0;
  geometry::PointCloud fine_;
  geometry::PointCloud icp_;
  PpfTable table_;
  float albedo_stddev_ = 0.0f;
  KdTree fine_tree_;
  std::vector<std::uint8_t> fine_patches_;
  std::vector<Eigen::Isometry3d> symmetries_;
};

/// FNV-1a over the point coordinates, normals and intensities of a cloud.
std::uint64_t HashCloud(const geometry::PointCloud& cloud);

}  // namespace picking::detector
