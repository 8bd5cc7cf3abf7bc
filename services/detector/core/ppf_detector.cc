#include "services/detector/core/ppf_detector.h"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "libs/parallel/parallel_for.h"
#include "services/detector/core/ppf_cloud.h"

namespace picking::detector {
namespace {

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

}  // namespace

ViewRangeGrid::ViewRangeGrid(const std::vector<Eigen::Vector3f>& points_S,
                             const Eigen::Vector3f& viewpoint_S, float cell_rad)
    : viewpoint_(viewpoint_S), cell_rad_(cell_rad) {
  if (!(cell_rad > 0.0f) || !std::isfinite(cell_rad)) {
    throw std::invalid_argument("ViewRangeGrid: cell_rad must be positive, got " +
                                std::to_string(cell_rad));
  }
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : points_S) {
    const Eigen::Vector3f d = p - viewpoint_S;
    const float n = d.norm();
    if (n > 0.0f && std::isfinite(n)) mean += (d / n).cast<double>();
  }
  if (!(mean.norm() > 1e-9)) return;
  const Eigen::Vector3f axis = mean.normalized().cast<float>();
  const Eigen::Vector3f b = axis.unitOrthogonal();
  R_.row(0) = axis.transpose();
  R_.row(1) = b.transpose();
  R_.row(2) = axis.cross(b).transpose();
  float u_lo = std::numeric_limits<float>::max(), v_lo = u_lo, u_hi = -u_lo, v_hi = -u_lo;
  for (const auto& p : points_S) {
    const Eigen::Vector3f q = R_ * (p - viewpoint_S);
    if (!(q.x() > 0.0f)) continue;
    const float u = std::atan2(q.y(), q.x()), v = std::atan2(q.z(), q.x());
    u_lo = std::min(u_lo, u);
    u_hi = std::max(u_hi, u);
    v_lo = std::min(v_lo, v);
    v_hi = std::max(v_hi, v);
  }
  if (u_lo > u_hi) return;
  constexpr double kMaxCells = 1 << 22;
  const double cells = (static_cast<double>(u_hi - u_lo) / cell_rad_ + 1.0) *
                       (static_cast<double>(v_hi - v_lo) / cell_rad_ + 1.0);
  if (cells > kMaxCells) cell_rad_ *= static_cast<float>(std::sqrt(cells / kMaxCells)) * 1.01f;
  u0_ = u_lo;
  v0_ = v_lo;
  width_ = static_cast<int>((u_hi - u_lo) / cell_rad_) + 1;
  height_ = static_cast<int>((v_hi - v_lo) / cell_rad_) + 1;
  ranges_.assign(static_cast<std::size_t>(width_) * height_,
                 std::numeric_limits<float>::infinity());
  for (const auto& p : points_S) {
    int u = 0, v = 0;
    if (!Cell(p, &u, &v)) continue;
    float& r = ranges_[static_cast<std::size_t>(v) * width_ + u];
    r = std::min(r, (p - viewpoint_S).norm());
  }
}

bool ViewRangeGrid::Cell(const Eigen::Vector3f& p_S, int* u, int* v) const {
  const Eigen::Vector3f q = R_ * (p_S - viewpoint_);
  if (!(q.x() > 0.0f)) return false;
  const float fu = (std::atan2(q.y(), q.x()) - u0_) / cell_rad_;
  const float fv = (std::atan2(q.z(), q.x()) - v0_) / cell_rad_;
  if (!(fu >= 0.0f && fv >= 0.0f && fu < width_ && fv < height_)) return false;
  *u = static_cast<int>(fu);
  *v = static_cast<int>(fv);
  return true;
}

float ViewRangeGrid::MinRange(const Eigen::Vector3f& p_S) const {
  int u = 0, v = 0;
  if (ranges_.empty() || !Cell(p_S, &u, &v)) return std::numeric_limits<float>::infinity();
  return ranges_[static_cast<std::size_t>(v) * width_ + u];
}

float ViewRangeGrid::MinRangeNear(const Eigen::Vector3f& p_S, int radius_cells) const {
  int u = 0, v = 0;
  if (ranges_.empty() || !Cell(p_S, &u, &v)) return std::numeric_limits<float>::infinity();
  float r = std::numeric_limits<float>::infinity();
  for (int y = std::max(0, v - radius_cells); y <= std::min(height_ - 1, v + radius_cells); ++y) {
    for (int x = std::max(0, u - radius_cells); x <= std::min(width_ - 1, u + radius_cells); ++x) {
      r = std::min(r, ranges_[static_cast<std::size_t>(y) * width_ + x]);
    }
  }
  return r;
}

