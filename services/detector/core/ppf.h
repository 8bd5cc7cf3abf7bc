#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <chrono>
#include <cstdint>
#include <vector>

#include "libs/geometry/point_cloud.h"
#include "services/detector/core/budget_clock.h"
#include "services/detector/core/kdtree.h"

namespace picking::detector {

/// The point pair feature of Drost et al. (2010): F(m1, m2) = (||d||, angle(n1, d),
/// angle(n2, d), angle(n1, n2)) with d = p2 - p1; distance in metres, angles in [0, pi] rad.
/// Returns NaN components when p1 == p2.
Eigen::Vector4f ComputePpf(const Eigen::Vector3f& p1, const Eigen::Vector3f& n1,
                           const Eigen::Vector3f& p2, const Eigen::Vector3f& n2);

/// Quantisation of point pair features into a dense key range [0, num_keys()).
///
/// Distances are quantised in steps of `distance_step_m` up to `max_distance_m`; angles in
/// steps of 2 pi / angle_bins (the angles of a feature lie in [0, pi], so ceil(angle_bins / 2)
/// angle cells are used). The same step quantises the rotation angle alpha in [-pi, pi).
class PpfQuantizer final {
 public:
  /// Throws std::invalid_argument for a non-positive step or distance, or angle_bins < 4 or
  /// a key range above 2^31.
  PpfQuantizer(float distance_step_m, float max_distance_m, int angle_bins);

  float distance_step_m() const { return distance_step_m_; }
  float max_distance_m() const { return max_distance_m_; }
  int angle_bins() const { return angle_bins_; }
  float angle_step_rad() const { return angle_step_rad_; }
  std::uint32_t num_keys() const { return num_keys_; }

  /// Key of a feature; false when the feature is not finite or longer than the maximum
  /// distance.
  bool Key(const Eigen::Vector4f& feature, std::uint32_t* key) const;

  /// Bin in [0, angle_bins) of an angle alpha in radians (any value; wrapped to [-pi, pi)).
  int AlphaBin(float alpha_rad) const;

  /// Centre of an alpha bin, radians in [-pi, pi).
  float AlphaBinCenter(int bin) const;

  /// True for a nearly coplanar pair: the angle between the normals in the first angle cell
  /// and both normal-to-d angles in the cell of 90 degrees or a neighbouring one. Such a pair
  /// constrains only the plane, not the position or rotation within it, and there are very many of
  /// them on planar objects.
  bool IsPlanar(const Eigen::Vector4f& feature) const;

  /// Angle cell of the angle whose cosine is `cosine` (clamped to [-1, 1]): the number of
  /// cell boundaries k * angle_step_rad (k >= 1) the angle reaches, at most
  /// ceil(angle_bins / 2) - 1. Equals the cell Key() gives for acos(cosine) up to float
  /// rounding at a boundary; no trigonometric call.
  int CosineCell(float cosine) const;

  /// Key of the pair (p1, n1) -> (p2, n2) (metres, unit normals) computed from the cosines of
  /// its angles, the way training and matching both quantise pairs; `planar` (optional)
  /// receives IsPlanar of the pair. False when p1 == p2, a value is not finite or the pair
  /// is longer than the maximum distance.
  bool PairKey(const Eigen::Vector3f& p1, const Eigen::Vector3f& n1, const Eigen::Vector3f& p2,
               const Eigen::Vector3f& n2, std::uint32_t* key, bool* planar = nullptr) const;

 private:
  float distance_step_m_;
  float max_distance_m_;
  int angle_bins_;
  float angle_step_rad_;
  int distance_cells_;
  int angle_cells_;
  std::uint32_t num_keys_;
  static constexpr int kCosLutSize = 4096;
  int right_angle_cell_ = 0;
  std::vector<float> cos_bounds_;      // cos(k * step), k = 0 .. angle_cells_ - 1
  std::vector<std::uint8_t> cos_lut_;  // cell of the upper end of each cosine interval
};

/// The rigid transform T that maps p to the origin and rotates n onto +x (Drost's T_{m->g}).
Eigen::Isometry3f AlignToXAxis(const Eigen::Vector3f& p, const Eigen::Vector3f& n);

/// Rotation angle about x of the point p2 after T = AlignToXAxis(p1, n1):
/// atan2(z, y) of T * p2, radians in [-pi, pi].
float PairAngle(const Eigen::Isometry3f& T, const Eigen::Vector3f& p2);

/// Options of the PPF model table.
struct PpfTableOptions {
  /// Angle quantisation: 2 pi / angle_bins per step (30 = 12 degrees, as Drost).
  int angle_bins = 30;
  /// Store the nearly coplanar pairs (see PpfQuantizer::IsPlanar). Matching decides how
  /// to weight them; false saves memory and time when matching never uses them.
  bool store_planar_pairs = false;
};

/// The global model description of Drost et al.: every ordered pair of sampled model points,
/// stored in a flat table indexed by the quantised feature (offsets into one contiguous
/// array, so a look-up is two reads and no hashing), with the reference point index and the
/// precomputed model angle alpha_m of each pair.
class PpfTable final {
 public:
  struct Entry {
    std::uint32_t model_reference = 0;  ///< Index of the first point of the pair.
    float alpha_m_rad = 0.0f;           ///< PairAngle of the pair, radians.
  };

