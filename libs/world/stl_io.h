#pragma once

#include <string>

#include "libs/world/mesh.h"

namespace picking::world {

/// Reads an STL file, binary or ASCII (detected from the content, not from the first word:
/// binary files whose header starts with "solid" are read as binary when the size matches).
/// Vertices are kept as written (no welding; three per triangle), in the file's units, which
/// the project's meshes use as metres. `name` of the result is the file stem.
/// Throws std::runtime_error naming the file and the position for a missing, truncated or
/// malformed file and for non-finite coordinates.
TriangleMesh ReadStl(const std::string& path);

/// Writes `mesh` as binary STL (normals from the triangle winding). Albedo and colours are
/// not stored. Throws std::runtime_error if the file cannot be written.
void WriteStlBinary(const std::string& path, const TriangleMesh& mesh);

/// The binary STL file of `mesh` as bytes (what WriteStlBinary writes), e.g. to serve it.
std::string EncodeStlBinary(const TriangleMesh& mesh);

}  // namespace picking::world
