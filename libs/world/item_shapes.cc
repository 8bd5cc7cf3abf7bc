#include "libs/world/item_shapes.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <filesystem>
#include <random>

#include "libs/world/mesh_utils.h"

namespace picking::world {
namespace {

[[noreturn]] void Fail(const std::string& source, const std::string& field,
                       const std::string& what) {
  throw ShapeTableError("shape table '" + source + "', field '" + field + "': " + what);
}

// Rectangles of the kBlocks texture on one face, in normalised face coordinates [0, 1]^2.
struct Block {
  double u0, v0, u1, v1;
};

class Painter {
 public:
  Painter(const ItemShape& shape, int seed) : shape_(shape), rng_(static_cast<unsigned>(seed)) {}

  // Starts a new face of size (lu, lv) metres.
  void NewFace(double lu, double lv) {
    lu_ = lu;
    lv_ = lv;
    blocks_.clear();
    std::uniform_real_distribution<double> pos(0.08, 0.75), len(0.1, 0.35);
    const int n = std::uniform_int_distribution<int>(2, 5)(rng_);
    for (int i = 0; i < n; ++i) {
      const double u0 = pos(rng_), v0 = pos(rng_);
      blocks_.push_back({u0, v0, std::min(0.95, u0 + len(rng_)), std::min(0.95, v0 + len(rng_))});
    }
  }

  // Albedo at face position (u, v) metres from the face corner.
  float At(double u, double v) const {
    const double p = shape_.pattern_period_m;
    switch (shape_.texture) {
      case TextureKind::kUniform:
        return shape_.albedo;
      case TextureKind::kStripes:
        return (static_cast<long>(std::floor(u / p)) % 2 == 0) ? shape_.albedo
                                                               : shape_.pattern_albedo;
      case TextureKind::kChecker:
        return ((static_cast<long>(std::floor(u / p)) + static_cast<long>(std::floor(v / p))) % 2 ==
                0)
                   ? shape_.albedo
                   : shape_.pattern_albedo;
      case TextureKind::kBlocks: {
        const double nu = lu_ > 0 ? u / lu_ : 0.0;
        const double nv = lv_ > 0 ? v / lv_ : 0.0;
        const double border = 0.04;
        if (nu < border || nu > 1 - border || nv < border || nv > 1 - border) {
          return shape_.pattern_albedo;
        }
        for (const Block& b : blocks_) {
          if (nu >= b.u0 && nu <= b.u1 && nv >= b.v0 && nv <= b.v1) return shape_.pattern_albedo;
        }
        return shape_.albedo;
      }
    }
    return shape_.albedo;
  }

