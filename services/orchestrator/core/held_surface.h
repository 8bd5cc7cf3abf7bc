#pragma once

#include <Eigen/Geometry>

#include "libs/geometry/point_cloud.h"

namespace picking::orchestrator {

/// Options of MeasureHeldSurface. Lengths in metres.
struct HeldSurfaceOptions {
  /// Points farther than this from the cup's lip are not the held item's (the longest APC
  /// item is 0.37 m).
  double reach_m = 0.40;
  /// The believed item's box is grown by this: the grasp is known to the detection's
  /// accuracy, and a few degrees off turn a long item's far end by a centimetre or two.
  double box_margin_m = 0.02;
  /// Only points this far out of the container's opening (in front of a shelf bin, above the
  /// tote's rim): the container's own contents and walls lie behind it.
  double out_of_opening_m = 0.03;
  /// Points this far behind the cup's lip (on the tube's side) may still be the item's (the
  /// cup compresses).
  double behind_lip_m = 0.005;
};

/// What a view shows of the space only a held item can fill: within reach of the cup, in
/// front of its lip, out of the container's opening.
struct HeldSurface {
  int on_item = 0;  ///< Points within the believed item's box (grown by the margin).
  int beyond = 0;   ///< Points outside it: surface of something larger than the item believed.
  int total() const { return on_item + beyond; }
  /// beyond / total, 0 for no point.
  double BeyondFraction() const { return total() > 0 ? double(beyond) / total() : 0.0; }
};

/// Counts the points of `cloud_Base` (finite ones) in the held item's space: within reach_m
/// of the cup's lip at X_BaseTcp, not more than behind_lip_m behind the lip (the tcp's z points
/// into the held item), and at least out_of_opening_m out of the container's opening plane
/// (a point on it, p_BaseOpening, and its outward unit normal n_BaseOpening); split by
/// whether they lie within the box of the believed item (size_m, centred on the item frame)
/// hanging at X_TcpItem. A held item the cup took for a smaller one shows as points beyond
/// its box; one smaller than believed leaves the box empty where the camera sees through
/// (the detector's Verify judges that).
HeldSurface MeasureHeldSurface(const geometry::PointCloud& cloud_Base,
                               const Eigen::Isometry3d& X_BaseTcp,
                               const Eigen::Isometry3d& X_TcpItem, const Eigen::Vector3d& size_m,
                               const Eigen::Vector3d& p_BaseOpening,
                               const Eigen::Vector3d& n_BaseOpening,
                               const HeldSurfaceOptions& options = {});

}  // namespace picking::orchestrator
