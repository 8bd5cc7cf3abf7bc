#pragma once

#include <Eigen/Geometry>

#include <optional>
#include <string>

#include "libs/world/ray_scene.h"

namespace picking::world {

/// The suction cup's lip and what it seals on. The simulator's values (SimOptions) are the
/// cell's; the planner judges its grasps by the same rule.
struct SealOptions {
  double cup_radius_m = 0.015;          ///< Radius of the cup's lip.
  int rim_samples = 16;                 ///< Points on the lip tested for contact and seal.
  double flatness_tolerance_m = 0.002;  ///< Max deviation of the lip's points from a plane.
  double angle_tolerance_rad = 0.35;    ///< Max angle between surface normal and -z_tcp.
  double max_gap_m = 0.004;             ///< Lip points may be at most this far in front.
  double lookback_m = 0.02;             ///< Surfaces up to this far behind the lip count.
};

/// Whether the lip seals where it stands, and what it met.
struct SealMeasure {
  bool sealed = false;
  int object_id = -1;       ///< What the cup's centre met (RayScene id), -1: nothing.
  double flatness_m = 0.0;  ///< Max deviation of the lip's hits from their plane.
  double angle_rad = 0.0;   ///< Angle between that plane's normal and -z_tcp.
  std::string reason;       ///< Why not, when not sealed.
};

/// The nearest surface that the cup's centre or one of its `rim_samples` lip points (on a
/// circle of `cup_radius_m` in X_BaseTcp's x-y plane) meets along the unit `direction_Base`
/// within `max_distance_m`, skipping `ignore_object_id` (-1: none): where a cup moved that way
/// first touches. std::nullopt when nothing is met.
std::optional<RayHit> CupFirstContact(const RayScene& scene, const Eigen::Isometry3d& X_BaseTcp,
                                      const Eigen::Vector3d& direction_Base, double max_distance_m,
                                      double cup_radius_m, int rim_samples,
                                      int ignore_object_id = -1);

/// Throws std::invalid_argument unless cup_radius_m > 0, rim_samples >= 3 and the tolerances,
/// gap and lookback are >= 0.
void ValidateSealOptions(const SealOptions& options);

/// The seal of a cup whose lip centre is X_BaseTcp (+z out of the cup, toward the surface):
/// rays along +z from the centre and `rim_samples` lip points, each from `lookback_m` behind
/// the lip, must all meet one object; their hits must lie within `flatness_tolerance_m` of a
/// plane tilted at most `angle_tolerance_rad` from the cup's axis, none farther than
/// `max_gap_m` in front of the lip. Throws std::invalid_argument for bad options.
SealMeasure MeasureSeal(const RayScene& scene, const Eigen::Isometry3d& X_BaseTcp,
                        const SealOptions& options);

}  // namespace picking::world
