#pragma once

// Data loading and pose helpers shared by the PPF / ICP / model tests.

#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>

#include <Eigen/Geometry>

#include <cmath>
#include <random>
#include <stdexcept>
#include <string>

#include "libs/geometry/point_cloud.h"

namespace picking::detector::testing {

inline std::string PointCloudPath(const std::string& name) {
  return std::string(PICKING_TEST_DATA_DIR) + "/pointclouds/" + name;
}

/// Reads the x y z fields of a PCD file (any PCD encoding); NaN points are kept.
inline geometry::PointCloud LoadPcd(const std::string& path) {
  pcl::PointCloud<pcl::PointXYZ> in;
  if (pcl::io::loadPCDFile(path, in) != 0) throw std::runtime_error("cannot read " + path);
  geometry::PointCloud out;
  out.points.reserve(in.size());
  for (const auto& p : in) out.points.emplace_back(p.x, p.y, p.z);
  out.width = in.width;
  out.height = in.height;
  return out;
}

inline geometry::PointCloud Transformed(const geometry::PointCloud& cloud,
                                        const Eigen::Isometry3d& X) {
  geometry::PointCloud out = cloud;
  const Eigen::Isometry3f Xf = X.cast<float>();
  for (auto& p : out.points) p = Xf * p;
  for (auto& n : out.normals) n = Xf.linear() * n;
  return out;
}

/// A uniformly random rotation and a translation uniform in a cube of half-size
/// max_translation_m.
inline Eigen::Isometry3d RandomPose(std::mt19937* rng, double max_translation_m) {
  std::normal_distribution<double> normal(0.0, 1.0);
  std::uniform_real_distribution<double> uniform(-max_translation_m, max_translation_m);
  Eigen::Quaterniond q(normal(*rng), normal(*rng), normal(*rng), normal(*rng));
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = q.normalized().toRotationMatrix();
  X.translation() = Eigen::Vector3d(uniform(*rng), uniform(*rng), uniform(*rng));
  return X;
}

/// A small random perturbation: rotation of angle_rad about a random axis and a translation
/// of length translation_m in a random direction.
inline Eigen::Isometry3d Perturbation(std::mt19937* rng, double angle_rad, double translation_m) {
  std::normal_distribution<double> normal(0.0, 1.0);
  const Eigen::Vector3d axis =
      Eigen::Vector3d(normal(*rng), normal(*rng), normal(*rng)).normalized();
  const Eigen::Vector3d dir =
      Eigen::Vector3d(normal(*rng), normal(*rng), normal(*rng)).normalized();
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::AngleAxisd(angle_rad, axis).toRotationMatrix();
  X.translation() = translation_m * dir;
  return X;
}

inline double TranslationError(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return (a.translation() - b.translation()).norm();
}

inline double RotationErrorRad(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  const double c = 0.5 * ((a.linear().transpose() * b.linear()).trace() - 1.0);
  return std::acos(std::max(-1.0, std::min(1.0, c)));
}

}  // namespace picking::detector::testing
