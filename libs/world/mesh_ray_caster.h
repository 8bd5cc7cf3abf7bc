#pragma once

#include <Eigen/Core>

#include <limits>
#include <optional>
#include <vector>

#include "libs/world/mesh.h"

namespace picking::world {

/// One ray / triangle intersection, in the frame of the mesh.
struct MeshRayHit {
  double distance_m = 0.0;     ///< Ray parameter (unit direction: metres).
  std::uint32_t triangle = 0;  ///< Index into TriangleMesh::triangles.
  Eigen::Vector3d normal;      ///< Unit geometric normal of the triangle (its winding).
};

/// Ray casting against one static triangle mesh through a bounding volume hierarchy (median
/// split, axis-aligned boxes). Used for geometric measurements of meshes (e.g. the shelf bins);
/// the simulator's scene-wide casting uses Embree.
///
/// The caster keeps a copy of the mesh; it is immutable after construction and safe to query
/// from several threads.
class MeshRayCaster final {
 public:
  /// Builds the hierarchy. Throws std::invalid_argument if the mesh is invalid or empty.
  explicit MeshRayCaster(TriangleMesh mesh);

  /// Nearest hit with distance in [t_min, t_max] (metres) along the ray from `origin` in
  /// `direction` (normalised here; must be non-zero). Both faces of a triangle count.
  std::optional<MeshRayHit> Cast(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                                 double t_min = 0.0,
                                 double t_max = std::numeric_limits<double>::infinity()) const;

  /// Every hit along the ray in [t_min, t_max], sorted by distance.
  std::vector<MeshRayHit> CastAll(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                                  double t_min = 0.0,
                                  double t_max = std::numeric_limits<double>::infinity()) const;

  const TriangleMesh& mesh() const { return mesh_; }

 private:
  struct Node {
    Eigen::Vector3f lo, hi;
    std::uint32_t first = 0;  // leaf: first index into order_; inner: right child index
    std::uint32_t count = 0;  // leaf: number of triangles; inner: 0
  };
  std::uint32_t Build(std::uint32_t begin, std::uint32_t end);
  template <typename Visit>
  void Traverse(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_min, double& t_max,
                Visit&& visit) const;

  TriangleMesh mesh_;
  std::vector<std::uint32_t> order_;
  std::vector<Eigen::Vector3f> centroids_;
  std::vector<Node> nodes_;
};

}  // namespace picking::world
