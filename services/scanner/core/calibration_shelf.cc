#include "services/scanner/core/calibration_shelf.h"

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>

#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>

namespace picking::scanner {
namespace {

struct Plane {
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // unit
  double offset = 0.0;                                // normal . p + offset = 0
  std::vector<int> inliers;

  double Distance(const Eigen::Vector3d& p) const { return normal.dot(p) + offset; }
};

// Least-squares plane through `indices` (smallest eigenvector of the scatter).
Plane RefinePlane(const std::vector<Eigen::Vector3d>& points, const std::vector<int>& indices) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (int i : indices) mean += points[i];
  mean /= static_cast<double>(indices.size());
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (int i : indices) {
    const Eigen::Vector3d d = points[i] - mean;
    scatter += d * d.transpose();
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(scatter);
  Plane plane;
  plane.normal = solver.eigenvectors().col(0).normalized();
  plane.offset = -plane.normal.dot(mean);
  plane.inliers = indices;
  return plane;
}

// RANSAC plane among `candidates` whose normal satisfies `accept`.
template <typename Accept>
bool FindPlane(const std::vector<Eigen::Vector3d>& points, const std::vector<int>& candidates,
               const ShelfPoseOptions& options, std::mt19937* rng, Accept accept, Plane* best) {
  if (static_cast<int>(candidates.size()) < options.min_face_points) return false;
  std::uniform_int_distribution<std::size_t> pick(0, candidates.size() - 1);
  std::size_t best_count = 0;
  Plane best_plane;
  for (int iteration = 0; iteration < options.ransac_iterations; ++iteration) {
    const Eigen::Vector3d& a = points[candidates[pick(*rng)]];
    const Eigen::Vector3d& b = points[candidates[pick(*rng)]];
    const Eigen::Vector3d& c = points[candidates[pick(*rng)]];
    const Eigen::Vector3d n = (b - a).cross(c - a);
    if (n.norm() < 1e-9) continue;
    Plane plane;
    plane.normal = n.normalized();
    plane.offset = -plane.normal.dot(a);
    if (!accept(plane.normal)) continue;
    std::size_t count = 0;
    for (int i : candidates) {
      if (std::abs(plane.Distance(points[i])) < options.plane_tolerance_m) ++count;
    }
    if (count > best_count) {
      best_count = count;
      best_plane = plane;
    }
  }
  if (static_cast<int>(best_count) < options.min_face_points) return false;
  // Refit on the inliers twice, re-collecting inliers each time.
  for (int pass = 0; pass < 2; ++pass) {
    std::vector<int> inliers;
    for (int i : candidates) {
      if (std::abs(best_plane.Distance(points[i])) < options.plane_tolerance_m)
        inliers.push_back(i);
    }
    if (static_cast<int>(inliers.size()) < options.min_face_points) return false;
    best_plane = RefinePlane(points, inliers);
  }
  best_plane.inliers.clear();
  for (int i : candidates) {
    if (std::abs(best_plane.Distance(points[i])) < options.plane_tolerance_m) {
      best_plane.inliers.push_back(i);
    }
  }
  *best = best_plane;
  return accept(best_plane.normal) || accept(-best_plane.normal);
}

}  // namespace

void ShelfTopModel::Validate() const {
  const Eigen::Vector3d front = p_ShelfFrontRight - p_ShelfFrontLeft;
  const Eigen::Vector3d back = p_ShelfBackRight - p_ShelfBackLeft;
  const Eigen::Vector3d left = p_ShelfBackLeft - p_ShelfFrontLeft;
  if (front.norm() < 0.05 || left.norm() < 0.05) {
    throw std::invalid_argument("ShelfTopModel: front and side edges must be at least 5 cm long");
  }
  if ((front - back).norm() > 1e-3 || std::abs(front.normalized().dot(left.normalized())) > 1e-3) {
    throw std::invalid_argument("ShelfTopModel: the four corners do not form a rectangle");
  }
}

Eigen::Isometry3d FitRigidTransform(const std::vector<Eigen::Vector3d>& p_A,
                                    const std::vector<Eigen::Vector3d>& p_B) {
  if (p_A.size() != p_B.size() || p_A.size() < 3) {
    throw std::invalid_argument("FitRigidTransform needs at least 3 point pairs of equal count");
  }
  Eigen::Vector3d mean_A = Eigen::Vector3d::Zero(), mean_B = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < p_A.size(); ++i) {
    mean_A += p_A[i];
    mean_B += p_B[i];
  }
  mean_A /= static_cast<double>(p_A.size());
  mean_B /= static_cast<double>(p_B.size());
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  for (std::size_t i = 0; i < p_A.size(); ++i) {
    covariance += (p_A[i] - mean_A) * (p_B[i] - mean_B).transpose();
  }
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(covariance,
                                              Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) D(2, 2) = -1.0;
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = svd.matrixU() * D * svd.matrixV().transpose();
  X.translation() = mean_A - X.linear() * mean_B;
  return X;
}