PpfScene PreparePpfScene(const geometry::PointCloud& scene, const ObjectModel& model,
                         const PpfSceneOptions& options) {
  CheckCloudChannels(scene, "PreparePpfScene");
  if (scene.empty()) throw std::invalid_argument("PreparePpfScene: the scene cloud is empty");
  if (options.use_input_normals && !scene.has_normals()) {
    throw std::invalid_argument("PreparePpfScene: use_input_normals set but the scene has none");
  }
  geometry::PointCloud valid = RemoveInvalidPoints(scene);
  if (valid.empty()) throw std::invalid_argument("PreparePpfScene: no finite scene point");
  IntensitiesFromColors(&valid);
  valid.colors.clear();
  if (!options.use_input_normals) valid.normals.clear();
  PpfScene out;
  out.viewpoint = options.viewpoint;
  out.fine = VoxelAverage(valid, model.fine_voxel_m());
  if (!options.use_input_normals) {
    PcaNormalOptions normal_options;
    normal_options.radius_m = model.normal_radius_m();
    normal_options.orientation = NormalOrientation::kTowardViewpoint;
    normal_options.viewpoint = options.viewpoint;
    out.fine = EstimatePcaNormals(out.fine, normal_options);
  }
  out.sampled = VoxelAverage(out.fine, model.sampling_distance_m());
  out.sampled.intensities.clear();
  out.fine_tree = KdTree(out.fine.points);
  out.sampled_tree = KdTree(out.sampled.points);
  // Cells of about two fine voxels at the median range, so that a surface leaves few holes.
  if (!out.fine.empty()) {
    std::vector<float> ranges;
    ranges.reserve(out.fine.size());
    for (const auto& p : out.fine.points) ranges.push_back((p - options.viewpoint).norm());
    std::nth_element(ranges.begin(), ranges.begin() + ranges.size() / 2, ranges.end());
    const float median = ranges[ranges.size() / 2];
    if (median > 0.0f) {
      out.view_ranges =
          ViewRangeGrid(out.fine.points, options.viewpoint, 2.0f * model.fine_voxel_m() / median);
    }
  }
  return out;
}

SceneAgreement MeasureAgreement(const ObjectModel& model, const PpfScene& scene,
                                const Eigen::Isometry3d& X_SceneModel, float distance_m,
                                float normal_angle_rad, float conflict_distance_m) {
  return MeasureAgreement(model.icp_cloud(), scene, X_SceneModel, distance_m, normal_angle_rad,
                          conflict_distance_m);
}

SceneAgreement MeasureAgreement(const geometry::PointCloud& m, const PpfScene& scene,
                                const Eigen::Isometry3d& X_SceneModel, float distance_m,
                                float normal_angle_rad, float conflict_distance_m) {
  if (!m.has_normals() || m.normals.size() != m.points.size()) {
    throw std::invalid_argument("MeasureAgreement: the model needs one normal per point");
  }
  const Eigen::Isometry3f X = X_SceneModel.cast<float>();
  const float d2_max = distance_m * distance_m;
  const float min_cos = std::cos(normal_angle_rad);
  // Something measured this far in front of a model point hides it from the sensor.
  const float occlusion_m = std::max(conflict_distance_m, 2.0f * distance_m);
  int visible = 0;
  int supported = 0;
  int conflicts = 0;
  int occluded = 0;
  for (std::size_t i = 0; i < m.size(); ++i) {
    const Eigen::Vector3f p = X * m.points[i];
    const Eigen::Vector3f n = X.linear() * m.normals[i];
    if (n.dot(scene.viewpoint - p) <= 0.0f) continue;
    ++visible;
    float d2 = 0.0f;
    const std::int32_t j = scene.fine_tree.Nearest(p, &d2, d2_max);
    if (j != KdTree::kNone && scene.fine.normals[j].dot(n) >= min_cos) {
      ++supported;
      continue;
    }
    const Eigen::Vector3f ray = scene.viewpoint - p;
    const float range = ray.norm();
    if (scene.view_ranges.MinRange(p) < range - occlusion_m) {
      ++occluded;
    } else if (n.dot(ray) >= kMinConflictViewCos * range &&
               scene.view_ranges.MinRangeNear(p, 1) - range > conflict_distance_m) {
      ++conflicts;  // +infinity (no measurement around the ray) is not a conflict
    }
  }
  SceneAgreement out;
  out.visible_points = visible;
  out.occluded_points = occluded;
  const int unoccluded = visible - occluded;
  if (unoccluded > 0) {
    out.support = static_cast<double>(supported) / unoccluded;
    out.conflict_fraction = static_cast<double>(conflicts) / unoccluded;
  }
  return out;
}

double SceneSupport(const ObjectModel& model, const PpfScene& scene,
                    const Eigen::Isometry3d& X_SceneModel, float distance_m, float normal_angle_rad,
                    int* visible_points) {
  const SceneAgreement a =
      MeasureAgreement(model, scene, X_SceneModel, distance_m, normal_angle_rad, 0.0f);
  if (visible_points != nullptr) *visible_points = a.visible_points;
  return a.support;
}

