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

// The whole file, or "cannot open".
std::vector<char> ReadFileBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) Fail(path, "cannot open");
  std::vector<char> data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  return data;
}

// Parses the header (within the first 64 KiB): the elements with their properties, in file
// order; *body_offset is set to the first byte after "end_header\n". Throws for a file that
// is not PLY, not binary little-endian, lacks end_header or has a malformed line.
std::vector<Element> ParseHeader(const std::string& path, const std::vector<char>& data,
                                 std::size_t* body_offset) {
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
  *body_offset = end + std::strlen("end_header\n");
  return elements;
}

// The binary body of a PLY file and the read position in it (bytes from the file start).
struct PlyBody {
  const std::string& path;
  const std::vector<char>& data;
  std::size_t offset = 0;

  // Throws "truncated in <what>" unless n more bytes follow the read position.
  void Need(std::size_t n, const std::string& what) const {
    if (offset + n > data.size()) Fail(path, "truncated in " + what);
  }
};

// Byte layout of one vertex record: offset of each property, record size, and which
// property holds each field the mesh keeps (-1 if none).
struct VertexLayout {
  std::vector<std::size_t> offs;
  std::size_t stride = 0;
  int ix = -1, iy = -1, iz = -1, ir = -1, ig = -1, ib = -1, ia = -1;
};

// Lays out the vertex element's records; throws for a list property or missing x, y or z.
VertexLayout LayOutVertex(const std::string& path, const Element& e) {
  VertexLayout layout;
  for (std::size_t k = 0; k < e.properties.size(); ++k) {
    const Property& p = e.properties[k];
    if (p.is_list) Fail(path, "list property in vertex element");
    layout.offs.push_back(layout.stride);
    layout.stride += TypeSize(path, p.type);
    const int ki = static_cast<int>(k);
    if (p.name == "x") layout.ix = ki;
    if (p.name == "y") layout.iy = ki;
    if (p.name == "z") layout.iz = ki;
    if (p.name == "red") layout.ir = ki;
    if (p.name == "green") layout.ig = ki;
    if (p.name == "blue") layout.ib = ki;
    if (p.name == "albedo") layout.ia = ki;
  }
  if (layout.ix < 0 || layout.iy < 0 || layout.iz < 0) {
    Fail(path, "vertex element lacks x, y or z");
  }
  return layout;
}

// Reads the vertex element at the read position into the mesh's vertices (and colours when
// red, green and blue are all present, albedo when present) and moves past it.
void ReadVertexElement(const Element& e, PlyBody* body, TriangleMesh* mesh) {
  const VertexLayout layout = LayOutVertex(body->path, e);
  const std::vector<std::size_t>& offs = layout.offs;
  const std::size_t stride = layout.stride;
  body->Need(stride * e.count, "vertex data");
  const bool rgb = layout.ir >= 0 && layout.ig >= 0 && layout.ib >= 0;
  mesh->vertices.reserve(e.count);
  for (std::size_t i = 0; i < e.count; ++i) {
    const char* rec = body->data.data() + body->offset + i * stride;
    const auto get = [&](int k) { return ReadScalar(rec + offs[k], e.properties[k].type); };
    mesh->vertices.emplace_back(get(layout.ix), get(layout.iy), get(layout.iz));
    if (rgb) {
      mesh->vertex_colors.push_back({static_cast<std::uint8_t>(get(layout.ir)),
                                     static_cast<std::uint8_t>(get(layout.ig)),
                                     static_cast<std::uint8_t>(get(layout.ib))});
    }
    if (layout.ia >= 0) mesh->vertex_albedo.push_back(static_cast<float>(get(layout.ia)));
  }
  body->offset += stride * e.count;
}

// Reads a non-vertex element at the read position and moves past it: a "face" element's
// vertex_indices (or vertex_index) lists are fanned into the mesh's triangles, every other
// property is skipped.
void ReadFaceOrSkippedElement(const Element& e, PlyBody* body, TriangleMesh* mesh) {
  const std::string& path = body->path;
  const std::vector<char>& data = body->data;
  std::size_t& offset = body->offset;
  for (std::size_t i = 0; i < e.count; ++i) {
    std::vector<std::uint32_t> indices;
    for (const Property& p : e.properties) {
      if (p.is_list) {
        const std::size_t cs = TypeSize(path, p.count_type);
        body->Need(cs, e.name + " list count");
        const auto n = static_cast<std::size_t>(ReadScalar(data.data() + offset, p.count_type));
        offset += cs;
        const std::size_t is = TypeSize(path, p.type);
        body->Need(n * is, e.name + " list");
        if (e.name == "face" && (p.name == "vertex_indices" || p.name == "vertex_index")) {
          for (std::size_t k = 0; k < n; ++k) {
            indices.push_back(
                static_cast<std::uint32_t>(ReadScalar(data.data() + offset + k * is, p.type)));
          }
        }
        offset += n * is;
      } else {
        const std::size_t s = TypeSize(path, p.type);
        body->Need(s, e.name);
        offset += s;
      }
    }
    for (std::size_t k = 1; k + 1 < indices.size(); ++k) {
      mesh->triangles.push_back({indices[0], indices[k], indices[k + 1]});
    }
  }
}

// Throws for the first triangle with a vertex index beyond the vertices read.
void CheckTriangleIndices(const std::string& path, const TriangleMesh& mesh) {
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    for (int k = 0; k < 3; ++k) {
      if (mesh.triangles[t][k] >= mesh.vertices.size()) {
        Fail(path, "face " + std::to_string(t) + " has vertex index " +
                       std::to_string(mesh.triangles[t][k]) + " out of range");
      }
    }
  }
}

}  // namespace

TriangleMesh ReadPly(const std::string& path) {
  const std::vector<char> data = ReadFileBytes(path);
  std::size_t body_offset = 0;
  const std::vector<Element> elements = ParseHeader(path, data, &body_offset);
  TriangleMesh mesh;
  mesh.name = std::filesystem::path(path).stem().string();
  PlyBody body{path, data, body_offset};
  for (const Element& e : elements) {
    if (e.name == "vertex") {
      ReadVertexElement(e, &body, &mesh);
    } else {
      ReadFaceOrSkippedElement(e, &body, &mesh);
    }
  }
  CheckTriangleIndices(path, mesh);
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