namespace {

// The shelf's top face: the largest plane within max_tilt_rad of level, its normal up.
Plane FindTopFace(const std::vector<Eigen::Vector3d>& points, const std::vector<int>& all,
                  const Eigen::Vector3d& up, const ShelfPoseOptions& options, std::mt19937* rng) {
  const double cos_tilt = std::cos(options.max_tilt_rad);
  Plane top;
  if (!FindPlane(
          points, all, options, rng,
          [&](const Eigen::Vector3d& n) { return std::abs(n.dot(up)) >= cos_tilt; }, &top)) {
    throw std::invalid_argument("EstimateShelfPose: no top face (a plane of at least " +
                                std::to_string(options.min_face_points) +
                                " points facing up) in the cloud of " +
                                std::to_string(points.size()) + " points");
  }
  if (top.normal.dot(up) < 0) {
    top.normal = -top.normal;
    top.offset = -top.offset;
  }
  return top;
}

// The shelf's front face among the points off the top face: perpendicular to the top and
// facing the robot, its normal toward the robot.
Plane FindFrontFace(const std::vector<Eigen::Vector3d>& points, const Plane& top,
                    const Eigen::Vector3d& front_hint, const ShelfPoseOptions& options,
                    std::mt19937* rng) {
  std::vector<bool> is_top(points.size(), false);
  for (int i : top.inliers) is_top[i] = true;
  std::vector<int> rest;
  for (std::size_t i = 0; i < points.size(); ++i) {
    if (!is_top[i]) rest.push_back(static_cast<int>(i));
  }
  const double cos_front = std::cos(options.max_front_angle_rad);
  const auto accept_front = [&](const Eigen::Vector3d& n) {
    // Perpendicular to the top face and facing the robot (either sign of the fitted normal).
    return std::abs(n.dot(top.normal)) < std::sin(0.1) && std::abs(n.dot(front_hint)) >= cos_front;
  };
  Plane front;
  if (!FindPlane(points, rest, options, rng, accept_front, &front)) {
    throw std::invalid_argument("EstimateShelfPose: no front face (a vertical plane of at least " +
                                std::to_string(options.min_face_points) +
                                " points facing the robot) in the cloud");
  }
  if (front.normal.dot(front_hint) < 0) {
    front.normal = -front.normal;
    front.offset = -front.offset;
  }
  return front;
}

// Where the two faces' points near their common edge end along it (the k-th extreme from
// either end), as distances along `edge` from `p_edge`.
std::pair<double, double> EdgeEnds(const std::vector<Eigen::Vector3d>& points, const Plane& top,
                                   const Plane& front, const Eigen::Vector3d& p_edge,
                                   const Eigen::Vector3d& edge, const ShelfPoseOptions& options) {
  std::vector<double> along;
  for (const auto* plane : {&top, &front}) {
    for (int i : plane->inliers) {
      const Eigen::Vector3d d = points[i] - p_edge;
      const Eigen::Vector3d off_line = d - d.dot(edge) * edge;
      if (off_line.norm() <= options.edge_band_m) along.push_back(d.dot(edge));
    }
  }
  const int k = std::max(1, options.edge_extreme_rank);
  if (static_cast<int>(along.size()) < 2 * k + 2) {
    throw std::invalid_argument("EstimateShelfPose: too few points near the front top edge (" +
                                std::to_string(along.size()) + ")");
  }
  std::sort(along.begin(), along.end());
  return {along[k - 1], along[along.size() - k]};
}

}  // namespace

