#pragma once

// A synthetic shelf bin shared by the region-preparation tests (preprocess, PrepareScene).

#include <Eigen/Geometry>

#include <cstddef>
#include <limits>
#include <vector>

#include "libs/geometry/point_cloud.h"
#include "services/detector/core/preprocess.h"

namespace picking::detector::testing {

// A bin 0.3 x 0.25 x 0.2 m (its box frame z up), rotated and translated, its inner floor and
// walls sampled every 5 mm, a 6 cm square item 5 cm above the floor, and 100 points outside
// the bin; `with_nan` adds one NaN point, as an organised scan holds.
struct BinScene {
  OrientedBox bin;
  geometry::PointCloud cloud;
  std::size_t item_points = 0;
};

inline BinScene MakeBinScene(double floor_z_m, bool with_nan) {
  BinScene s;
  s.bin.size_m = Eigen::Vector3d(0.3, 0.25, 0.2);
  s.bin.X_BaseBox =
      Eigen::Translation3d(0.8, 0.1, 1.2) * Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitZ());
  std::vector<Eigen::Vector3d> p_Bin;
  for (double a = -0.145; a <= 0.145; a += 0.005) {
    for (double b = -0.12; b <= 0.12; b += 0.005) p_Bin.emplace_back(a, b, floor_z_m);
  }
  for (double b = -0.12; b <= 0.12; b += 0.005) {
    for (double c = -0.095; c <= 0.095; c += 0.005) {
      p_Bin.emplace_back(-0.148, b, c);  // left wall
      p_Bin.emplace_back(0.148, b, c);   // right wall
    }
  }
  const std::size_t walls = p_Bin.size();
  for (double a = -0.03; a <= 0.03; a += 0.004) {
    for (double b = -0.03; b <= 0.03; b += 0.004) p_Bin.emplace_back(a, b, -0.05);
  }
  s.item_points = p_Bin.size() - walls;
  for (int i = 0; i < 100; ++i) p_Bin.emplace_back(0.3 + 0.001 * i, 0.0, 0.0);  // outside
  for (const Eigen::Vector3d& p : p_Bin) {
    s.cloud.points.push_back((s.bin.X_BaseBox * p).cast<float>());
  }
  if (with_nan)
    s.cloud.points.push_back(Eigen::Vector3f::Constant(std::numeric_limits<float>::quiet_NaN()));
  s.cloud.width = static_cast<std::uint32_t>(s.cloud.points.size());
  return s;
}

}  // namespace picking::detector::testing
