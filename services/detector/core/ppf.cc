#include "services/detector/core/ppf.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <map>
#include <numeric>
#include <stdexcept>
#include <string>
#include <unordered_map>
#include <utility>

#include "libs/parallel/parallel_for.h"
#include "services/detector/core/ppf_cloud.h"

namespace picking::detector {
namespace {

constexpr float kPi = static_cast<float>(M_PI);
constexpr std::size_t kMaxModelPoints = 8192;  // model_reference fits 13 bits of a vote code
constexpr int kCodeShift = 13;
constexpr std::uint32_t kCodeMask = (1u << kCodeShift) - 1;

float SafeAngle(const Eigen::Vector3f& a, const Eigen::Vector3f& b) {
  // atan2 of |a x b| and a.b is accurate near 0 and pi, unlike acos.
  return std::atan2(a.cross(b).norm(), a.dot(b));
}

void CheckUnitNormals(const geometry::PointCloud& cloud, const char* what) {
  CheckCloudChannels(cloud, what);
  if (!cloud.has_normals()) throw std::invalid_argument(std::string(what) + ": no normals");
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!cloud.points[i].allFinite() || !cloud.normals[i].allFinite() ||
        std::abs(cloud.normals[i].norm() - 1.0f) > 1e-3f) {
      throw std::invalid_argument(std::string(what) + ": point " + std::to_string(i) +
                                  " has a non-finite coordinate or a non-unit normal");
    }
  }
}

// atan2 with an absolute error below 2e-5 rad (a 7th order minimax polynomial of atan on
// [0, 1]); the voting quantises the angle in steps of several milliradians.
float FastAtan2(float y, float x) {
  const float ax = std::abs(x), ay = std::abs(y);
  const float hi = std::max(ax, ay);
  if (!(hi > 0.0f)) return 0.0f;
  const float a = std::min(ax, ay) / hi;
  const float s = a * a;
  float r = ((-0.0464964749f * s + 0.15931422f) * s - 0.327622764f) * s * a + a;
  if (ay > ax) r = 0.5f * kPi - r;
  if (x < 0.0f) r = kPi - r;
  return y < 0.0f ? -r : r;
}

Eigen::Isometry3d ToDouble(const Eigen::Isometry3f& T) {
  Eigen::Isometry3d out = Eigen::Isometry3d::Identity();
  out.linear() = T.linear().cast<double>();
  out.translation() = T.translation().cast<double>();
  return out;
}

Eigen::Isometry3d Orthonormalized(const Eigen::Isometry3d& X) {
  Eigen::Isometry3d out = X;
  out.linear() = Eigen::Quaterniond(X.linear()).normalized().toRotationMatrix();
  return out;
}

}  // namespace

Eigen::Vector4f ComputePpf(const Eigen::Vector3f& p1, const Eigen::Vector3f& n1,
                           const Eigen::Vector3f& p2, const Eigen::Vector3f& n2) {
  const Eigen::Vector3f d = p2 - p1;
  const float distance = d.norm();
  if (!(distance > 0.0f)) return Eigen::Vector4f::Constant(std::nanf(""));
  return {distance, SafeAngle(n1, d), SafeAngle(n2, d), SafeAngle(n1, n2)};
}

PpfQuantizer::PpfQuantizer(float distance_step_m, float max_distance_m, int angle_bins)
    : distance_step_m_(distance_step_m), max_distance_m_(max_distance_m), angle_bins_(angle_bins) {
  if (!(distance_step_m > 0.0f) || !std::isfinite(distance_step_m)) {
    throw std::invalid_argument("PpfQuantizer: distance_step_m must be positive, got " +
                                std::to_string(distance_step_m));
  }
  if (!(max_distance_m > 0.0f) || !std::isfinite(max_distance_m)) {
    throw std::invalid_argument("PpfQuantizer: max_distance_m must be positive, got " +
                                std::to_string(max_distance_m));
  }
  if (angle_bins < 4 || angle_bins > 360) {
    throw std::invalid_argument("PpfQuantizer: angle_bins must be in [4, 360], got " +
                                std::to_string(angle_bins));
  }
  angle_step_rad_ = 2.0f * kPi / static_cast<float>(angle_bins);
  angle_cells_ = (angle_bins + 1) / 2;
  const double cells = std::floor(max_distance_m / distance_step_m) + 1.0;
  const double keys = cells * angle_cells_ * angle_cells_ * angle_cells_;
  if (keys > static_cast<double>(1u << 31)) {
    throw std::invalid_argument("PpfQuantizer: " + std::to_string(keys) +
                                " keys; the distance step is too small for the diameter");
  }
  distance_cells_ = static_cast<int>(cells);
  num_keys_ = static_cast<std::uint32_t>(keys);
  right_angle_cell_ =
      std::clamp(static_cast<int>(0.5f * kPi / angle_step_rad_), 0, angle_cells_ - 1);
  cos_bounds_.resize(angle_cells_);
  for (int k = 0; k < angle_cells_; ++k) {
    cos_bounds_[k] = std::cos(static_cast<float>(k) * angle_step_rad_);
  }
  // cos_lut_[i]: cell of the largest cosine of interval i, a lower bound of the cell of every
  // cosine in the interval; the intervals are narrower than the gaps between the bounds, so
  // at most one bound lies inside an interval.
  cos_lut_.resize(kCosLutSize);
  for (int i = 0; i < kCosLutSize; ++i) {
    const float c = -1.0f + 2.0f * static_cast<float>(i + 1) / static_cast<float>(kCosLutSize);
    int cell = 0;
    while (cell + 1 < angle_cells_ && c <= cos_bounds_[cell + 1]) ++cell;
    cos_lut_[i] = static_cast<std::uint8_t>(cell);
  }
}