namespace {

// Scene points matched by the posed model's visible points, with their shading-compensated
// intensities: what the appearance of a pose (and of its symmetric turns) is judged on.
struct AppearanceSamples {
  std::vector<Eigen::Vector3f> p_S;
  std::vector<float> intensity;
};

AppearanceSamples CollectAppearanceSamples(const ObjectModel& model, const PpfScene& scene,
                                           const Eigen::Isometry3d& X_SceneModel, float distance_m,
                                           float normal_angle_rad,
                                           const AppearanceOptions& options) {
  AppearanceSamples out;
  if (!model.has_albedo() || !scene.fine.has_intensities() || !scene.fine.has_normals()) return out;
  const Eigen::Isometry3f X = X_SceneModel.cast<float>();
  const float d2_max = distance_m * distance_m;
  const float min_cos = std::cos(normal_angle_rad);
  const geometry::PointCloud& m = model.icp_cloud();
  for (std::size_t i = 0; i < m.size(); ++i) {
    const Eigen::Vector3f p = X * m.points[i];
    const Eigen::Vector3f n = X.linear() * m.normals[i];
    if (n.dot(scene.viewpoint - p) <= 0.0f) continue;
    float d2 = 0.0f;
    const std::int32_t j = scene.fine_tree.Nearest(p, &d2, d2_max);
    if (j == KdTree::kNone || scene.fine.normals[j].dot(n) < min_cos) continue;
    const std::optional<float> sample = AppearanceSample(
        scene.fine.intensities[j], scene.fine.points[j], n, scene.viewpoint, options);
    if (!sample) continue;
    out.p_S.push_back(scene.fine.points[j]);
    out.intensity.push_back(*sample);
  }
  return out;
}

// Correlation of the samples with the albedo of the model posed at X_SceneModel. With
// `off_surface`, also their mean truncated squared point-to-plane distance to the model
// surface, min(r^2, tau^2) / tau^2 (1 for a sample with no model point within lookup_m).
AppearanceScore ScoreAppearanceSamples(const ObjectModel& model, const AppearanceSamples& samples,
                                       const Eigen::Isometry3d& X_SceneModel, float lookup_m,
                                       const AppearanceOptions& options, float tau_m = 0.0f,
                                       double* off_surface = nullptr) {
  const Eigen::Isometry3f X_ModelScene = X_SceneModel.inverse().cast<float>();
  const float d2_max = lookup_m * lookup_m;
  const float tau_sq = tau_m * tau_m;
  const geometry::PointCloud& fine = model.fine_cloud();
  std::vector<float> albedo, intensity;
  std::vector<std::uint8_t> patches;
  albedo.reserve(samples.p_S.size());
  intensity.reserve(samples.p_S.size());
  patches.reserve(samples.p_S.size());
  double off = 0.0;
  for (std::size_t k = 0; k < samples.p_S.size(); ++k) {
    const Eigen::Vector3f q = X_ModelScene * samples.p_S[k];
    const std::int32_t i = model.fine_tree().Nearest(q, nullptr, d2_max);
    if (i == KdTree::kNone) {
      off += 1.0;
      continue;
    }
    if (off_surface != nullptr) {
      const float r = fine.normals[i].dot(q - fine.points[i]);
      off += std::min(r * r, tau_sq) / tau_sq;
    }
    albedo.push_back(fine.intensities[i]);
    intensity.push_back(samples.intensity[k]);
    patches.push_back(model.fine_patches()[i]);
  }
  if (off_surface != nullptr) {
    *off_surface = samples.p_S.empty() ? 0.0 : off / static_cast<double>(samples.p_S.size());
  }
  return CorrelateAppearance(albedo, intensity, options, &patches);
}

float AppearanceLookupDistance(const ObjectModel& model, float distance_m) {
  return std::max(distance_m, 2.0f * model.fine_voxel_m());
}

}  // namespace

AppearanceScore MeasureAppearance(const ObjectModel& model, const PpfScene& scene,
                                  const Eigen::Isometry3d& X_SceneModel, float distance_m,
                                  float normal_angle_rad, const AppearanceOptions& options) {
  options.Validate();
  const AppearanceSamples samples =
      CollectAppearanceSamples(model, scene, X_SceneModel, distance_m, normal_angle_rad, options);
  if (samples.p_S.empty()) return {};
  return ScoreAppearanceSamples(model, samples, X_SceneModel,
                                AppearanceLookupDistance(model, distance_m), options);
}

