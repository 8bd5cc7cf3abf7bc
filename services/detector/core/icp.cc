#include "services/detector/core/icp.h"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <cstdint>
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

using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

// The correspondence search of one RunIcp call: pairs source points at a pose with their
// nearest target points, rejected by distance, normal angle and (optionally) view angle.
// It remembers the nearest target point of each source point at the previous pose: its
// distance at the new pose bounds the search (the poses of successive iterations are
// close), which prunes most of the tree without changing the answer.
struct PairFinder {
  PairFinder(const geometry::PointCloud& source_in, const geometry::PointCloud& target_in,
             const KdTree& target_tree_in, const IcpOptions& options_in)
      : source(source_in),
        target(target_in),
        target_tree(target_tree_in),
        options(options_in),
        use_normals(source_in.has_normals()),
        max_d2(options_in.max_correspondence_distance_m * options_in.max_correspondence_distance_m),
        min_cos(std::cos(options_in.max_normal_angle_rad)),
        view_cos(std::cos(options_in.max_view_angle_rad)),
        last(source_in.size(), KdTree::kNone) {
    pairs.reserve(source.size());
  }

  // Replaces `pairs` by those of every stride-th source point at X_ts (X_TargetSource);
  // facing_only skips source points whose normal points away from options.viewpoint.
  void Find(const Eigen::Isometry3d& X_ts, std::size_t stride, bool facing_only) {
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
  }

  const geometry::PointCloud& source;
  const geometry::PointCloud& target;
  const KdTree& target_tree;
  const IcpOptions& options;
  const bool use_normals;          // the source has normals: pairs are also rejected by angle
  const float max_d2;              // max_correspondence_distance_m squared, m^2
  const float min_cos;             // cos(max_normal_angle_rad)
  const float view_cos;            // cos(max_view_angle_rad)
  std::vector<std::int32_t> last;  // per source point: its nearest target point, or kNone
  std::vector<Pair> pairs;         // of the last Find
};

// The source subsampling stride of the first iterations: coarse_stride, or 1 when the
// subsample would have fewer than 20 * min_correspondences points.
std::size_t InitialStride(std::size_t source_size, const IcpOptions& options) {
  std::size_t stride = static_cast<std::size_t>(options.coarse_stride);
  if (source_size / stride < 20 * static_cast<std::size_t>(options.min_correspondences)) {
    stride = 1;
  }
  return stride;
}

// Keeps the trim_fraction of the pairs with the smallest |residual| (at least
// min_correspondences): the others are the likeliest outliers.
void TrimPairs(const IcpOptions& options, std::vector<Pair>* pairs) {
  if (options.trim_fraction < 1.0f) {
    const std::size_t keep = std::max<std::size_t>(
        options.min_correspondences,
        static_cast<std::size_t>(std::ceil(options.trim_fraction * pairs->size())));
    if (keep < pairs->size()) {
      std::nth_element(
          pairs->begin(), pairs->begin() + keep, pairs->end(),
          [](const Pair& a, const Pair& b) { return std::abs(a.residual) < std::abs(b.residual); });
      pairs->resize(keep);
    }
  }
}

// The robustly weighted, linearised point-to-plane system of one iteration. Rotations are
// taken about the pairs' centroid and scaled by their spread, so that the six directions
// are comparable and the system's eigenvalues say how well each is held.
struct NormalEquations {
  Matrix6d A = Matrix6d::Zero();
  Vector6d b = Vector6d::Zero();
  Eigen::Vector3d p_TargetCentroid = Eigen::Vector3d::Zero();  // of the posed pairs
  double spread_m = 0.0;  // RMS distance of the posed pairs to the centroid, >= 1e-6
};

// Builds the system at X_TargetSource; `posed` is scratch space for the paired source
// points at that pose (kept by the caller to reuse its allocation).
NormalEquations BuildNormalEquations(const geometry::PointCloud& source,
                                     const geometry::PointCloud& target, const IcpOptions& options,
                                     const Eigen::Isometry3d& X_TargetSource,
                                     const std::vector<Pair>& pairs,
                                     std::vector<Eigen::Vector3d>* posed) {
  const Eigen::Isometry3d& X = X_TargetSource;
  // Each paired source point at the current pose, once for the three passes below.
  posed->clear();
  for (const Pair& pr : pairs) posed->push_back(X * source.points[pr.source].cast<double>());
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& p : *posed) centroid += p;
  centroid /= static_cast<double>(pairs.size());
  double spread_sq = 0.0;
  for (const Eigen::Vector3d& p : *posed) spread_sq += (p - centroid).squaredNorm();
  const double spread = std::max(1e-6, std::sqrt(spread_sq / static_cast<double>(pairs.size())));
  Matrix6d A = Matrix6d::Zero();
  Vector6d b = Vector6d::Zero();
  for (std::size_t k_pair = 0; k_pair < pairs.size(); ++k_pair) {
    const Pair& pr = pairs[k_pair];
    const Eigen::Vector3d& p = (*posed)[k_pair];
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
    Vector6d J;
    J.head<3>() = (p - centroid).cross(n) / spread;
    J.tail<3>() = n;
    A.noalias() += w * J * J.transpose();
    b.noalias() -= w * r * J;
  }
  NormalEquations equations;
  equations.A = A;
  equations.b = b;
  equations.p_TargetCentroid = centroid;
  equations.spread_m = spread;
  return equations;
}

