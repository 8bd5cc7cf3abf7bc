#pragma once

#include <Eigen/Geometry>

#include <chrono>
#include <cstdint>
#include <limits>
#include <vector>

#include "libs/geometry/point_cloud.h"
#include "libs/world/mesh.h"
#include "services/detector/core/budget_clock.h"
#include "services/detector/core/detection.h"

namespace picking::detector {

/// A depth image: z in the camera frame per pixel (metres), NaN where nothing was seen.
struct RangeImage {
  int width = 0;
  int height = 0;
  std::vector<float> depth_m;  ///< Row-major, width * height.

  float at(int u, int v) const { return depth_m[static_cast<std::size_t>(v) * width + u]; }
};

/// `n` unit directions spread uniformly over the sphere (Fibonacci / golden-angle spiral).
/// Throws std::invalid_argument for n < 1.
std::vector<Eigen::Vector3d> FibonacciSphere(int n);

/// Points with outward face normals sampled uniformly over the mesh surface with about
/// `spacing_m` between neighbours (area-weighted, seeded). Throws std::invalid_argument on
/// an empty mesh, an out-of-range index or spacing_m <= 0.
geometry::PointCloud SampleMeshSurface(const world::TriangleMesh& mesh, double spacing_m,
                                       std::uint32_t seed = 1);

/// Renders `model` (item frame; normals optional, used for back-face culling) seen by
/// `camera` at X_CameraItem with a z-buffer point splat: each point covers a square of about
/// its own spacing (`point_spacing_m`) in the image. Throws std::invalid_argument on an
/// point_spacing_m <= 0.
RangeImage RenderRangeImage(const geometry::PointCloud& model,
                            const Eigen::Isometry3d& X_CameraItem, const PinholeCamera& camera,
                            double point_spacing_m);

/// The organised cloud (camera frame) of a range image.
geometry::PointCloud RangeImageToCloud(const RangeImage& image, const PinholeCamera& camera);

/// One view of the object: its range image from a template camera and the pose that produced
/// it. The template camera looks along +z at the object's centre from `distance_m`.
struct RangeTemplate {
  Eigen::Isometry3d X_CameraItem = Eigen::Isometry3d::Identity();
  /// Cropped range image: pixel (u, v) of `image` is pixel (u + u0, v + v0) of the camera.
  RangeImage image;
  int u0 = 0;
  int v0 = 0;
  /// Subsample of the range image pixels as points and normals (camera frame).
  std::vector<Eigen::Vector3f> p_CameraPoints;
  std::vector<Eigen::Vector3f> n_CameraPoints;
  /// The template point closest to the camera centre.
  Eigen::Vector3f p_CameraClosest = Eigen::Vector3f::Zero();
};

struct TemplateOptions {
  int num_views = 1024;     ///< Viewpoints on a Fibonacci sphere; >= 1.
  double distance_m = 0.6;  ///< Camera distance to the model's centre; > 0.
  /// The template camera's focal length is set so the model's diameter spans this many
  /// pixels at distance_m (template images are about this size); >= 8.
  int image_size_px = 64;
  int max_points_per_template = 300;  ///< Points kept for alignment; >= 10.
  /// Model points are voxel-down-sampled to about this spacing before rendering; 0 = pixel
  /// size / 2.
  double model_spacing_m = 0.0;
};

/// The 1024 (by default) range-image templates of one object model.
class RangeTemplateSet final {
 public:
  /// `model`: points in the item frame, with normals (estimate them for scanned models).
  /// Throws std::invalid_argument on a model without points or normals, or bad options.
  RangeTemplateSet(const geometry::PointCloud& model, const TemplateOptions& options = {});

  const std::vector<RangeTemplate>& templates() const { return templates_; }
  const PinholeCamera& camera() const { return camera_; }
  /// Down-sampled model used for rendering and refinement (item frame, with normals).
  const geometry::PointCloud& model() const { return model_; }
  double diameter_m() const { return diameter_m_; }
  const Eigen::Vector3d& p_ItemCenter() const { return p_ItemCenter_; }

