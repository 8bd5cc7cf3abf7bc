// SceneContext: what the estimators of one scene share, each built once on first use.
#include "services/detector/core/estimators.h"

#include <algorithm>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <utility>

#include "libs/errors/errors.h"
#include "services/detector/core/estimator_stages.h"

namespace picking::detector {

using estimator_stages::Clock;

SceneContext::SceneContext(const geometry::PointCloud& scene, const Eigen::Isometry3d& X_BaseSensor,
                           std::optional<PinholeCamera> camera, SceneContextOptions options)
    : scene_(&scene),
      X_BaseSensor_(X_BaseSensor),
      camera_(std::move(camera)),
      options_(std::move(options)) {
  if (options_.max_clusters < 1) {
    throw std::invalid_argument("SceneContext: max_clusters must be >= 1");
  }
  const bool any_finite = std::any_of(scene.points.begin(), scene.points.end(),
                                      [](const Eigen::Vector3f& p) { return p.allFinite(); });
  if (!any_finite) throw std::invalid_argument("SceneContext: the scene has no finite point");
}

SceneContext::~SceneContext() = default;

void SceneContext::CheckDeadline() const {
  if (Clock::now() > deadline_) {
    throw TimeoutError("detection did not finish within the call's deadline");
  }
}

const PpfScene& SceneContext::PpfSceneFor(const LoadedModel& model) {
  std::lock_guard<std::mutex> lock(mutex_);
  auto& slot = ppf_scenes_[model.spec.item];
  if (!slot) {
    PpfSceneOptions options;
    options.viewpoint = X_BaseSensor_.translation().cast<float>();
    slot = std::make_unique<PpfScene>(PreparePpfScene(*scene_, *model.object, options));
  }
  return *slot;
}

const VerificationScene* SceneContext::Verification() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!verification_built_) {
    if (camera_) {
      std::vector<SensorView> sensors = {SensorView{X_BaseSensor_, *camera_}};
      sensors.insert(sensors.end(), options_.other_sensors.begin(), options_.other_sensors.end());
      verification_ = std::make_unique<VerificationScene>(*scene_, std::move(sensors));
    }
    verification_built_ = true;
  }
  return verification_.get();
}

const SceneContext::Clusters& SceneContext::SceneClusters() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!clusters_) {
    auto c = std::make_unique<Clusters>();
    PlaneRemovalOptions plane = options_.plane;
    plane.keep_organized = true;
    c->cloud = options_.remove_dominant_plane ? RemoveDominantPlane(*scene_, plane).cloud : *scene_;
    c->clusters = EuclideanClusters(c->cloud, options_.clusters, &c->representatives);
    if (c->clusters.size() > static_cast<std::size_t>(options_.max_clusters)) {
      c->clusters.resize(static_cast<std::size_t>(options_.max_clusters));
      c->representatives.resize(static_cast<std::size_t>(options_.max_clusters));
    }
    for (const auto& cluster : c->clusters) {
      Eigen::AlignedBox3f box;
      for (int i : cluster) box.extend(c->cloud.points[i]);
      c->extent_m.push_back(cluster.empty() ? 0.0 : static_cast<double>(box.diagonal().norm()));
    }
    clusters_ = std::move(c);
  }
  return *clusters_;
}

std::vector<std::int32_t> SceneContext::ClusterLabels(const std::vector<Eigen::Vector3f>& points,
                                                      float max_distance_m) {
  const Clusters& clusters = SceneClusters();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!cluster_tree_) {
      std::vector<Eigen::Vector3f> clustered;
      for (std::size_t c = 0; c < clusters.representatives.size(); ++c) {
        for (int i : clusters.representatives[c]) {
          clustered.push_back(clusters.cloud.points[i]);
          cluster_labels_.push_back(static_cast<std::int32_t>(c));
        }
      }
      cluster_tree_ = std::make_unique<KdTree>(clustered);
    }
  }
  std::vector<std::int32_t> labels(points.size(), -1);
  if (cluster_tree_->empty()) return labels;
  const float max_sq = max_distance_m * max_distance_m;
  for (std::size_t i = 0; i < points.size(); ++i) {
    const std::int32_t j = cluster_tree_->Nearest(points[i], nullptr, max_sq);
    if (j != KdTree::kNone) labels[i] = cluster_labels_[j];
  }
  return labels;
}

}  // namespace picking::detector
