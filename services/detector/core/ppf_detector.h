#pragma once

#include <Eigen/Geometry>

#include <vector>

#include "libs/geometry/point_cloud.h"
#include "services/detector/core/icp.h"
#include "services/detector/core/kdtree.h"
#include "services/detector/core/model.h"
#include "services/detector/core/ppf.h"

namespace picking::detector {

/// A scene prepared for one object model: the fine cloud with normals (ICP target and
/// verification) and the cloud sampled with the model's distance step (PPF voting), both in
/// the scene frame S, metres, with their search trees.
struct PpfScene {
  geometry::PointCloud fine;
  geometry::PointCloud sampled;
  KdTree fine_tree;
  KdTree sampled_tree;
  Eigen::Vector3f viewpoint = Eigen::Vector3f::Zero();  ///< Sensor origin in S, metres.
};

/// Options of PreparePpfScene.
struct PpfSceneOptions {
  /// Sensor origin in the scene frame, metres; normals are oriented toward it.
  Eigen::Vector3f viewpoint = Eigen::Vector3f::Zero();
  /// Keep the scene's own unit normals instead of estimating them.
  bool use_input_normals = false;
};

/// Drops invalid points, samples the scene with the model's fine voxel, estimates normals
/// with the model's radius (or keeps the input ones) and samples again with the model's
/// distance step. Throws std::invalid_argument for an empty scene or one with no valid
/// point, mismatched channels, or use_input_normals without normals.
PpfScene PreparePpfScene(const geometry::PointCloud& scene, const ObjectModel& model,
                         const PpfSceneOptions& options = {});

/// Options of DetectPpf.
struct PpfDetectorOptions {
  PpfMatchOptions match;
  /// ICP defaults; the correspondence distance and loss scale are overridden by the
  /// relative values below (fractions of the model's sampling distance).
  IcpOptions icp;
  float icp_distance_rel = 1.0f;
  float icp_loss_scale_rel = 0.25f;
  /// Coarse ICP pass (correspondences up to coarse_icp_distance_rel) before the fine one, to
  /// pull in hypotheses whose rotation is off by up to one angle step.
  float coarse_icp_distance_rel = 2.5f;
  int coarse_icp_iterations = 10;
  /// Verification: a visible model point is supported when a scene point lies within
  /// support_distance_rel (of the sampling distance) and its normal within
  /// support_normal_angle_rad.
  float support_distance_rel = 0.5f;
  float support_normal_angle_rad = 0.5f;
  /// Detections need at least this support (fraction of the visible model points). A wrong
  /// object can lean on a scene's planes and edges for up to about two thirds of its
  /// visible points (the Stanford bunny in the PCL milk scene: 0.67), while true poses of a
  /// present object score above 0.8.
  float min_support = 0.75f;
  /// Hypotheses (by votes) refined by ICP and verified.
  int hypotheses_to_verify = 6;
};

/// A verified pose of the model in the scene.
struct PpfDetection {
  Eigen::Isometry3d X_SceneModel = Eigen::Isometry3d::Identity();
  double support = 0.0;  ///< Supported / visible model points, [0, 1].
  int visible_points = 0;
  double votes = 0.0;  ///< Votes of the PPF cluster it came from.
  IcpResult icp;
};

struct PpfDetectionResult {
  /// Hypotheses with support >= min_support, best support first; distinct poses only.
  std::vector<PpfDetection> detections;
  /// The best verified hypothesis even when below min_support (support 0 when none).
  PpfDetection best;
  PpfMatchResult match;
  double match_s = 0.0;
  double refine_s = 0.0;
};

/// Scene support of a model pose: the fraction of the model's ICP points that face the
/// viewpoint and have a scene point within `distance_m` with normals within `normal_angle_rad`.
/// `visible_points` (optional) receives the number of facing points.
double SceneSupport(const ObjectModel& model, const PpfScene& scene,
                    const Eigen::Isometry3d& X_SceneModel, float distance_m, float normal_angle_rad,
                    int* visible_points = nullptr);

/// PPF voting, pose clustering, ICP refinement and verification of the best hypotheses.
PpfDetectionResult DetectPpf(const ObjectModel& model, const PpfScene& scene,
                             const PpfDetectorOptions& options = {});

}  // namespace picking::detector
