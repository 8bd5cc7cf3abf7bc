#include "services/detector/core/ppf.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <numeric>
#include <stdexcept>
#include <string>
#include <thread>

#include "services/detector/core/ppf_cloud.h"

namespace picking::detector {
namespace {

constexpr float kPi = static_cast<float>(M_PI);
constexpr std::size_t kMaxModelPoints = 8192;

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
      const Eigen::Vector4f f =
          ComputePpf(model_.points[i], model_.normals[i], model_.points[j], model_.normals[j]);
      std::uint32_t key = 0;
      if (!quantizer_.Key(f, &key)) continue;
      if (!store_planar_pairs_ && quantizer_.IsPlanar(f)) continue;
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
  tree_ = KdTree(model_.points);
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
  tree_ = KdTree(model_.points);
}

double RotationAngle(const Eigen::Matrix3d& R_a, const Eigen::Matrix3d& R_b) {
  const double c = 0.5 * ((R_a.transpose() * R_b).trace() - 1.0);
  return std::acos(std::clamp(c, -1.0, 1.0));
}

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
  struct Cluster {
    Eigen::Isometry3d first;
    Eigen::Quaterniond q_first;
    Eigen::Vector3d t_sum = Eigen::Vector3d::Zero();
    Eigen::Vector4d q_sum = Eigen::Vector4d::Zero();
    double weight = 0.0;
    int count = 0;
  };
  std::vector<Cluster> clusters;
  for (std::size_t idx : order) {
    const Eigen::Isometry3d& X = poses[idx];
    Cluster* target = nullptr;
    for (Cluster& c : clusters) {
      if ((c.first.translation() - X.translation()).norm() < translation_threshold_m &&
          RotationAngle(c.first.linear(), X.linear()) < rotation_threshold_rad) {
        target = &c;
        break;
      }
    }
    if (target == nullptr) {
      clusters.push_back({X, Eigen::Quaterniond(X.linear())});
      target = &clusters.back();
    }
    Eigen::Quaterniond q(X.linear());
    if (q.dot(target->q_first) < 0.0) q.coeffs() = -q.coeffs();
    const double w = std::max(votes[idx], 1e-12);
    target->t_sum += w * X.translation();
    target->q_sum += w * q.coeffs();
    target->weight += w;
    target->count += 1;
  }
  std::vector<PpfHypothesis> out;
  out.reserve(clusters.size());
  for (const Cluster& c : clusters) {
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

namespace {

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
}

}  // namespace

PpfMatchResult MatchPpf(const PpfTable& table, const geometry::PointCloud& scene,
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
  PpfMatchResult result;
  const PpfQuantizer& quant = table.quantizer();
  const geometry::PointCloud& model = table.sampled_model();
  const int bins = quant.angle_bins();
  const std::size_t acc_size = model.size() * static_cast<std::size_t>(bins);
  const float step_inv = 1.0f / quant.angle_step_rad();
  const float planar_weight = options.planar_pair_weight;
  const bool skip_planar = planar_weight <= 0.0f;

  std::vector<std::int32_t> references;
  for (std::size_t i = 0; i < scene.size(); i += options.reference_step) {
    if (scene.points[i].allFinite() && scene.normals[i].allFinite()) {
      references.push_back(static_cast<std::int32_t>(i));
    }
  }
  result.reference_points = static_cast<int>(references.size());

  int threads = options.num_threads > 0 ? options.num_threads
                                        : static_cast<int>(std::thread::hardware_concurrency());
  threads = std::clamp(threads, 1, std::max(1, static_cast<int>(references.size())));
  std::vector<std::vector<Peak>> peaks(threads);
  std::vector<std::int64_t> lookups(threads, 0);
  std::vector<std::int64_t> votes_cast(threads, 0);
  std::atomic<std::size_t> next{0};
  constexpr std::size_t kChunk = 8;

  auto worker = [&](int t) {
    std::vector<float> acc(acc_size);
    std::vector<std::int32_t> neighbors;
    std::vector<std::pair<float, std::int32_t>> top;
    for (;;) {
      const std::size_t start = next.fetch_add(kChunk);
      if (start >= references.size()) break;
      const std::size_t stop = std::min(references.size(), start + kChunk);
      for (std::size_t r = start; r < stop; ++r) {
        const std::int32_t ref = references[r];
        const Eigen::Vector3f& p_r = scene.points[ref];
        const Eigen::Vector3f& n_r = scene.normals[ref];
        const Eigen::Isometry3f T_s = AlignToXAxis(p_r, n_r);
        std::fill(acc.begin(), acc.end(), 0.0f);
        scene_tree.RadiusSearch(p_r, table.diameter_m(), &neighbors);
        for (std::int32_t i : neighbors) {
          if (i == ref) continue;
          const Eigen::Vector3f& n_i = scene.normals[i];
          if (!n_i.allFinite()) continue;
          const Eigen::Vector4f f = ComputePpf(p_r, n_r, scene.points[i], n_i);
          std::uint32_t key = 0;
          if (!quant.Key(f, &key)) continue;
          float w = 1.0f;
          if (quant.IsPlanar(f)) {
            if (skip_planar) continue;
            w = planar_weight;
          }
          ++lookups[t];
          const PpfTable::Entry* b = table.begin(key);
          const PpfTable::Entry* e = table.end(key);
          votes_cast[t] += e - b;
          // alpha = theta_s - theta_m, binned over [-pi, pi).
          const float shifted = PairAngle(T_s, scene.points[i]) + static_cast<float>(M_PI);
          for (; b != e; ++b) {
            int bin = static_cast<int>(std::floor((shifted - b->alpha_m_rad) * step_inv));
            if (bin < 0) bin += bins;
            if (bin >= bins) bin -= bins;
            bin = std::clamp(bin, 0, bins - 1);
            acc[static_cast<std::size_t>(b->model_reference) * bins + bin] += w;
          }
        }
        // The highest peaks of this reference point.
        top.clear();
        const std::size_t k = static_cast<std::size_t>(options.peaks_per_reference);
        for (std::size_t a = 0; a < acc_size; ++a) {
          const float v = acc[a];
          if (v <= 0.0f || (top.size() == k && v <= top.back().first)) continue;
          auto it = std::upper_bound(
              top.begin(), top.end(), v,
              [](float value, const std::pair<float, std::int32_t>& p) { return value > p.first; });
          top.insert(it, {v, static_cast<std::int32_t>(a)});
          if (top.size() > k) top.pop_back();
        }
        const Eigen::Isometry3d X_SceneAligned = ToDouble(T_s).inverse();
        for (std::size_t rank = 0; rank < top.size(); ++rank) {
          if (top[rank].first < options.peak_ratio * top.front().first) break;
          const int m = top[rank].second / bins;
          const int bin = top[rank].second % bins;
          const Eigen::Isometry3d T_m = ToDouble(AlignToXAxis(model.points[m], model.normals[m]));
          const Eigen::Isometry3d R_x(
              Eigen::AngleAxisd(quant.AlphaBinCenter(bin), Eigen::Vector3d::UnitX()));
          peaks[t].push_back({ref, static_cast<std::int32_t>(rank), top[rank].first,
                              Orthonormalized(X_SceneAligned * R_x * T_m)});
        }
      }
    }
  };
  std::vector<std::thread> pool;
  for (int t = 1; t < threads; ++t) pool.emplace_back(worker, t);
  worker(0);
  for (auto& th : pool) th.join();

  std::vector<Peak> all;
  for (int t = 0; t < threads; ++t) {
    all.insert(all.end(), peaks[t].begin(), peaks[t].end());
    result.pair_lookups += lookups[t];
    result.votes_cast += votes_cast[t];
  }
  std::sort(all.begin(), all.end(), [](const Peak& a, const Peak& b) {
    return a.reference != b.reference ? a.reference < b.reference : a.rank < b.rank;
  });
  std::vector<Eigen::Isometry3d> poses;
  std::vector<double> votes;
  poses.reserve(all.size());
  votes.reserve(all.size());
  for (const Peak& p : all) {
    poses.push_back(p.X_SceneModel);
    votes.push_back(p.votes);
  }
  std::vector<PpfHypothesis> clusters =
      ClusterPoses(poses, votes, options.cluster_translation_rel * table.diameter_m(),
                   options.cluster_rotation_rad);

  // Merge clusters that place a symmetric model identically.
  const std::size_t candidates =
      std::min(clusters.size(), static_cast<std::size_t>(3 * options.max_hypotheses));
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
  for (std::size_t c = 0; c < clusters.size(); ++c) {
    if (c < candidates && merged[c]) continue;
    result.hypotheses.push_back(clusters[c]);
  }
  std::stable_sort(
      result.hypotheses.begin(), result.hypotheses.end(),
      [](const PpfHypothesis& a, const PpfHypothesis& b) { return a.votes > b.votes; });
  if (result.hypotheses.size() > static_cast<std::size_t>(options.max_hypotheses)) {
    result.hypotheses.resize(options.max_hypotheses);
  }
  return result;
}

}  // namespace picking::detector