int PpfQuantizer::CosineCell(float c) const {
  c = std::clamp(c, -1.0f, 1.0f);
  const int i = std::min(static_cast<int>((c + 1.0f) * (0.5f * kCosLutSize)), kCosLutSize - 1);
  int cell = cos_lut_[i];
  while (cell + 1 < angle_cells_ && c <= cos_bounds_[cell + 1]) ++cell;
  return cell;
}

bool PpfQuantizer::PairKey(const Eigen::Vector3f& p1, const Eigen::Vector3f& n1,
                           const Eigen::Vector3f& p2, const Eigen::Vector3f& n2, std::uint32_t* key,
                           bool* planar) const {
  const Eigen::Vector3f d = p2 - p1;
  const float d2 = d.squaredNorm();
  if (!(d2 > 0.0f) || !std::isfinite(d2)) return false;
  const float distance = std::sqrt(d2);
  if (distance > max_distance_m_) return false;
  const float inv = 1.0f / distance;
  const float c1 = n1.dot(d) * inv;
  const float c2 = n2.dot(d) * inv;
  const float c3 = n1.dot(n2);
  if (!std::isfinite(c1) || !std::isfinite(c2) || !std::isfinite(c3)) return false;
  const int a1 = CosineCell(c1), a2 = CosineCell(c2), a3 = CosineCell(c3);
  const int dc = std::min(static_cast<int>(distance / distance_step_m_), distance_cells_ - 1);
  *key = static_cast<std::uint32_t>(((dc * angle_cells_ + a1) * angle_cells_ + a2) * angle_cells_ +
                                    a3);
  if (planar != nullptr) {
    *planar =
        a3 == 0 && std::abs(a1 - right_angle_cell_) <= 1 && std::abs(a2 - right_angle_cell_) <= 1;
  }
  return true;
}

bool PpfQuantizer::Key(const Eigen::Vector4f& f, std::uint32_t* key) const {
  if (!f.allFinite() || f[0] > max_distance_m_) return false;
  const int d = std::min(static_cast<int>(f[0] / distance_step_m_), distance_cells_ - 1);
  const auto angle = [this](float a) {
    return std::clamp(static_cast<int>(a / angle_step_rad_), 0, angle_cells_ - 1);
  };
  *key = static_cast<std::uint32_t>(
      ((d * angle_cells_ + angle(f[1])) * angle_cells_ + angle(f[2])) * angle_cells_ + angle(f[3]));
  return true;
}

int PpfQuantizer::AlphaBin(float alpha_rad) const {
  float a = std::remainder(alpha_rad, 2.0f * kPi);  // [-pi, pi]
  int bin = static_cast<int>(std::floor((a + kPi) / angle_step_rad_));
  if (bin >= angle_bins_) bin -= angle_bins_;
  if (bin < 0) bin += angle_bins_;
  return bin;
}

float PpfQuantizer::AlphaBinCenter(int bin) const {
  return -kPi + (static_cast<float>(bin) + 0.5f) * angle_step_rad_;
}

bool PpfQuantizer::IsPlanar(const Eigen::Vector4f& f) const {
  // Decided on the quantised cells, so that the skipped set is exactly a set of table keys:
  // normals in the first angle cell, both normal-to-d angles in the cells next to 90 deg.
  const auto cell = [this](float a) {
    return std::clamp(static_cast<int>(a / angle_step_rad_), 0, angle_cells_ - 1);
  };
  const int right_angle = cell(0.5f * kPi);
  return cell(f[3]) == 0 && std::abs(cell(f[1]) - right_angle) <= 1 &&
         std::abs(cell(f[2]) - right_angle) <= 1;
}

Eigen::Isometry3f AlignToXAxis(const Eigen::Vector3f& p, const Eigen::Vector3f& n) {
  Eigen::Isometry3f T = Eigen::Isometry3f::Identity();
  T.linear() = Eigen::Quaternionf::FromTwoVectors(n, Eigen::Vector3f::UnitX()).toRotationMatrix();
  T.translation() = -(T.linear() * p);
  return T;
}

float PairAngle(const Eigen::Isometry3f& T, const Eigen::Vector3f& p2) {
  const Eigen::Vector3f q = T * p2;
  return std::atan2(q.z(), q.y());
}

