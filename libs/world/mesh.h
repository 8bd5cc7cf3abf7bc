#pragma once

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace picking::world {

/// A triangle mesh in its own object frame (metres), as the simulator, the renderer and the
/// planner's collision world share it.
///
/// `triangles` index into `vertices`, counter-clockwise seen from outside (the face normal
/// points out of the object). `vertex_albedo` is either empty (use `albedo` for the whole
/// mesh) or one reflectance in [0, 1] per vertex, interpolated across each triangle — the
/// monochrome scanner camera sees grey levels, so texture is carried as albedo.
/// `vertex_colors` optionally carries RGB for colour views (empty or one per vertex).
struct TriangleMesh {
  std::vector<Eigen::Vector3f> vertices;
  std::vector<std::array<std::uint32_t, 3>> triangles;
  std::vector<float> vertex_albedo;
  std::vector<std::array<std::uint8_t, 3>> vertex_colors;
  float albedo = 0.6f;
  std::string name;

  std::size_t num_triangles() const { return triangles.size(); }
  bool empty() const { return triangles.empty(); }
};

}  // namespace picking::world