 private:
  const ItemShape& shape_;
  std::mt19937 rng_;
  double lu_ = 0.0, lv_ = 0.0;
  std::vector<Block> blocks_;
};

int Cells(double length_m, double cell_m) {
  return std::max(1, static_cast<int>(std::ceil(length_m / cell_m - 1e-9)));
}

// Appends a quad cell with its own four vertices (CCW seen from outside) and one albedo.
void AddCell(TriangleMesh& mesh, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
             const Eigen::Vector3d& c, const Eigen::Vector3d& d, float albedo) {
  const auto base = static_cast<std::uint32_t>(mesh.vertices.size());
  for (const auto* p : {&a, &b, &c, &d}) {
    mesh.vertices.push_back(p->cast<float>());
    mesh.vertex_albedo.push_back(albedo);
  }
  mesh.triangles.push_back({base, base + 1, base + 2});
  mesh.triangles.push_back({base, base + 2, base + 3});
}

// A rectangular face: corner `o`, edges `eu` and `ev` with eu x ev pointing outward.
void AddGridFace(TriangleMesh& mesh, Painter& painter, const Eigen::Vector3d& o,
                 const Eigen::Vector3d& eu, const Eigen::Vector3d& ev, double cell_m) {
  const double lu = eu.norm(), lv = ev.norm();
  painter.NewFace(lu, lv);
  const int nu = Cells(lu, cell_m), nv = Cells(lv, cell_m);
  for (int i = 0; i < nu; ++i) {
    for (int j = 0; j < nv; ++j) {
      const Eigen::Vector3d p00 = o + eu * (double(i) / nu) + ev * (double(j) / nv);
      const Eigen::Vector3d p10 = o + eu * (double(i + 1) / nu) + ev * (double(j) / nv);
      const Eigen::Vector3d p11 = o + eu * (double(i + 1) / nu) + ev * (double(j + 1) / nv);
      const Eigen::Vector3d p01 = o + eu * (double(i) / nu) + ev * (double(j + 1) / nv);
      AddCell(mesh, p00, p10, p11, p01, painter.At((i + 0.5) * lu / nu, (j + 0.5) * lv / nv));
    }
  }
}

TextureKind ParseTexture(const std::string& source, const std::string& field,
                         const std::string& s) {
  if (s == "uniform") return TextureKind::kUniform;
  if (s == "stripes") return TextureKind::kStripes;
  if (s == "checker") return TextureKind::kChecker;
  if (s == "blocks") return TextureKind::kBlocks;
  Fail(source, field, "unknown texture '" + s + "' (uniform|stripes|checker|blocks)");
}

}  // namespace

ShapeTable ShapeTable::FromYamlFile(const std::string& path, const apc::Catalogue& catalogue) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::Exception& e) {
    throw ShapeTableError("shape table '" + path + "': " + e.what());
  }
  if (!root.IsMap()) Fail(path, "", "top level must be a mapping");
  if (!root["version"] || root["version"].as<std::string>() != "1") {
    Fail(path, "version", "must be 1");
  }
  const YAML::Node items = root["items"];
  if (!items || !items.IsMap()) Fail(path, "items", "missing or not a mapping");
  ShapeTable table;
  for (const auto& kv : items) {
    const auto name = kv.first.as<std::string>();
    const std::string field = "items." + name;
    if (!catalogue.contains(name)) Fail(path, field, "not a catalogue item");
    if (!kv.second.IsMap()) Fail(path, field, "must be a mapping");
    ItemShape shape;
    for (const auto& e : kv.second) {
      const auto key = e.first.as<std::string>();
      const std::string f = field + "." + key;
      try {
        if (key == "shape") {
          const auto s = e.second.as<std::string>();
          if (s == "box") {
            shape.kind = ShapeKind::kBox;
          } else if (s == "cylinder") {
            shape.kind = ShapeKind::kCylinder;
          } else if (s == "sphere") {
            shape.kind = ShapeKind::kSphere;
          } else if (s == "scan") {
            shape.kind = ShapeKind::kScan;
          } else {
            Fail(path, f, "unknown shape '" + s + "' (box|cylinder|sphere|scan)");
          }
        } else if (key == "axis") {
          const auto s = e.second.as<std::string>();
          if (s != "long" && s != "short") Fail(path, f, "must be long or short");
          shape.axis_along_long_side = s == "long";
        } else if (key == "fold") {
          if (!e.second.IsSequence() || e.second.size() != 2) Fail(path, f, "must be [n, n]");
          shape.fold_long = e.second[0].as<int>();
          shape.fold_middle = e.second[1].as<int>();
          if (shape.fold_long < 1 || shape.fold_middle < 1) Fail(path, f, "must be >= 1");
        } else if (key == "albedo" || key == "pattern_albedo") {
          const auto a = e.second.as<float>();
          if (!(a >= 0.0f && a <= 1.0f)) Fail(path, f, "must be in [0, 1]");
          (key == "albedo" ? shape.albedo : shape.pattern_albedo) = a;
        } else if (key == "texture") {
          shape.texture = ParseTexture(path, f, e.second.as<std::string>());
        } else if (key == "period_m") {
          shape.pattern_period_m = e.second.as<double>();
          if (!(shape.pattern_period_m > 0.0)) Fail(path, f, "must be positive");
        } else if (key == "file") {
          shape.scan_file = e.second.as<std::string>();
        } else {
          Fail(path, f, "unknown key");
        }
      } catch (const YAML::Exception& ex) {
        Fail(path, f, std::string("wrong type: ") + ex.what());
      }
    }
    if (shape.kind == ShapeKind::kScan && shape.scan_file.empty()) {
      Fail(path, field + ".file", "required for shape scan");
    }
    table.entries_[name] = shape;
  }
  return table;
}

ItemShape ShapeTable::at(const std::string& item) const {
  const auto it = entries_.find(item);
  return it == entries_.end() ? ItemShape{} : it->second;
}

std::string DefaultShapeTablePath() {
  return (std::filesystem::path(apc::DefaultDataDir()) / "items" / "shapes.yaml").string();
}

Eigen::Vector3d ModelledSize(const apc::Item& item, const ItemShape& shape) {
  Eigen::Vector3d s(item.long_side_m / shape.fold_long, item.middle_side_m / shape.fold_middle,
                    item.short_side_m * shape.fold_long * shape.fold_middle);
  std::sort(s.data(), s.data() + 3, std::greater<double>());
  return s;
}