PpfTable::PpfTable(const geometry::PointCloud& sampled_model, float diameter_m,
                   float distance_step_m, const PpfTableOptions& options)
    : model_(sampled_model),
      diameter_m_(diameter_m),
      store_planar_pairs_(options.store_planar_pairs),
      quantizer_(distance_step_m, diameter_m, options.angle_bins) {
  if (model_.empty()) throw std::invalid_argument("PpfTable: the sampled model is empty");
  CheckUnitNormals(model_, "PpfTable");
  if (model_.size() > kMaxModelPoints) {
    throw std::invalid_argument("PpfTable: " + std::to_string(model_.size()) +
                                " sampled model points exceed the limit of " +
                                std::to_string(kMaxModelPoints) +
                                "; use a larger sampling distance");
  }
  const std::size_t n = model_.size();
  std::vector<Eigen::Isometry3f> T(n);
  for (std::size_t i = 0; i < n; ++i) T[i] = AlignToXAxis(model_.points[i], model_.normals[i]);

  // Pass 1: keys of all ordered pairs; pass 2: counting sort into one flat array.
  std::vector<std::uint32_t> keys(n * n, std::numeric_limits<std::uint32_t>::max());
  offsets_.assign(static_cast<std::size_t>(quantizer_.num_keys()) + 1, 0);
  for (std::size_t i = 0; i < n; ++i) {
    for (std::size_t j = 0; j < n; ++j) {
      if (i == j) continue;
      std::uint32_t key = 0;
      bool planar = false;
      if (!quantizer_.PairKey(model_.points[i], model_.normals[i], model_.points[j],
                              model_.normals[j], &key, &planar)) {
        continue;
      }
      if (!store_planar_pairs_ && planar) continue;
      keys[i * n + j] = key;
      ++offsets_[key + 1];
    }
  }
  std::partial_sum(offsets_.begin(), offsets_.end(), offsets_.begin());
  entries_.resize(offsets_.back());
  std::vector<std::uint32_t> fill(offsets_.begin(), offsets_.end() - 1);
  for (std::size_t i = 0; i < n; ++i) {
    for (std::size_t j = 0; j < n; ++j) {
      const std::uint32_t key = keys[i * n + j];
      if (key == std::numeric_limits<std::uint32_t>::max()) continue;
      entries_[fill[key]++] = {static_cast<std::uint32_t>(i), PairAngle(T[i], model_.points[j])};
    }
  }
  BuildVoteCodes();
  tree_ = KdTree(model_.points);
}

void PpfTable::BuildVoteCodes() {
  const int units = quantizer_.angle_bins() * kAlphaSubsteps;
  const float scale = static_cast<float>(units) / (2.0f * kPi);
  vote_codes_.resize(entries_.size());
  for (std::size_t k = 0; k < entries_.size(); ++k) {
    const Entry& e = entries_[k];
    const int code =
        std::clamp(static_cast<int>(std::floor((e.alpha_m_rad + kPi) * scale)), 0, units - 1);
    vote_codes_[k] = (e.model_reference << kCodeShift) | static_cast<std::uint32_t>(code);
  }
}

PpfTable::PpfTable(geometry::PointCloud sampled_model, float diameter_m, float distance_step_m,
                   int angle_bins, bool store_planar_pairs, std::vector<std::uint32_t> offsets,
                   std::vector<Entry> entries)
    : model_(std::move(sampled_model)),
      diameter_m_(diameter_m),
      store_planar_pairs_(store_planar_pairs),
      quantizer_(distance_step_m, diameter_m, angle_bins),
      offsets_(std::move(offsets)),
      entries_(std::move(entries)) {
  if (model_.empty()) throw std::invalid_argument("PpfTable: the sampled model is empty");
  CheckUnitNormals(model_, "PpfTable");
  if (model_.size() > kMaxModelPoints) {
    throw std::invalid_argument("PpfTable: too many sampled model points");
  }
  if (offsets_.size() != static_cast<std::size_t>(quantizer_.num_keys()) + 1) {
    throw std::invalid_argument("PpfTable: offsets has " + std::to_string(offsets_.size()) +
                                " entries, expected " + std::to_string(quantizer_.num_keys() + 1));
  }
  if (offsets_.front() != 0 || offsets_.back() != entries_.size() ||
      !std::is_sorted(offsets_.begin(), offsets_.end())) {
    throw std::invalid_argument("PpfTable: offsets are not a prefix sum of the entries");
  }
  for (const Entry& e : entries_) {
    if (e.model_reference >= model_.size() || !std::isfinite(e.alpha_m_rad)) {
      throw std::invalid_argument("PpfTable: an entry refers to a missing model point");
    }
  }
  BuildVoteCodes();
  tree_ = KdTree(model_.points);
}

double RotationAngle(const Eigen::Matrix3d& R_a, const Eigen::Matrix3d& R_b) {
  const double c = 0.5 * ((R_a.transpose() * R_b).trace() - 1.0);
  return std::acos(std::clamp(c, -1.0, 1.0));
}

namespace {

// A pose cluster of ClusterPoses: its first (most voted) pose and the vote-weighted sums of
// the poses that joined it.
struct PoseCluster {
  Eigen::Isometry3d first;
  Eigen::Quaterniond q_first;
  Eigen::Vector3d t_sum = Eigen::Vector3d::Zero();
  Eigen::Vector4d q_sum = Eigen::Vector4d::Zero();
  double weight = 0.0;
  int count = 0;
};

// The first cluster (in creation order) a pose joins. Clusters are kept by the grid cell
// (edge = translation threshold) of their first pose, so that a pose only tests the clusters
// of the 27 cells around it; ids ascend within a cell, and the lowest matching id is the first
// cluster in creation order, as in a linear scan (used without a finite threshold).
class PoseClusterIndex {
 public:
  PoseClusterIndex(double translation_threshold_m, double rotation_threshold_rad)
      : translation_m_(translation_threshold_m),
        rotation_rad_(rotation_threshold_rad),
        use_grid_(translation_threshold_m > 0.0 && std::isfinite(translation_threshold_m)) {}