SymmetricAppearance MatchSymmetricAppearance(const ObjectModel& model, const PpfScene& scene,
                                             const Eigen::Isometry3d& X_SceneModel,
                                             float distance_m, float normal_angle_rad,
                                             const AppearanceOptions& options) {
  options.Validate();
  SymmetricAppearance out;
  out.X_SceneModel = X_SceneModel;
  const AppearanceSamples samples =
      CollectAppearanceSamples(model, scene, X_SceneModel, distance_m, normal_angle_rad, options);
  if (samples.p_S.empty()) return out;
  const float lookup_m = AppearanceLookupDistance(model, distance_m);
  const std::vector<Eigen::Isometry3d>& turns = model.symmetries();
  for (std::size_t s = 0; s < turns.size(); ++s) {
    const Eigen::Isometry3d X = X_SceneModel * turns[s];
    const AppearanceScore a = ScoreAppearanceSamples(model, samples, X, lookup_m, options);
    if (s == 0) {
      out.unturned = a;
      out.appearance = a;
      continue;
    }
    if (a.defined && (!out.appearance.defined || a.correlation > out.appearance.correlation)) {
      out.appearance = a;
      out.symmetry = static_cast<int>(s);
      out.X_SceneModel = X;
    }
  }
  // A cylinder's turns are a grid: refine the best one between its neighbours (a step of 10
  // degrees is a centimetre of arc on a 6 cm radius, as much as a printed detail).
  const ModelSymmetry symmetry = model.options().symmetry;
  if (out.appearance.defined &&
      (symmetry == ModelSymmetry::kCylinderX || symmetry == ModelSymmetry::kCylinderZ)) {
    const Eigen::Vector3d axis =
        symmetry == ModelSymmetry::kCylinderX ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitZ();
    const double step = 2.0 * M_PI / model.options().cylinder_symmetry_steps;
    const Eigen::Isometry3d X_best = out.X_SceneModel;
    for (double fraction : {-0.375, -0.25, -0.125, 0.125, 0.25, 0.375}) {
      Eigen::Isometry3d turn = Eigen::Isometry3d::Identity();
      turn.linear() = Eigen::AngleAxisd(fraction * step, axis).toRotationMatrix();
      const Eigen::Isometry3d X = X_best * turn;
      const AppearanceScore a = ScoreAppearanceSamples(model, samples, X, lookup_m, options);
      if (a.defined && a.correlation > out.appearance.correlation) {
        out.appearance = a;
        out.X_SceneModel = X;
      }
    }
  }
  return out;
}

void AppearanceSearchOptions::Validate() const {
  if (levels < 0) throw std::invalid_argument("AppearanceSearchOptions: levels must be >= 0");
  if (!(start_step_m > 0.0) || !std::isfinite(start_step_m)) {
    throw std::invalid_argument("AppearanceSearchOptions: start_step_m must be positive");
  }
  if (max_samples < 30) {
    throw std::invalid_argument("AppearanceSearchOptions: max_samples must be >= 30");
  }
  if (max_moves_per_level < 1) {
    throw std::invalid_argument("AppearanceSearchOptions: max_moves_per_level must be >= 1");
  }
}

AppearancePose SearchAppearancePose(const ObjectModel& model, const PpfScene& scene,
                                    const Eigen::Isometry3d& X_SceneModel, float distance_m,
                                    float normal_angle_rad, const AppearanceOptions& options,
                                    const AppearanceSearchOptions& search) {
  options.Validate();
  search.Validate();
  AppearancePose out;
  out.X_SceneModel = X_SceneModel;
  if (search.levels == 0) {
    out.appearance =
        MeasureAppearance(model, scene, X_SceneModel, distance_m, normal_angle_rad, options);
    return out;
  }
  const AppearanceSamples all =
      CollectAppearanceSamples(model, scene, X_SceneModel, distance_m, normal_angle_rad, options);
  if (all.p_S.empty()) return out;
  const float lookup_m = AppearanceLookupDistance(model, distance_m);
  out.appearance = ScoreAppearanceSamples(model, all, X_SceneModel, lookup_m, options);
  if (!out.appearance.defined) return out;

  // An even subset: the search's many evaluations need the shape of the correlation, not
  // its last digit.
  AppearanceSamples subset;
  const std::size_t stride = (all.p_S.size() + static_cast<std::size_t>(search.max_samples) - 1) /
                             static_cast<std::size_t>(search.max_samples);
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (std::size_t k = 0; k < all.p_S.size(); k += stride) {
    subset.p_S.push_back(all.p_S[k]);
    subset.intensity.push_back(all.intensity[k]);
    centroid += all.p_S[k].cast<double>();
  }
  centroid /= static_cast<double>(subset.p_S.size());
  // Moves along and about the samples' principal axes: for a face, two slide in it and one
  // leaves it, so the search's steps do not zig-zag across a tilted plane.
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  for (const Eigen::Vector3f& p : subset.p_S) {
    const Eigen::Vector3d d = p.cast<double>() - centroid;
    covariance += d * d.transpose();
  }
  covariance /= static_cast<double>(subset.p_S.size());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> pca(covariance);
  const Eigen::Matrix3d axes = pca.eigenvectors();
  const double radius = std::max(1e-3, std::sqrt(covariance.trace()));

  // The objective: the print's correlation, less the samples' mean truncated point-to-plane
  // distance to the model surface (squared, over tau squared). The print alone is blind to
  // a move off the surface, which the look-up's tolerance lets pass; the geometric term
  // keeps the surface where ICP put it and leaves free what the shape leaves free.
  const float tau = std::max(1e-4f, 0.5f * distance_m);
  // Objectives lie in [-2, 1]; a pose whose samples give no evidence is worse than any.
  constexpr double kNoEvidence = -std::numeric_limits<double>::infinity();
  const auto score = [&](const Eigen::Isometry3d& X) {
    double off_surface = 0.0;
    const AppearanceScore a =
        ScoreAppearanceSamples(model, subset, X, lookup_m, options, tau, &off_surface);
    return a.defined ? a.correlation - off_surface : kNoEvidence;
  };
  Eigen::Isometry3d X_best = X_SceneModel;
  double best = score(X_best);
  if (best == kNoEvidence) return out;
  double step = search.start_step_m;
  for (int level = 0; level < search.levels; ++level, step *= 0.5) {
    for (int move = 0; move < search.max_moves_per_level; ++move) {
      Eigen::Isometry3d X_move = X_best;
      double move_score = best;
      for (int axis = 0; axis < 6; ++axis) {
        for (double sign : {-1.0, 1.0}) {
          Eigen::Isometry3d delta = Eigen::Isometry3d::Identity();
          if (axis < 3) {
            delta.translation() = sign * step * axes.col(axis);
          } else {
            // Turn about the samples' centroid: S <- c + R (S - c).
            const Eigen::Matrix3d R =
                Eigen::AngleAxisd(sign * step / radius, axes.col(axis - 3)).toRotationMatrix();
            delta.linear() = R;
            delta.translation() = centroid - R * centroid;
          }
          const Eigen::Isometry3d X = delta * X_best;
          const double s = score(X);
          if (s > move_score + 1e-4) {
            move_score = s;
            X_move = X;
          }
        }
      }
      if (!(move_score > best)) break;
      best = move_score;
      X_best = X_move;
    }
  }
  const AppearanceScore final_score = ScoreAppearanceSamples(model, all, X_best, lookup_m, options);
  if (final_score.defined && final_score.correlation > out.appearance.correlation) {
    out.appearance = final_score;
    out.X_SceneModel = X_best;
  }
  return out;
}