TriangleMesh MakePrimitiveItemMesh(const apc::Item& item, const ItemShape& shape) {
  if (shape.kind == ShapeKind::kScan) {
    throw std::invalid_argument("MakePrimitiveItemMesh: '" + item.name + "' is a scanned model");
  }
  const Eigen::Vector3d size = ModelledSize(item, shape);
  if (!(size.minCoeff() > 0.0) || !size.allFinite()) {
    throw std::invalid_argument("MakePrimitiveItemMesh: '" + item.name + "' has bad dimensions");
  }
  const double cell = std::clamp(size.maxCoeff() / 30.0, 0.004, 0.01);
  Painter painter(shape, item.id);
  TriangleMesh mesh;
  mesh.name = item.name;
  mesh.albedo = shape.albedo;
  const Eigen::Vector3d h = 0.5 * size;
  if (shape.kind == ShapeKind::kBox) {
    for (int axis = 0; axis < 3; ++axis) {
      const int u = (axis + 1) % 3, v = (axis + 2) % 3;
      for (int sign : {+1, -1}) {
        Eigen::Vector3d o = Eigen::Vector3d::Zero();
        Eigen::Vector3d eu = Eigen::Vector3d::Zero(), ev = Eigen::Vector3d::Zero();
        o[axis] = sign * h[axis];
        o[v] = -h[v];
        if (sign > 0) {
          o[u] = -h[u];
          eu[u] = size[u];
        } else {
          o[u] = h[u];
          eu[u] = -size[u];
        }
        ev[v] = size[v];
        AddGridFace(mesh, painter, o, eu, ev, cell);
      }
    }
    return mesh;
  }
  if (shape.kind == ShapeKind::kSphere) {
    const double r = 0.5 * size.minCoeff();
    const int rings = 16, segments = 32;
    painter.NewFace(2 * M_PI * r, M_PI * r);
    const auto point = [r](double theta, double phi) {
      return Eigen::Vector3d(r * std::cos(theta) * std::cos(phi),
                             r * std::cos(theta) * std::sin(phi), r * std::sin(theta));
    };
    for (int j = 0; j < rings; ++j) {
      const double t0 = M_PI * j / rings - M_PI / 2, t1 = M_PI * (j + 1) / rings - M_PI / 2;
      for (int i = 0; i < segments; ++i) {
        const double p0 = 2 * M_PI * i / segments, p1 = 2 * M_PI * (i + 1) / segments;
        // Seam-like stripes run in longitude: the painter sees (longitude, latitude) arc
        // lengths.
        const float a =
            painter.At((i + 0.5) * 2 * M_PI * r / segments, (j + 0.5) * M_PI * r / rings);
        AddCell(mesh, point(t0, p0), point(t0, p1), point(t1, p1), point(t1, p0), a);
      }
    }
    return mesh;
  }
  // Cylinder along x (long side) or z (short side) of the item frame.
  const bool along_x = shape.axis_along_long_side;
  const double length = along_x ? size.x() : size.z();
  const double r = 0.5 * (along_x ? std::min(size.y(), size.z()) : std::min(size.x(), size.y()));
  // Local cylinder frame: axis z', then mapped to the item frame.
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  if (along_x) R << 0, 0, 1, 1, 0, 0, 0, 1, 0;  // z' -> x, x' -> y, y' -> z
  const auto map = [&](double x, double y, double z) {
    return Eigen::Vector3d(R * Eigen::Vector3d(x, y, z));
  };
  const int segments = std::max(24, Cells(2 * M_PI * r, cell));
  const int stacks = Cells(length, cell);
  painter.NewFace(2 * M_PI * r, length);
  const double hz = 0.5 * length;
  for (int i = 0; i < segments; ++i) {
    const double a0 = 2 * M_PI * i / segments, a1 = 2 * M_PI * (i + 1) / segments;
    for (int j = 0; j < stacks; ++j) {
      const double z0 = -hz + length * j / stacks, z1 = -hz + length * (j + 1) / stacks;
      const float alb =
          painter.At((i + 0.5) * 2 * M_PI * r / segments, (j + 0.5) * length / stacks);
      AddCell(mesh, map(r * std::cos(a0), r * std::sin(a0), z0),
              map(r * std::cos(a1), r * std::sin(a1), z0),
              map(r * std::cos(a1), r * std::sin(a1), z1),
              map(r * std::cos(a0), r * std::sin(a0), z1), alb);
    }
  }
  // Caps: fans with one albedo per sector (the pattern seen on the cap as angular sectors).
  for (int sign : {+1, -1}) {
    painter.NewFace(2 * M_PI * r, r);
    for (int i = 0; i < segments; ++i) {
      const double a0 = 2 * M_PI * i / segments, a1 = 2 * M_PI * (i + 1) / segments;
      const float alb = painter.At((i + 0.5) * 2 * M_PI * r / segments, 0.5 * r);
      const auto base = static_cast<std::uint32_t>(mesh.vertices.size());
      mesh.vertices.push_back(map(0, 0, sign * hz).cast<float>());
      mesh.vertices.push_back(map(r * std::cos(a0), r * std::sin(a0), sign * hz).cast<float>());
      mesh.vertices.push_back(map(r * std::cos(a1), r * std::sin(a1), sign * hz).cast<float>());
      mesh.vertex_albedo.insert(mesh.vertex_albedo.end(), 3, alb);
      if (sign > 0) {
        mesh.triangles.push_back({base, base + 1, base + 2});
      } else {
        mesh.triangles.push_back({base, base + 2, base + 1});
      }
    }
  }
  return mesh;
}

}  // namespace picking::world
