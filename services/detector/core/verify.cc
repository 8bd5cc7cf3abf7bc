#include "services/detector/core/verify.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "libs/parallel/parallel_for.h"
#include "services/detector/core/kdtree.h"

namespace picking::detector {

struct VerificationScene::Impl {
  // Per sensor: row-major depth image, NaN where nothing was measured.
  std::vector<std::vector<float>> depth;
  // Per sensor: X_Sensor0Sensor, the sensor's pose in the reference sensor's frame.
  std::vector<Eigen::Isometry3f> X_ReferenceSensor;
  // Scene points in the reference sensor's frame.
  std::vector<Eigen::Vector3f> p_SensorPoints;
  std::vector<Eigen::Vector3f> n_SensorPoints;  // empty when the scene has no normals
  std::vector<float> intensities;               // empty when the scene has none
  KdTree tree;
};

namespace {
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
// Albedo differences above this fraction of the brighter side make a print edge.
constexpr float kAlbedoEdgeContrast = 0.2f;
}  // namespace

VerificationScene::VerificationScene(const geometry::PointCloud& scene,
                                     const Eigen::Isometry3d& X_BaseSensor,
                                     const PinholeCamera& camera)
    : VerificationScene(scene, std::vector<SensorView>{SensorView{X_BaseSensor, camera}}) {}

VerificationScene::VerificationScene(const geometry::PointCloud& scene,
                                     std::vector<SensorView> sensors)
    : sensors_(std::move(sensors)), impl_(std::make_unique<Impl>()) {
  if (sensors_.empty()) throw std::invalid_argument("VerificationScene: no sensor");
  if (!scene.normals.empty() && scene.normals.size() != scene.size())
    throw std::invalid_argument("VerificationScene: normals size differs from points size");
  if (!scene.intensities.empty() && scene.intensities.size() != scene.size())
    throw std::invalid_argument("VerificationScene: intensities size differs from points size");
  if (!scene.colors.empty() && scene.colors.size() != scene.size())
    throw std::invalid_argument("VerificationScene: colors size differs from points size");
  for (const SensorView& s : sensors_) {
    if (!s.X_BaseSensor.matrix().allFinite())
      throw std::invalid_argument("VerificationScene: a sensor pose is not finite");
  }
  const Eigen::Isometry3f X_SensorBase = sensors_.front().X_BaseSensor.inverse().cast<float>();
  const bool normals = scene.has_normals();
  for (std::size_t i = 0; i < scene.size(); ++i) {
    if (!scene.points[i].allFinite()) continue;
    impl_->p_SensorPoints.push_back(X_SensorBase * scene.points[i]);
    if (normals) impl_->n_SensorPoints.push_back(X_SensorBase.linear() * scene.normals[i]);
    if (scene.has_intensities()) {
      impl_->intensities.push_back(scene.intensities[i]);
    } else if (scene.has_colors()) {
      impl_->intensities.push_back(ColorLuma(scene.colors[i]));
    }
  }
  if (impl_->p_SensorPoints.empty())
    throw std::invalid_argument("VerificationScene: scene has no finite point");
  // Each sensor's depth image is the merged scene's nearest point per pixel: where a sensor
  // did not measure a surface another one did, the merged points still stand in front of
  // whatever that sensor could not see, so its free space is not overstated. The images and
  // the search tree are independent: built concurrently.
  const std::size_t count = sensors_.size();
  impl_->depth.resize(count);
  impl_->X_ReferenceSensor.resize(count);
  const auto build_depth = [this](std::size_t k) {
    const SensorView& s = sensors_[k];
    const Eigen::Isometry3f X_ReferenceSensor =
        (sensors_.front().X_BaseSensor.inverse() * s.X_BaseSensor).cast<float>();
    const Eigen::Isometry3f X_SensorReference = X_ReferenceSensor.inverse();
    std::vector<float> depth(static_cast<std::size_t>(s.camera.width()) * s.camera.height(), kNaN);
    for (const Eigen::Vector3f& p_Reference : impl_->p_SensorPoints) {
      const Eigen::Vector3f p = X_SensorReference * p_Reference;
      if (p.z() <= 0.0f) continue;
      const auto uv = s.camera.Project(p.cast<double>());
      if (!uv) continue;
      const int u = static_cast<int>(std::lround(uv->x()));
      const int v = static_cast<int>(std::lround(uv->y()));
      if (u < 0 || v < 0 || u >= s.camera.width() || v >= s.camera.height()) continue;
      float& d = depth[static_cast<std::size_t>(v) * s.camera.width() + u];
      if (!(d <= p.z())) d = p.z();
    }
    impl_->depth[k] = std::move(depth);
    impl_->X_ReferenceSensor[k] = X_ReferenceSensor;
  };
  // Task 0 the tree, task 1 + k sensor k's image: a thread each, as many as there are tasks.
  const int tasks = static_cast<int>(count) + 1;
  parallel::ParallelFor(tasks, tasks, [&](int task) {
    if (task == 0) {
      impl_->tree = KdTree(impl_->p_SensorPoints);
    } else {
      build_depth(static_cast<std::size_t>(task - 1));
    }
  });
}

VerificationScene::~VerificationScene() = default;

float VerificationScene::DepthAt(int u, int v, std::size_t sensor) const {
  if (sensor >= sensors_.size()) return kNaN;
  const PinholeCamera& camera = sensors_[sensor].camera;
  const std::vector<float>& depth = impl_->depth[sensor];
  if (u < 0 || v < 0 || u >= camera.width() || v >= camera.height()) return kNaN;
  const float d = depth[static_cast<std::size_t>(v) * camera.width() + u];
  if (std::isfinite(d)) return d;
  // A single missing pixel (sparser clouds): nearest of the 8 neighbours.
  float best = kNaN;
  for (int dv = -1; dv <= 1; ++dv) {
    for (int du = -1; du <= 1; ++du) {
      const int uu = u + du, vv = v + dv;
      if (uu < 0 || vv < 0 || uu >= camera.width() || vv >= camera.height()) continue;
      const float n = depth[static_cast<std::size_t>(vv) * camera.width() + uu];
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

namespace {

// Throws std::invalid_argument when the model or the options cannot be verified against.
void CheckVerifyInputs(const geometry::PointCloud& model, const VerifyOptions& options) {
  if (model.empty()) throw std::invalid_argument("Verify: empty model");
  if (model.normals.size() != model.size())
    throw std::invalid_argument("Verify: the model needs one normal per point");
  if (options.max_model_points < 1)
    throw std::invalid_argument("Verify: max_model_points must be >= 1");
  if (!model.intensities.empty() && model.intensities.size() != model.size())
    throw std::invalid_argument("Verify: the model's albedo (intensities) has " +
                                std::to_string(model.intensities.size()) + " entries for " +
                                std::to_string(model.size()) + " points");
  if (!(options.outline_distance_m > 0.0 && options.outline_margin_m > 0.0))
    throw std::invalid_argument("Verify: outline_distance_m and outline_margin_m must be > 0");
  if (!(options.outline_prior >= 0.0 && options.outline_prior <= 1.0 &&
        options.outline_prior_samples >= 0.0 && options.outline_free_fraction >= 0.0 &&
        options.outline_free_fraction < 1.0))
    throw std::invalid_argument(
        "Verify: outline_prior must be in [0, 1], outline_prior_samples >= 0 and "
        "outline_free_fraction in [0, 1)");
  options.appearance.Validate();
  if (!(options.appearance_contradiction_scale >= 0.0 &&
        options.appearance_contradiction_scale <= 1.0))
    throw std::invalid_argument("Verify: appearance_contradiction_scale must be in [0, 1]");
}

// The model points Verify scores: every stride-th point with a finite position and normal.
struct ModelSample {
  // Points and normals (and albedo, in intensities) posed in the reference sensor's frame.
  geometry::PointCloud sub;
  std::vector<std::uint8_t> sub_patches;     // SurfacePatch of each model normal
  std::vector<Eigen::Vector3f> p_ItemModel;  // sub's points in the item frame
};

// Deterministic subsample of `model` to at most options.max_model_points, posed at X_BaseItem
// in the reference sensor's frame.
ModelSample SubsampleModel(const VerificationScene& scene, const geometry::PointCloud& model,
                           const Eigen::Isometry3d& X_BaseItem, const VerifyOptions& options) {
  const std::size_t stride = (model.size() + options.max_model_points - 1) /
                             static_cast<std::size_t>(options.max_model_points);
  const Eigen::Isometry3f X_SensorItem =
      (scene.X_BaseSensor().inverse() * X_BaseItem).cast<float>();
  ModelSample subsample;
  geometry::PointCloud& sub = subsample.sub;
  std::vector<std::uint8_t>& sub_patches = subsample.sub_patches;
  std::vector<Eigen::Vector3f>& p_ItemModel = subsample.p_ItemModel;
  for (std::size_t i = 0; i < model.size(); i += stride) {
    if (!model.points[i].allFinite() || !model.normals[i].allFinite()) continue;
    p_ItemModel.push_back(model.points[i]);
    sub.points.push_back(X_SensorItem * model.points[i]);
    sub.normals.push_back(X_SensorItem.linear() * model.normals[i]);
    if (model.has_intensities()) sub.intensities.push_back(model.intensities[i]);
    sub_patches.push_back(SurfacePatch(model.normals[i]));
  }
  sub.width = static_cast<std::uint32_t>(sub.points.size());
  return subsample;
}

// What the sensors showed of a model point: flags of its ClassifyVisibility state.
enum : std::uint8_t { kVisible = 1, kHidden = 2, kClear = 4, kSeenThrough = 8, kReference = 16 };

// A model point (index into sub) facing a sensor and inside its image: pixel (u, v), splat
// radius r (pixels) and depth z (sensor frame, metres).
struct Projected {
  std::size_t index;
  int u, v, r;
  float z;
};

// The pixels a sensor's splats cover, inclusive (u1 < u0 when there are none).
struct PixelBox {
  int u0, v0, u1, v1;
  int width() const { return u1 - u0 + 1; }
  int height() const { return v1 - v0 + 1; }
};

// Back-face culling: replaces `front` by the points of `sub` (reference sensor frame) that
// face the sensor `cam` (at X_SensorReference) and project into its image, each with a splat
// radius of about the sample `spacing` (metres), at most 8 pixels. Returns the pixels the
// splats cover.
PixelBox ProjectFacingPoints(const PinholeCamera& cam, const Eigen::Isometry3f& X_SensorReference,
                             const geometry::PointCloud& sub, double spacing,
                             std::vector<Projected>* front_out) {
  std::vector<Projected>& front = *front_out;
  front.clear();
  int u0 = cam.width(), v0 = cam.height(), u1 = -1, v1 = -1;
  for (std::size_t i = 0; i < sub.size(); ++i) {
    const Eigen::Vector3f p = X_SensorReference * sub.points[i];
    if (p.z() <= 1e-3f || (X_SensorReference.linear() * sub.normals[i]).dot(p) >= 0.0f) continue;
    const auto uv = cam.Project(p.cast<double>());
    if (!uv) continue;
    const int u = static_cast<int>(std::lround(uv->x()));
    const int v = static_cast<int>(std::lround(uv->y()));
    if (u < 0 || v < 0 || u >= cam.width() || v >= cam.height()) continue;
    const int r = std::min(8, static_cast<int>(0.75 * cam.fx() * spacing / p.z()));
    front.push_back({i, u, v, r, p.z()});
    u0 = std::min(u0, u - r);
    v0 = std::min(v0, v - r);
    u1 = std::max(u1, u + r);
    v1 = std::max(v1, v + r);
  }
  return PixelBox{u0, v0, u1, v1};
}

// The model's own z-buffer in one sensor, over its footprint `box` only (row-major, metres,
// +inf where no splat): each splat keeps the nearest depth.
void SplatModelDepth(const std::vector<Projected>& front, const PixelBox& box,
                     std::vector<float>* zbuf_out) {
  std::vector<float>& zbuf = *zbuf_out;
  const int u0 = box.u0, v0 = box.v0;
  const int zw = box.width(), zh = box.height();
  zbuf.assign(static_cast<std::size_t>(zw) * zh, std::numeric_limits<float>::infinity());
  for (const Projected& pr : front) {
    for (int dv = -pr.r; dv <= pr.r; ++dv) {
      for (int du = -pr.r; du <= pr.r; ++du) {
        float& z = zbuf[static_cast<std::size_t>(pr.v + dv - v0) * zw + (pr.u + du - u0)];
        z = std::min(z, pr.z);
      }
    }
  }
}

// Marks in `state` the points of `front` that the model itself does not hide from sensor k
// (within self_tolerance, metres, of its z-buffer `zbuf` over `box`) as visible, and what the
// sensor measured along their rays: something in front of them (hidden), free space beyond
// them (seen through; reference sensor only) or their surface (clear).
void MarkSensorVisibility(const VerificationScene& scene, std::size_t k,
                          const std::vector<Projected>& front, const PixelBox& box,
                          const std::vector<float>& zbuf, float self_tolerance,
                          const VerifyOptions& options, std::vector<std::uint8_t>* state_out) {
  std::vector<std::uint8_t>& state = *state_out;
  const int u0 = box.u0, v0 = box.v0;
  const int zw = box.width();
  for (const Projected& pr : front) {
    if (pr.z > zbuf[static_cast<std::size_t>(pr.v - v0) * zw + (pr.u - u0)] + self_tolerance)
      continue;
    std::uint8_t& st = state[pr.index];
    st |= kVisible;
    if (k == 0) st |= kReference;
    const float measured = scene.DepthAt(pr.u, pr.v, k);
    if (!std::isfinite(measured)) continue;
    if (measured < pr.z - options.occlusion_margin_m) {
      st |= kHidden;
    } else if (measured > pr.z + options.conflict_margin_m) {
      // Free space only from the reference sensor: another sensor's depth image is the
      // merged scene seen from there, so behind a surface that sensor did not measure it
      // holds what the others saw beyond it, which is not free space seen through.
      if (k == 0) st |= kSeenThrough;
    } else {
      st |= kClear;
    }
  }
}

// The model's silhouette in one sensor with the gaps between its splats closed: the splats'
// footprint (`zbuf` finite over `box`) dilated by `radius` pixels, over `box` grown by
// `radius` on every side.
class Silhouette {
 public:
  Silhouette(const PixelBox& box, const std::vector<float>& zbuf, int radius)
      : box_{box.u0 - radius, box.v0 - radius, box.u1 + radius, box.v1 + radius},
        mask_(box_.height(), box_.width(), CV_8U, cv::Scalar(0)) {
    const cv::Mat footprint(box.height(), box.width(), CV_32F,
                            const_cast<float*>(zbuf.data()));  // read only
    // +inf where no splat covers a pixel.
    const cv::Mat splatted = footprint < std::numeric_limits<float>::infinity();
    splatted.copyTo(mask_(cv::Rect(radius, radius, box.width(), box.height())));
    cv::dilate(mask_, mask_,
               cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * radius + 1, 2 * radius + 1)));
  }
  bool Inside(int u, int v) const {
    if (u < box_.u0 || v < box_.v0 || u > box_.u1 || v > box_.v1) return false;
    return mask_.at<std::uint8_t>(v - box_.v0, u - box_.u0) != 0;
  }

 private:
  PixelBox box_;
  cv::Mat mask_;
};

// The scene just past the model's silhouette in the reference sensor (its z-buffer `zbuf` over
// `box`, splatted from `front`): from each splat on the silhouette, a step of
// options.outline_distance_m outward in each direction that leaves the silhouette, where the
// measured depth is compared with the model's depth carried on linearly across the edge.
// Counts into result's num_outline (measured, not in front) and num_outline_continued (within
// outline_margin_m of the carried-on surface). Visits the splats, not the footprint's pixels:
// a few thousand look-ups per pose.
void CountOutline(const VerificationScene& scene, const std::vector<Projected>& front,
                  const PixelBox& box, const std::vector<float>& zbuf, double spacing,
                  const VerifyOptions& options, VerifyResult* result) {
  const float fx = static_cast<float>(scene.camera().fx());
  // The splats of a random surface sample (and their radius is capped) leave holes between
  // them up to about the sample's spacing: the silhouette closes them.
  float nearest_z = std::numeric_limits<float>::infinity();
  for (const Projected& pr : front) nearest_z = std::min(nearest_z, pr.z);
  const int gap = std::clamp(static_cast<int>(std::ceil(fx * spacing / nearest_z)), 1, 32);
  const Silhouette silhouette(box, zbuf, gap);
  const int zw = box.width();
  const auto model_z = [&](int u, int v) {
    if (u < box.u0 || v < box.v0 || u > box.u1 || v > box.v1) return kNaN;
    const float z = zbuf[static_cast<std::size_t>(v - box.v0) * zw + (u - box.u0)];
    return std::isfinite(z) ? z : kNaN;
  };
  const float margin = static_cast<float>(options.outline_margin_m);
  constexpr int kSteps[4][2] = {{1, 0}, {-1, 0}, {0, 1}, {0, -1}};
  for (const Projected& pr : front) {
    const float z = model_z(pr.u, pr.v);
    if (!(z >= pr.z - margin)) continue;  // hidden behind the model's own surface
    const int step =
        std::max(2, static_cast<int>(std::lround(fx * options.outline_distance_m / z)));
    for (const auto& d : kSteps) {
      // On the silhouette this way: just past the splat and its gap lies no model.
      const int edge = pr.r + gap + 1;
      if (silhouette.Inside(pr.u + edge * d[0], pr.v + edge * d[1])) continue;
      const int uo = pr.u + (edge + step) * d[0], vo = pr.v + (edge + step) * d[1];
      if (silhouette.Inside(uo, vo)) continue;  // the silhouette again
      const float measured = scene.DepthAt(uo, vo, 0);
      if (!std::isfinite(measured)) continue;
      if (measured < z - margin) {
        ++result->num_outline_hidden;
        continue;
      }
      const float inner = model_z(pr.u - step * d[0], pr.v - step * d[1]);
      const float carried = std::isfinite(inner) ? z + (z - inner) * (edge + step) / step : z;
      ++result->num_outline;
      if (std::abs(measured - carried) <= margin) ++result->num_outline_continued;
    }
  }
}

// Per point of `sub` (reference sensor frame), the kVisible... flags over all sensors
// (X_ReferenceSensor: each sensor's pose in the reference sensor's frame). Back-face culling
// and a splat z-buffer of the model itself give the points a sensor would see; what it
// measured along their rays says whether they are hidden by other surfaces (in front of
// them) or lie in free space (the sensor saw beyond them).
std::vector<std::uint8_t> ClassifyVisibility(
    const VerificationScene& scene, const std::vector<Eigen::Isometry3f>& X_ReferenceSensor,
    const geometry::PointCloud& sub, double spacing, const VerifyOptions& options,
    VerifyResult* result) {
  const float self_tolerance = static_cast<float>(std::max(2.0 * spacing, 0.002));
  std::vector<std::uint8_t> state(sub.size(), 0);
  std::vector<Projected> front;
  std::vector<float> zbuf;
  for (std::size_t k = 0; k < scene.sensors().size(); ++k) {
    const PinholeCamera& cam = scene.sensors()[k].camera;
    const Eigen::Isometry3f X_SensorReference = X_ReferenceSensor[k].inverse();
    const PixelBox box = ProjectFacingPoints(cam, X_SensorReference, sub, spacing, &front);
    if (front.empty()) continue;
    SplatModelDepth(front, box, &zbuf);
    MarkSensorVisibility(scene, k, front, box, zbuf, self_tolerance, options, &state);
    if (k == 0) CountOutline(scene, front, box, zbuf, spacing, options, result);
  }
  return state;
}

// The scene points Verify matches against, reference sensor frame: the parts of the private
// VerificationScene::Impl that only Verify (a friend) can name.
struct SceneSurface {
  const KdTree& tree;                                  // over p_SensorPoints
  const std::vector<Eigen::Vector3f>& p_SensorPoints;  // all finite scene points
  const std::vector<Eigen::Vector3f>& n_SensorPoints;  // empty without normals
  const std::vector<float>& intensities;               // empty without intensities
};

// The appearance samples of the supported model points: their matched scene points
// (reference sensor frame) and those points' shading-compensated intensities.
struct MatchedSamples {
  std::vector<Eigen::Vector3f> p_SensorMatched;
  std::vector<float> intensity;
};

// Counts the visible points of `sub` (flags in `state`) into result's num_visible,
// num_supported (a scene point within tolerance), num_conflicts and num_occluded; with
// `appearance`, collects the supported points' samples in `matched`. Returns the supported
// points' sum of squared distances to the scene (metres^2).
double CountSupport(const geometry::PointCloud& sub, const std::vector<std::uint8_t>& state,
                    const SceneSurface& impl, bool appearance, const VerifyOptions& options,
                    MatchedSamples* matched, VerifyResult* verify_result) {
  VerifyResult& result = *verify_result;
  std::vector<Eigen::Vector3f>& p_SensorMatched = matched->p_SensorMatched;
  std::vector<float>& intensity = matched->intensity;
  const float distance_sq =
      static_cast<float>(options.distance_tolerance_m * options.distance_tolerance_m);
  const float cos_normal = static_cast<float>(std::cos(options.normal_tolerance_rad));
  double sum_sq = 0.0;
  for (std::size_t i = 0; i < sub.size(); ++i) {
    const std::uint8_t st = state[i];
    if (!(st & kVisible)) continue;
    const Eigen::Vector3f& p = sub.points[i];
    ++result.num_visible;
    float d_sq = 0.0f;
    const std::int32_t j = impl.tree.Nearest(p, &d_sq, distance_sq);
    bool supported = j != KdTree::kNone;
    if (supported && !impl.n_SensorPoints.empty()) {
      const Eigen::Vector3f& n = impl.n_SensorPoints[j];
      if (n.allFinite()) supported = std::abs(n.dot(sub.normals[i])) >= cos_normal;
    }
    if (supported) {
      ++result.num_supported;
      sum_sq += d_sq;
      if (appearance) {
        const Eigen::Vector3f& q = impl.p_SensorPoints[j];
        // The posed model's normal: the hypothesis's exact surface, where the scan's normals
        // are noisy (a grazing face's 1 / cos amplifies their noise).
        const std::optional<float> sample = AppearanceSample(
            impl.intensities[j], q, sub.normals[i], Eigen::Vector3f::Zero(), options.appearance);
        if (!sample) continue;
        p_SensorMatched.push_back(q);
        intensity.push_back(*sample);
      }
      continue;
    }
    // Unsupported. Seen only by other sensors than the reference, and none of them measured
    // anything along its ray: the scene is a region cut out of those sensors' scans (a bin
    // without its walls and floor), so their empty pixels there say nothing; not counted.
    // The reference sensor's empty pixels still count against the pose, as with one sensor.
    // The reference sensor seeing through the point outweighs the others; it is hidden only
    // when no sensor that measured a depth there had a clear line to it.
    if (!(st & (kReference | kHidden | kClear | kSeenThrough))) {
      --result.num_visible;
    } else if (st & kSeenThrough) {
      ++result.num_conflicts;
    } else if ((st & kHidden) && !(st & kClear)) {
      ++result.num_occluded;
    }
  }
  return sum_sq;
}

// The scores and conflict fraction from result's counts, when enough unoccluded points are
// visible (else they stay 0): the support's, and that scaled by the outline's factor.
void ScoreSupport(const VerifyOptions& options, VerifyResult* verify_result) {
  VerifyResult& result = *verify_result;
  const double samples = static_cast<double>(result.num_outline) + options.outline_prior_samples;
  const double continued = samples > 0.0 ? (static_cast<double>(result.num_outline_continued) +
                                            options.outline_prior_samples * options.outline_prior) /
                                               samples
                                         : 0.0;
  result.outline_factor =
      options.outline_check
          ? std::clamp((1.0 - continued) / (1.0 - options.outline_free_fraction), 0.0, 1.0)
          : 1.0;
  const std::size_t considered = result.num_visible - result.num_occluded;
  if (considered >= static_cast<std::size_t>(std::max(1, options.min_visible_points))) {
    result.support_score =
        std::clamp((static_cast<double>(result.num_supported) -
                    options.conflict_weight * static_cast<double>(result.num_conflicts)) /
                       static_cast<double>(considered),
                   0.0, 1.0);
    result.score = result.support_score * result.outline_factor;
    result.conflict_fraction =
        static_cast<double>(result.num_conflicts) / static_cast<double>(considered);
  }
}

// Whether a model point (index into p_ItemModel and sub) lies on a print edge: where the
// albedo changes within a sampling step, which side a scene point belongs to is down to
// millimetres of registration, so such model points give no sample. Worked out on first
// look-up and kept.
struct AlbedoEdges {
  const KdTree& model_tree;                         // over p_ItemModel
  const std::vector<Eigen::Vector3f>& p_ItemModel;  // item frame
  const geometry::PointCloud& sub;                  // albedo in intensities
  float edge_radius;                                // metres
  std::vector<std::int8_t> albedo_edge;             // per point: -1 not yet known, else 0 / 1
  std::vector<std::int32_t> neighbours;             // scratch

  bool operator()(std::int32_t i) {
    std::int8_t& flag = albedo_edge[static_cast<std::size_t>(i)];
    if (flag < 0) {
      model_tree.RadiusSearch(p_ItemModel[i], edge_radius, &neighbours);
      float lo = sub.intensities[i], hi = lo;
      for (std::int32_t j : neighbours) {
        const float a = sub.intensities[j];
        if (!std::isfinite(a)) continue;
        lo = std::min(lo, a);
        hi = std::max(hi, a);
      }
      flag = hi - lo > kAlbedoEdgeContrast * hi ? 1 : 0;
    }
    return flag == 1;
  }
};

// The appearance at one turn of the pose (X_ItemSensor: the reference sensor in the turned
// item frame): each matched scene point's intensity against the albedo of the model point
// nearest it in the item frame (model_tree, within lookup_sq, metres^2), but for model points
// on a print edge. `albedo` and `patches` are scratch, kept between turns.
AppearanceScore CorrelateTurn(const Eigen::Isometry3f& X_ItemSensor, const KdTree& model_tree,
                              float lookup_sq, const ModelSample& subsample,
                              const MatchedSamples& matched, const VerifyOptions& options,
                              AlbedoEdges* edges, std::vector<float>* albedo_out,
                              std::vector<std::uint8_t>* patches_out) {
  const geometry::PointCloud& sub = subsample.sub;
  const std::vector<std::uint8_t>& sub_patches = subsample.sub_patches;
  const std::vector<Eigen::Vector3f>& p_SensorMatched = matched.p_SensorMatched;
  const std::vector<float>& intensity = matched.intensity;
  AlbedoEdges& on_albedo_edge = *edges;
  std::vector<float>& albedo = *albedo_out;
  std::vector<std::uint8_t>& patches = *patches_out;
  albedo.clear();
  patches.clear();
  std::vector<float> matched_intensity;
  matched_intensity.reserve(intensity.size());
  for (std::size_t k = 0; k < p_SensorMatched.size(); ++k) {
    const std::int32_t i =
        model_tree.Nearest(X_ItemSensor * p_SensorMatched[k], nullptr, lookup_sq);
    if (i == KdTree::kNone || !std::isfinite(sub.intensities[i]) || on_albedo_edge(i)) continue;
    albedo.push_back(sub.intensities[i]);
    matched_intensity.push_back(intensity[k]);
    patches.push_back(sub_patches[i]);
  }
  return CorrelateAppearance(albedo, matched_intensity, options.appearance, &patches);
}

// The appearance of the best symmetric turn of X_BaseItem (the first on ties) into result's
// appearance, appearance_symmetry and X_BaseItem_appearance; scales the score when the
// appearance contradicts the pose.
void ScoreAppearance(const VerificationScene& scene, const Eigen::Isometry3d& X_BaseItem,
                     const ModelSample& subsample, double spacing, const MatchedSamples& matched,
                     const VerifyOptions& options, VerifyResult* verify_result) {
  VerifyResult& result = *verify_result;
  const std::vector<Eigen::Vector3f>& p_ItemModel = subsample.p_ItemModel;
  // The albedo the pose (or a symmetric turn of it) shows at each matched scene point: that
  // of the model point nearest the scene point, in the item frame. Not the albedo of the
  // model point that found the match: a print's dark parts are measured worst (at a grazing
  // angle they may not be decoded at all), so along their edges the model point on the
  // dark side is matched by a bright scene point beside it. The points are sub's, so their
  // albedo and patch are sub's.
  const KdTree model_tree(p_ItemModel);
  const float lookup_sq = static_cast<float>(std::max(options.distance_tolerance_m, 2.0 * spacing) *
                                             std::max(options.distance_tolerance_m, 2.0 * spacing));
  const float edge_radius = static_cast<float>(1.5 * spacing);
  AlbedoEdges on_albedo_edge{model_tree,
                             p_ItemModel,
                             subsample.sub,
                             edge_radius,
                             std::vector<std::int8_t>(p_ItemModel.size(), -1),
                             std::vector<std::int32_t>()};
  std::vector<float> albedo;
  std::vector<std::uint8_t> patches;
  const std::size_t turns = std::max<std::size_t>(1, options.symmetries.size());
  for (std::size_t s = 0; s < turns; ++s) {
    const Eigen::Isometry3d X_BaseTurned =
        options.symmetries.empty() ? X_BaseItem : X_BaseItem * options.symmetries[s];
    const Eigen::Isometry3f X_ItemSensor =
        (X_BaseTurned.inverse() * scene.X_BaseSensor()).cast<float>();
    const AppearanceScore a = CorrelateTurn(X_ItemSensor, model_tree, lookup_sq, subsample, matched,
                                            options, &on_albedo_edge, &albedo, &patches);
    // A turn without evidence ranks as neutral: above one the print contradicts, below one
    // it confirms.
    const auto rank = [&](const AppearanceScore& x) {
      return x.defined ? x.correlation : options.min_appearance_correlation;
    };
    if (s == 0 || rank(a) > rank(result.appearance)) {
      result.appearance = a;
      result.appearance_symmetry = static_cast<int>(s);
      result.X_BaseItem_appearance = X_BaseTurned;
    }
  }
  if (result.appearance.defined &&
      result.appearance.correlation < options.min_appearance_correlation) {
    result.appearance_contradicts = true;
    result.score *= options.appearance_contradiction_scale;
  }
}

}  // namespace

VerifyResult Verify(const VerificationScene& scene, const geometry::PointCloud& model,
                    const Eigen::Isometry3d& X_BaseItem, const VerifyOptions& options) {
  CheckVerifyInputs(model, options);
  const VerificationScene::Impl& impl = *scene.impl_;

  // Deterministic subsample, in the sensor frame.
  const ModelSample subsample = SubsampleModel(scene, model, X_BaseItem, options);
  const geometry::PointCloud& sub = subsample.sub;
  VerifyResult result;
  result.num_model_points = sub.size();
  if (sub.empty()) return result;
  const double spacing = std::max(MeanPointSpacing(sub), 1e-4);

  // Per sensor: which model points it would see, and whether they are hidden or in free space.
  const std::vector<std::uint8_t> state =
      ClassifyVisibility(scene, impl.X_ReferenceSensor, sub, spacing, options, &result);
  // Support of the visible points, with their appearance samples.
  const bool appearance = sub.has_intensities() && !impl.intensities.empty();
  MatchedSamples matched;
  const double sum_sq = CountSupport(
      sub, state,
      SceneSurface{impl.tree, impl.p_SensorPoints, impl.n_SensorPoints, impl.intensities},
      appearance, options, &matched, &result);
  ScoreSupport(options, &result);
  result.X_BaseItem_appearance = X_BaseItem;
  if (appearance) ScoreAppearance(scene, X_BaseItem, subsample, spacing, matched, options, &result);
  if (result.num_supported > 0)
    result.inlier_rmse_m = std::sqrt(sum_sq / static_cast<double>(result.num_supported));
  return result;
}

}  // namespace picking::detector
