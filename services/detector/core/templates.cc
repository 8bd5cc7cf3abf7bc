#include "services/detector/core/templates.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "services/detector/core/appearance.h"
#include "services/detector/core/icp.h"
#include "services/detector/core/kdtree.h"
#include "services/detector/core/preprocess.h"
#include "services/detector/core/verify.h"

namespace picking::detector {
namespace {

using geometry::PointCloud;
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// Splat z-buffer; `winner` (optional) receives the index of the point that owns each pixel.
RangeImage Render(const PointCloud& model, const Eigen::Isometry3d& X_CameraItem,
                  const PinholeCamera& camera, double spacing_m, std::vector<int>* winner) {
  if (!(spacing_m > 0.0)) throw std::invalid_argument("RenderRangeImage: spacing must be > 0");
  RangeImage image;
  image.width = camera.width();
  image.height = camera.height();
  image.depth_m.assign(static_cast<std::size_t>(camera.width()) * camera.height(), kNaN);
  if (winner) winner->assign(image.depth_m.size(), -1);
  const Eigen::Isometry3f X = X_CameraItem.cast<float>();
  const bool normals = model.normals.size() == model.size();
  for (std::size_t i = 0; i < model.size(); ++i) {
    if (!model.points[i].allFinite()) continue;
    const Eigen::Vector3f p = X * model.points[i];
    if (p.z() <= 1e-4f) continue;
    if (normals) {
      const Eigen::Vector3f n = X.linear() * model.normals[i];
      if (n.allFinite() && n.dot(p) >= 0.0f) continue;  // facing away from the camera
    }
    const Eigen::Vector2d uv =
        camera.NormalizedToPixel(Eigen::Vector2d(p.x() / p.z(), p.y() / p.z()));
    const int r = static_cast<int>(std::floor(0.7 * camera.fx() * spacing_m / p.z()));
    const int ui = static_cast<int>(std::lround(uv.x())),
              vi = static_cast<int>(std::lround(uv.y()));
    for (int dv = -r; dv <= r; ++dv) {
      for (int du = -r; du <= r; ++du) {
        const int uu = ui + du, vv = vi + dv;
        if (uu < 0 || vv < 0 || uu >= camera.width() || vv >= camera.height()) continue;
        const std::size_t k = static_cast<std::size_t>(vv) * camera.width() + uu;
        float& z = image.depth_m[k];
        if (!(z <= p.z())) {
          z = p.z();
          if (winner) (*winner)[k] = static_cast<int>(i);
        }
      }
    }
  }
  return image;
}

Eigen::Matrix3d RotationZTo(const Eigen::Vector3d& direction) {
  const Eigen::Vector3d z = direction.normalized();
  const Eigen::Vector3d helper =
      std::abs(z.z()) < 0.9 ? Eigen::Vector3d::UnitZ() : Eigen::Vector3d::UnitX();
  const Eigen::Vector3d x = helper.cross(z).normalized();
  const Eigen::Vector3d y = z.cross(x);
  Eigen::Matrix3d R;
  R << x, y, z;
  return R;
}

struct Hypothesis {
  double cost;
  int template_index;
  Eigen::Isometry3d X_SensorCamera;  // template camera frame -> sensor frame
};

// Two-way truncated range residual of a template placed at X_SensorCamera.
double Cost(const RangeTemplate& t, const PinholeCamera& template_camera,
            const Eigen::Isometry3f& X_SensorCamera, const RangeImage& scene_depth,
            const PinholeCamera& camera, const std::vector<Eigen::Vector3f>& cluster_samples,
            float tau) {
  double sum_a = 0.0;
  for (const Eigen::Vector3f& p : t.p_CameraPoints) {
    const Eigen::Vector3f q = X_SensorCamera * p;
    float r = tau;
    if (q.z() > 1e-3f) {
      const Eigen::Vector2d uv =
          camera.NormalizedToPixel(Eigen::Vector2d(q.x() / q.z(), q.y() / q.z()));
      const int u = static_cast<int>(std::lround(uv.x()));
      const int v = static_cast<int>(std::lround(uv.y()));
      if (u >= 0 && v >= 0 && u < camera.width() && v < camera.height()) {
        const float zs = scene_depth.at(u, v);
        if (std::isfinite(zs)) r = std::min(std::abs(zs - q.z()), tau);
      }
    }
    sum_a += r;
  }
  const Eigen::Isometry3f X_CameraSensor = X_SensorCamera.inverse();
  double sum_b = 0.0;
  for (const Eigen::Vector3f& s : cluster_samples) {
    const Eigen::Vector3f p = X_CameraSensor * s;
    float r = tau;
    if (p.z() > 1e-3f) {
      const int u = static_cast<int>(
                        std::lround(template_camera.fx() * p.x() / p.z() + template_camera.cx())) -
                    t.u0;
      const int v = static_cast<int>(
                        std::lround(template_camera.fy() * p.y() / p.z() + template_camera.cy())) -
                    t.v0;
      if (u >= 0 && v >= 0 && u < t.image.width && v < t.image.height) {
        const float zt = t.image.at(u, v);
        if (std::isfinite(zt)) r = std::min(std::abs(zt - p.z()), tau);
      }
    }
    sum_b += r;
  }
  const double mean_a = t.p_CameraPoints.empty() ? tau : sum_a / t.p_CameraPoints.size();
  const double mean_b = cluster_samples.empty() ? tau : sum_b / cluster_samples.size();
  return 0.5 * (mean_a + mean_b);
}

// Throws std::invalid_argument unless every count and threshold of `options` is in range.
void ValidateMatchOptions(const TemplateMatchOptions& options) {
  if (options.in_plane_steps < 1 || options.num_refine < 1 || options.refine_iterations < 1 ||
      !(options.truncation_m > 0.0) || !(options.max_cost_m > 0.0) ||
      options.max_cluster_points < 10 || options.max_target_points < 10 ||
      !(options.min_cluster_extent_rel >= 0.0) ||
      !(options.max_cluster_extent_rel >= options.min_cluster_extent_rel))
    throw std::invalid_argument("TemplateMatchOptions: a count or threshold is out of range");
}

// The scene's range image seen from the sensor (nearest point per pixel); the templates'
// points are scored against it.
RangeImage RenderSceneDepth(const PointCloud& scene, const Eigen::Isometry3f& X_SensorBase_f,
                            const PinholeCamera& camera) {
  RangeImage scene_depth;
  scene_depth.width = camera.width();
  scene_depth.height = camera.height();
  scene_depth.depth_m.assign(static_cast<std::size_t>(camera.width()) * camera.height(), kNaN);
  for (const auto& p_Base : scene.points) {
    if (!p_Base.allFinite()) continue;
    const Eigen::Vector3f p = X_SensorBase_f * p_Base;
    if (p.z() <= 0.0f) continue;
    const Eigen::Vector2d uv =
        camera.NormalizedToPixel(Eigen::Vector2d(p.x() / p.z(), p.y() / p.z()));
    const int u = static_cast<int>(std::lround(uv.x()));
    const int v = static_cast<int>(std::lround(uv.y()));
    if (u < 0 || v < 0 || u >= camera.width() || v >= camera.height()) continue;
    float& z = scene_depth.depth_m[static_cast<std::size_t>(v) * camera.width() + u];
    if (!(z <= p.z())) z = p.z();
  }
  return scene_depth;
}

// The finite points of cluster `c` (indices into `scene`) in the sensor frame. Throws
// std::invalid_argument on an index out of range.
PointCloud GatherCluster(const PointCloud& scene, const std::vector<int>& indices, std::size_t c,
                         const Eigen::Isometry3f& X_SensorBase_f) {
  PointCloud cluster;
  for (int i : indices) {
    if (i < 0 || static_cast<std::size_t>(i) >= scene.size())
      throw std::invalid_argument("MatchTemplates: cluster " + std::to_string(c) + " has index " +
                                  std::to_string(i) + " out of range");
    if (scene.points[i].allFinite()) cluster.points.push_back(X_SensorBase_f * scene.points[i]);
  }
  return cluster;
}

// Whether the diagonal of the cluster's bounding box is a plausible size for the item
// (within [min_cluster_extent_rel, max_cluster_extent_rel] times its diameter).
bool HasPlausibleExtent(const std::vector<Eigen::Vector3f>& p_SensorPoints, double diameter_m,
                        const TemplateMatchOptions& options) {
  Eigen::AlignedBox3f box;
  for (const auto& p : p_SensorPoints) box.extend(p);
  const double extent_m = box.diagonal().norm();
  return !(extent_m < options.min_cluster_extent_rel * diameter_m ||
           extent_m > options.max_cluster_extent_rel * diameter_m);
}

// The point closest to the sensor origin (the first of equals); `p_SensorPoints` is not empty.
Eigen::Vector3f ClosestToSensor(const std::vector<Eigen::Vector3f>& p_SensorPoints) {
  Eigen::Vector3f closest = p_SensorPoints.front();
  for (const auto& p : p_SensorPoints)
    if (p.norm() < closest.norm()) closest = p;
  return closest;
}

// Thins `points` evenly (by stride) to at most max_points, so that normals and k-d tree of
// a huge merged cluster stay within the time budget.
void ThinEvenly(int max_points, std::vector<Eigen::Vector3f>* points) {
  if (points->size() > static_cast<std::size_t>(max_points)) {
    const std::size_t step = (points->size() + max_points - 1) / max_points;
    std::vector<Eigen::Vector3f> thinned;
    for (std::size_t i = 0; i < points->size(); i += step) {
      thinned.push_back((*points)[i]);
    }
    *points = std::move(thinned);
  }
}

// The points of `cluster` with a finite normal: the ICP target.
PointCloud WithFiniteNormals(const PointCloud& cluster) {
  PointCloud target;
  for (std::size_t i = 0; i < cluster.size(); ++i) {
    if (!cluster.normals[i].allFinite()) continue;
    target.points.push_back(cluster.points[i]);
    target.normals.push_back(cluster.normals[i]);
  }
  target.width = static_cast<std::uint32_t>(target.points.size());
  return target;
}

// Every stride-th cluster point, at most about max_points of them: the cluster side of Cost.
std::vector<Eigen::Vector3f> SampleCluster(const PointCloud& cluster, int max_points) {
  std::vector<Eigen::Vector3f> samples;
  const std::size_t stride = (cluster.size() + max_points - 1) / max_points;
  for (std::size_t i = 0; i < cluster.size(); i += stride) samples.push_back(cluster.points[i]);
  return samples;
}

// What a template placed in the sensor frame is scored against (see Cost).
struct CostInputs {
  const PinholeCamera& template_camera;
  const RangeImage& scene_depth;                        // seen from the sensor
  const PinholeCamera& camera;                          // the sensor's
  const std::vector<Eigen::Vector3f>& p_SensorSamples;  // of the cluster
  float tau;                                            // truncation, metres
};

// Result of the coarse search of one cluster.
struct CoarseResult {
  std::vector<Hypothesis> hypotheses;  // one per template and in-plane angle
  bool out_of_time = false;            // the deadline passed: the search is unfinished
};

// Coarse stage: every template at every in-plane angle, its view direction along the ray to
// the cluster's closest point and its closest point on that point, scored by Cost. The
// deadline is checked before each in-plane angle.
CoarseResult CoarseSearch(const std::vector<RangeTemplate>& all, const Eigen::Vector3f& closest,
                          const CostInputs& in, const TemplateMatchOptions& options) {
  const Eigen::Matrix3d R_align = RotationZTo(closest.cast<double>());
  CoarseResult coarse;
  std::vector<Hypothesis>& hypotheses = coarse.hypotheses;
  hypotheses.reserve(all.size() * options.in_plane_steps);
  bool& out_of_time = coarse.out_of_time;
  for (int k = 0; k < options.in_plane_steps && !out_of_time; ++k) {
    out_of_time = options.clock.Now() > options.deadline;
    const Eigen::Matrix3d R = R_align * Eigen::AngleAxisd(2.0 * M_PI * k / options.in_plane_steps,
                                                          Eigen::Vector3d::UnitZ())
                                            .toRotationMatrix();
    for (std::size_t t = 0; t < all.size(); ++t) {
      Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
      X.linear() = R;
      X.translation() = closest.cast<double>() - R * all[t].p_CameraClosest.cast<double>();
      const double cost = Cost(all[t], in.template_camera, X.cast<float>(), in.scene_depth,
                               in.camera, in.p_SensorSamples, in.tau);
      hypotheses.push_back({cost, static_cast<int>(t), X});
    }
  }
  return coarse;
}

// Moves the num_refine cheapest hypotheses, cheapest first, to the front; returns how many.
std::size_t KeepCheapest(int num_refine, std::vector<Hypothesis>* hypotheses) {
  const std::size_t keep = std::min<std::size_t>(num_refine, hypotheses->size());
  std::partial_sort(hypotheses->begin(), hypotheses->begin() + keep, hypotheses->end(),
                    [](const Hypothesis& a, const Hypothesis& b) { return a.cost < b.cost; });
  return keep;
}

// The ICP target of one cluster (sensor frame) and its k-d tree.
struct IcpTarget {
  const PointCloud& cloud;
  const KdTree& tree;
};

// Fine stage: ICP (coarse, then fine correspondence distance) of the template points of
// the first `keep` hypotheses on the cluster, rescored by Cost; returns the cheapest
// (cost_m infinite when keep is 0).
TemplateMatch RefineHypotheses(const std::vector<RangeTemplate>& all,
                               const std::vector<Hypothesis>& hypotheses, std::size_t keep,
                               const IcpTarget& target, const CostInputs& in,
                               const Eigen::Isometry3d& X_BaseSensor, std::size_t c,
                               const TemplateMatchOptions& options) {
  TemplateMatch best;
  best.cost_m = std::numeric_limits<double>::infinity();
  for (std::size_t h = 0; h < keep; ++h) {
    const RangeTemplate& t = all[hypotheses[h].template_index];
    PointCloud source;
    source.points = t.p_CameraPoints;
    source.normals = t.n_CameraPoints;
    source.width = static_cast<std::uint32_t>(source.points.size());
    IcpOptions icp;
    icp.max_iterations = options.refine_iterations;
    icp.max_correspondence_distance_m = static_cast<float>(2.0 * options.truncation_m);
    icp.loss_scale_m = static_cast<float>(0.25 * options.truncation_m);
    IcpResult coarse = RunIcp(source, target.cloud, target.tree, hypotheses[h].X_SensorCamera, icp);
    icp.max_correspondence_distance_m = static_cast<float>(0.5 * options.truncation_m);
    IcpResult fine = RunIcp(source, target.cloud, target.tree, coarse.X_TargetSource, icp);
    const double cost = Cost(t, in.template_camera, fine.X_TargetSource.cast<float>(),
                             in.scene_depth, in.camera, in.p_SensorSamples, in.tau);
    if (cost < best.cost_m) {
      best.cost_m = cost;
      best.template_index = hypotheses[h].template_index;
      best.cluster_index = static_cast<int>(c);
      best.X_BaseItem = X_BaseSensor * fine.X_TargetSource * t.X_CameraItem;
      best.fitness = fine.fitness;
      best.inlier_rmse_m = fine.inlier_rmse_m;
    }
  }
  return best;
}

// The points (and normals) of `model` (item frame) whose normal faces the sensor at
// X_SensorItem.
PointCloud FacingSurface(const PointCloud& model, const Eigen::Isometry3d& X_SensorItem) {
  PointCloud facing;
  for (std::size_t i = 0; i < model.size(); ++i) {
    const Eigen::Vector3d p = X_SensorItem * model.points[i].cast<double>();
    const Eigen::Vector3d n = X_SensorItem.linear() * model.normals[i].cast<double>();
    if (n.dot(p) < 0.0) {
      facing.points.push_back(model.points[i]);
      facing.normals.push_back(model.normals[i]);
    }
  }
  facing.width = static_cast<std::uint32_t>(facing.points.size());
  return facing;
}

// Final stage: ICP of the model's surface facing the sensor on the cluster; `best` takes its
// pose and figures unless its fitness fell below half of the template's.
void RefineOnModel(const PointCloud& model, const IcpTarget& target,
                   const Eigen::Isometry3d& X_BaseSensor, const Eigen::Isometry3d& X_SensorBase,
                   const TemplateMatchOptions& options, TemplateMatch* best) {
  const Eigen::Isometry3d X_SensorItem = X_SensorBase * best->X_BaseItem;
  const PointCloud facing = FacingSurface(model, X_SensorItem);
  if (facing.size() >= 10) {
    IcpOptions icp;
    icp.max_correspondence_distance_m = static_cast<float>(0.5 * options.truncation_m);
    icp.loss_scale_m = static_cast<float>(0.25 * options.truncation_m);
    const IcpResult final_icp = RunIcp(facing, target.cloud, target.tree, X_SensorItem, icp);
    if (final_icp.fitness >= 0.5 * best->fitness) {
      best->X_BaseItem = X_BaseSensor * final_icp.X_TargetSource;
      best->fitness = final_icp.fitness;
      best->inlier_rmse_m = final_icp.inlier_rmse_m;
    }
  }
}

}  // namespace

std::vector<Eigen::Vector3d> FibonacciSphere(int n) {
  if (n < 1) throw std::invalid_argument("FibonacciSphere: n must be >= 1");
  std::vector<Eigen::Vector3d> directions;
  directions.reserve(n);
  const double golden_angle = M_PI * (3.0 - std::sqrt(5.0));
  for (int i = 0; i < n; ++i) {
    const double z = 1.0 - (2.0 * i + 1.0) / n;
    const double radius = std::sqrt(std::max(0.0, 1.0 - z * z));
    const double phi = golden_angle * i;
    directions.emplace_back(radius * std::cos(phi), radius * std::sin(phi), z);
  }
  return directions;
}

PointCloud SampleMeshSurface(const world::TriangleMesh& mesh, double spacing_m,
                             std::uint32_t seed) {
  // The textured sampling draws the same points; only its albedo channel is dropped.
  PointCloud out = SampleTexturedMeshSurface(mesh, spacing_m, seed);
  out.intensities.clear();
  return out;
}

RangeImage RenderRangeImage(const PointCloud& model, const Eigen::Isometry3d& X_CameraItem,
                            const PinholeCamera& camera, double point_spacing_m) {
  return Render(model, X_CameraItem, camera, point_spacing_m, nullptr);
}

PointCloud RangeImageToCloud(const RangeImage& image, const PinholeCamera& camera) {
  PointCloud out;
  out.width = static_cast<std::uint32_t>(image.width);
  out.height = static_cast<std::uint32_t>(image.height);
  out.points.resize(image.depth_m.size());
  for (int v = 0; v < image.height; ++v) {
    for (int u = 0; u < image.width; ++u) {
      const float z = image.at(u, v);
      out.points[static_cast<std::size_t>(v) * image.width + u] =
          std::isfinite(z) ? (camera.Unproject(Eigen::Vector2d(u, v)) * z).cast<float>().eval()
                           : Eigen::Vector3f::Constant(kNaN);
    }
  }
  return out;
}

RangeTemplateSet::RangeTemplateSet(const PointCloud& model, const TemplateOptions& options) {
  if (model.empty()) throw std::invalid_argument("RangeTemplateSet: model has no points");
  if (model.normals.size() != model.size())
    throw std::invalid_argument("RangeTemplateSet: model needs one normal per point");
  if (options.num_views < 1) throw std::invalid_argument("TemplateOptions.num_views must be >= 1");
  if (!(options.distance_m > 0.0))
    throw std::invalid_argument("TemplateOptions.distance_m must be > 0");
  if (options.image_size_px < 8)
    throw std::invalid_argument("TemplateOptions.image_size_px must be >= 8");
  if (options.max_points_per_template < 10)
    throw std::invalid_argument("TemplateOptions.max_points_per_template must be >= 10");
  Eigen::AlignedBox3d bounds;
  for (const auto& p : model.points)
    if (p.allFinite()) bounds.extend(p.cast<double>());
  if (bounds.isEmpty()) throw std::invalid_argument("RangeTemplateSet: model has no finite point");
  diameter_m_ = bounds.diagonal().norm();
  p_ItemCenter_ = bounds.center();
  if (!(diameter_m_ > 0.0)) throw std::invalid_argument("RangeTemplateSet: model has no extent");
  if (options.distance_m <= diameter_m_)
    throw std::invalid_argument("TemplateOptions.distance_m must exceed the model diameter");

  const double f = options.image_size_px * options.distance_m / diameter_m_;
  const int size = static_cast<int>(std::ceil(options.image_size_px * options.distance_m /
                                              (options.distance_m - 0.5 * diameter_m_))) +
                   4;
  camera_ = PinholeCamera(size, size, f, f, 0.5 * (size - 1), 0.5 * (size - 1));
  const double pixel_m = options.distance_m / f;
  const double spacing = options.model_spacing_m > 0.0 ? options.model_spacing_m : 0.5 * pixel_m;
  model_ = VoxelDownsample(model, spacing);

  for (const Eigen::Vector3d& d : FibonacciSphere(options.num_views)) {
    // Camera on the sphere looking at the centre: its z axis is -d.
    Eigen::Isometry3d X_ItemCamera = Eigen::Isometry3d::Identity();
    X_ItemCamera.linear() = RotationZTo(-d);
    X_ItemCamera.translation() = p_ItemCenter_ + options.distance_m * d;
    RangeTemplate t;
    t.X_CameraItem = X_ItemCamera.inverse();
    std::vector<int> winner;
    const RangeImage full = Render(model_, t.X_CameraItem, camera_, spacing, &winner);
    int u_min = size, v_min = size, u_max = -1, v_max = -1;
    for (int v = 0; v < size; ++v)
      for (int u = 0; u < size; ++u)
        if (std::isfinite(full.at(u, v))) {
          u_min = std::min(u_min, u);
          u_max = std::max(u_max, u);
          v_min = std::min(v_min, v);
          v_max = std::max(v_max, v);
        }
    if (u_max < 0) continue;  // nothing visible (cannot happen for a real model)
    t.u0 = u_min;
    t.v0 = v_min;
    t.image.width = u_max - u_min + 1;
    t.image.height = v_max - v_min + 1;
    t.image.depth_m.resize(static_cast<std::size_t>(t.image.width) * t.image.height);
    std::vector<Eigen::Vector3f> points, normals;
    float closest = std::numeric_limits<float>::infinity();
    const Eigen::Matrix3f R = t.X_CameraItem.linear().cast<float>();
    for (int v = v_min; v <= v_max; ++v) {
      for (int u = u_min; u <= u_max; ++u) {
        const float z = full.at(u, v);
        t.image.depth_m[static_cast<std::size_t>(v - v_min) * t.image.width + (u - u_min)] = z;
        if (!std::isfinite(z)) continue;
        const Eigen::Vector3f p(static_cast<float>((u - camera_.cx()) * z / f),
                                static_cast<float>((v - camera_.cy()) * z / f), z);
        points.push_back(p);
        normals.push_back(R * model_.normals[winner[static_cast<std::size_t>(v) * size + u]]);
        if (p.norm() < closest) {
          closest = p.norm();
          t.p_CameraClosest = p;
        }
      }
    }
    const std::size_t stride =
        (points.size() + options.max_points_per_template - 1) / options.max_points_per_template;
    for (std::size_t i = 0; i < points.size(); i += stride) {
      t.p_CameraPoints.push_back(points[i]);
      t.n_CameraPoints.push_back(normals[i]);
    }
    templates_.push_back(std::move(t));
  }
}

std::vector<TemplateMatch> MatchTemplates(const RangeTemplateSet& templates,
                                          const PointCloud& scene,
                                          const std::vector<std::vector<int>>& clusters,
                                          const Eigen::Isometry3d& X_BaseSensor,
                                          const PinholeCamera& camera,
                                          const TemplateMatchOptions& options,
                                          TemplateSearchReport* report) {
  ValidateMatchOptions(options);
  TemplateSearchReport seen;
  seen.clusters = static_cast<int>(clusters.size());
  const Eigen::Isometry3d X_SensorBase = X_BaseSensor.inverse();
  const Eigen::Isometry3f X_SensorBase_f = X_SensorBase.cast<float>();
  const RangeImage scene_depth = RenderSceneDepth(scene, X_SensorBase_f, camera);
  const float tau = static_cast<float>(options.truncation_m);
  const auto& all = templates.templates();

  std::vector<TemplateMatch> matches;
  for (std::size_t c = 0; c < clusters.size(); ++c) {
    PointCloud cluster = GatherCluster(scene, clusters[c], c, X_SensorBase_f);
    if (options.clock.Now() > options.deadline) break;
    if (cluster.points.size() < 10 ||
        !HasPlausibleExtent(cluster.points, templates.diameter_m(), options)) {
      ++seen.implausible_clusters;
      continue;
    }
    const Eigen::Vector3f closest = ClosestToSensor(cluster.points);
    ThinEvenly(options.max_target_points, &cluster.points);
    cluster.width = static_cast<std::uint32_t>(cluster.points.size());
    NormalOptions normal_options;  // viewpoint: the sensor origin
    cluster = EstimateNormals(cluster, normal_options);
    const PointCloud target = WithFiniteNormals(cluster);  // for ICP
    if (target.size() < 10) {
      ++seen.implausible_clusters;
      continue;
    }
    const KdTree tree(target.points);
    const std::vector<Eigen::Vector3f> samples = SampleCluster(cluster, options.max_cluster_points);
    const CostInputs cost_inputs{templates.camera(), scene_depth, camera, samples, tau};

    CoarseResult coarse = CoarseSearch(all, closest, cost_inputs, options);
    if (coarse.out_of_time) break;  // An unfinished coarse search says nothing about the cluster.
    const std::size_t keep = KeepCheapest(options.num_refine, &coarse.hypotheses);

    const IcpTarget icp_target{target, tree};
    TemplateMatch best = RefineHypotheses(all, coarse.hypotheses, keep, icp_target, cost_inputs,
                                          X_BaseSensor, c, options);
    ++seen.searched_clusters;
    if (!(best.cost_m < options.max_cost_m)) {
      if (std::isfinite(best.cost_m))
        seen.best_rejected_cost_m = std::min(seen.best_rejected_cost_m, best.cost_m);
      continue;
    }
    RefineOnModel(templates.model(), icp_target, X_BaseSensor, X_SensorBase, options, &best);
    matches.push_back(best);
  }
  std::sort(matches.begin(), matches.end(),
            [](const TemplateMatch& a, const TemplateMatch& b) { return a.cost_m < b.cost_m; });
  if (report != nullptr) *report = seen;
  return matches;
}

}  // namespace picking::detector