namespace {

// Throws std::invalid_argument naming the first bad field of DetectPpf's options, or for an
// empty prepared scene; the checks run in a fixed order (that of the messages below).
void ValidateDetectorInputs(const PpfScene& scene, const PpfDetectorOptions& options) {
  if (options.coarse_icp_stride < 1) {
    throw std::invalid_argument("PpfDetectorOptions: coarse_icp_stride must be >= 1");
  }
  if (options.hypotheses_to_verify < 1) {
    throw std::invalid_argument("PpfDetectorOptions: hypotheses_to_verify must be >= 1");
  }
  if (!(options.max_conflict_fraction >= 0.0f && options.max_conflict_fraction <= 1.0f)) {
    throw std::invalid_argument("PpfDetectorOptions: max_conflict_fraction must be in [0, 1]");
  }
  if (!(options.min_visible_fraction >= 0.0f && options.min_visible_fraction <= 1.0f)) {
    throw std::invalid_argument("PpfDetectorOptions: min_visible_fraction must be in [0, 1]");
  }
  if (options.min_visible_points < 0) {
    throw std::invalid_argument("PpfDetectorOptions: min_visible_points must be >= 0");
  }
  if (!(options.conflict_distance_rel > 0.0f)) {
    throw std::invalid_argument("PpfDetectorOptions: conflict_distance_rel must be positive");
  }
  if (scene.sampled.empty() || scene.fine.empty()) {
    throw std::invalid_argument("DetectPpf: the prepared scene is empty");
  }
  options.appearance.Validate();
  options.appearance_search.Validate();
  if (!(options.appearance_weight >= 0.0f) || !std::isfinite(options.appearance_weight)) {
    throw std::invalid_argument("PpfDetectorOptions: appearance_weight must be >= 0");
  }
  if (!(options.min_appearance_correlation >= -1.0f &&
        options.min_appearance_correlation <= 1.0f)) {
    throw std::invalid_argument(
        "PpfDetectorOptions: min_appearance_correlation must be in [-1, 1]");
  }
  if (!(options.seed_keep_margin >= 0.0f)) {
    throw std::invalid_argument("PpfDetectorOptions: seed_keep_margin must be >= 0");
  }
  if (!(options.seed_refine_fraction >= 0.0f && options.seed_refine_fraction < 1.0f)) {
    throw std::invalid_argument("PpfDetectorOptions: seed_refine_fraction must be in [0, 1)");
  }
}

// How a verified hypothesis ranks (higher is better): support - conflicts +
// appearance_weight * print correlation (0 without appearance evidence).
double RankOf(double support, double conflict_fraction, const AppearanceScore& appearance,
              const PpfDetectorOptions& options) {
  return support - conflict_fraction +
         options.appearance_weight * (appearance.defined ? appearance.correlation : 0.0);
}

// One hypothesis to refine: a voted one (index into the match's hypotheses) or a seed pose
// (index into the seed_source's poses).
struct RefineJob {
  bool seed = false;
  std::size_t index = 0;
};

// Refines one hypothesis and measures it against the scene: ICP (coarse for voted ones, then
// fine), the model's symmetric turn whose print fits best, the print search (voted ones) and,
// for a seed, its unrefined pose when that agrees better. Read-only, shared by the threads.
class HypothesisRefiner {
 public:
  HypothesisRefiner(const ObjectModel& model, const PpfScene& scene,
                    const PpfDetectorOptions& options);

