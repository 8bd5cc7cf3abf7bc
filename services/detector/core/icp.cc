#include "services/detector/core/icp.h"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include "services/detector/core/ppf_cloud.h"

namespace picking::detector {
namespace {

struct Pair {
  std::int32_t source = 0;
  std::int32_t target = 0;
  float residual = 0.0f;  // signed point-to-plane
  float distance_sq = 0.0f;
};

void Validate(const geometry::PointCloud& source, const geometry::PointCloud& target,
              const KdTree& tree, const IcpOptions& o) {
  CheckCloudChannels(source, "RunIcp source");
  CheckCloudChannels(target, "RunIcp target");
  if (source.empty()) throw std::invalid_argument("RunIcp: the source cloud is empty");
  if (target.empty()) throw std::invalid_argument("RunIcp: the target cloud is empty");
  if (!target.has_normals()) throw std::invalid_argument("RunIcp: the target has no normals");
  if (tree.size() != target.size()) {
    throw std::invalid_argument("RunIcp: the target tree indexes " + std::to_string(tree.size()) +
                                " points, the target has " + std::to_string(target.size()));
  }
  auto fail = [](const std::string& what) { throw std::invalid_argument("IcpOptions: " + what); };
  if (o.max_iterations < 1) fail("max_iterations must be >= 1");
  if (!(o.max_correspondence_distance_m > 0.0f)) fail("max_correspondence_distance_m <= 0");
  if (!(o.max_normal_angle_rad > 0.0f && o.max_normal_angle_rad <= M_PI)) {
    fail("max_normal_angle_rad must be in (0, pi]");
  }
  if (!(o.trim_fraction > 0.0f && o.trim_fraction <= 1.0f)) fail("trim_fraction not in (0, 1]");
  if (!(o.loss_scale_m > 0.0f)) fail("loss_scale_m must be positive");
  if (o.min_correspondences < 6) fail("min_correspondences must be >= 6");
  if (!(o.max_step_rotation_rad > 0.0)) fail("max_step_rotation_rad must be positive");
  if (o.coarse_stride < 1) fail("coarse_stride must be >= 1");
  if (!(o.max_view_angle_rad > 0.0f && o.max_view_angle_rad <= M_PI)) {
    fail("max_view_angle_rad must be in (0, pi]");
  }
  if (o.viewpoint && !o.viewpoint->allFinite()) fail("viewpoint must be finite");
  if (!(o.min_constraint_ratio >= 0.0 && o.min_constraint_ratio < 1.0)) {
    fail("min_constraint_ratio must be in [0, 1)");
  }
}

}  // namespace

IcpResult RunIcp(const geometry::PointCloud& source, const geometry::PointCloud& target,
                 const KdTree& target_tree, const Eigen::Isometry3d& X_TargetSource_init,
                 const IcpOptions& options) {
  Validate(source, target, target_tree, options);
  const bool use_normals = source.has_normals();
  const float max_d2 =
      options.max_correspondence_distance_m * options.max_correspondence_distance_m;
  const float min_cos = std::cos(options.max_normal_angle_rad);

  IcpResult result;
  Eigen::Isometry3d X = X_TargetSource_init;
  std::vector<Pair> pairs;
  pairs.reserve(source.size());

  // Nearest target point of each source point at the previous pose: its distance at the
  // new pose bounds the search (the poses of successive iterations are close), which prunes
  // most of the tree without changing the answer.
  std::vector<std::int32_t> last(source.size(), KdTree::kNone);
  const bool cull = use_normals && options.viewpoint.has_value();
  const float view_cos = std::cos(options.max_view_angle_rad);
  auto correspond = [&](const Eigen::Isometry3d& X_ts, std::size_t stride, bool facing_only) {
    pairs.clear();
    const Eigen::Isometry3f Xf = X_ts.cast<float>();
    for (std::size_t i = 0; i < source.size(); i += stride) {
      const Eigen::Vector3f p = Xf * source.points[i];
      if (facing_only) {
        const Eigen::Vector3f ray = *options.viewpoint - p;
        if ((Xf.linear() * source.normals[i]).dot(ray) < view_cos * ray.norm()) continue;
      }
      float bound = max_d2;
      if (last[i] != KdTree::kNone) {
        bound = std::min(bound, (target.points[last[i]] - p).squaredNorm() * 1.0001f + 1e-12f);
      }
      float d2 = 0.0f;
      const std::int32_t j = target_tree.Nearest(p, &d2, bound);
      last[i] = j;
      if (j == KdTree::kNone) continue;
      const Eigen::Vector3f& n = target.normals[j];
      if (use_normals && (Xf.linear() * source.normals[i]).dot(n) < min_cos) continue;
      pairs.push_back({static_cast<std::int32_t>(i), j, n.dot(p - target.points[j]), d2});
    }
  };

  std::vector<Eigen::Vector3d> posed;
  posed.reserve(source.size());
  std::size_t stride = static_cast<std::size_t>(options.coarse_stride);
  if (source.size() / stride < 20 * static_cast<std::size_t>(options.min_correspondences)) {
    stride = 1;
  }
  for (int it = 0; it < options.max_iterations; ++it) {
    if (stride > 1 && 2 * it >= options.max_iterations) stride = 1;
    correspond(X, stride, cull);
    if (static_cast<int>(pairs.size()) < options.min_correspondences) break;
    if (options.trim_fraction < 1.0f) {
      const std::size_t keep = std::max<std::size_t>(
          options.min_correspondences,
          static_cast<std::size_t>(std::ceil(options.trim_fraction * pairs.size())));
      if (keep < pairs.size()) {
        std::nth_element(pairs.begin(), pairs.begin() + keep, pairs.end(),
                         [](const Pair& a, const Pair& b) {
                           return std::abs(a.residual) < std::abs(b.residual);
                         });
        pairs.resize(keep);
      }
    }
    // Each paired source point at the current pose, once for the three passes below.
    posed.clear();
    for (const Pair& pr : pairs) posed.push_back(X * source.points[pr.source].cast<double>());
    // Rotations are taken about the pairs' centroid and scaled by their spread, so that the
    // six directions are comparable and the system's eigenvalues say how well each is held.
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (const Eigen::Vector3d& p : posed) centroid += p;
    centroid /= static_cast<double>(pairs.size());
    double spread_sq = 0.0;
    for (const Eigen::Vector3d& p : posed) spread_sq += (p - centroid).squaredNorm();
    const double spread = std::max(1e-6, std::sqrt(spread_sq / static_cast<double>(pairs.size())));
    Eigen::Matrix<double, 6, 6> A = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 1> b = Eigen::Matrix<double, 6, 1>::Zero();
    for (std::size_t k_pair = 0; k_pair < pairs.size(); ++k_pair) {
      const Pair& pr = pairs[k_pair];
      const Eigen::Vector3d& p = posed[k_pair];
      const Eigen::Vector3d n = target.normals[pr.target].cast<double>();
      const double r = pr.residual;
      double w = 1.0;
      const double ar = std::abs(r);
      const double k = options.loss_scale_m;
      if (options.loss == IcpLoss::kHuber) {
        w = ar <= k ? 1.0 : k / ar;
      } else if (options.loss == IcpLoss::kTukey) {
        const double u = r / k;
        w = ar < k ? (1.0 - u * u) * (1.0 - u * u) : 0.0;
      }
      Eigen::Matrix<double, 6, 1> J;
      J.head<3>() = (p - centroid).cross(n) / spread;
      J.tail<3>() = n;
      A.noalias() += w * J * J.transpose();
      b.noalias() -= w * r * J;
    }
    // Directions the pairs hardly constrain (a box whose ends are hidden slides along its
    // top face) are left where the start put them: along them the update is noise in the
    // normals amplified by a near-zero eigenvalue, and the iterations would drift.
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> eigen(A);
    const Eigen::Matrix<double, 6, 1>& lambda = eigen.eigenvalues();  // ascending
    const double min_eigenvalue =
        std::max(options.min_constraint_ratio * lambda[5], 1e-12 * lambda[5]);
    Eigen::Matrix<double, 6, 1> y = Eigen::Matrix<double, 6, 1>::Zero();
    for (int e = 0; e < 6; ++e) {
      if (!(lambda[e] > min_eigenvalue)) continue;
      const auto v = eigen.eigenvectors().col(e);
      y += v * (v.dot(b) / lambda[e]);
    }
    // Back to a rotation about the origin: p + w x (p - c) + t' = p + w x p + (t' - w x c).
    Eigen::Matrix<double, 6, 1> x;
    x.head<3>() = y.head<3>() / spread;
    x.tail<3>() = y.tail<3>() - x.head<3>().cross(centroid);
    if (!x.allFinite()) break;
    // Trust region: a poorly constrained system (faces sliding along each other) must not
    // jump beyond the correspondence distance or by more than max_step_rotation_rad.
    const double scale =
        std::min({1.0, options.max_correspondence_distance_m / std::max(1e-12, x.tail<3>().norm()),
                  options.max_step_rotation_rad / std::max(1e-12, x.head<3>().norm())});
    x *= scale;
    const Eigen::Vector3d omega = x.head<3>();
    const double angle = omega.norm();
    Eigen::Isometry3d dX = Eigen::Isometry3d::Identity();
    if (angle > 0.0) dX.linear() = Eigen::AngleAxisd(angle, omega / angle).toRotationMatrix();
    dX.translation() = x.tail<3>();
    X = dX * X;
    X.linear() = Eigen::Quaterniond(X.linear()).normalized().toRotationMatrix();
    result.iterations = it + 1;
    if (stride > 1) {
      if (angle < 10.0 * options.convergence_rotation_rad &&
          x.tail<3>().norm() < 10.0 * options.convergence_translation_m) {
        stride = 1;
      }
    } else if (angle < options.convergence_rotation_rad &&
               x.tail<3>().norm() < options.convergence_translation_m) {
      result.converged = true;
      break;
    }
  }

  correspond(X, 1, false);
  result.X_TargetSource = X;
  result.correspondences = static_cast<int>(pairs.size());
  result.fitness = static_cast<double>(pairs.size()) / static_cast<double>(source.size());
  double sum = 0.0;
  for (const Pair& pr : pairs) sum += pr.distance_sq;
  result.inlier_rmse_m = pairs.empty() ? 0.0 : std::sqrt(sum / static_cast<double>(pairs.size()));
  return result;
}

}  // namespace picking::detector
