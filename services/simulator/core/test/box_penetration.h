#pragma once

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

namespace picking::simulator {

// How deep two oriented boxes (half sizes, poses of their centres) interpenetrate: the least
// overlap over the 15 separating axes of two boxes; <= 0 when they are apart. The tests' own
// measure, apart from the code under test.
inline double BoxPenetration(const Eigen::Vector3d& ha, const Eigen::Isometry3d& Xa,
                             const Eigen::Vector3d& hb, const Eigen::Isometry3d& Xb) {
  const Eigen::Matrix3d A = Xa.linear(), B = Xb.linear();
  const Eigen::Vector3d d = Xb.translation() - Xa.translation();
  std::vector<Eigen::Vector3d> axes;
  for (int i = 0; i < 3; ++i) {
    axes.push_back(A.col(i));
    axes.push_back(B.col(i));
    for (int j = 0; j < 3; ++j) {
      const Eigen::Vector3d c = A.col(i).cross(B.col(j));
      if (c.norm() > 1e-6) axes.push_back(c.normalized());
    }
  }
  double least = std::numeric_limits<double>::infinity();
  for (const Eigen::Vector3d& n : axes) {
    const double ra = (A.transpose() * n).cwiseAbs().dot(ha);
    const double rb = (B.transpose() * n).cwiseAbs().dot(hb);
    least = std::min(least, ra + rb - std::abs(n.dot(d)));
  }
  return least;
}

}  // namespace picking::simulator