  // Support and conflicts of X_SceneModel at the options' distances (relative to the step).
  SceneAgreement Agreement(const Eigen::Isometry3d& X_SceneModel) const;

  // The refined and measured detection of `job`, which starts at hypotheses[job.index]
  // (voted) or seed_poses[job.index] (seed).
  PpfDetection Refine(const RefineJob& job, const std::vector<PpfHypothesis>& hypotheses,
                      const std::vector<Eigen::Isometry3d>& seed_poses) const;

 private:
  // ICP from X (X_SceneModel, a copy the passes move): the coarse pass (not for a seed: the
  // scene's surfaces place it already, and the pass would let it slide to a neighbour's),
  // then the fine one. Sets d->icp and d->X_SceneModel (X as the coarse pass left it when
  // the fine one finds too few correspondences).
  void FitIcp(Eigen::Isometry3d X, bool seed, PpfDetection* d) const;

  // Moves *d to the nearby pose whose print fits better (SearchAppearancePose) when that
  // ranks higher: the print may not buy a worse fit of the shape. Returns the agreement of
  // the pose kept when the search compared two, so that it is measured once.
  std::optional<SceneAgreement> SearchPrint(PpfDetection* d) const;

  const ObjectModel& model_;
  const PpfScene& scene_;
  const PpfDetectorOptions& options_;
  const float step_m_;  // the model's sampling distance, metres
  IcpOptions coarse_;
  IcpOptions fine_;
  // Every coarse_icp_stride-th ICP point of the model; empty without a coarse pass.
  geometry::PointCloud coarse_model_;
  const float support_m_;  // support_distance_rel * step_m_, metres
};

HypothesisRefiner::HypothesisRefiner(const ObjectModel& model, const PpfScene& scene,
                                     const PpfDetectorOptions& options)
    : model_(model),
      scene_(scene),
      options_(options),
      step_m_(model.sampling_distance_m()),
      coarse_(options.icp),
      fine_(options.icp),
      support_m_(options.support_distance_rel * step_m_) {
  coarse_.max_correspondence_distance_m = options.coarse_icp_distance_rel * step_m_;
  coarse_.loss_scale_m = options.icp_loss_scale_rel * step_m_ * 2.0f;
  coarse_.max_iterations = options.coarse_icp_iterations;
  fine_.max_correspondence_distance_m = options.icp_distance_rel * step_m_;
  fine_.loss_scale_m = options.icp_loss_scale_rel * step_m_;
  // Only the model's side facing the sensor can have partners in the scene.
  coarse_.viewpoint = scene.viewpoint;
  fine_.viewpoint = scene.viewpoint;
  if (options.coarse_icp_iterations > 0) {
    coarse_model_ =
        EveryNthPoint(model.icp_cloud(), static_cast<std::size_t>(options.coarse_icp_stride));
  }
}

SceneAgreement HypothesisRefiner::Agreement(const Eigen::Isometry3d& X_SceneModel) const {
  return MeasureAgreement(model_, scene_, X_SceneModel, support_m_,
                          options_.support_normal_angle_rad,
                          options_.conflict_distance_rel * step_m_);
}

void HypothesisRefiner::FitIcp(Eigen::Isometry3d X, bool seed, PpfDetection* d) const {
  if (options_.coarse_icp_iterations > 0 && !seed) {
    const IcpResult c = RunIcp(coarse_model_, scene_.fine, scene_.fine_tree, X, coarse_);
    if (c.correspondences >= coarse_.min_correspondences) X = c.X_TargetSource;
  }
  d->icp = RunIcp(model_.icp_cloud(), scene_.fine, scene_.fine_tree, X, fine_);
  d->X_SceneModel = d->icp.correspondences >= fine_.min_correspondences ? d->icp.X_TargetSource : X;
}

std::optional<SceneAgreement> HypothesisRefiner::SearchPrint(PpfDetection* d) const {
  std::optional<SceneAgreement> kept;
  const AppearancePose ap = SearchAppearancePose(model_, scene_, d->X_SceneModel, support_m_,
                                                 options_.support_normal_angle_rad,
                                                 options_.appearance, options_.appearance_search);
  if (ap.appearance.correlation > d->appearance.correlation) {
    const SceneAgreement before = Agreement(d->X_SceneModel);
    const SceneAgreement after = Agreement(ap.X_SceneModel);
    if (RankOf(after.support, after.conflict_fraction, ap.appearance, options_) >
        RankOf(before.support, before.conflict_fraction, d->appearance, options_)) {
      d->X_SceneModel = ap.X_SceneModel;
      d->appearance = ap.appearance;
      kept = after;
    } else {
      kept = before;
    }
  }
  return kept;
}

PpfDetection HypothesisRefiner::Refine(const RefineJob& job,
                                       const std::vector<PpfHypothesis>& hypotheses,
                                       const std::vector<Eigen::Isometry3d>& seed_poses) const {
  PpfDetection d;
  d.seed = job.seed;
  if (!job.seed) d.votes = hypotheses[job.index].votes;
  FitIcp(job.seed ? seed_poses[job.index] : hypotheses[job.index].X_SceneModel, job.seed, &d);
  if (model_.has_albedo() && scene_.fine.has_intensities()) {
    const SymmetricAppearance sa =
        MatchSymmetricAppearance(model_, scene_, d.X_SceneModel, support_m_,
                                 options_.support_normal_angle_rad, options_.appearance);
    d.X_SceneModel = sa.X_SceneModel;
    d.symmetry = sa.symmetry;
    d.appearance = sa.appearance;
  }
  // The agreement of the pose kept: measured once, also when the search compared two.
  std::optional<SceneAgreement> kept;
  if (options_.appearance_search.levels > 0 && d.appearance.defined && !job.seed) {
    kept = SearchPrint(&d);
  }
  SceneAgreement a = kept ? *kept : Agreement(d.X_SceneModel);
  if (job.seed) {
    // A seed placed flush on the scene's faces can be better than where ICP takes it: a
    // thin box cut by the floor band, or pulled onto a neighbour's surface.
    const Eigen::Isometry3d& X_seed = seed_poses[job.index];
    const SceneAgreement s = Agreement(X_seed);
    if (s.support - s.conflict_fraction >
        a.support - a.conflict_fraction + options_.seed_keep_margin) {
      a = s;
      d.X_SceneModel = X_seed;
    }
  }
  d.support = a.support;
  d.conflict_fraction = a.conflict_fraction;
  d.visible_points = a.visible_points;
  return d;
}

// Which refined hypotheses become detections (Passes), and which voted one is good enough
// that the seeds will not be needed (Found).
class DetectionGate {
 public:
  DetectionGate(const ObjectModel& model, const PpfDetectorOptions& options)
      : options_(options),
        min_visible_(std::max(
            static_cast<double>(options.min_visible_points),
            options.min_visible_fraction * static_cast<double>(model.icp_cloud().size()))) {}