  // The id of the cluster X joins, or -1.
  std::int32_t Find(const Eigen::Isometry3d& X, const std::vector<PoseCluster>& clusters) const {
    const auto joins = [&](const PoseCluster& c) {
      return (c.first.translation() - X.translation()).norm() < translation_m_ &&
             RotationAngle(c.first.linear(), X.linear()) < rotation_rad_;
    };
    std::int32_t found = -1;
    if (!use_grid_ || !X.translation().allFinite()) {
      for (std::size_t id = 0; id < clusters.size(); ++id) {
        if (joins(clusters[id])) return static_cast<std::int32_t>(id);
      }
      return found;
    }
    const auto c = CellOf(X.translation());
    for (std::int64_t dx = -1; dx <= 1; ++dx) {
      for (std::int64_t dy = -1; dy <= 1; ++dy) {
        for (std::int64_t dz = -1; dz <= 1; ++dz) {
          const auto it = grid_.find(CellKey(c[0] + dx, c[1] + dy, c[2] + dz));
          if (it == grid_.end()) continue;
          for (std::int32_t id : it->second) {
            if (found >= 0 && id >= found) break;
            if (joins(clusters[id])) {
              found = id;
              break;
            }
          }
        }
      }
    }
    return found;
  }

  // Files a new cluster `id` whose first pose is X.
  void Add(const Eigen::Isometry3d& X, std::int32_t id) {
    if (!use_grid_ || !X.translation().allFinite()) return;
    const auto c = CellOf(X.translation());
    grid_[CellKey(c[0], c[1], c[2])].push_back(id);
  }

 private:
  Eigen::Matrix<std::int64_t, 3, 1> CellOf(const Eigen::Vector3d& p) const {
    return (p / translation_m_)
        .array()
        .floor()
        .cwiseMax(-1.0e6)
        .cwiseMin(1.0e6)
        .cast<std::int64_t>()
        .matrix()
        .eval();
  }
  static std::uint64_t CellKey(std::int64_t x, std::int64_t y, std::int64_t z) {
    constexpr std::int64_t kOffset = 1 << 20;
    return (static_cast<std::uint64_t>(x + kOffset) << 42) |
           (static_cast<std::uint64_t>(y + kOffset) << 21) |
           static_cast<std::uint64_t>(z + kOffset);
  }

  double translation_m_, rotation_rad_;
  bool use_grid_;
  std::unordered_map<std::uint64_t, std::vector<std::int32_t>> grid_;
};

// The clusters' vote-weighted mean poses, most votes first.
std::vector<PpfHypothesis> MeanPosesOf(const std::vector<PoseCluster>& clusters) {
  std::vector<PpfHypothesis> out;
  out.reserve(clusters.size());
  for (const PoseCluster& c : clusters) {
    PpfHypothesis h;
    Eigen::Quaterniond q;
    q.coeffs() = c.q_sum;
    h.X_SceneModel.linear() = q.normalized().toRotationMatrix();
    h.X_SceneModel.translation() = c.t_sum / c.weight;
    h.votes = c.weight;
    h.num_poses = c.count;
    out.push_back(h);
  }
  std::stable_sort(out.begin(), out.end(), [](const PpfHypothesis& a, const PpfHypothesis& b) {
    return a.votes > b.votes;
  });
  return out;
}

}  // namespace

std::vector<PpfHypothesis> ClusterPoses(const std::vector<Eigen::Isometry3d>& poses,
                                        const std::vector<double>& votes,
                                        double translation_threshold_m,
                                        double rotation_threshold_rad) {
  if (poses.size() != votes.size()) {
    throw std::invalid_argument("ClusterPoses: poses and votes differ in length");
  }
  std::vector<std::size_t> order(poses.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(),
                   [&](std::size_t a, std::size_t b) { return votes[a] > votes[b]; });
  std::vector<PoseCluster> clusters;
  PoseClusterIndex index(translation_threshold_m, rotation_threshold_rad);
  for (std::size_t idx : order) {
    const Eigen::Isometry3d& X = poses[idx];
    const std::int32_t found = index.Find(X, clusters);
    PoseCluster* target = nullptr;
    if (found >= 0) {
      target = &clusters[found];
    } else {
      clusters.push_back({X, Eigen::Quaterniond(X.linear())});
      target = &clusters.back();
      index.Add(X, static_cast<std::int32_t>(clusters.size() - 1));
    }
    Eigen::Quaterniond q(X.linear());
    if (q.dot(target->q_first) < 0.0) q.coeffs() = -q.coeffs();
    const double w = std::max(votes[idx], 1e-12);
    target->t_sum += w * X.translation();
    target->q_sum += w * q.coeffs();
    target->weight += w;
    target->count += 1;
  }
  return MeanPosesOf(clusters);
}