ShelfPoseResult EstimateShelfPose(const geometry::PointCloud& cloud_Base,
                                  const ShelfTopModel& model, const ShelfPoseOptions& options) {
  model.Validate();
  if (!cloud_Base.frame_id.empty() && cloud_Base.frame_id != "base") {
    throw std::invalid_argument("EstimateShelfPose: the cloud is in frame '" + cloud_Base.frame_id +
                                "', expected 'base'");
  }
  const Eigen::Vector3d up = options.up_Base.normalized();
  Eigen::Vector3d front_hint = options.front_hint_Base - options.front_hint_Base.dot(up) * up;
  if (front_hint.norm() < 1e-6) {
    throw std::invalid_argument("ShelfPoseOptions.front_hint_Base must not be parallel to up");
  }
  front_hint.normalize();

  std::vector<Eigen::Vector3d> points;
  points.reserve(cloud_Base.size());
  for (const Eigen::Vector3f& p : cloud_Base.points) {
    if (p.allFinite()) points.push_back(p.cast<double>());
  }
  std::vector<int> all(points.size());
  for (std::size_t i = 0; i < points.size(); ++i) all[i] = static_cast<int>(i);
  std::mt19937 rng(options.seed);
  const Plane top = FindTopFace(points, all, up, options, &rng);
  const Plane front = FindFrontFace(points, top, front_hint, options, &rng);
  // Make the front normal exactly perpendicular to the top normal.
  Eigen::Vector3d n_front = (front.normal - front.normal.dot(top.normal) * top.normal).normalized();

  // Front top edge: the line on both planes, directed from the front-left to the front-right
  // corner. For corners counter-clockwise seen from above, FR - FL = n_top x n_front.
  const Eigen::Vector3d edge = top.normal.cross(n_front).normalized();
  Eigen::Matrix3d A;
  A.row(0) = top.normal.transpose();
  A.row(1) = front.normal.transpose();
  A.row(2) = edge.transpose();
  const Eigen::Vector3d p_edge =
      A.colPivHouseholderQr().solve(Eigen::Vector3d(-top.offset, -front.offset, 0.0));
  const auto [left_s, right_s] = EdgeEnds(points, top, front, p_edge, edge, options);

  const Eigen::Vector3d model_edge = model.p_ShelfFrontRight - model.p_ShelfFrontLeft;
  const Eigen::Vector3d model_side = model.p_ShelfBackLeft - model.p_ShelfFrontLeft;
  const double model_length = model_edge.norm();
  const double model_depth = model_side.norm();

  ShelfPoseResult result;
  result.top_inliers = static_cast<int>(top.inliers.size());
  result.front_inliers = static_cast<int>(front.inliers.size());
  result.top_normal_Base = top.normal;
  result.front_normal_Base = n_front;
  result.p_BaseFrontLeft = p_edge + left_s * edge;
  result.p_BaseFrontRight = p_edge + right_s * edge;
  result.edge_length_error_m = (right_s - left_s) - model_length;
  if (std::abs(result.edge_length_error_m) > options.max_edge_length_error_m) {
    throw std::invalid_argument("EstimateShelfPose: the measured front top edge is " +
                                std::to_string(right_s - left_s) + " m long but the model's is " +
                                std::to_string(model_length) +
                                " m (is the whole edge in the scan?)");
  }
  // Centre the measured edge on the model's length: the ends are the least certain part.
  const double middle_s = 0.5 * (left_s + right_s);
  const Eigen::Vector3d p_FL = p_edge + (middle_s - 0.5 * model_length) * edge;
  const Eigen::Vector3d p_FR = p_edge + (middle_s + 0.5 * model_length) * edge;
  const std::vector<Eigen::Vector3d> measured = {p_FL, p_FR, p_FR - model_depth * n_front,
                                                 p_FL - model_depth * n_front};
  const std::vector<Eigen::Vector3d> nominal = {model.p_ShelfFrontLeft, model.p_ShelfFrontRight,
                                                model.p_ShelfBackRight, model.p_ShelfBackLeft};
  result.X_BaseShelf = FitRigidTransform(measured, nominal);
  double sum = 0.0;
  for (std::size_t i = 0; i < measured.size(); ++i) {
    sum += (result.X_BaseShelf * nominal[i] - measured[i]).squaredNorm();
  }
  result.fit_rms_m = std::sqrt(sum / measured.size());
  return result;
}

}  // namespace picking::scanner