  bool Passes(const PpfDetection& d) const {
    // A seed was screened by its source; its support and print here are seen from one
    // viewpoint, which undercounts a merged scan's side faces, so the caller's verification
    // (every view) judges it.
    return (d.seed || (d.support >= options_.min_support &&
                       !(d.appearance.defined &&
                         d.appearance.correlation < options_.min_appearance_correlation))) &&
           d.conflict_fraction <= options_.max_conflict_fraction &&
           d.visible_points >= min_visible_;
  }

  bool Found(const PpfDetection& d) const {
    return Passes(d) && d.support >= options_.seed_fallback_support;
  }

 private:
  const PpfDetectorOptions& options_;
  const double min_visible_;  // model points that must face the sensor
};

// The refinement's jobs and results, shared by its threads: the best-voted hypotheses, then
// the seed poses (added only when no voted hypothesis is found).
struct RefineWork {
  std::vector<RefineJob> jobs;
  std::vector<Eigen::Isometry3d> seed_poses;         // Filled when the fallback is taken.
  std::vector<std::optional<PpfDetection>> refined;  // Per job; empty: not refined.
  std::atomic<bool> voted_found{false};
};

// Refines jobs [begin, end) of *work in parallel, each taken only while the mean time of
// those done so far (on options.clock) still fits before the deadline (the first always is:
// early_deadline while no voted hypothesis is found, refine_deadline after); the results keep
// the jobs' order, so that without a deadline the outcome does not depend on threads. After
// the first exception of a job the jobs not started are skipped, and it is rethrown once all
// threads stopped.
void RefineRange(const HypothesisRefiner& refiner, const DetectionGate& gate,
                 const PpfDetectorOptions& options, const std::vector<PpfHypothesis>& hypotheses,
                 std::size_t begin, std::size_t end,
                 std::chrono::steady_clock::time_point early_deadline, RefineWork* work) {
  std::atomic<bool>& voted_found = work->voted_found;
  std::vector<std::optional<PpfDetection>>& refined = work->refined;
  std::atomic<std::int64_t> done{0};
  std::atomic<std::int64_t> busy_ns{0};
  const int jobs = static_cast<int>(end - begin);
  const int threads =
      std::clamp(parallel::ResolveThreads(options.match.num_threads), 1, std::max(1, jobs));
  parallel::ParallelFor(jobs, threads, [&](int job) {
    const std::size_t h = begin + static_cast<std::size_t>(job);
    const auto now = options.clock.Now();
    const std::int64_t n = done.load();
    const auto mean = std::chrono::nanoseconds(n > 0 ? busy_ns.load() / n : 0);
    // Once a voted hypothesis is found the seeds' share of the time is not needed. A thread
    // whose job does not fit skips it and stops (leaves the job); the others go on.
    if (h > begin && now + mean > (voted_found ? options.refine_deadline : early_deadline)) {
      return false;
    }
    refined[h] = refiner.Refine(work->jobs[h], hypotheses, work->seed_poses);
    if (!refined[h]->seed && gate.Found(*refined[h])) voted_found = true;
    busy_ns +=
        std::chrono::duration_cast<std::chrono::nanoseconds>(options.clock.Now() - now).count();
    ++done;
    return true;
  });
}

// Throws std::invalid_argument when a seed pose is not a finite rigid motion.
void CheckSeedPoses(const std::vector<Eigen::Isometry3d>& seed_poses) {
  for (const Eigen::Isometry3d& X : seed_poses) {
    const Eigen::Matrix3d& R = X.linear();
    if (!X.matrix().allFinite() ||
        !(R.transpose() * R).isApprox(Eigen::Matrix3d::Identity(), 1e-6) || R.determinant() < 0) {
      throw std::invalid_argument("DetectPpf: a seed pose is not a finite rigid motion");
    }
  }
}

// Refines the best-voted hypotheses and, when none of them is found and there is a
// seed_source, its poses (called once, here). Returns one entry per job, voted ones first,
// empty for a job the deadline skipped.
std::vector<std::optional<PpfDetection>> RefineHypotheses(
    const HypothesisRefiner& refiner, const DetectionGate& gate, const PpfDetectorOptions& options,
    const std::vector<PpfHypothesis>& hypotheses) {
  RefineWork work;
  const std::size_t voted =
      std::min(hypotheses.size(), static_cast<std::size_t>(options.hypotheses_to_verify));
  for (std::size_t i = 0; i < voted; ++i) work.jobs.push_back({false, i});
  work.refined.resize(voted);
  // The voted hypotheses leave seed_refine_fraction of the refinement time to the seeds,
  // unless one of them is found.
  const auto refine_start = options.clock.Now();
  auto voted_deadline = options.refine_deadline;
  if (options.seed_source &&
      options.refine_deadline != std::chrono::steady_clock::time_point::max()) {
    const auto span = std::max(std::chrono::steady_clock::duration::zero(),
                               options.refine_deadline - refine_start);
    voted_deadline = refine_start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                        span * (1.0 - options.seed_refine_fraction));
  }
  if (voted > 0) RefineRange(refiner, gate, options, hypotheses, 0, voted, voted_deadline, &work);
  if (!work.voted_found && options.seed_source) {
    work.seed_poses = options.seed_source();
    CheckSeedPoses(work.seed_poses);
    for (std::size_t i = 0; i < work.seed_poses.size(); ++i) work.jobs.push_back({true, i});
    work.refined.resize(work.jobs.size());
    if (!work.seed_poses.empty()) {
      RefineRange(refiner, gate, options, hypotheses, voted, work.jobs.size(),
                  options.refine_deadline, &work);
    }
  }
  return std::move(work.refined);
}