namespace {

// Integer votes: a pair counts kVoteUnit, a planar pair its weight in units of 1 / kVoteUnit.
constexpr std::uint32_t kVoteUnit = 64;

struct Peak {
  std::int32_t reference = 0;
  std::int32_t rank = 0;
  float votes = 0.0f;
  Eigen::Isometry3d X_SceneModel;
};

void ValidateMatchOptions(const PpfMatchOptions& o) {
  auto fail = [](const std::string& what) {
    throw std::invalid_argument("PpfMatchOptions: " + what);
  };
  if (o.reference_step < 1) fail("reference_step must be >= 1");
  if (!(o.planar_pair_weight >= 0.0f && o.planar_pair_weight <= 1.0f)) {
    fail("planar_pair_weight must be in [0, 1]");
  }
  if (o.peaks_per_reference < 1) fail("peaks_per_reference must be >= 1");
  if (!(o.peak_ratio > 0.0f && o.peak_ratio <= 1.0f)) fail("peak_ratio must be in (0, 1]");
  if (!(o.cluster_translation_rel > 0.0f)) fail("cluster_translation_rel must be positive");
  if (!(o.cluster_rotation_rad > 0.0f)) fail("cluster_rotation_rad must be positive");
  if (o.max_hypotheses < 1) fail("max_hypotheses must be >= 1");
  if (o.num_threads < 0) fail("num_threads must be >= 0");
  if (o.hypotheses_per_segment < 1) fail("hypotheses_per_segment must be >= 1");
}

// Validation stage of MatchPpf: throws std::invalid_argument for invalid options or inputs.
void ValidateMatchInputs(const PpfTable& table, const geometry::PointCloud& scene,
                         const KdTree& scene_tree, const PpfMatchOptions& options) {
  ValidateMatchOptions(options);
  CheckCloudChannels(scene, "MatchPpf scene");
  if (!scene.has_normals()) throw std::invalid_argument("MatchPpf: the scene has no normals");
  if (scene_tree.size() != scene.size()) {
    throw std::invalid_argument("MatchPpf: the scene tree indexes " +
                                std::to_string(scene_tree.size()) + " points, the scene has " +
                                std::to_string(scene.size()));
  }
  if (table.entries().empty() && table.offsets().empty()) {
    throw std::invalid_argument("MatchPpf: the table is not trained");
  }
  if (!options.segments.empty() && options.segments.size() != scene.size()) {
    throw std::invalid_argument(
        "PpfMatchOptions: segments has " + std::to_string(options.segments.size()) +
        " labels, the scene has " + std::to_string(scene.size()) + " points");
  }
}

// Read-only inputs and constants of the voting, shared by all worker threads.
struct VoteContext {
  const geometry::PointCloud& scene;
  const KdTree& scene_tree;
  const PpfQuantizer& quant;
  const geometry::PointCloud& model;
  int bins;
  std::size_t acc_size;
  bool skip_planar;
  std::uint32_t planar_units;
  const std::uint32_t* codes;
  const std::uint32_t* offsets;
  int units;
  float code_scale;
  std::vector<std::uint16_t> wrap;
  std::vector<std::uint32_t> flag_bit;
  bool skip_duplicates;
  float radius;
};

// Setup stage of MatchPpf: vote weights, fixed-point angle tables and the other voting constants.
VoteContext MakeVoteContext(const PpfTable& table, const geometry::PointCloud& scene,
                            const KdTree& scene_tree, const PpfMatchOptions& options) {
  const PpfQuantizer& quant = table.quantizer();
  const geometry::PointCloud& model = table.sampled_model();
  const int bins = quant.angle_bins();
  const std::size_t acc_size = model.size() * static_cast<std::size_t>(bins);
  const bool skip_planar = options.planar_pair_weight <= 0.0f;
  const std::uint32_t planar_units =
      skip_planar ? 0u
                  : std::max<std::uint32_t>(1u, static_cast<std::uint32_t>(std::lround(
                                                    options.planar_pair_weight * kVoteUnit)));

  // Fixed-point angles: `units` per turn. The alpha bin of (scene code s, model code m) is
  // wrap[s - m + units + units / 2] (the extra half turn makes bin 0 start at -pi).
  constexpr int kSub = PpfTable::kAlphaSubsteps;
  const int units = bins * kSub;
  const float code_scale = static_cast<float>(units) / (2.0f * kPi);
  std::vector<std::uint16_t> wrap(3 * static_cast<std::size_t>(units));
  for (std::size_t i = 0; i < wrap.size(); ++i) {
    wrap[i] = static_cast<std::uint16_t>((i / kSub) % static_cast<std::size_t>(bins));
  }
  // Flag bit of a scene angle code for skip_duplicate_votes.
  std::vector<std::uint32_t> flag_bit(units);
  for (int c = 0; c < units; ++c) {
    const int coarse = c / kSub;
    flag_bit[c] = 1u << (bins <= 32 ? coarse : coarse * 32 / bins);
  }
  return VoteContext{scene,
                     scene_tree,
                     quant,
                     model,
                     bins,
                     acc_size,
                     skip_planar,
                     planar_units,
                     table.vote_codes().data(),
                     table.offsets().data(),
                     units,
                     code_scale,
                     std::move(wrap),
                     std::move(flag_bit),
                     options.skip_duplicate_votes,
                     table.diameter_m()};
}

// Reference selection stage: every reference_step-th scene point with a finite point and normal.
std::vector<std::int32_t> SelectReferencePoints(const geometry::PointCloud& scene,
                                                int reference_step) {
  std::vector<std::int32_t> references;
  for (std::size_t i = 0; i < scene.size(); i += reference_step) {
    if (scene.points[i].allFinite() && scene.normals[i].allFinite()) {
      references.push_back(static_cast<std::int32_t>(i));
    }
  }
  return references;
}

// Visit order stage: the reference points reordered to spread over the scene.
std::vector<std::int32_t> SpreadVisitOrder(const std::vector<std::int32_t>& references) {
  // Visit order spread over the scene (every kSpread-th reference point first, then the
  // ones after them, ...), so that voting stopped by the deadline has covered all of it.
  constexpr std::size_t kSpread = 16;
  std::vector<std::int32_t> order;
  order.reserve(references.size());
  for (std::size_t offset = 0; offset < kSpread; ++offset) {
    for (std::size_t i = offset; i < references.size(); i += kSpread) {
      order.push_back(references[i]);
    }
  }
  return order;
}

// Buffers of one worker thread, reused for every reference point it votes for.
struct VoteScratch {
  std::vector<std::uint32_t> acc;
  std::vector<std::uint32_t> flags;
  std::vector<std::uint32_t> flagged;
  std::vector<std::int32_t> neighbors;
  std::vector<std::pair<std::uint32_t, std::int32_t>> candidates;
};

// Counters of one worker thread.
struct VoteCounts {
  std::int64_t lookups = 0;
  std::int64_t votes = 0;
  std::int64_t duplicates = 0;
};

// Voting stage (the hot kernel): adds the votes of the pairs of reference point `ref`, whose
// alignment is T_s, to scratch->acc and leaves scratch->flags cleared.
void VoteReference(const VoteContext& ctx, std::int32_t ref, const Eigen::Isometry3f& T_s,
                   VoteScratch* scratch, VoteCounts* counts) {
  const geometry::PointCloud& scene = ctx.scene;
  const PpfQuantizer& quant = ctx.quant;
  const int bins = ctx.bins;
  const int units = ctx.units;
  const float code_scale = ctx.code_scale;
  const bool skip_planar = ctx.skip_planar;
  const std::uint32_t planar_units = ctx.planar_units;
  const bool skip_duplicates = ctx.skip_duplicates;
  const std::uint32_t* codes = ctx.codes;
  const std::uint32_t* offsets = ctx.offsets;
  const std::vector<std::uint16_t>& wrap = ctx.wrap;
  const std::vector<std::uint32_t>& flag_bit = ctx.flag_bit;
  std::vector<std::uint32_t>& acc = scratch->acc;
  std::vector<std::uint32_t>& flags = scratch->flags;
  std::vector<std::uint32_t>& flagged = scratch->flagged;
  std::vector<std::int32_t>& neighbors = scratch->neighbors;
  std::int64_t n_lookups = 0, n_votes = 0, n_duplicates = 0;

  const Eigen::Vector3f& p_r = scene.points[ref];
  const Eigen::Vector3f& n_r = scene.normals[ref];
  const Eigen::Vector3f row_y = T_s.linear().row(1).transpose();
  const Eigen::Vector3f row_z = T_s.linear().row(2).transpose();
  ctx.scene_tree.RadiusSearch(p_r, ctx.radius, &neighbors);
  for (std::int32_t i : neighbors) {
    if (i == ref) continue;
    const Eigen::Vector3f& p_i = scene.points[i];
    const Eigen::Vector3f& n_i = scene.normals[i];
    std::uint32_t key = 0;
    bool planar = false;
    if (!quant.PairKey(p_r, n_r, p_i, n_i, &key, &planar)) continue;
    std::uint32_t w = kVoteUnit;
    if (planar) {
      if (skip_planar) continue;
      w = planar_units;
    }
    // alpha_s: rotation angle of p_i about x after T_s (PairAngle), as a code.
    const Eigen::Vector3f d = p_i - p_r;
    const float theta = FastAtan2(row_z.dot(d), row_y.dot(d));
    const int s_code = std::clamp(static_cast<int>((theta + kPi) * code_scale), 0, units - 1);
    if (skip_duplicates) {
      std::uint32_t& word = flags[key];
      const std::uint32_t bit = flag_bit[s_code];
      if (word & bit) {
        ++n_duplicates;
        continue;
      }
      if (word == 0) flagged.push_back(key);
      word |= bit;
    }
    ++n_lookups;
    const std::uint32_t* b = codes + offsets[key];
    const std::uint32_t* e = codes + offsets[key + 1];
    n_votes += e - b;
    const std::uint16_t* wrap_s = wrap.data() + s_code + units + units / 2;
    for (; b != e; ++b) {
      const std::uint32_t c = *b;
      acc[(c >> kCodeShift) * bins + wrap_s[-static_cast<int>(c & kCodeMask)]] += w;
    }
  }
  for (std::uint32_t key : flagged) flags[key] = 0;
  flagged.clear();
  counts->lookups += n_lookups;
  counts->votes += n_votes;
  counts->duplicates += n_duplicates;
}

// Peak stage: moves the best accumulator cells to the front of scratch->candidates, highest
// first, and clears the accumulator; returns how many there are (0 without votes).
std::size_t FindAccumulatorPeaks(const VoteContext& ctx, const PpfMatchOptions& options,
                                 VoteScratch* scratch) {
  const std::size_t acc_size = ctx.acc_size;
  std::vector<std::uint32_t>& acc = scratch->acc;
  std::vector<std::pair<std::uint32_t, std::int32_t>>& candidates = scratch->candidates;
  // The highest peaks of this reference point: the maximum, then every cell with at
  // least peak_ratio of it, highest first (ties by cell index).
  std::uint32_t best = 0;
  for (std::size_t a = 0; a < acc_size; ++a) best = std::max(best, acc[a]);
  if (best == 0) return 0;
  const std::uint32_t threshold =
      std::max<std::uint32_t>(1u, static_cast<std::uint32_t>(std::ceil(options.peak_ratio * best)));
  candidates.clear();
  for (std::size_t a = 0; a < acc_size; ++a) {
    if (acc[a] >= threshold) candidates.emplace_back(acc[a], static_cast<std::int32_t>(a));
  }
  std::fill(acc.begin(), acc.end(), 0u);
  const std::size_t k =
      std::min(candidates.size(), static_cast<std::size_t>(options.peaks_per_reference));
  std::partial_sort(candidates.begin(), candidates.begin() + k, candidates.end(),
                    [](const auto& x, const auto& y) {
                      return x.first != y.first ? x.first > y.first : x.second < y.second;
                    });
  return k;
}

// Pose stage: appends the poses X_SceneModel of the first k peak candidates of `ref` to *peaks.
void AppendPeakPoses(const VoteContext& ctx, std::int32_t ref, const Eigen::Isometry3f& T_s,
                     const std::vector<std::pair<std::uint32_t, std::int32_t>>& candidates,
                     std::size_t k, std::vector<Peak>* peaks) {
  const int bins = ctx.bins;
  const geometry::PointCloud& model = ctx.model;
  const Eigen::Isometry3d X_SceneAligned = ToDouble(T_s).inverse();
  for (std::size_t rank = 0; rank < k; ++rank) {
    const int m = candidates[rank].second / bins;
    const int bin = candidates[rank].second % bins;
    const Eigen::Isometry3d T_m = ToDouble(AlignToXAxis(model.points[m], model.normals[m]));
    const Eigen::Isometry3d R_x(
        Eigen::AngleAxisd(ctx.quant.AlphaBinCenter(bin), Eigen::Vector3d::UnitX()));
    peaks->push_back({ref, static_cast<std::int32_t>(rank),
                      static_cast<float>(candidates[rank].first) / kVoteUnit,
                      Orthonormalized(X_SceneAligned * R_x * T_m)});
  }
}

// Parallel voting stage: votes for the reference points of `order` on worker threads until
// the deadline; returns the peaks by reference point and rank and fills the counters of
// *result (whose reference_points must be set).
std::vector<Peak> VoteAllReferences(const VoteContext& ctx, const PpfMatchOptions& options,
                                    const std::vector<std::int32_t>& order,
                                    PpfMatchResult* result) {
  const int threads = std::clamp(parallel::ResolveThreads(options.num_threads), 1,
                                 std::max(1, result->reference_points));
  std::vector<std::vector<Peak>> peaks(threads);
  std::vector<std::int64_t> lookups(threads, 0);
  std::vector<std::int64_t> votes_cast(threads, 0);
  std::vector<std::int64_t> duplicates(threads, 0);
  std::vector<int> voted(threads, 0);
  std::atomic<std::size_t> next{0};
  std::atomic<bool> timed_out{false};
  const bool has_deadline = options.deadline != std::chrono::steady_clock::time_point::max();
  constexpr std::size_t kChunk = 8;

  auto worker = [&](int t) {
    VoteScratch scratch;
    scratch.acc.assign(ctx.acc_size, 0u);
    scratch.flags.assign(ctx.skip_duplicates ? ctx.quant.num_keys() : 0u, 0u);
    VoteCounts counts;
    for (;;) {
      if (has_deadline && options.clock.Now() >= options.deadline) {
        timed_out = true;
        break;
      }
      const std::size_t start = next.fetch_add(kChunk);
      if (start >= order.size()) break;
      const std::size_t stop = std::min(order.size(), start + kChunk);
      voted[t] += static_cast<int>(stop - start);
      for (std::size_t r = start; r < stop; ++r) {
        const std::int32_t ref = order[r];
        const Eigen::Isometry3f T_s = AlignToXAxis(ctx.scene.points[ref], ctx.scene.normals[ref]);
        VoteReference(ctx, ref, T_s, &scratch, &counts);
        const std::size_t k = FindAccumulatorPeaks(ctx, options, &scratch);
        if (k > 0) AppendPeakPoses(ctx, ref, T_s, scratch.candidates, k, &peaks[t]);
      }
    }
    lookups[t] = counts.lookups;
    votes_cast[t] = counts.votes;
    duplicates[t] = counts.duplicates;
  };
  // One task per worker, each taking chunks of reference points from `next` until none are
  // left: handing the chunks themselves out as ParallelFor's tasks measured 5-15 % slower
  // (bench_detector's milk match).
  parallel::ParallelFor(threads, threads, [&worker](int task) { worker(task); });

  std::vector<Peak> all;
  for (int t = 0; t < threads; ++t) {
    all.insert(all.end(), peaks[t].begin(), peaks[t].end());
    result->pair_lookups += lookups[t];
    result->votes_cast += votes_cast[t];
    result->duplicate_pairs += duplicates[t];
    result->voted_reference_points += voted[t];
  }
  result->voted_reference_points =
      std::min(result->voted_reference_points, result->reference_points);
  result->timed_out = timed_out.load() && result->voted_reference_points < result->reference_points;
  std::sort(all.begin(), all.end(), [](const Peak& a, const Peak& b) {
    return a.reference != b.reference ? a.reference < b.reference : a.rank < b.rank;
  });
  return all;
}

// Symmetry merge stage: marks each of the first `candidates` clusters that places the model
// like an earlier unmarked one, whose votes and poses it joins.
std::vector<bool> MergeSymmetricClusters(const PpfTable& table, const PpfMatchOptions& options,
                                         std::size_t candidates,
                                         std::vector<PpfHypothesis>* clusters_io) {
  const PpfQuantizer& quant = table.quantizer();
  const geometry::PointCloud& model = table.sampled_model();
  std::vector<PpfHypothesis>& clusters = *clusters_io;
  std::vector<bool> merged(candidates, false);
  if (options.symmetry_tolerance_rel > 0.0f && candidates > 1) {
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (const auto& p : model.points) centroid += p.cast<double>();
    centroid /= static_cast<double>(model.size());
    const std::size_t stride = std::max<std::size_t>(1, model.size() / 200);
    const double tolerance = options.symmetry_tolerance_rel * quant.distance_step_m();
    for (std::size_t j = 1; j < candidates; ++j) {
      for (std::size_t i = 0; i < j; ++i) {
        if (merged[i]) continue;
        const Eigen::Isometry3d& X_i = clusters[i].X_SceneModel;
        const Eigen::Isometry3d& X_j = clusters[j].X_SceneModel;
        if ((X_i * centroid - X_j * centroid).norm() > 2.0 * quant.distance_step_m()) continue;
        const Eigen::Isometry3f X_rel = (X_i.inverse() * X_j).cast<float>();
        double sum = 0.0;
        std::size_t count = 0;
        for (std::size_t m = 0; m < model.size(); m += stride, ++count) {
          float d2 = 0.0f;
          table.model_tree().Nearest(X_rel * model.points[m], &d2);
          sum += std::sqrt(d2);
        }
        if (sum / static_cast<double>(count) < tolerance) {
          merged[j] = true;
          clusters[i].votes += clusters[j].votes;
          clusters[i].num_poses += clusters[j].num_poses;
          break;
        }
      }
    }
  }
  return merged;
}

// Pose clustering stage: pose clusters of a set of peaks, merged where a symmetric model is
// placed identically, by votes; the best `keep` of them.
std::vector<PpfHypothesis> ClusterPeaks(const PpfTable& table, const PpfMatchOptions& options,
                                        const std::vector<const Peak*>& group, std::size_t keep) {
  std::vector<Eigen::Isometry3d> poses;
  std::vector<double> votes;
  poses.reserve(group.size());
  votes.reserve(group.size());
  for (const Peak* p : group) {
    poses.push_back(p->X_SceneModel);
    votes.push_back(p->votes);
  }
  std::vector<PpfHypothesis> clusters =
      ClusterPoses(poses, votes, options.cluster_translation_rel * table.diameter_m(),
                   options.cluster_rotation_rad);
  const std::size_t candidates = std::min(clusters.size(), 3 * keep);
  const std::vector<bool> merged = MergeSymmetricClusters(table, options, candidates, &clusters);
  std::vector<PpfHypothesis> out;
  for (std::size_t c = 0; c < clusters.size(); ++c) {
    if (c < candidates && merged[c]) continue;
    out.push_back(clusters[c]);
  }
  std::stable_sort(out.begin(), out.end(), [](const PpfHypothesis& a, const PpfHypothesis& b) {
    return a.votes > b.votes;
  });
  if (out.size() > keep) out.resize(keep);
  return out;
}

// Result assembly stage: the hypotheses of all peaks, or of each segment in rounds.
void AssembleHypotheses(const PpfTable& table, const PpfMatchOptions& options,
                        const std::vector<Peak>& all, PpfMatchResult* result) {
  const auto max_hypotheses = static_cast<std::size_t>(options.max_hypotheses);
  if (options.segments.empty()) {
    std::vector<const Peak*> group;
    group.reserve(all.size());
    for (const Peak& p : all) group.push_back(&p);
    result->hypotheses = ClusterPeaks(table, options, group, max_hypotheses);
    return;
  }
  // Per segment (by label, in order of the labels), then in rounds over the segments.
  std::map<std::int32_t, std::vector<const Peak*>> groups;
  for (const Peak& p : all) groups[options.segments[p.reference]].push_back(&p);
  std::vector<std::vector<PpfHypothesis>> per_segment;
  for (const auto& [label, group] : groups) {
    per_segment.push_back(ClusterPeaks(table, options, group, max_hypotheses));
  }
  std::stable_sort(per_segment.begin(), per_segment.end(),
                   [](const std::vector<PpfHypothesis>& a, const std::vector<PpfHypothesis>& b) {
                     const double va = a.empty() ? 0.0 : a.front().votes;
                     const double vb = b.empty() ? 0.0 : b.front().votes;
                     return va > vb;
                   });
  const auto per = static_cast<std::size_t>(options.hypotheses_per_segment);
  for (std::size_t round = 0; round < per; ++round) {
    for (const auto& hypotheses : per_segment) {
      if (round < hypotheses.size() && result->hypotheses.size() < max_hypotheses) {
        result->hypotheses.push_back(hypotheses[round]);
      }
    }
  }
  // The remaining places go to the other clusters by votes, whatever their segment.
  std::vector<PpfHypothesis> rest;
  for (const auto& hypotheses : per_segment) {
    if (hypotheses.size() > per)
      rest.insert(rest.end(), hypotheses.begin() + per, hypotheses.end());
  }
  std::stable_sort(rest.begin(), rest.end(), [](const PpfHypothesis& a, const PpfHypothesis& b) {
    return a.votes > b.votes;
  });
  for (const PpfHypothesis& h : rest) {
    if (result->hypotheses.size() >= max_hypotheses) break;
    result->hypotheses.push_back(h);
  }
}

}  // namespace

PpfMatchResult MatchPpf(const PpfTable& table, const geometry::PointCloud& scene,
                        const KdTree& scene_tree, const PpfMatchOptions& options) {
  ValidateMatchInputs(table, scene, scene_tree, options);
  PpfMatchResult result;
  const VoteContext ctx = MakeVoteContext(table, scene, scene_tree, options);
  const std::vector<std::int32_t> references = SelectReferencePoints(scene, options.reference_step);
  result.reference_points = static_cast<int>(references.size());
  const std::vector<std::int32_t> order = SpreadVisitOrder(references);
  const std::vector<Peak> all = VoteAllReferences(ctx, options, order, &result);
  AssembleHypotheses(table, options, all, &result);
  return result;
}

}  // namespace picking::detector
