#include "services/detector/core/ppf_detector.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>

namespace picking::detector {
namespace {

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

}  // namespace

PpfScene PreparePpfScene(const geometry::PointCloud& scene, const ObjectModel& model,
                         const PpfSceneOptions& options) {
  CheckCloudChannels(scene, "PreparePpfScene");
  if (scene.empty()) throw std::invalid_argument("PreparePpfScene: the scene cloud is empty");
  if (options.use_input_normals && !scene.has_normals()) {
    throw std::invalid_argument("PreparePpfScene: use_input_normals set but the scene has none");
  }
  geometry::PointCloud valid = RemoveInvalidPoints(scene);
  if (valid.empty()) throw std::invalid_argument("PreparePpfScene: no finite scene point");
  valid.colors.clear();
  valid.intensities.clear();
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
  out.fine_tree = KdTree(out.fine.points);
  out.sampled_tree = KdTree(out.sampled.points);
  return out;
}

double SceneSupport(const ObjectModel& model, const PpfScene& scene,
                    const Eigen::Isometry3d& X_SceneModel, float distance_m, float normal_angle_rad,
                    int* visible_points) {
  const Eigen::Isometry3f X = X_SceneModel.cast<float>();
  const float d2_max = distance_m * distance_m;
  const float min_cos = std::cos(normal_angle_rad);
  const geometry::PointCloud& m = model.icp_cloud();
  int visible = 0;
  int supported = 0;
  for (std::size_t i = 0; i < m.size(); ++i) {
    const Eigen::Vector3f p = X * m.points[i];
    const Eigen::Vector3f n = X.linear() * m.normals[i];
    if (n.dot(scene.viewpoint - p) <= 0.0f) continue;
    ++visible;
    float d2 = 0.0f;
    const std::int32_t j = scene.fine_tree.Nearest(p, &d2, d2_max);
    if (j != KdTree::kNone && scene.fine.normals[j].dot(n) >= min_cos) ++supported;
  }
  if (visible_points != nullptr) *visible_points = visible;
  return visible == 0 ? 0.0 : static_cast<double>(supported) / visible;
}

PpfDetectionResult DetectPpf(const ObjectModel& model, const PpfScene& scene,
                             const PpfDetectorOptions& options) {
  if (options.hypotheses_to_verify < 1) {
    throw std::invalid_argument("PpfDetectorOptions: hypotheses_to_verify must be >= 1");
  }
  if (scene.sampled.empty() || scene.fine.empty()) {
    throw std::invalid_argument("DetectPpf: the prepared scene is empty");
  }
  PpfDetectionResult result;
  auto start = std::chrono::steady_clock::now();
  result.match = MatchPpf(model.table(), scene.sampled, scene.sampled_tree, options.match);
  result.match_s = Seconds(start);

  start = std::chrono::steady_clock::now();
  const float step = model.sampling_distance_m();
  IcpOptions coarse = options.icp;
  coarse.max_correspondence_distance_m = options.coarse_icp_distance_rel * step;
  coarse.loss_scale_m = options.icp_loss_scale_rel * step * 2.0f;
  coarse.max_iterations = options.coarse_icp_iterations;
  IcpOptions fine = options.icp;
  fine.max_correspondence_distance_m = options.icp_distance_rel * step;
  fine.loss_scale_m = options.icp_loss_scale_rel * step;

  std::vector<PpfDetection> verified;
  const std::size_t count = std::min(result.match.hypotheses.size(),
                                     static_cast<std::size_t>(options.hypotheses_to_verify));
  for (std::size_t h = 0; h < count; ++h) {
    const PpfHypothesis& hyp = result.match.hypotheses[h];
    PpfDetection d;
    d.votes = hyp.votes;
    Eigen::Isometry3d X = hyp.X_SceneModel;
    if (options.coarse_icp_iterations > 0) {
      const IcpResult c = RunIcp(model.icp_cloud(), scene.fine, scene.fine_tree, X, coarse);
      if (c.correspondences >= coarse.min_correspondences) X = c.X_TargetSource;
    }
    d.icp = RunIcp(model.icp_cloud(), scene.fine, scene.fine_tree, X, fine);
    d.X_SceneModel = d.icp.correspondences >= fine.min_correspondences ? d.icp.X_TargetSource : X;
    d.support = SceneSupport(model, scene, d.X_SceneModel, options.support_distance_rel * step,
                             options.support_normal_angle_rad, &d.visible_points);
    verified.push_back(d);
  }
  std::stable_sort(
      verified.begin(), verified.end(),
      [](const PpfDetection& a, const PpfDetection& b) { return a.support > b.support; });
  if (!verified.empty()) result.best = verified.front();
  // Keep distinct poses only: hypotheses that converged to the same place are one object.
  for (const PpfDetection& d : verified) {
    if (d.support < options.min_support) continue;
    bool duplicate = false;
    for (const PpfDetection& kept : result.detections) {
      if ((kept.X_SceneModel.translation() - d.X_SceneModel.translation()).norm() <
              options.match.cluster_translation_rel * model.diameter_m() &&
          RotationAngle(kept.X_SceneModel.linear(), d.X_SceneModel.linear()) <
              options.match.cluster_rotation_rad) {
        duplicate = true;
        break;
      }
    }
    if (!duplicate) result.detections.push_back(d);
  }
  result.refine_s = Seconds(start);
  return result;
}

}  // namespace picking::detector