// Sorts the detections best rank (RankOf) first; equal ranks keep their order.
void SortByRank(const PpfDetectorOptions& options, std::vector<PpfDetection>* detections) {
  const auto rank = [&options](const PpfDetection& d) {
    return RankOf(d.support, d.conflict_fraction, d.appearance, options);
  };
  std::stable_sort(
      detections->begin(), detections->end(),
      [&rank](const PpfDetection& a, const PpfDetection& b) { return rank(a) > rank(b); });
}

// The ranked detections that pass the gate, without those within the match's cluster
// distances of one kept before them: hypotheses that converged to the same place are one
// object.
std::vector<PpfDetection> DistinctDetections(const std::vector<PpfDetection>& ranked,
                                             const DetectionGate& gate, const ObjectModel& model,
                                             const PpfDetectorOptions& options) {
  std::vector<PpfDetection> detections;
  for (const PpfDetection& d : ranked) {
    if (!gate.Passes(d)) continue;
    bool duplicate = false;
    for (const PpfDetection& kept : detections) {
      if ((kept.X_SceneModel.translation() - d.X_SceneModel.translation()).norm() <
              options.match.cluster_translation_rel * model.diameter_m() &&
          RotationAngle(kept.X_SceneModel.linear(), d.X_SceneModel.linear()) <
              options.match.cluster_rotation_rad) {
        duplicate = true;
        break;
      }
    }
    if (!duplicate) detections.push_back(d);
  }
  return detections;
}

}  // namespace

PpfDetectionResult DetectPpf(const ObjectModel& model, const PpfScene& scene,
                             const PpfDetectorOptions& options) {
  ValidateDetectorInputs(scene, options);
  PpfDetectionResult result;
  auto start = std::chrono::steady_clock::now();
  result.match = MatchPpf(model.table(), scene.sampled, scene.sampled_tree, options.match);
  result.match_s = Seconds(start);

  start = std::chrono::steady_clock::now();
  const HypothesisRefiner refiner(model, scene, options);
  const DetectionGate gate(model, options);
  std::vector<std::optional<PpfDetection>> refined =
      RefineHypotheses(refiner, gate, options, result.match.hypotheses);
  std::vector<PpfDetection> verified;
  for (std::optional<PpfDetection>& d : refined) {
    if (!d) continue;
    ++result.refined_hypotheses;
    verified.push_back(std::move(*d));
  }
  SortByRank(options, &verified);
  if (!verified.empty()) result.best = verified.front();
  result.detections = DistinctDetections(verified, gate, model, options);
  result.refine_s = Seconds(start);
  return result;
}

}  // namespace picking::detector
