#include "services/planner/core/grasp_reach.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

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
    return container.kind == GraspContainerKind::kTote ? "floor" : "back wall";
  }
  if (std::abs(normal_Base.z()) > 0.7) return normal_Base.z() > 0.0 ? "ceiling" : "floor";
  return "side wall";
}

}  // namespace

TubeReachResult CheckTubeReach(const GraspContainer& container, const GraspCandidate& grasp,
                               const TubeReachOptions& options) {
  TubeReachResult result;
  const Eigen::Matrix3d R_BaseContainer = container.X_BaseContainer.linear();
  const Eigen::Vector3d p_Container = container.X_BaseContainer.inverse() * grasp.p_BasePoint;
  // Along the tube, from the lip toward the flange.
  const Eigen::Vector3d d_Container = -(R_BaseContainer.transpose() * grasp.approach_Base);
  const Eigen::Vector3d o_Container =
      R_BaseContainer.transpose() * container.opening_direction_Base;
  int open_axis = 0;
  o_Container.cwiseAbs().maxCoeff(&open_axis);
  const double open_sign = o_Container[open_axis] > 0.0 ? 1.0 : -1.0;
  const Eigen::Vector3d half = 0.5 * container.inner_size_m;
  const double r = options.tube_radius_m;
  // How far the tube's surface reaches beyond its axis along each container axis.
  Eigen::Vector3d extent;
  for (int i = 0; i < 3; ++i)
    extent[i] = r * std::sqrt(std::max(0.0, 1.0 - d_Container[i] * d_Container[i]));
  result.depth_m = half[open_axis] - open_sign * p_Container[open_axis];
  result.angle_rad = std::acos(std::clamp(d_Container.dot(o_Container), -1.0, 1.0));

  // The tube from the cup's base to the flange, as far as its axis is front_edge_m or more
  // behind the opening plane: nearer to it the walls may already have ended.
  const double s0 = options.cup_length_m;
  double s1 = options.lip_to_flange_m;
  const double outward = open_sign * d_Container[open_axis];
  if (result.depth_m <= options.front_edge_m) return result;
  if (outward > 1e-9) {
    s1 = std::clamp((result.depth_m - options.front_edge_m) / outward, s0, s1);
  }
  // Penetration past a face is linear along the tube: its largest value is at an end.
  double worst = -1e9;
  for (int axis = 0; axis < 3; ++axis) {
    for (const double sign : {-1.0, 1.0}) {
      if (axis == open_axis && sign == open_sign) continue;  // the opening itself
      auto penetration = [&](double s) {
        return sign * (p_Container[axis] + s * d_Container[axis]) + extent[axis] - half[axis];
      };
      const double pen = std::max(penetration(s0), penetration(s1));
      if (pen <= worst) continue;
      worst = pen;
      result.penetration_m = pen;
      const double slope = sign * d_Container[axis];
      const double at_s0 = penetration(s0);
      result.meets_at_m =
          at_s0 >= 0.0 || std::abs(slope) < 1e-12 ? s0 : std::clamp(s0 - at_s0 / slope, s0, s1);
      result.container_size_m = container.inner_size_m[axis];
      Eigen::Vector3d n_Container = Eigen::Vector3d::Zero();
      n_Container[axis] = sign;
      result.wall = FaceName(container, axis, open_axis, R_BaseContainer * n_Container);
    }
  }
  if (worst <= options.wall_tolerance_m) {
    result.wall.clear();
    result.meets_at_m = result.penetration_m = result.container_size_m = 0.0;
    return result;
  }
  result.reaches = false;
  const bool tote = container.kind == GraspContainerKind::kTote;
  const std::string size_word = result.wall == "ceiling" || result.wall == "floor" ? "high"
                                : result.wall == "back wall"                       ? "deep"
                                                                                   : "wide";
  result.message = "the straight " + Fixed(options.lip_to_flange_m, 2) + " m tube, " +
                   Fixed(result.angle_rad * 180.0 / EIGEN_PI, 0) +
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
