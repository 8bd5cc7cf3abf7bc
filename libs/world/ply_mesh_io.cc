#include "libs/world/ply_mesh_io.h"

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
  throw std::runtime_error("PLY '" + path + "': " + what);
}

std::size_t TypeSize(const std::string& path, const std::string& type) {
  if (type == "char" || type == "uchar" || type == "int8" || type == "uint8") return 1;
  if (type == "short" || type == "ushort" || type == "int16" || type == "uint16") return 2;
  if (type == "int" || type == "uint" || type == "float" || type == "int32" || type == "uint32" ||
      type == "float32") {
    return 4;
  }
  if (type == "double" || type == "float64") return 8;
  Fail(path, "unknown property type '" + type + "'");
}

double ReadScalar(const char* p, const std::string& type) {
  if (type == "float" || type == "float32") {
    float v;
    std::memcpy(&v, p, 4);
    return v;
  }
  if (type == "double" || type == "float64") {
    double v;
    std::memcpy(&v, p, 8);
    return v;
  }
  if (type == "uchar" || type == "uint8") return static_cast<unsigned char>(*p);
  if (type == "char" || type == "int8") return static_cast<signed char>(*p);
  if (type == "short" || type == "int16") {
    std::int16_t v;
    std::memcpy(&v, p, 2);
    return v;
  }
  if (type == "ushort" || type == "uint16") {
    std::uint16_t v;
    std::memcpy(&v, p, 2);
    return v;
  }
  if (type == "int" || type == "int32") {
    std::int32_t v;
    std::memcpy(&v, p, 4);
    return v;
  }
  std::uint32_t v;
  std::memcpy(&v, p, 4);
  return v;
}

struct Property {
  std::string name, type;
  bool is_list = false;
  std::string count_type;
};

struct Element {
  std::string name;
  std::size_t count = 0;
  std::vector<Property> properties;
};

}  // namespace

TriangleMesh ReadPly(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) Fail(path, "cannot open");
  std::vector<char> data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string head(data.data(), std::min<std::size_t>(data.size(), 65536));
  const auto end = head.find("end_header\n");
  if (head.rfind("ply", 0) != 0) Fail(path, "not a PLY file");
  if (end == std::string::npos) Fail(path, "no end_header");
  std::istringstream hs(head.substr(0, end));
  std::string line;
  std::vector<Element> elements;
  int line_no = 0;
  while (std::getline(hs, line)) {
    ++line_no;
    std::istringstream ls(line);
    std::string word;
    ls >> word;
    if (word == "format") {
      std::string format;
      ls >> format;
      if (format != "binary_little_endian") {
        Fail(path, "format '" + format + "' not supported (binary_little_endian only)");
      }
    } else if (word == "element") {
      Element e;
      ls >> e.name >> e.count;
      if (!ls) Fail(path, "header line " + std::to_string(line_no) + ": bad element");
      elements.push_back(e);
    } else if (word == "property") {
      if (elements.empty()) Fail(path, "property before element");
      Property p;
      ls >> p.type;
      if (p.type == "list") {
        p.is_list = true;
        ls >> p.count_type >> p.type;
      }
      ls >> p.name;
      if (!ls) Fail(path, "header line " + std::to_string(line_no) + ": bad property");
      TypeSize(path, p.type);
      elements.back().properties.push_back(p);
    }
  }
  TriangleMesh mesh;
  mesh.name = std::filesystem::path(path).stem().string();
  std::size_t offset = end + std::strlen("end_header\n");
  const auto need = [&](std::size_t n, const std::string& what) {
    if (offset + n > data.size()) Fail(path, "truncated in " + what);
  };
  for (const Element& e : elements) {
    if (e.name == "vertex") {
      int ix = -1, iy = -1, iz = -1, ir = -1, ig = -1, ib = -1, ia = -1;
      std::vector<std::size_t> offs;
      std::size_t stride = 0;
      for (std::size_t k = 0; k < e.properties.size(); ++k) {
        const Property& p = e.properties[k];
        if (p.is_list) Fail(path, "list property in vertex element");
        offs.push_back(stride);
        stride += TypeSize(path, p.type);
        const int ki = static_cast<int>(k);
        if (p.name == "x") ix = ki;
        if (p.name == "y") iy = ki;
        if (p.name == "z") iz = ki;
        if (p.name == "red") ir = ki;
        if (p.name == "green") ig = ki;
        if (p.name == "blue") ib = ki;
        if (p.name == "albedo") ia = ki;
      }
      if (ix < 0 || iy < 0 || iz < 0) Fail(path, "vertex element lacks x, y or z");
      need(stride * e.count, "vertex data");
      const bool rgb = ir >= 0 && ig >= 0 && ib >= 0;
      mesh.vertices.reserve(e.count);
      for (std::size_t i = 0; i < e.count; ++i) {
        const char* rec = data.data() + offset + i * stride;
        const auto get = [&](int k) { return ReadScalar(rec + offs[k], e.properties[k].type); };
        mesh.vertices.emplace_back(get(ix), get(iy), get(iz));
        if (rgb) {
          mesh.vertex_colors.push_back({static_cast<std::uint8_t>(get(ir)),
                                        static_cast<std::uint8_t>(get(ig)),
                                        static_cast<std::uint8_t>(get(ib))});
        }
        if (ia >= 0) mesh.vertex_albedo.push_back(static_cast<float>(get(ia)));
      }
      offset += stride * e.count;
    } else {
      for (std::size_t i = 0; i < e.count; ++i) {
        std::vector<std::uint32_t> indices;
        for (const Property& p : e.properties) {
          if (p.is_list) {
            const std::size_t cs = TypeSize(path, p.count_type);
            need(cs, e.name + " list count");
            const auto n = static_cast<std::size_t>(ReadScalar(data.data() + offset, p.count_type));
            offset += cs;
            const std::size_t is = TypeSize(path, p.type);
            need(n * is, e.name + " list");
            if (e.name == "face" && (p.name == "vertex_indices" || p.name == "vertex_index")) {
              for (std::size_t k = 0; k < n; ++k) {
                indices.push_back(
                    static_cast<std::uint32_t>(ReadScalar(data.data() + offset + k * is, p.type)));
              }
            }
            offset += n * is;
          } else {
            const std::size_t s = TypeSize(path, p.type);
            need(s, e.name);
            offset += s;
          }
        }
        for (std::size_t k = 1; k + 1 < indices.size(); ++k) {
          mesh.triangles.push_back({indices[0], indices[k], indices[k + 1]});
        }
      }
    }
  }
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    for (int k = 0; k < 3; ++k) {
      if (mesh.triangles[t][k] >= mesh.vertices.size()) {
        Fail(path, "face " + std::to_string(t) + " has vertex index " +
                       std::to_string(mesh.triangles[t][k]) + " out of range");
      }
    }
  }
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