  PpfTable() = default;

  /// Trains on a sampled model (points in metres in the model frame M, unit normals) with
  /// distances quantised in steps of `distance_step_m`. `diameter_m` bounds the pair
  /// distance (pairs further apart are dropped). Throws std::invalid_argument for an empty
  /// model, a model without normals, non-finite or non-unit normals, or more than 8192
  /// points (sample the model coarser).
  PpfTable(const geometry::PointCloud& sampled_model, float diameter_m, float distance_step_m,
           const PpfTableOptions& options = {});

  /// Rebuilds a table from serialised parts; validates sizes and throws
  /// std::invalid_argument naming the inconsistent part.
  PpfTable(geometry::PointCloud sampled_model, float diameter_m, float distance_step_m,
           int angle_bins, bool store_planar_pairs, std::vector<std::uint32_t> offsets,
           std::vector<Entry> entries);

  const geometry::PointCloud& sampled_model() const { return model_; }
  const PpfQuantizer& quantizer() const { return quantizer_; }
  float diameter_m() const { return diameter_m_; }
  bool store_planar_pairs() const { return store_planar_pairs_; }
  const std::vector<std::uint32_t>& offsets() const { return offsets_; }
  const std::vector<Entry>& entries() const { return entries_; }
  /// Nearest-neighbour index over the sampled model points.
  const KdTree& model_tree() const { return tree_; }

  /// Entries stored under `key` as [begin, end). `key` must be < quantizer().num_keys().
  const Entry* begin(std::uint32_t key) const { return entries_.data() + offsets_[key]; }
  const Entry* end(std::uint32_t key) const { return entries_.data() + offsets_[key + 1]; }

  /// Sub-steps per alpha bin of the fixed-point model angles in vote_codes().
  static constexpr int kAlphaSubsteps = 16;
  /// The entries packed for voting, one per entry in the same order:
  /// (model_reference << 13) | code, where code = floor((alpha_m_rad + pi) / (2 pi) *
  /// angle_bins * kAlphaSubsteps) in [0, angle_bins * kAlphaSubsteps).
  const std::vector<std::uint32_t>& vote_codes() const { return vote_codes_; }

 private:
  geometry::PointCloud model_;
  float diameter_m_ = 0.0f;
  bool store_planar_pairs_ = true;
  PpfQuantizer quantizer_{1.0f, 1.0f, 30};
  std::vector<std::uint32_t> offsets_;
  std::vector<Entry> entries_;
  std::vector<std::uint32_t> vote_codes_;
  KdTree tree_;

