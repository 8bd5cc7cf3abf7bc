#include "libs/world/mesh_utils.h"

#include <cmath>
#include <stdexcept>
#include <string>

namespace picking::world {

TriangleMesh Transformed(const TriangleMesh& mesh, const Eigen::Isometry3d& X_NewOld) {
  TriangleMesh out = mesh;
  const Eigen::Isometry3f X = X_NewOld.cast<float>();
  for (auto& v : out.vertices) v = X * v;
  return out;
}

Eigen::AlignedBox3d Bounds(const TriangleMesh& mesh) {
  Eigen::AlignedBox3d box;
  for (const auto& v : mesh.vertices) box.extend(v.cast<double>());
  return box;
}

Eigen::AlignedBox3d Bounds(const TriangleMesh& mesh, const Eigen::Isometry3d& X_NewOld) {
  Eigen::AlignedBox3d box;
  for (const auto& v : mesh.vertices) box.extend(X_NewOld * v.cast<double>());
  return box;
}

TriangleMesh Merge(const std::vector<TriangleMesh>& parts) {
  TriangleMesh out;
  bool any_albedo = false;
  bool any_colors = false;
  for (const auto& p : parts) {
    any_albedo |= !p.vertex_albedo.empty();
    any_colors |= !p.vertex_colors.empty();
  }
  for (const auto& p : parts) {
    const auto base = static_cast<std::uint32_t>(out.vertices.size());
    out.vertices.insert(out.vertices.end(), p.vertices.begin(), p.vertices.end());
    for (const auto& t : p.triangles)
      out.triangles.push_back({t[0] + base, t[1] + base, t[2] + base});
    if (any_albedo) {
      if (p.vertex_albedo.empty()) {
        out.vertex_albedo.insert(out.vertex_albedo.end(), p.vertices.size(), p.albedo);
      } else {
        out.vertex_albedo.insert(out.vertex_albedo.end(), p.vertex_albedo.begin(),
                                 p.vertex_albedo.end());
      }
    }
    if (any_colors) {
      if (p.vertex_colors.empty()) {
        const auto g = static_cast<std::uint8_t>(std::lround(255.0f * p.albedo));
        out.vertex_colors.insert(out.vertex_colors.end(), p.vertices.size(), {g, g, g});
      } else {
        out.vertex_colors.insert(out.vertex_colors.end(), p.vertex_colors.begin(),
                                 p.vertex_colors.end());
      }
    }
  }
  if (!parts.empty()) out.albedo = parts.front().albedo;
  return out;
}

Eigen::Vector3f FaceNormal(const TriangleMesh& mesh, std::size_t t) {
  const auto& tri = mesh.triangles[t];
  const Eigen::Vector3f& a = mesh.vertices[tri[0]];
  const Eigen::Vector3f& b = mesh.vertices[tri[1]];
  const Eigen::Vector3f& c = mesh.vertices[tri[2]];
  const Eigen::Vector3f n = (b - a).cross(c - a);
  const float len = n.norm();
  return len > 0.0f ? Eigen::Vector3f(n / len) : Eigen::Vector3f::Zero();
}

double SurfaceArea(const TriangleMesh& mesh) {
  double area = 0.0;
  for (const auto& tri : mesh.triangles) {
    const Eigen::Vector3d a = mesh.vertices[tri[0]].cast<double>();
    const Eigen::Vector3d b = mesh.vertices[tri[1]].cast<double>();
    const Eigen::Vector3d c = mesh.vertices[tri[2]].cast<double>();
    area += 0.5 * (b - a).cross(c - a).norm();
  }
  return area;
}

double SignedVolume(const TriangleMesh& mesh) {
  double volume = 0.0;
  for (const auto& tri : mesh.triangles) {
    const Eigen::Vector3d a = mesh.vertices[tri[0]].cast<double>();
    const Eigen::Vector3d b = mesh.vertices[tri[1]].cast<double>();
    const Eigen::Vector3d c = mesh.vertices[tri[2]].cast<double>();
    volume += a.dot(b.cross(c)) / 6.0;
  }
  return volume;
}

void Validate(const TriangleMesh& mesh) {
  const std::string who = "mesh '" + mesh.name + "'";
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    for (int k = 0; k < 3; ++k) {
      if (mesh.triangles[t][k] >= mesh.vertices.size()) {
        throw std::invalid_argument(who + ": triangle " + std::to_string(t) + " index " +
                                    std::to_string(mesh.triangles[t][k]) +
                                    " >= " + std::to_string(mesh.vertices.size()) + " vertices");
      }
    }
  }
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    if (!mesh.vertices[i].allFinite()) {
      throw std::invalid_argument(who + ": vertex " + std::to_string(i) + " is not finite");
    }
  }
  if (!mesh.vertex_albedo.empty() && mesh.vertex_albedo.size() != mesh.vertices.size()) {
    throw std::invalid_argument(who + ": vertex_albedo has " +
                                std::to_string(mesh.vertex_albedo.size()) + " entries for " +
                                std::to_string(mesh.vertices.size()) + " vertices");
  }
  if (!mesh.vertex_colors.empty() && mesh.vertex_colors.size() != mesh.vertices.size()) {
    throw std::invalid_argument(who + ": vertex_colors has " +
                                std::to_string(mesh.vertex_colors.size()) + " entries for " +
                                std::to_string(mesh.vertices.size()) + " vertices");
  }
}

