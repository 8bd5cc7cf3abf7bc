#include "libs/world/ply_mesh_io.h"

#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <utility>

#include "libs/geometry/ply_io.h"
#include "libs/world/mesh_utils.h"

namespace picking::world {

TriangleMesh ReadPly(const std::string& path) {
  geometry::PlyReadOptions options;
  options.scalar_property = "albedo";
  options.faces = true;
  geometry::PlyFile ply = geometry::ReadPlyFile(path, options);
  TriangleMesh mesh;
  mesh.vertices = std::move(ply.cloud.points);
  mesh.triangles = std::move(ply.triangles);
  mesh.vertex_albedo = std::move(ply.cloud.intensities);
  mesh.vertex_colors = std::move(ply.cloud.colors);
  mesh.name = std::filesystem::path(path).stem().string();
  return mesh;
}

void WritePly(const std::string& path, const TriangleMesh& mesh, const std::string& comment) {
  Validate(mesh);
  std::ofstream out(path, std::ios::binary);
  if (!out) throw std::runtime_error("PLY '" + path + "': cannot open for writing");
  const bool rgb = !mesh.vertex_colors.empty();
  const bool albedo = !mesh.vertex_albedo.empty();
  out << "ply\nformat binary_little_endian 1.0\n";
  if (!comment.empty()) out << "comment " << comment << "\n";
  out << "element vertex " << mesh.vertices.size() << "\n"
      << "property float x\nproperty float y\nproperty float z\n";
  if (rgb) out << "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  if (albedo) out << "property float albedo\n";
  out << "element face " << mesh.triangles.size() << "\n"
      << "property list uchar int vertex_indices\nend_header\n";
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    out.write(reinterpret_cast<const char*>(mesh.vertices[i].data()), 12);
    if (rgb) out.write(reinterpret_cast<const char*>(mesh.vertex_colors[i].data()), 3);
    if (albedo) out.write(reinterpret_cast<const char*>(&mesh.vertex_albedo[i]), 4);
  }
  for (const auto& t : mesh.triangles) {
    const std::uint8_t n = 3;
    out.write(reinterpret_cast<const char*>(&n), 1);
    const std::int32_t idx[3] = {static_cast<std::int32_t>(t[0]), static_cast<std::int32_t>(t[1]),
                                 static_cast<std::int32_t>(t[2])};
    out.write(reinterpret_cast<const char*>(idx), 12);
  }
  if (!out) throw std::runtime_error("PLY '" + path + "': write failed");
}

}  // namespace picking::world