  void BuildVoteCodes();
};

/// Options of MatchPpf. Defaults suit a sensor scene sampled with the model's sampling
/// distance.
struct PpfMatchOptions {
  /// Every k-th point of the sampled scene is a reference point (>= 1).
  int reference_step = 5;
  /// Weight of the votes of nearly coplanar pairs, in [0, 1]; 0 skips them (default).
  /// These pairs vote for every model point of a plane equally and flood the accumulator
  /// with ambiguous votes on planar scenes (tables, shelf walls); skipping them also avoids
  /// the largest table buckets. Pairs across faces and curved surfaces carry the pose.
  float planar_pair_weight = 0.0f;
  /// Accumulator peaks kept per reference point (>= 1): the highest and others with at
  /// least peak_ratio of its votes.
  int peaks_per_reference = 3;
  float peak_ratio = 0.9f;
  /// Pose clustering: poses within this translation (fraction of the model diameter) and
  /// rotation (radians) of a cluster's first pose join it.
  float cluster_translation_rel = 0.1f;
  float cluster_rotation_rad = 0.4f;
  /// Clusters whose poses place the model identically (a symmetric object): the relative
  /// transform maps the sampled model onto itself within this mean distance, in units of
  /// the distance step. <= 0 disables the merge.
  float symmetry_tolerance_rel = 0.5f;
  /// Hinterstoisser et al. (2016): per reference point, a scene pair whose feature key and
  /// scene angle bin were already voted for is skipped (one 32-bit flag word per key; with
  /// more than 32 angle bins neighbouring bins share a flag). Nearly identical scene pairs
  /// then vote once, which removes most look-ups on dense surfaces.
  bool skip_duplicate_votes = true;
  /// Number of pose hypotheses returned (>= 1).
  int max_hypotheses = 10;
  /// Worker threads over the reference points; 0 = hardware concurrency.
  int num_threads = 0;
  /// Scene segments (e.g. euclidean clusters): one label per scene point, any value (points
  /// of no segment share one label, e.g. -1); empty: the whole scene is one segment. Each
  /// segment's reference points have their poses clustered on their own and every segment
  /// contributes its best hypotheses_per_segment clusters before the remaining places go by
  /// votes: an item among larger neighbours gets hypotheses although the neighbours collect
  /// more votes. Pairs still span segments.
  std::vector<std::int32_t> segments;
  /// Hypotheses kept per segment (>= 1) when `segments` is set.
  int hypotheses_per_segment = 2;
  /// Voting stops at this time and the hypotheses come from the reference points voted so
  /// far (PpfMatchResult::timed_out). Reference points are visited in an order spread over
  /// the whole scene, so a partial vote still covers it. Default: no limit.
  std::chrono::steady_clock::time_point deadline = std::chrono::steady_clock::time_point::max();
  /// The clock `deadline` is judged by (read by the voting threads).
  BudgetClock clock;
};

/// One pose cluster.
struct PpfHypothesis {
  Eigen::Isometry3d X_SceneModel = Eigen::Isometry3d::Identity();  ///< Proper rotation.
  double votes = 0.0;  ///< Sum of the votes of the poses in the cluster.
  int num_poses = 0;   ///< Poses in the cluster (including merged symmetric clusters).
};

struct PpfMatchResult {
  /// Sorted by votes, highest first; with segments, in hypotheses_per_segment rounds first
  /// (every segment's best hypothesis, segments by their best votes, then every segment's
  /// second one, ...), then the other clusters of all segments by votes; at most
  /// max_hypotheses in all.
  std::vector<PpfHypothesis> hypotheses;
  int reference_points = 0;
  /// Reference points that voted (fewer than reference_points when the deadline stopped the
  /// voting).
  int voted_reference_points = 0;
  bool timed_out = false;
  std::int64_t pair_lookups = 0;  ///< Scene pairs looked up in the table.
  std::int64_t votes_cast = 0;
  /// Scene pairs not looked up because their key and scene angle bin had voted already.
  std::int64_t duplicate_pairs = 0;
};

/// Drost's voting scheme: for each reference point of `scene` (points in the scene frame S
/// in metres with unit normals, sampled with the model's distance step) pairs it with every
/// scene point within the model diameter, looks the pair feature up, votes for (model
/// reference point, alpha) in an accumulator reused per reference point, and turns the
/// peaks into poses X_SceneModel, which are clustered. Threads share nothing but the
/// read-only inputs; the result does not depend on the number of threads.
///
/// `scene_tree` must index scene.points. Throws std::invalid_argument for a scene without
/// normals, channel length mismatches, a tree of another size or invalid options.
PpfMatchResult MatchPpf(const PpfTable& table, const geometry::PointCloud& scene,
                        const KdTree& scene_tree, const PpfMatchOptions& options = {});

/// Greedy pose clustering used by MatchPpf, exposed for tests: `poses` with their votes are
/// visited by decreasing votes; each joins the first cluster whose first pose is within the
/// thresholds, otherwise starts a new one. Cluster poses are the vote-weighted mean of the
/// translations and of the (sign-aligned) quaternions, re-normalised to a proper rotation.
std::vector<PpfHypothesis> ClusterPoses(const std::vector<Eigen::Isometry3d>& poses,
                                        const std::vector<double>& votes,
                                        double translation_threshold_m,
                                        double rotation_threshold_rad);

/// Rotation angle of R_a^T R_b, radians in [0, pi].
double RotationAngle(const Eigen::Matrix3d& R_a, const Eigen::Matrix3d& R_b);

}  // namespace picking::detector
