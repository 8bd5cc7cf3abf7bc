#pragma once

#include <Eigen/Geometry>

#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <vector>

#include "libs/world/mesh.h"

namespace picking::world {

/// A surface along a ray, in the base frame.
struct RayHit {
  double distance_m = 0.0;     ///< Along the (normalised) ray direction.
  int object_id = -1;          ///< Id given to RayScene::Add.
  std::uint32_t triangle = 0;  ///< Index into the added mesh's TriangleMesh::triangles.
  Eigen::Vector3d p_BaseHit = Eigen::Vector3d::Zero();
  /// Unit geometric normal (triangle winding: outward for well-formed meshes), base frame.
  Eigen::Vector3d n_Base = Eigen::Vector3d::UnitZ();
};

/// How RayScene reports a hit's distance.
enum class HitDistance {
  /// Embree's: vertices, ray and distance in single precision (the simulator's world).
  kSingle,
  /// Embree finds the surface; the distance is then computed again in double precision on the
  /// hit triangle (its vertices placed in double precision) from the double-precision ray, as
  /// exact as the mesh's vertices (measurements: the shelf's bins and the tote's inner box).
  kDouble,
};

/// Ray casting against a set of placed meshes with Embree (embree 3: one device and one
/// static scene per RayScene; vertices and ray parameters in single precision, distances as
/// `HitDistance` says). The one ray caster of the project: the simulator's world and the
/// measurement of the shelf's bins and the tote's inner box (MeasureBins, MeasureToteInner)
/// use it. Build with Add() and Commit(); Cast() and CastAll() are const and thread safe after
/// Commit(). Not copyable.
class RayScene final {
 public:
  explicit RayScene(HitDistance distance = HitDistance::kSingle);
  ~RayScene();
  RayScene(const RayScene&) = delete;
  RayScene& operator=(const RayScene&) = delete;

  /// Adds `mesh` placed at X_BaseObject (vertices are copied and transformed). `object_id` is
  /// reported in hits (several meshes may share an id). Throws std::logic_error after Commit,
  /// std::invalid_argument for an invalid mesh or a non-finite pose. Empty meshes are ignored.
  void Add(int object_id, const TriangleMesh& mesh, const Eigen::Isometry3d& X_BaseObject);
  /// Builds the acceleration structure. Idempotent.
  void Commit();

  /// Nearest hit in (t_min, t_max] along `origin + t * direction.normalized()`, skipping
  /// surfaces of `ignore_object_id` (-1: none). Both faces count. Throws std::logic_error
  /// before Commit, std::invalid_argument for a non-finite or zero ray.
  std::optional<RayHit> Cast(const Eigen::Vector3d& p_BaseOrigin,
                             const Eigen::Vector3d& direction_Base, double t_max,
                             int ignore_object_id = -1, double t_min = 0.0) const;

  /// Every surface in (t_min, t_max] along the same ray as Cast, sorted by distance (strictly
  /// increasing: surfaces met at the same single-precision distance, e.g. the two triangles
  /// of a shared edge or coincident faces, are one hit; with HitDistance::kDouble the order is
  /// Embree's, i.e. to single precision). Both faces count. Throws as Cast.
  std::vector<RayHit> CastAll(const Eigen::Vector3d& p_BaseOrigin,
                              const Eigen::Vector3d& direction_Base,
                              double t_max = std::numeric_limits<double>::infinity(),
                              double t_min = 0.0) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace picking::world