// Solves the system for the update x (rotation vector about the origin, radians; then
// translation, metres), which may be non-finite. Directions the pairs hardly constrain (a
// box whose ends are hidden slides along its top face) are left where the start put them:
// along them the update is noise in the normals amplified by a near-zero eigenvalue, and
// the iterations would drift.
Vector6d SolveUpdate(const NormalEquations& equations, const IcpOptions& options) {
  const Eigen::SelfAdjointEigenSolver<Matrix6d> eigen(equations.A);
  const Vector6d& lambda = eigen.eigenvalues();  // ascending
  const double min_eigenvalue =
      std::max(options.min_constraint_ratio * lambda[5], 1e-12 * lambda[5]);
  Vector6d y = Vector6d::Zero();
  for (int e = 0; e < 6; ++e) {
    if (!(lambda[e] > min_eigenvalue)) continue;
    const auto v = eigen.eigenvectors().col(e);
    y += v * (v.dot(equations.b) / lambda[e]);
  }
  // Back to a rotation about the origin: p + w x (p - c) + t' = p + w x p + (t' - w x c).
  Vector6d x;
  x.head<3>() = y.head<3>() / equations.spread_m;
  x.tail<3>() = y.tail<3>() - x.head<3>().cross(equations.p_TargetCentroid);
  return x;
}

// Size of an applied update, for the convergence test.
struct StepSize {
  double rotation_rad = 0.0;
  double translation_m = 0.0;
};

// Applies the (finite) update x to X_TargetSource as an exact rotation, within the trust
// region: a poorly constrained system (faces sliding along each other) must not jump
// beyond the correspondence distance or by more than max_step_rotation_rad.
StepSize ApplyUpdate(const Vector6d& update, const IcpOptions& options,
                     Eigen::Isometry3d* X_TargetSource) {
  Vector6d x = update;
  const double scale =
      std::min({1.0, options.max_correspondence_distance_m / std::max(1e-12, x.tail<3>().norm()),
                options.max_step_rotation_rad / std::max(1e-12, x.head<3>().norm())});
  x *= scale;
  const Eigen::Vector3d omega = x.head<3>();
  const double angle = omega.norm();
  Eigen::Isometry3d dX = Eigen::Isometry3d::Identity();
  if (angle > 0.0) dX.linear() = Eigen::AngleAxisd(angle, omega / angle).toRotationMatrix();
  dX.translation() = x.tail<3>();
  Eigen::Isometry3d& X = *X_TargetSource;
  X = dX * X;
  X.linear() = Eigen::Quaterniond(X.linear()).normalized().toRotationMatrix();
  StepSize step;
  step.rotation_rad = angle;
  step.translation_m = x.tail<3>().norm();
  return step;
}

// Fills the quality figures of `result` from the pairs of all source points at the final
// pose.
void MeasureFit(const std::vector<Pair>& pairs, std::size_t source_size, IcpResult* result) {
  result->correspondences = static_cast<int>(pairs.size());
  result->fitness = static_cast<double>(pairs.size()) / static_cast<double>(source_size);
  double sum = 0.0;
  for (const Pair& pr : pairs) sum += pr.distance_sq;
  result->inlier_rmse_m = pairs.empty() ? 0.0 : std::sqrt(sum / static_cast<double>(pairs.size()));
}

}  // namespace

IcpResult RunIcp(const geometry::PointCloud& source, const geometry::PointCloud& target,
                 const KdTree& target_tree, const Eigen::Isometry3d& X_TargetSource_init,
                 const IcpOptions& options) {
  Validate(source, target, target_tree, options);
  IcpResult result;
  Eigen::Isometry3d X = X_TargetSource_init;
  PairFinder finder(source, target, target_tree, options);
  std::vector<Pair>& pairs = finder.pairs;
  const bool cull = finder.use_normals && options.viewpoint.has_value();

  std::vector<Eigen::Vector3d> posed;
  posed.reserve(source.size());
  std::size_t stride = InitialStride(source.size(), options);
  for (int it = 0; it < options.max_iterations; ++it) {
    if (stride > 1 && 2 * it >= options.max_iterations) stride = 1;
    finder.Find(X, stride, cull);
    if (static_cast<int>(pairs.size()) < options.min_correspondences) break;
    TrimPairs(options, &pairs);
    const NormalEquations equations =
        BuildNormalEquations(source, target, options, X, pairs, &posed);
    const Vector6d x = SolveUpdate(equations, options);
    if (!x.allFinite()) break;
    const StepSize step = ApplyUpdate(x, options, &X);
    result.iterations = it + 1;
    if (stride > 1) {
      if (step.rotation_rad < 10.0 * options.convergence_rotation_rad &&
          step.translation_m < 10.0 * options.convergence_translation_m) {
        stride = 1;
      }
    } else if (step.rotation_rad < options.convergence_rotation_rad &&
               step.translation_m < options.convergence_translation_m) {
      result.converged = true;
      break;
    }
  }

  finder.Find(X, 1, false);
  result.X_TargetSource = X;
  MeasureFit(pairs, source.size(), &result);
  return result;
}

}  // namespace picking::detector
