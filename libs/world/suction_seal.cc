#include "libs/world/suction_seal.h"

#include <Eigen/SVD>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

namespace picking::world {

void ValidateSealOptions(const SealOptions& o) {
  if (!(o.cup_radius_m > 0.0) || o.rim_samples < 3 || !(o.flatness_tolerance_m >= 0.0) ||
      !(o.angle_tolerance_rad >= 0.0) || !(o.max_gap_m >= 0.0) || !(o.lookback_m >= 0.0)) {
    throw std::invalid_argument(
        "seal options: cup_radius_m > 0, rim_samples >= 3, tolerances, gap and lookback >= 0");
  }
}

std::optional<RayHit> CupFirstContact(const RayScene& scene, const Eigen::Isometry3d& X_BaseTcp,
                                      const Eigen::Vector3d& direction_Base, double max_distance_m,
                                      double cup_radius_m, int rim_samples, int ignore_object_id) {
  const Eigen::Vector3d x = X_BaseTcp.linear().col(0), y = X_BaseTcp.linear().col(1);
  std::optional<RayHit> first;
  for (int k = -1; k < rim_samples; ++k) {
    Eigen::Vector3d p = X_BaseTcp.translation();
    if (k >= 0) {
      const double a = 2 * M_PI * k / rim_samples;
      p += cup_radius_m * (std::cos(a) * x + std::sin(a) * y);
    }
    const auto hit = scene.Cast(p, direction_Base, max_distance_m, ignore_object_id);
    if (hit && (!first || hit->distance_m < first->distance_m)) first = hit;
  }
  return first;
}

SealMeasure MeasureSeal(const RayScene& scene, const Eigen::Isometry3d& X_BaseTcp,
                        const SealOptions& options) {
  ValidateSealOptions(options);
  SealMeasure result;
  const Eigen::Vector3d z = X_BaseTcp.linear().col(2);
  const Eigen::Vector3d x = X_BaseTcp.linear().col(0), y = X_BaseTcp.linear().col(1);
  std::vector<Eigen::Vector3d> points;
  std::vector<double> gaps;  // distance of each hit in front of the lip plane
  bool same = true;
  // Rays reach past the sealing gap so a tilted surface is still measured (and refused).
  const double reach = options.lookback_m + options.max_gap_m + 2 * options.cup_radius_m;
  for (int k = -1; k < options.rim_samples; ++k) {
    Eigen::Vector3d p = X_BaseTcp.translation() - options.lookback_m * z;
    if (k >= 0) {
      const double a = 2 * M_PI * k / options.rim_samples;
      p += options.cup_radius_m * (std::cos(a) * x + std::sin(a) * y);
    }
    const auto hit = scene.Cast(p, z, reach);
    if (!hit) {
      result.reason = k < 0 ? "no surface under the cup centre" : "a lip point meets no surface";
      return result;
    }
    if (k < 0) {
      result.object_id = hit->object_id;
    } else if (hit->object_id != result.object_id) {
      same = false;
    }
    points.push_back(hit->p_BaseHit);
    gaps.push_back(hit->distance_m - options.lookback_m);
  }
  if (!same) {
    result.reason = "the lip spans more than one object";
    return result;
  }
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : points) mean += p;
  mean /= static_cast<double>(points.size());
  Eigen::MatrixXd A(points.size(), 3);
  for (std::size_t i = 0; i < points.size(); ++i) A.row(i) = (points[i] - mean).transpose();
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(A, Eigen::ComputeThinV);
  Eigen::Vector3d normal = svd.matrixV().col(2);
  if (normal.dot(z) > 0) normal = -normal;
  for (const auto& p : points) {
    result.flatness_m = std::max(result.flatness_m, std::abs((p - mean).dot(normal)));
  }
  result.angle_rad = std::acos(std::clamp(normal.dot(-z), -1.0, 1.0));
  if (result.flatness_m > options.flatness_tolerance_m) {
    result.reason = "surface under the lip is not flat enough";
  } else if (result.angle_rad > options.angle_tolerance_rad) {
    result.reason = "surface is tilted too far from the cup axis";
  } else if (*std::max_element(gaps.begin(), gaps.end()) > options.max_gap_m) {
    result.reason = "the lip does not touch the surface";
  } else {
    result.sealed = true;
  }
  return result;
}

}  // namespace picking::world
