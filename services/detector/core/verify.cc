#include "services/detector/core/verify.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "services/detector/core/kdtree.h"

namespace picking::detector {

struct VerificationScene::Impl {
  std::vector<float> depth;  // row-major, NaN where nothing was measured
  std::vector<Eigen::Vector3f> p_SensorPoints;
  std::vector<Eigen::Vector3f> n_SensorPoints;  // empty when the scene has no normals
  std::vector<float> intensities;               // empty when the scene has none
  KdTree tree;
};

namespace {
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
}  // namespace

VerificationScene::VerificationScene(const geometry::PointCloud& scene,
                                     const Eigen::Isometry3d& X_BaseSensor,
                                     const PinholeCamera& camera)
    : camera_(camera), X_BaseSensor_(X_BaseSensor), impl_(std::make_unique<Impl>()) {
  if (!scene.normals.empty() && scene.normals.size() != scene.size())
    throw std::invalid_argument("VerificationScene: normals size differs from points size");
  if (!scene.intensities.empty() && scene.intensities.size() != scene.size())
    throw std::invalid_argument("VerificationScene: intensities size differs from points size");
  if (!scene.colors.empty() && scene.colors.size() != scene.size())
    throw std::invalid_argument("VerificationScene: colors size differs from points size");
  const Eigen::Isometry3f X_SensorBase = X_BaseSensor.inverse().cast<float>();
  impl_->depth.assign(static_cast<std::size_t>(camera_.width()) * camera_.height(), kNaN);
  const bool normals = scene.has_normals();
  for (std::size_t i = 0; i < scene.size(); ++i) {
    if (!scene.points[i].allFinite()) continue;
    const Eigen::Vector3f p = X_SensorBase * scene.points[i];
    impl_->p_SensorPoints.push_back(p);
    if (normals) impl_->n_SensorPoints.push_back(X_SensorBase.linear() * scene.normals[i]);
    if (scene.has_intensities()) {
      impl_->intensities.push_back(scene.intensities[i]);
    } else if (scene.has_colors()) {
      impl_->intensities.push_back(ColorLuma(scene.colors[i]));
    }
    if (p.z() <= 0.0f) continue;
    const auto uv = camera_.Project(p.cast<double>());
    if (!uv) continue;
    const int u = static_cast<int>(std::lround(uv->x()));
    const int v = static_cast<int>(std::lround(uv->y()));
    if (u < 0 || v < 0 || u >= camera_.width() || v >= camera_.height()) continue;
    float& d = impl_->depth[static_cast<std::size_t>(v) * camera_.width() + u];
    if (!(d <= p.z())) d = p.z();
  }
  if (impl_->p_SensorPoints.empty())
    throw std::invalid_argument("VerificationScene: scene has no finite point");
  impl_->tree = KdTree(impl_->p_SensorPoints);
}

VerificationScene::~VerificationScene() = default;

float VerificationScene::DepthAt(int u, int v) const {
  if (u < 0 || v < 0 || u >= camera_.width() || v >= camera_.height()) return kNaN;
  const float d = impl_->depth[static_cast<std::size_t>(v) * camera_.width() + u];
  if (std::isfinite(d)) return d;
  // A single missing pixel (sparser clouds): nearest of the 8 neighbours.
  float best = kNaN;
  for (int dv = -1; dv <= 1; ++dv) {
    for (int du = -1; du <= 1; ++du) {
      const int uu = u + du, vv = v + dv;
      if (uu < 0 || vv < 0 || uu >= camera_.width() || vv >= camera_.height()) continue;
      const float n = impl_->depth[static_cast<std::size_t>(vv) * camera_.width() + uu];
      if (std::isfinite(n) && !(best <= n)) best = n;
    }
  }
  return best;
}

double MeanPointSpacing(const geometry::PointCloud& cloud) {
  std::vector<Eigen::Vector3f> finite;
  for (const auto& p : cloud.points)
    if (p.allFinite()) finite.push_back(p);
  if (finite.size() < 2) return 0.0;
  KdTree tree(finite);
  const std::size_t samples = std::min<std::size_t>(500, finite.size());
  const std::size_t stride = finite.size() / samples;
  double sum = 0.0;
  std::size_t count = 0;
  std::vector<std::int32_t> neighbours;
  for (std::size_t k = 0; k < samples; ++k) {
    const Eigen::Vector3f& q = finite[k * stride];
    // Nearest other point: smallest non-zero distance among a small radius search, else
    // grow the radius.
    float radius = 0.002f;
    float best = std::numeric_limits<float>::infinity();
    for (int attempt = 0; attempt < 12 && !std::isfinite(best); ++attempt, radius *= 2.0f) {
      tree.RadiusSearch(q, radius, &neighbours);
      for (std::int32_t j : neighbours) {
        const float d = (finite[j] - q).norm();
        if (d > 0.0f && d < best) best = d;
      }
    }
    if (std::isfinite(best)) {
      sum += best;
      ++count;
    }
  }
  return count == 0 ? 0.0 : sum / static_cast<double>(count);
}

VerifyResult Verify(const VerificationScene& scene, const geometry::PointCloud& model,
                    const Eigen::Isometry3d& X_BaseItem, const VerifyOptions& options) {
  if (model.empty()) throw std::invalid_argument("Verify: empty model");
  if (model.normals.size() != model.size())
    throw std::invalid_argument("Verify: the model needs one normal per point");
  if (options.max_model_points < 1)
    throw std::invalid_argument("Verify: max_model_points must be >= 1");
  if (!model.intensities.empty() && model.intensities.size() != model.size())
    throw std::invalid_argument("Verify: the model's albedo (intensities) has " +
                                std::to_string(model.intensities.size()) + " entries for " +
                                std::to_string(model.size()) + " points");
  options.appearance.Validate();
  if (!(options.appearance_contradiction_scale >= 0.0 &&
        options.appearance_contradiction_scale <= 1.0))
    throw std::invalid_argument("Verify: appearance_contradiction_scale must be in [0, 1]");
  const PinholeCamera& cam = scene.camera();
  const VerificationScene::Impl& impl = *scene.impl_;

  // Deterministic subsample, in the sensor frame.
  const std::size_t stride = (model.size() + options.max_model_points - 1) /
                             static_cast<std::size_t>(options.max_model_points);
  const Eigen::Isometry3f X_SensorItem =
      (scene.X_BaseSensor().inverse() * X_BaseItem).cast<float>();
  geometry::PointCloud sub;
  std::vector<std::uint8_t> sub_patches;  // SurfacePatch of each model normal
  for (std::size_t i = 0; i < model.size(); i += stride) {
    if (!model.points[i].allFinite() || !model.normals[i].allFinite()) continue;
    sub.points.push_back(X_SensorItem * model.points[i]);
    sub.normals.push_back(X_SensorItem.linear() * model.normals[i]);
    if (model.has_intensities()) sub.intensities.push_back(model.intensities[i]);
    sub_patches.push_back(SurfacePatch(model.normals[i]));
  }
  sub.width = static_cast<std::uint32_t>(sub.points.size());
  VerifyResult result;
  result.num_model_points = sub.size();
  if (sub.empty()) return result;
  const double spacing = std::max(MeanPointSpacing(sub), 1e-4);

  // Back-face culling and a splat z-buffer of the model itself.
  struct Projected {
    std::size_t index;
    int u, v;
  };
  std::vector<Projected> front;
  std::vector<float> zbuf(static_cast<std::size_t>(cam.width()) * cam.height(),
                          std::numeric_limits<float>::infinity());
  for (std::size_t i = 0; i < sub.size(); ++i) {
    const Eigen::Vector3f& p = sub.points[i];
    if (p.z() <= 1e-3f || sub.normals[i].dot(p) >= 0.0f) continue;
    const auto uv = cam.Project(p.cast<double>());
    if (!uv) continue;
    const int u = static_cast<int>(std::lround(uv->x()));
    const int v = static_cast<int>(std::lround(uv->y()));
    if (u < 0 || v < 0 || u >= cam.width() || v >= cam.height()) continue;
    front.push_back({i, u, v});
    const int r = std::min(8, static_cast<int>(0.75 * cam.fx() * spacing / p.z()));
    for (int dv = -r; dv <= r; ++dv) {
      for (int du = -r; du <= r; ++du) {
        const int uu = u + du, vv = v + dv;
        if (uu < 0 || vv < 0 || uu >= cam.width() || vv >= cam.height()) continue;
        float& z = zbuf[static_cast<std::size_t>(vv) * cam.width() + uu];
        z = std::min(z, p.z());
      }
    }
  }
  const float self_tolerance = static_cast<float>(std::max(2.0 * spacing, 0.002));
  const float distance_sq =
      static_cast<float>(options.distance_tolerance_m * options.distance_tolerance_m);
  const float cos_normal = static_cast<float>(std::cos(options.normal_tolerance_rad));
  double sum_sq = 0.0;
  const bool appearance = sub.has_intensities() && !impl.intensities.empty();
  std::vector<float> albedo, intensity;
  std::vector<std::uint8_t> patches;
  std::vector<Eigen::Vector3f> p_SensorMatched;  // scene points of the albedo samples
  for (const Projected& pr : front) {
    const Eigen::Vector3f& p = sub.points[pr.index];
    if (p.z() > zbuf[static_cast<std::size_t>(pr.v) * cam.width() + pr.u] + self_tolerance)
      continue;
    ++result.num_visible;
    float d_sq = 0.0f;
    const std::int32_t j = impl.tree.Nearest(p, &d_sq, distance_sq);
    bool supported = j != KdTree::kNone;
    if (supported && !impl.n_SensorPoints.empty()) {
      const Eigen::Vector3f& n = impl.n_SensorPoints[j];
      if (n.allFinite()) supported = std::abs(n.dot(sub.normals[pr.index])) >= cos_normal;
    }
    if (supported) {
      ++result.num_supported;
      sum_sq += d_sq;
      if (appearance) {
        const Eigen::Vector3f& q = impl.p_SensorPoints[j];
        // The posed model's normal: the hypothesis's exact surface, where the scan's normals
        // are noisy (a grazing face's 1 / cos amplifies their noise).
        const std::optional<float> sample =
            AppearanceSample(impl.intensities[j], q, sub.normals[pr.index], Eigen::Vector3f::Zero(),
                             options.appearance);
        if (!sample) continue;
        albedo.push_back(sub.intensities[pr.index]);
        patches.push_back(sub_patches[pr.index]);
        p_SensorMatched.push_back(q);
        intensity.push_back(*sample);
      }
      continue;
    }
    const float measured = scene.DepthAt(pr.u, pr.v);
    if (!std::isfinite(measured)) continue;
    if (measured < p.z() - options.occlusion_margin_m) {
      ++result.num_occluded;
    } else if (measured > p.z() + options.conflict_margin_m) {
      ++result.num_conflicts;
    }
  }
  const std::size_t considered = result.num_visible - result.num_occluded;
  if (considered >= static_cast<std::size_t>(std::max(1, options.min_visible_points))) {
    result.score =
        std::clamp((static_cast<double>(result.num_supported) -
                    options.conflict_weight * static_cast<double>(result.num_conflicts)) /
                       static_cast<double>(considered),
                   0.0, 1.0);
    result.conflict_fraction =
        static_cast<double>(result.num_conflicts) / static_cast<double>(considered);
  }
  result.X_BaseItem_appearance = X_BaseItem;
  if (appearance) {
    result.appearance = CorrelateAppearance(albedo, intensity, options.appearance, &patches);
    if (options.symmetries.size() > 1 && !p_SensorMatched.empty()) {
      // The albedo a turned model shows at each matched scene point: its point nearest to
      // the scene point, in the item frame. The points are those of `sub` (same stride and
      // filter), so their albedo and patch are sub's.
      std::vector<Eigen::Vector3f> p_ItemModel;
      p_ItemModel.reserve(sub.size());
      for (std::size_t i = 0; i < model.size(); i += stride) {
        if (!model.points[i].allFinite() || !model.normals[i].allFinite()) continue;
        p_ItemModel.push_back(model.points[i]);
      }
      const KdTree model_tree(p_ItemModel);
      const float lookup_sq =
          static_cast<float>(std::max(options.distance_tolerance_m, 2.0 * spacing) *
                             std::max(options.distance_tolerance_m, 2.0 * spacing));
      std::vector<float> turned_albedo, turned_intensity;
      std::vector<std::uint8_t> turned_patches;
      for (std::size_t s = 1; s < options.symmetries.size(); ++s) {
        const Eigen::Isometry3d X_BaseTurned = X_BaseItem * options.symmetries[s];
        const Eigen::Isometry3f X_ItemSensor =
            (X_BaseTurned.inverse() * scene.X_BaseSensor()).cast<float>();
        turned_albedo.clear();
        turned_intensity.clear();
        turned_patches.clear();
        for (std::size_t k = 0; k < p_SensorMatched.size(); ++k) {
          const std::int32_t i =
              model_tree.Nearest(X_ItemSensor * p_SensorMatched[k], nullptr, lookup_sq);
          if (i == KdTree::kNone) continue;
          turned_albedo.push_back(sub.intensities[i]);
          turned_intensity.push_back(intensity[k]);
          turned_patches.push_back(sub_patches[i]);
        }
        const AppearanceScore a = CorrelateAppearance(turned_albedo, turned_intensity,
                                                      options.appearance, &turned_patches);
        if (a.defined &&
            (!result.appearance.defined || a.correlation > result.appearance.correlation)) {
          result.appearance = a;
          result.appearance_symmetry = static_cast<int>(s);
          result.X_BaseItem_appearance = X_BaseTurned;
        }
      }
    }
    if (result.appearance.defined &&
        result.appearance.correlation < options.min_appearance_correlation) {
      result.appearance_contradicts = true;
      result.score *= options.appearance_contradiction_scale;
    }
  }
  if (result.num_supported > 0)
    result.inlier_rmse_m = std::sqrt(sum_sq / static_cast<double>(result.num_supported));
  return result;
}

}  // namespace picking::detector
