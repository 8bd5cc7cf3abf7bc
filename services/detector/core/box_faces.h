#pragma once

#include <Eigen/Geometry>

#include <cstddef>
#include <functional>
#include <optional>
#include <vector>

#include "libs/geometry/point_cloud.h"
#include "services/detector/core/kdtree.h"

namespace picking::detector {

/// Options of FindPlanarPatches and BoxPosesOnPatch.
struct BoxFaceOptions {
  /// Region growing joins points within this distance of a member, metres (> 0).
  double neighbour_radius_m = 0.008;
  /// ... whose normal is within this angle of the patch's plane normal, radians, in (0, pi/2).
  double normal_tolerance_rad = 0.2;
  /// ... and that lie within this distance of the patch's plane, metres (> 0).
  double plane_tolerance_m = 0.004;
  /// Patches with fewer points are dropped (>= 3).
  std::size_t min_points = 30;
  /// At most this many patches are returned, the largest first (>= 1).
  int max_patches = 16;
  /// A patch may exceed a face by this much along each side and still be that face (it
  /// carries a few points of the neighbouring faces' rounded edges), metres (>= 0) ...
  double size_tolerance_m = 0.008;
  /// ... plus this fraction of the face's side (>= 0).
  double size_tolerance_rel = 0.08;
  /// A face side differing from the patch's side by less than this is taken as seen whole
  /// (one placement instead of three along that side), metres (>= 0).
  double whole_side_m = 0.006;

  /// Throws std::invalid_argument naming the bad field.
  void Validate() const;
};

/// A planar patch of a scene: its plane and the smallest rectangle in that plane holding its
/// points.
struct PlanarPatch {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();  ///< Of the rectangle, in the plane.
  /// Unit plane normal, pointing the way the points' normals point (toward the sensors).
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
  /// Unit rectangle sides in the plane; axis_u x axis_v = normal.
  Eigen::Vector3d axis_u = Eigen::Vector3d::UnitX();
  Eigen::Vector3d axis_v = Eigen::Vector3d::UnitY();
  double half_u = 0.0;  ///< Half the rectangle's side along axis_u, metres.
  double half_v = 0.0;
  std::size_t points = 0;
  double rms_m = 0.0;  ///< RMS distance of the points to the plane.
};

/// Planar patches of `cloud` (points with unit normals, e.g. PpfScene::fine; `tree` over its
/// points): region growing from each unassigned point over neighbours whose normal agrees with
/// the patch's plane and that lie on it, the plane refitted (least squares) as the patch
/// doubles; then each patch's minimum-area bounding rectangle in its plane (rotating calipers
/// over the convex hull). Largest patches first. Throws std::invalid_argument for a cloud
/// without normals, a tree of another size or bad options.
std::vector<PlanarPatch> FindPlanarPatches(const geometry::PointCloud& cloud, const KdTree& tree,
                                           const BoxFaceOptions& options = {});

/// Poses X_SceneItem of a box with half sides `half_size` (the item frame at its centre, sides
/// along x, y, z) that put one of its faces on `patch`: the face's outward normal along the
/// patch normal, its sides along the rectangle's (both ways round), and the face over the
/// rectangle either centred on it or, where the face is longer than the patch (the rest of it
/// hidden), flush with either end of the rectangle along that side. Faces the patch does not
/// fit in (beyond the size tolerance) give none. A box is symmetric under half turns about its
/// axes, so the face's side of the box and the turn of the print are left to verification.
std::vector<Eigen::Isometry3d> BoxPosesOnPatch(const PlanarPatch& patch,
                                               const Eigen::Vector3d& half_size,
                                               const BoxFaceOptions& options = {});

/// Options of BoxSurfaceContinuation.
struct ContinuationOptions {
  /// Probes lie this far outside a face's edges, in its plane, metres (> 0) ...
  double offset_m = 0.008;
  /// ... every this many metres along the edges (> 0).
  double spacing_m = 0.005;
  /// A probe is continued when a scene point lies within this distance of it, metres (> 0),
  double match_radius_m = 0.003;
  /// ... within plane_tolerance_m of the face's plane (> 0) ...
  double plane_tolerance_m = 0.003;
  /// ... with its normal within this angle of the face's, radians (> 0).
  double normal_tolerance_rad = 0.3;

  /// Throws std::invalid_argument naming the bad field.
  void Validate() const;
};

/// How much of the rim of a box's faces that face `viewpoint` the scene's surface runs on
/// past, in the face's plane: the fraction of probes just outside the faces' edges that
/// have a coplanar scene point with a parallel normal (0 when no face faces the viewpoint).
/// A real box's faces end at its edges: the scene there bends round to the next
/// face, drops to what is behind, or is hidden. A box pose laid inside a larger surface (a
/// thin box along the edge strip of a bigger one) has faces that the scene continues past.
/// `scene` needs unit normals and `tree` over its points; X_SceneBox puts the box's centre
/// (sides along its axes, half sides `half_size`) in the scene. Throws
/// std::invalid_argument for a scene without normals, a tree of another size, bad sizes or
/// options.
double BoxSurfaceContinuation(const geometry::PointCloud& scene, const KdTree& tree,
                              const Eigen::Isometry3d& X_SceneBox, const Eigen::Vector3d& half_size,
                              const Eigen::Vector3d& viewpoint,
                              const ContinuationOptions& options = {});

/// The quarter-turns of a box about its centre (item frame: half sides `half_size`, centre
/// `p_ItemCentre`) that map it nearly onto itself: one about each axis whose two
/// perpendicular sides differ by at most `tolerance` (>= 0) of the longer. Each is
/// T_ItemItem', so that X_BaseItem * T is the turned pose. A nearly square face fits a scan
/// of it about as well either way, and a box's symmetry turns (half turns) do not cover
/// this. Throws std::invalid_argument for sizes that are not positive or a negative
/// tolerance.
std::vector<Eigen::Isometry3d> NearSquareQuarterTurns(const Eigen::Vector3d& half_size,
                                                      const Eigen::Vector3d& p_ItemCentre,
                                                      double tolerance);

/// Pattern search of a pose's translation on a score: from X (scoring `score`), tries a
/// move by `step_m` (> 0) along each of `axes` (columns of X's rotation, 0-2) both ways and
/// takes the best while it scores higher (at most kMaxPolishMoves times), then does the
/// same with half the step; `levels` (>= 0) step sizes in all.
/// `score_of` gives a pose's score, or nothing when there is no time left (the search then
/// stops with the best so far). Returns the best pose and its score (X and `score` when
/// no move scored higher). Throws std::invalid_argument for bad steps, levels or axes.
inline constexpr int kMaxPolishMoves = 16;
struct PosePolish {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  double score = 0.0;
  int evaluations = 0;
};
PosePolish PolishTranslation(
    const Eigen::Isometry3d& X, double score, const std::vector<int>& axes, double step_m,
    int levels, const std::function<std::optional<double>(const Eigen::Isometry3d&)>& score_of);

}  // namespace picking::detector
