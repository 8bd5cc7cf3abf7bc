#include "libs/world/stl_io.h"

#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <vector>

#include "libs/world/mesh_utils.h"

namespace picking::world {
namespace {

[[noreturn]] void Fail(const std::string& path, const std::string& what) {
  throw std::runtime_error("STL '" + path + "': " + what);
}

TriangleMesh ReadBinary(const std::string& path, const std::vector<char>& data) {
  std::uint32_t count = 0;
  std::memcpy(&count, data.data() + 80, 4);
  const std::size_t expected = 84 + 50ull * count;
  if (data.size() < expected) {
    Fail(path, "truncated binary file: header declares " + std::to_string(count) + " triangles (" +
                   std::to_string(expected) + " bytes) but the file has " +
                   std::to_string(data.size()) + " bytes");
  }
  TriangleMesh mesh;
  mesh.vertices.reserve(3ull * count);
  mesh.triangles.reserve(count);
  for (std::uint32_t t = 0; t < count; ++t) {
    const char* rec = data.data() + 84 + 50ull * t;
    float xyz[9];
    std::memcpy(xyz, rec + 12, sizeof(xyz));
    const auto base = static_cast<std::uint32_t>(mesh.vertices.size());
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector3f v(xyz[3 * k], xyz[3 * k + 1], xyz[3 * k + 2]);
      if (!v.allFinite()) Fail(path, "triangle " + std::to_string(t) + " has a non-finite vertex");
      mesh.vertices.push_back(v);
    }
    mesh.triangles.push_back({base, base + 1, base + 2});
  }
  return mesh;
}

TriangleMesh ReadAscii(const std::string& path, const std::string& text) {
  std::istringstream in(text);
  std::string line;
  TriangleMesh mesh;
  int line_no = 0;
  int in_facet = 0;  // vertices seen in the current facet
  bool facet_open = false;
  bool solid_closed = false;
  while (std::getline(in, line)) {
    ++line_no;
    std::istringstream ls(line);
    std::string word;
    if (!(ls >> word)) continue;
    const std::string where = "line " + std::to_string(line_no);
    if (word == "solid" || word == "outer" || word == "endloop") continue;
    if (word == "facet") {
      if (facet_open) Fail(path, where + ": 'facet' inside an open facet");
      facet_open = true;
      in_facet = 0;
    } else if (word == "vertex") {
      if (!facet_open) Fail(path, where + ": 'vertex' outside a facet");
      double x, y, z;
      if (!(ls >> x >> y >> z)) Fail(path, where + ": expected three numbers after 'vertex'");
      if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) {
        Fail(path, where + ": non-finite vertex");
      }
      if (++in_facet > 3) Fail(path, where + ": facet with more than 3 vertices");
      mesh.vertices.emplace_back(static_cast<float>(x), static_cast<float>(y),
                                 static_cast<float>(z));
    } else if (word == "endfacet") {
      if (!facet_open || in_facet != 3) {
        Fail(path, where + ": facet ended with " + std::to_string(in_facet) + " vertices");
      }
      const auto base = static_cast<std::uint32_t>(mesh.vertices.size() - 3);
      mesh.triangles.push_back({base, base + 1, base + 2});
      facet_open = false;
    } else if (word == "endsolid") {
      solid_closed = true;
      break;
    } else {
      Fail(path, where + ": unexpected keyword '" + word + "'");
    }
  }
  if (facet_open || !solid_closed) Fail(path, "truncated ASCII file: no 'endsolid'");
  return mesh;
}

}  // namespace

TriangleMesh ReadStl(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) Fail(path, "cannot open");
  std::vector<char> data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  TriangleMesh mesh;
  bool binary = false;
  if (data.size() >= 84) {
    std::uint32_t count = 0;
    std::memcpy(&count, data.data() + 80, 4);
    binary = data.size() == 84 + 50ull * count;
  }
  const bool starts_solid = data.size() >= 5 && std::strncmp(data.data(), "solid", 5) == 0;
  if (binary) {
    mesh = ReadBinary(path, data);
  } else if (starts_solid) {
    mesh = ReadAscii(path, std::string(data.begin(), data.end()));
  } else if (data.size() < 84) {
    Fail(path, "truncated: " + std::to_string(data.size()) + " bytes, a binary STL needs 84");
  } else {
    mesh = ReadBinary(path, data);  // size mismatch: reports truncation or accepts trailing data
  }
  mesh.name = std::filesystem::path(path).stem().string();
  return mesh;
}

std::string EncodeStlBinary(const TriangleMesh& mesh) {
  Validate(mesh);
  std::string out(84 + 50 * mesh.triangles.size(), '\0');
  std::snprintf(out.data(), 80, "binary STL %s", mesh.name.c_str());
  out[79] = '\0';  // the header is 80 bytes, not a terminated string
  const auto count = static_cast<std::uint32_t>(mesh.triangles.size());
  std::memcpy(out.data() + 80, &count, 4);
  char* record = out.data() + 84;
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t, record += 50) {
    float rec[12];
    const Eigen::Vector3f n = FaceNormal(mesh, t);
    for (int k = 0; k < 3; ++k) rec[k] = n[k];
    for (int v = 0; v < 3; ++v) {
      for (int k = 0; k < 3; ++k) rec[3 + 3 * v + k] = mesh.vertices[mesh.triangles[t][v]][k];
    }
    std::memcpy(record, rec, sizeof(rec));  // the 2 attribute bytes stay 0
  }
  return out;
}

void WriteStlBinary(const std::string& path, const TriangleMesh& mesh) {
  const std::string bytes = EncodeStlBinary(mesh);
  std::ofstream out(path, std::ios::binary);
  if (!out) throw std::runtime_error("STL '" + path + "': cannot open for writing");
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (!out) throw std::runtime_error("STL '" + path + "': write failed");
}

}  // namespace picking::world
