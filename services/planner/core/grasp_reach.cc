#include "services/planner/core/grasp_reach.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

namespace picking::planner {
namespace {

std::string Fixed(double v, int digits) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.*f", digits, v);
  return buf;
}

// The name of face (axis, sign) of a container whose opening is along `open_axis`.
std::string FaceName(const GraspContainer& container, int axis, int open_axis,
                     const Eigen::Vector3d& normal_Base) {
  if (axis == open_axis) {
    return container.kind == GraspContainerKind::kOpenTop ? "floor" : "back wall";
  }
  if (std::abs(normal_Base.z()) > 0.7) return normal_Base.z() > 0.0 ? "ceiling" : "floor";
  return "side wall";
}

}  // namespace

namespace {

// A straight piece of the tube's axis in the container frame: p0 + s d for s in [s0, s1];
// `from_lip_m` is the distance along the tube from the lip to p0.
struct AxisPiece {
  Eigen::Vector3d p0_Container;
  Eigen::Vector3d d_Container;
  double s0 = 0.0, s1 = 0.0;
  double from_lip_m = 0.0;
};

// The deepest crossing of one of the inner box's faces (not the opening) by the piece's
// surface, as far as its axis is front_edge_m or more behind the opening plane.
void WorstCrossing(const GraspContainer& container, const AxisPiece& piece, int open_axis,
                   double open_sign, double tube_radius_m, double front_edge_m, double* worst,
                   TubeReachResult* result) {
  const Eigen::Vector3d half = 0.5 * container.inner_size_m;
  const Eigen::Vector3d& p = piece.p0_Container;
  const Eigen::Vector3d& d = piece.d_Container;
  double s0 = piece.s0, s1 = piece.s1;
  // Depth behind the opening plane at s: half - open_sign * (p + s d)[open_axis].
  auto depth = [&](double s) {
    return half[open_axis] - open_sign * (p[open_axis] + s * d[open_axis]);
  };
  const double outward = open_sign * d[open_axis];
  if (std::abs(outward) > 1e-9) {
    const double s_edge = (half[open_axis] - front_edge_m - open_sign * p[open_axis]) / outward;
    if (outward > 0.0)
      s1 = std::min(s1, s_edge);
    else
      s0 = std::max(s0, s_edge);
  } else if (depth(s0) <= front_edge_m) {
    return;
  }
  if (s1 <= s0) return;
  // How far the tube's surface reaches beyond its axis along each container axis.
  Eigen::Vector3d extent;
  for (int i = 0; i < 3; ++i)
    extent[i] = tube_radius_m * std::sqrt(std::max(0.0, 1.0 - d[i] * d[i]));
  // Penetration past a face is linear along the piece: its largest value is at an end.
  for (int axis = 0; axis < 3; ++axis) {
    for (const double sign : {-1.0, 1.0}) {
      if (axis == open_axis && sign == open_sign) continue;  // the opening itself
      auto penetration = [&](double s) {
        return sign * (p[axis] + s * d[axis]) + extent[axis] - half[axis];
      };
      const double pen = std::max(penetration(s0), penetration(s1));
      if (pen <= *worst) continue;
      *worst = pen;
      result->penetration_m = pen;
      const double slope = sign * d[axis];
      const double at_s0 = penetration(s0);
      result->meets_at_m =
          piece.from_lip_m +
          (at_s0 >= 0.0 || std::abs(slope) < 1e-12 ? s0 : std::clamp(s0 - at_s0 / slope, s0, s1));
      result->container_size_m = container.inner_size_m[axis];
      Eigen::Vector3d n_Container = Eigen::Vector3d::Zero();
      n_Container[axis] = sign;
      result->wall =
          FaceName(container, axis, open_axis, container.X_BaseContainer.linear() * n_Container);
    }
  }
}

}  // namespace

TubeReachResult CheckTubeReach(const GraspContainer& container, const GraspCandidate& grasp,
                               const TubeReachOptions& options) {
  TubeReachResult result;
  const Eigen::Matrix3d R_ContainerBase = container.X_BaseContainer.linear().transpose();
  const Eigen::Vector3d p_Container = container.X_BaseContainer.inverse() * grasp.p_BasePoint;
  // Along the tube, from the lip toward the flange (the head's part).
  const Eigen::Vector3d d_Container = -(R_ContainerBase * grasp.approach_Base);
  const Eigen::Vector3d o_Container = R_ContainerBase * container.opening_direction_Base;
  int open_axis = 0;
  o_Container.cwiseAbs().maxCoeff(&open_axis);
  const double open_sign = o_Container[open_axis] > 0.0 ? 1.0 : -1.0;
  const Eigen::Vector3d half = 0.5 * container.inner_size_m;
  result.depth_m = half[open_axis] - open_sign * p_Container[open_axis];
  const bool bent = options.head_length_m > 0.0 && options.head_angle_rad != 0.0;
  // The tube's direction from the joint toward the flange.
  const double a = options.head_angle_rad;
  const Eigen::Vector3d t_Container =
      bent ? Eigen::Vector3d(R_ContainerBase * grasp.X_BaseTcp.linear() *
                             -Eigen::Vector3d(0.0, std::sin(a), std::cos(a)))
           : d_Container;
  result.angle_rad = std::acos(std::clamp(t_Container.dot(o_Container), -1.0, 1.0));
  if (result.depth_m <= options.front_edge_m) return result;

  std::vector<AxisPiece> pieces;
  if (!bent) {
    pieces.push_back(
        {p_Container, d_Container, options.cup_length_m, options.lip_to_flange_m, 0.0});
  } else {
    const double L = options.head_length_m;
    pieces.push_back({p_Container, d_Container, options.cup_length_m, L, 0.0});
    const double rest = std::max(0.0, options.lip_to_flange_m - L);
    pieces.push_back({p_Container + L * d_Container, t_Container, 0.0, rest, L});
  }
  double worst = -1e9;
  for (const AxisPiece& piece : pieces) {
    WorstCrossing(container, piece, open_axis, open_sign, options.tube_radius_m,
                  options.front_edge_m, &worst, &result);
  }
  if (worst <= options.wall_tolerance_m) {
    result.wall.clear();
    result.meets_at_m = result.penetration_m = result.container_size_m = 0.0;
    return result;
  }
  result.reaches = false;
  const bool tote = container.kind == GraspContainerKind::kOpenTop;
  const std::string size_word = result.wall == "ceiling" || result.wall == "floor" ? "high"
                                : result.wall == "back wall"                       ? "deep"
                                                                                   : "wide";
  const std::string tube = bent ? "the " + Fixed(options.lip_to_flange_m, 2) + " m tube bent " +
                                      Fixed(a * 180.0 / EIGEN_PI, 0) + " deg at its head, its rest "
                                : "the straight " + Fixed(options.lip_to_flange_m, 2) + " m tube, ";
  result.message = tube + Fixed(result.angle_rad * 180.0 / EIGEN_PI, 0) +
                   " deg from the opening direction, meets the " + (tote ? "tote's " : "bin's ") +
                   result.wall + " " + Fixed(result.meets_at_m, 2) + " m from the cup (" +
                   Fixed(result.penetration_m, 2) + " m into it): it cannot reach a '" +
                   grasp.surface + "' " + Fixed(result.depth_m, 2) + " m deep in a " +
                   Fixed(result.container_size_m, 2) + " m-" + size_word + " " +
                   (tote ? "tote" : "bin") +
                   "; grasp a surface that faces the opening, or move the item nearer to it";
  return result;
}

}  // namespace picking::planner
