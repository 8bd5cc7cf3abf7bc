#pragma once

#include <string>

#include "libs/world/mesh.h"

namespace picking::world {

/// Reads a PLY file through geometry::ReadPlyFile (ASCII or binary, either byte order): the
/// vertex element's x y z, red green blue (or r g b) and float `albedo`, and an optional face
/// element (vertex_indices or vertex_index lists; polygons are fanned into triangles). Other
/// properties and elements are skipped. A file without faces gives a mesh with vertices only
/// (a point set). Throws std::runtime_error (geometry::PointCloudIoError) naming the file and
/// what is wrong (a malformed header, truncation, a vertex index out of range, a missing x/y/z).
TriangleMesh ReadPly(const std::string& path);

/// Writes `mesh` as binary little-endian PLY: x y z float, red green blue uchar (when the mesh
/// has colours), albedo float (when it has per-vertex albedo), faces as uchar-count int lists.
/// `comment` lines go into the header. Throws std::runtime_error if it cannot be written.
void WritePly(const std::string& path, const TriangleMesh& mesh, const std::string& comment = "");

}  // namespace picking::world