 private:
  std::vector<RangeTemplate> templates_;
  PinholeCamera camera_{1, 1, 1.0, 1.0, 0.0, 0.0};
  geometry::PointCloud model_;
  double diameter_m_ = 0.0;
  Eigen::Vector3d p_ItemCenter_ = Eigen::Vector3d::Zero();
};

struct TemplateMatchOptions {
  /// Rotations about the viewing ray tried per template; >= 1.
  int in_plane_steps = 18;
  /// Residuals are truncated at this depth difference, metres; > 0.
  double truncation_m = 0.01;
  /// Best coarse hypotheses per cluster refined by ICP and rescored; >= 1.
  int num_refine = 12;
  int refine_iterations = 20;
  /// Accept the best hypothesis only if its cost (mean truncated residual, metres) is below.
  double max_cost_m = 0.003;
  /// Scene samples per cluster used in the cost.
  int max_cluster_points = 400;
  /// A cluster's points are thinned (evenly, by stride) to at most this many before its
  /// normals and k-d tree are built for the ICP stages: a merged multi-view scan puts 100k+
  /// points on one cluster, whose normals alone would take longer than the time budget; >= 10.
  int max_target_points = 15000;
  /// Only clusters of a plausible size for the item are matched: the diagonal of the
  /// cluster's bounding box must lie within [min_cluster_extent_rel, max_cluster_extent_rel]
  /// times the item's diameter. A smaller cluster shows too little of the item to fix a pose;
  /// a larger one is several touching items (or a whole bin), whose closest point is rarely
  /// the item's. Defaults 0.2 and 1.5; >= 0 and min <= max.
  double min_cluster_extent_rel = 0.2;
  double max_cluster_extent_rel = 1.5;
  /// The search stops at this time point (the call's time budget; checked between clusters
  /// and in-plane rotations) and returns the matches of the clusters finished so far.
  std::chrono::steady_clock::time_point deadline = std::chrono::steady_clock::time_point::max();
  /// The clock `deadline` is judged by.
  BudgetClock clock;
};

struct TemplateMatch {
  Eigen::Isometry3d X_BaseItem = Eigen::Isometry3d::Identity();
  double cost_m = 0.0;  ///< Mean truncated two-way range residual.
  int template_index = -1;
  int cluster_index = -1;
  double fitness = 0.0;  ///< Of the last ICP.
  double inlier_rmse_m = 0.0;
};

/// What a template search saw, for saying why it matched nothing.
struct TemplateSearchReport {
  int clusters = 0;  ///< Clusters in the scene.
  /// Skipped: too few points (with normals) or a size implausible for the item.
  int implausible_clusters = 0;
  int searched_clusters = 0;  ///< Searched to the end.
  /// The lowest cost of a cluster's best hypothesis above max_cost_m (metres; infinity: none).
  double best_rejected_cost_m = std::numeric_limits<double>::infinity();
};

/// Aligns every template to every cluster of the scene: rotated so its view direction is the
/// ray to the cluster's closest point (with `in_plane_steps` rotations about it), translated so
/// the template's closest point lies on the cluster's closest point, scored by the two-way
/// range residual (template points against the scene's depth image, cluster points against
/// the template's range image); the best hypotheses are refined by point-to-plane ICP on the
/// cluster and rescored. Returns matches below max_cost_m, best first (at most one per
/// cluster). `scene` is in the base frame; `clusters` index its points. Clusters of an
/// implausible size for the item are skipped (see TemplateMatchOptions). `report`, when given,
/// receives what the search saw.
/// Throws std::invalid_argument on bad options or a bad cluster index.
std::vector<TemplateMatch> MatchTemplates(const RangeTemplateSet& templates,
                                          const geometry::PointCloud& scene,
                                          const std::vector<std::vector<int>>& clusters,
                                          const Eigen::Isometry3d& X_BaseSensor,
                                          const PinholeCamera& camera,
                                          const TemplateMatchOptions& options = {},
                                          TemplateSearchReport* report = nullptr);

}  // namespace picking::detector