namespace {

void RequirePositive(double value, const char* what) {
  if (!std::isfinite(value) || value <= 0.0) {
    throw std::invalid_argument(std::string(what) + " must be positive and finite, got " +
                                std::to_string(value));
  }
}

}  // namespace

TriangleMesh MakeBox(const Eigen::Vector3d& size) {
  RequirePositive(size.x(), "box size x");
  RequirePositive(size.y(), "box size y");
  RequirePositive(size.z(), "box size z");
  const Eigen::Vector3f h = (0.5 * size).cast<float>();
  TriangleMesh mesh;
  mesh.name = "box";
  // One face per (axis, sign): the four corners in CCW order seen from outside.
  for (int axis = 0; axis < 3; ++axis) {
    for (int sign : {+1, -1}) {
      const int u = (axis + 1) % 3;
      const int v = (axis + 2) % 3;
      const auto base = static_cast<std::uint32_t>(mesh.vertices.size());
      const float su[4] = {-1, 1, 1, -1};
      const float sv[4] = {-1, -1, 1, 1};
      for (int k = 0; k < 4; ++k) {
        Eigen::Vector3f p;
        p[axis] = sign * h[axis];
        // (u, v, axis) is right-handed, so CCW in (u, v) faces +axis; mirror u for -axis.
        p[u] = (sign > 0 ? su[k] : -su[k]) * h[u];
        p[v] = sv[k] * h[v];
        mesh.vertices.push_back(p);
      }
      mesh.triangles.push_back({base, base + 1, base + 2});
      mesh.triangles.push_back({base, base + 2, base + 3});
    }
  }
  return mesh;
}

TriangleMesh MakeCylinder(double radius, double height, int segments) {
  RequirePositive(radius, "cylinder radius");
  RequirePositive(height, "cylinder height");
  if (segments < 3) throw std::invalid_argument("cylinder needs at least 3 segments");
  TriangleMesh mesh;
  mesh.name = "cylinder";
  const float r = static_cast<float>(radius);
  const float hz = static_cast<float>(0.5 * height);
  const auto n = static_cast<std::uint32_t>(segments);
  // Side: separate vertex rings so caps and side do not share (sharp edges, own texture).
  for (std::uint32_t i = 0; i <= n; ++i) {
    const double a = 2.0 * M_PI * i / n;
    const float c = static_cast<float>(std::cos(a)) * r;
    const float s = static_cast<float>(std::sin(a)) * r;
    mesh.vertices.emplace_back(c, s, -hz);
    mesh.vertices.emplace_back(c, s, hz);
  }
  for (std::uint32_t i = 0; i < n; ++i) {
    const std::uint32_t b0 = 2 * i, t0 = 2 * i + 1, b1 = 2 * i + 2, t1 = 2 * i + 3;
    mesh.triangles.push_back({b0, b1, t1});
    mesh.triangles.push_back({b0, t1, t0});
  }
  for (int sign : {+1, -1}) {
    const auto centre = static_cast<std::uint32_t>(mesh.vertices.size());
    mesh.vertices.emplace_back(0.0f, 0.0f, sign * hz);
    for (std::uint32_t i = 0; i < n; ++i) {
      const double a = 2.0 * M_PI * i / n;
      mesh.vertices.emplace_back(static_cast<float>(std::cos(a)) * r,
                                 static_cast<float>(std::sin(a)) * r, sign * hz);
    }
    for (std::uint32_t i = 0; i < n; ++i) {
      const std::uint32_t a = centre + 1 + i;
      const std::uint32_t b = centre + 1 + (i + 1) % n;
      if (sign > 0) {
        mesh.triangles.push_back({centre, a, b});
      } else {
        mesh.triangles.push_back({centre, b, a});
      }
    }
  }
  return mesh;
}

TriangleMesh MakeSphere(double radius, int rings, int segments) {
  RequirePositive(radius, "sphere radius");
  if (rings < 2) throw std::invalid_argument("sphere needs at least 2 rings");
  if (segments < 3) throw std::invalid_argument("sphere needs at least 3 segments");
  TriangleMesh mesh;
  mesh.name = "sphere";
  const auto n = static_cast<std::uint32_t>(segments);
  const auto m = static_cast<std::uint32_t>(rings);
  // Vertex (ring j, segment i) for j in [0, m], i in [0, n]: j = 0 is the south pole.
  for (std::uint32_t j = 0; j <= m; ++j) {
    const double theta = M_PI * j / m - M_PI / 2;
    for (std::uint32_t i = 0; i <= n; ++i) {
      const double phi = 2.0 * M_PI * i / n;
      mesh.vertices.emplace_back(static_cast<float>(radius * std::cos(theta) * std::cos(phi)),
                                 static_cast<float>(radius * std::cos(theta) * std::sin(phi)),
                                 static_cast<float>(radius * std::sin(theta)));
    }
  }
  const auto idx = [n](std::uint32_t j, std::uint32_t i) { return j * (n + 1) + i; };
  for (std::uint32_t j = 0; j < m; ++j) {
    for (std::uint32_t i = 0; i < n; ++i) {
      const std::uint32_t a = idx(j, i), b = idx(j, i + 1), c = idx(j + 1, i + 1),
                          d = idx(j + 1, i);
      if (j != 0) mesh.triangles.push_back({a, b, c});
      if (j != m - 1) mesh.triangles.push_back({a, c, d});
    }
  }
  return mesh;
}

}  // namespace picking::world
