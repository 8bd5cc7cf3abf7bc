#pragma once

#include <Eigen/Geometry>

#include <vector>

#include "libs/world/mesh.h"

namespace picking::world {

/// Returns `mesh` with every vertex mapped by `X_NewOld` (vertices given in frame Old are
/// returned in frame New). Albedo, colours and name are kept. A reflection in `X_NewOld`
/// would flip the winding; the linear part must be a rotation.
TriangleMesh Transformed(const TriangleMesh& mesh, const Eigen::Isometry3d& X_NewOld);

/// Axis-aligned bounds of the vertices in the mesh frame (metres). Empty box for a mesh
/// without vertices.
Eigen::AlignedBox3d Bounds(const TriangleMesh& mesh);

/// Axis-aligned bounds of the mesh after mapping by `X_NewOld`, in frame New.
Eigen::AlignedBox3d Bounds(const TriangleMesh& mesh, const Eigen::Isometry3d& X_NewOld);

/// Concatenates meshes into one. If any part has per-vertex albedo or colours the result has
/// them for every vertex (parts without take their uniform `albedo` / mid grey).
TriangleMesh Merge(const std::vector<TriangleMesh>& parts);

/// Unit outward normal of triangle `t` (zero for a degenerate triangle).
Eigen::Vector3f FaceNormal(const TriangleMesh& mesh, std::size_t t);

/// Total surface area in square metres.
double SurfaceArea(const TriangleMesh& mesh);

/// Signed volume in cubic metres (positive for a closed mesh with outward CCW triangles).
double SignedVolume(const TriangleMesh& mesh);

/// Checks the index ranges and per-vertex array sizes; throws std::invalid_argument naming
/// the mesh and the first bad entry.
void Validate(const TriangleMesh& mesh);

/// Box with edge lengths `size` (metres, x y z), centred on the origin, 12 outward CCW
/// triangles with 24 vertices (4 per face, so each face can carry its own texture).
/// Throws std::invalid_argument for a non-positive or non-finite size.
TriangleMesh MakeBox(const Eigen::Vector3d& size);

/// Closed cylinder of `radius` and `height` (metres) around the z axis, centred on the
/// origin, with `segments` (>= 3) facets around. Throws std::invalid_argument on bad input.
TriangleMesh MakeCylinder(double radius, double height, int segments = 32);

/// Sphere of `radius` (metres) centred on the origin: a latitude/longitude mesh with
/// `rings` (>= 2) bands and `segments` (>= 3) facets around. Throws std::invalid_argument.
TriangleMesh MakeSphere(double radius, int rings = 16, int segments = 32);

}  // namespace picking::world
