#pragma once

// The PLY reader behind ReadPointCloud, for users that also need a file's faces (the world
// model's mesh reader).

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "libs/geometry/point_cloud.h"

namespace picking::geometry {

/// What ReadPlyFile reads besides the vertex positions, normals and colours.
struct PlyReadOptions {
  /// The scalar vertex property read into PointCloud::intensities (e.g. "albedo" for meshes).
  std::string scalar_property = "intensity";
  /// Read the "face" element's vertex_indices (or vertex_index) lists into `triangles`.
  bool faces = false;
};

/// A PLY file's vertex element as a cloud and, when asked for, its faces.
struct PlyFile {
  PointCloud cloud;
  /// Faces fanned into triangles (polygon 0 1 2 3 gives 0 1 2 and 0 2 3), indices into
  /// cloud.points.
  std::vector<std::array<std::uint32_t, 3>> triangles;
};

/// Reads a PLY file as ReadPointCloud documents it (every encoding and property type, skipped
/// elements and properties, frame_id and organisation comments), with `options`. Throws
/// PointCloudIoError as ReadPointCloud does, and for a face with a vertex index out of range.
PlyFile ReadPlyFile(const std::string& path, const PlyReadOptions& options = {});

}  // namespace picking::geometry
