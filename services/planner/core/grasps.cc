#include "services/planner/core/grasps.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <set>
#include <sstream>

#include "libs/world/mesh_utils.h"

namespace picking::planner {

GraspTableError::GraspTableError(const std::string& source, const std::string& item,
                                 const std::string& field, const std::string& what)
    : std::runtime_error("grasp table '" + source + "'" +
                         (item.empty() ? std::string() : ", item '" + item + "'") +
                         (field.empty() ? std::string() : ", field '" + field + "'") + ": " + what),
      source_(source),
      item_(item),
      field_(field) {}

namespace {

constexpr double kDeg = EIGEN_PI / 180.0;

std::string Fixed(double v, int digits) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.*f", digits, v);
  return buf;
}

// ---------------------------------------------------------------------------------------------
// Reading the table.

class TableReader {
 public:
  explicit TableReader(std::string source) : source_(std::move(source)) {}

  [[noreturn]] void Fail(const std::string& item, const std::string& field, const std::string& what,
                         const YAML::Node& node = YAML::Node()) const {
    std::string where;
    if (node.IsDefined() && node.Mark().line >= 0) {
      where = " (line " + std::to_string(node.Mark().line + 1) + ")";
    }
    throw GraspTableError(source_, item, field, what + where);
  }

  void CheckKeys(const YAML::Node& node, const std::string& item, const std::string& field,
                 const std::set<std::string>& allowed) const {
    if (!node.IsMap()) Fail(item, field, "must be a mapping", node);
    for (const auto& kv : node) {
      const auto key = kv.first.as<std::string>();
      if (!allowed.count(key)) {
        Fail(item, field.empty() ? key : field + "." + key, "unknown key", kv.first);
      }
    }
  }

  double Number(const YAML::Node& parent, const std::string& key, const std::string& item,
                const std::string& field) const {
    const YAML::Node node = parent[key];
    if (!node) Fail(item, field, "missing", parent);
    double v = 0.0;
    try {
      v = node.as<double>();
    } catch (const YAML::Exception&) {
      Fail(item, field, "not a number", node);
    }
    if (!std::isfinite(v)) Fail(item, field, "not finite", node);
    return v;
  }

  Eigen::VectorXd Numbers(const YAML::Node& parent, const std::string& key, const std::string& item,
                          const std::string& field, int n) const {
    const YAML::Node node = parent[key];
    if (!node) Fail(item, field, "missing", parent);
    if (!node.IsSequence() || static_cast<int>(node.size()) != n) {
      Fail(item, field, "must be a list of " + std::to_string(n) + " numbers", node);
    }
    Eigen::VectorXd v(n);
    for (int i = 0; i < n; ++i) {
      const std::string f = field + "[" + std::to_string(i) + "]";
      try {
        v[i] = node[i].as<double>();
      } catch (const YAML::Exception&) {
        Fail(item, f, "not a number", node[i]);
      }
      if (!std::isfinite(v[i])) Fail(item, f, "not finite", node[i]);
    }
    return v;
  }

  double Quality(const YAML::Node& parent, const std::string& item,
                 const std::string& field) const {
    if (!parent["quality"]) return 1.0;
    const double q = Number(parent, "quality", item, field);
    if (!(q > 0.0 && q <= 1.0)) {
      Fail(item, field, "must be in (0, 1], is " + Fixed(q, 3), parent["quality"]);
    }
    return q;
  }

  SuctionPoint Point(const YAML::Node& node, const ItemGrasps& grasps,
                     const std::string& field) const {
    const std::string& item = grasps.item;
    CheckKeys(node, item, field, {"name", "p_ItemPoint", "approach_Item", "face_m", "quality"});
    SuctionPoint point;
    const YAML::Node name = node["name"];
    if (!name) Fail(item, field + ".name", "missing", node);
    if (!name.IsScalar() || name.as<std::string>().empty()) {
      Fail(item, field + ".name", "must be a non-empty string", name);
    }
    point.name = name.as<std::string>();
    point.p_ItemPoint = Numbers(node, "p_ItemPoint", item, field + ".p_ItemPoint", 3);
    const Eigen::Vector3d half = grasps.size_m / 2.0;
    if (((point.p_ItemPoint.cwiseAbs() - half).array() > 1e-3).any()) {
      Fail(item, field + ".p_ItemPoint",
           "outside the item box size_m (more than 1 mm beyond a face)", node["p_ItemPoint"]);
    }
    const Eigen::Vector3d a = Numbers(node, "approach_Item", item, field + ".approach_Item", 3);
    if (std::abs(a.norm() - 1.0) > 1e-3) {
      Fail(item, field + ".approach_Item",
           "must be a unit vector (norm " + Fixed(a.norm(), 4) + ")", node["approach_Item"]);
    }
    point.approach_Item = a.normalized();
    if (point.approach_Item.dot(point.p_ItemPoint) > 1e-6) {
      Fail(item, field + ".approach_Item",
           "points away from the item's centre (it must point INTO the surface)",
           node["approach_Item"]);
    }
    point.face_m = Numbers(node, "face_m", item, field + ".face_m", 2);
    if (!(point.face_m.minCoeff() > 0.0)) {
      Fail(item, field + ".face_m", "must be positive", node["face_m"]);
    }
    if (point.face_m[1] > point.face_m[0]) std::swap(point.face_m[0], point.face_m[1]);
    point.quality = Quality(node, item, field + ".quality");
    return point;
  }

  ItemGrasps Item(const std::string& name, const YAML::Node& node) const {
    CheckKeys(node, name, "", {"size_m", "quality", "points"});
    ItemGrasps grasps;
    grasps.item = name;
    grasps.size_m = Numbers(node, "size_m", name, "size_m", 3);
    if (!(grasps.size_m.minCoeff() > 0.0)) Fail(name, "size_m", "must be positive", node["size_m"]);
    grasps.quality = Quality(node, name, "quality");
    const YAML::Node points = node["points"];
    if (!points) Fail(name, "points", "missing", node);
    if (!points.IsSequence() || points.size() == 0) {
      Fail(name, "points", "must be a non-empty list of suction points", points);
    }
    for (std::size_t i = 0; i < points.size(); ++i) {
      grasps.points.push_back(Point(points[i], grasps, "points[" + std::to_string(i) + "]"));
    }
    return grasps;
  }

 private:
  std::string source_;
};

// ---------------------------------------------------------------------------------------------
// The default rule.

double CurvatureQuality(double radius_m, double cup_diameter_m) {
  const double half = cup_diameter_m / 2.0;
  if (radius_m <= half) return 0.1;
  const double sag = radius_m - std::sqrt(radius_m * radius_m - half * half);
  return std::max(0.1, 1.0 - sag / half);
}

const char* kAxisNames[3] = {"x", "y", "z"};

std::string Signed(double s, int axis) { return std::string(s > 0 ? "+" : "-") + kAxisNames[axis]; }

// ---------------------------------------------------------------------------------------------
// Checks of ComputeGrasps' inputs.

void CheckRigid(const Eigen::Isometry3d& X, const std::string& what) {
  if (!X.matrix().allFinite()) throw std::invalid_argument(what + " is not finite");
  const Eigen::Matrix3d R = X.linear();
  const double orthogonality =
      (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (orthogonality > 1e-6 || R.determinant() < 0.0) {
    throw std::invalid_argument(what + " is not rigid (its rotation part is not a rotation)");
  }
  if ((X.matrix().row(3) - Eigen::RowVector4d(0, 0, 0, 1)).cwiseAbs().maxCoeff() > 1e-12) {
    throw std::invalid_argument(what + " is not rigid (bottom row is not [0 0 0 1])");
  }
}

void CheckContainer(const GraspContainer& c) {
  const std::string what = "container '" + c.name + "'";
  CheckRigid(c.X_BaseContainer, what + " X_BaseContainer");
  if (!c.inner_size_m.allFinite() || !(c.inner_size_m.minCoeff() > 0.0)) {
    throw std::invalid_argument(what + ": inner_size_m must be positive and finite");
  }
  if (!c.opening_direction_Base.allFinite() ||
      std::abs(c.opening_direction_Base.norm() - 1.0) > 1e-6) {
    throw std::invalid_argument(what + ": opening_direction_Base must be a unit vector");
  }
}

void CheckOptions(const GraspOptions& o) {
  auto require = [](bool ok, const char* what) {
    if (!ok) throw std::invalid_argument(std::string("GraspOptions: ") + what);
  };
  require(std::isfinite(o.pregrasp_standoff_m) && o.pregrasp_standoff_m >= 0.0,
          "pregrasp_standoff_m must be >= 0");
  require(o.max_approach_angle_rad > 0.0 && o.max_approach_angle_rad <= EIGEN_PI,
          "max_approach_angle_rad must be in (0, pi]");
  require(o.max_tote_approach_angle_rad > 0.0 && o.max_tote_approach_angle_rad <= EIGEN_PI,
          "max_tote_approach_angle_rad must be in (0, pi]");
  require(o.max_tilt_rad >= 0.0 && o.max_tilt_rad <= kSealAngleToleranceRad,
          "max_tilt_rad must be in [0, kSealAngleToleranceRad]: the cup seals only on a "
          "surface within that angle of its axis");
  require(o.tilt_steps >= 0, "tilt_steps must be >= 0");
  require(std::isfinite(o.container_tolerance_m) && o.container_tolerance_m >= 0.0,
          "container_tolerance_m must be >= 0");
  require(std::isfinite(o.min_clearance_m) && o.min_clearance_m >= 0.0,
          "min_clearance_m must be >= 0");
  require(std::isfinite(o.required_clearance_m) && o.required_clearance_m > 0.0,
          "required_clearance_m must be > 0");
  require(std::isfinite(o.max_clearance_m) && o.max_clearance_m > 0.0 &&
              o.max_clearance_m >= o.min_clearance_m,
          "max_clearance_m must be > 0 and >= min_clearance_m");
  require(std::isfinite(o.edge_margin_toward_opening_m),
          "edge_margin_toward_opening_m must be finite (negative: off)");
  require(std::isfinite(o.min_shift_toward_opening_m) && o.min_shift_toward_opening_m > 0.0,
          "min_shift_toward_opening_m must be > 0");
  require(std::isfinite(o.full_face_size_m) && o.full_face_size_m > 0.0,
          "full_face_size_m must be > 0");
  require(o.vertical_roll_threshold_rad > 0.0 && o.vertical_roll_threshold_rad < EIGEN_PI / 2.0,
          "vertical_roll_threshold_rad must be in (0, pi/2)");
  for (double w : {o.face_size_weight, o.centrality_weight, o.clearance_weight, o.approach_weight,
                   o.tilt_weight}) {
    require(std::isfinite(w) && w >= 0.0, "score weights must be finite and >= 0");
  }
}

double AngleBetween(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::acos(std::clamp(a.dot(b), -1.0, 1.0));
}

// Free distance from p_Base along direction_Base inside the container box: the distance to its
// boundary, or max_m if the ray leaves through the opening face.
double GeometricClearance(const GraspContainer& c, const Eigen::Vector3d& p_Base,
                          const Eigen::Vector3d& direction_Base, double max_m) {
  const Eigen::Isometry3d X_ContainerBase = c.X_BaseContainer.inverse();
  const Eigen::Vector3d half = c.inner_size_m / 2.0;
  const Eigen::Vector3d q = (X_ContainerBase * p_Base).cwiseMax(-half).cwiseMin(half);
  const Eigen::Vector3d d = X_ContainerBase.linear() * direction_Base;
  const Eigen::Vector3d o = X_ContainerBase.linear() * c.opening_direction_Base;
  int opening_axis = 0;
  o.cwiseAbs().maxCoeff(&opening_axis);
  const bool opening_positive = o[opening_axis] > 0.0;

  double t_exit = std::numeric_limits<double>::infinity();
  int exit_axis = -1;
  bool exit_positive = false;
  for (int i = 0; i < 3; ++i) {
    if (std::abs(d[i]) < 1e-12) continue;
    const double t = ((d[i] > 0.0 ? half[i] : -half[i]) - q[i]) / d[i];
    if (t < t_exit) {
      t_exit = t;
      exit_axis = i;
      exit_positive = d[i] > 0.0;
    }
  }
  if (exit_axis == opening_axis && exit_positive == opening_positive) return max_m;
  return std::clamp(t_exit, 0.0, max_m);
}

Eigen::Matrix3d TcpRotation(const Eigen::Vector3d& approach_Base, double vertical_threshold_rad) {
  const Eigen::Vector3d z = approach_Base;
  const bool near_vertical = std::abs(z.z()) > std::cos(vertical_threshold_rad);
  const Eigen::Vector3d reference =
      near_vertical ? Eigen::Vector3d::UnitX() : Eigen::Vector3d(-Eigen::Vector3d::UnitZ());
  Eigen::Vector3d x = reference - reference.dot(z) * z;
  if (x.norm() < 1e-9) x = Eigen::Vector3d::UnitY() - z.y() * z;  // Unreachable for valid options.
  x.normalize();
  Eigen::Matrix3d R;
  R.col(0) = x;
  R.col(1) = z.cross(x);
  R.col(2) = z;
  return R;
}

}  // namespace

// -------------------------------------------------------------------------------------------------

GraspTable GraspTable::FromYamlFile(const std::string& path, const apc::Catalogue& catalogue) {
  std::ifstream in(path);
  if (!in) throw GraspTableError(path, "", "", "cannot open the file");
  std::stringstream text;
  text << in.rdbuf();
  return FromYaml(text.str(), path, catalogue);
}

GraspTable GraspTable::FromYaml(const std::string& yaml_text, const std::string& source_name,
                                const apc::Catalogue& catalogue) {
  const TableReader rd(source_name);
  YAML::Node root;
  try {
    root = YAML::Load(yaml_text);
  } catch (const YAML::Exception& e) {
    throw GraspTableError(source_name, "", "", std::string("not valid YAML: ") + e.what());
  }
  GraspTable table;
  table.source_ = source_name;
  try {
    if (!root.IsMap()) rd.Fail("", "", "top level must be a mapping", root);
    rd.CheckKeys(root, "", "", {"version", "cup_diameter_m", "items"});
    if (!root["version"] || root["version"].as<std::string>() != "1") {
      rd.Fail("", "version", "must be 1", root["version"]);
    }
    if (root["cup_diameter_m"]) {
      table.cup_diameter_m_ = rd.Number(root, "cup_diameter_m", "", "cup_diameter_m");
      if (!(table.cup_diameter_m_ > 0.0)) {
        rd.Fail("", "cup_diameter_m", "must be positive", root["cup_diameter_m"]);
      }
    }
    const YAML::Node items = root["items"];
    if (!items) rd.Fail("", "items", "missing", root);
    if (!items.IsMap()) rd.Fail("", "items", "must be a mapping of item name to grasps", items);
    for (const auto& kv : items) {
      const auto name = kv.first.as<std::string>();
      if (!catalogue.contains(name)) {
        rd.Fail(name, "items." + name, "not a catalogue item", kv.first);
      }
      if (table.items_.count(name)) rd.Fail(name, "items." + name, "listed twice", kv.first);
      table.items_.emplace(name, rd.Item(name, kv.second));
    }
    for (const apc::Item& item : catalogue.items()) {
      if (!table.items_.count(item.name)) {
        rd.Fail(item.name, "items." + item.name, "missing (every catalogue item needs an entry)");
      }
    }
  } catch (const YAML::Exception& e) {
    // A type yaml-cpp refused where the checks did not look first (e.g. a list as a key).
    throw GraspTableError(source_name, "", "", std::string("malformed: ") + e.what());
  }
  return table;
}

const ItemGrasps& GraspTable::at(const std::string& item) const {
  const ItemGrasps* grasps = find(item);
  if (grasps == nullptr) throw apc::UnknownItemError(item);
  return *grasps;
}

const ItemGrasps* GraspTable::find(const std::string& item) const {
  const auto it = items_.find(item);
  return it == items_.end() ? nullptr : &it->second;
}

std::string DefaultGraspTablePath() {
  return (std::filesystem::path(apc::DefaultDataDir()) / "planner" / "grasps.yaml").string();
}

namespace {

constexpr double kSizeTolerance = 1e-9;

// A box's faces wide enough for the cup (the widest only, when none is), largest first, each
// at its centre and, on a face four cups long, at the centre of each half as well.
std::vector<SuctionPoint> BoxSuctionPoints(const Eigen::Vector3d& size_m, double cup) {
  const Eigen::Matrix3d E = Eigen::Matrix3d::Identity();
  double widest = 0.0;  // the largest of the faces' smaller sides
  for (int i = 0; i < 3; ++i) {
    widest = std::max(widest, std::min(size_m[(i + 1) % 3], size_m[(i + 2) % 3]));
  }
  const double threshold = std::min(cup, widest);
  std::vector<SuctionPoint> points;
  for (int i = 2; i >= 0; --i) {  // Largest faces (z) first.
    const int j = (i + 1) % 3, k = (i + 2) % 3;
    const double larger = std::max(size_m[j], size_m[k]);
    const double smaller = std::min(size_m[j], size_m[k]);
    if (smaller < threshold - kSizeTolerance) continue;
    const int long_axis = size_m[j] >= size_m[k] ? j : k;
    for (double s : {1.0, -1.0}) {
      SuctionPoint p;
      p.name = Signed(s, i) + " face";
      p.p_ItemPoint = s * size_m[i] / 2.0 * E.col(i);
      p.approach_Item = -s * E.col(i);
      p.face_m = Eigen::Vector2d(larger, smaller);
      points.push_back(p);
      if (larger < 4.0 * cup - kSizeTolerance) continue;
      for (double h : {-1.0, 1.0}) {
        SuctionPoint half = p;
        half.name = p.name + ", " + Signed(h, long_axis) + " half";
        half.p_ItemPoint += h * size_m[long_axis] / 4.0 * E.col(long_axis);
        half.face_m =
            Eigen::Vector2d(std::max(larger / 2.0, smaller), std::min(larger / 2.0, smaller));
        points.push_back(half);
      }
    }
  }
  return points;
}

// A cylinder's side every 45 degrees (where the cup fits along it) and its two ends.
std::vector<SuctionPoint> CylinderSuctionPoints(const Eigen::Vector3d& size_m,
                                                const world::ItemShape& shape, double cup) {
  const Eigen::Matrix3d E = Eigen::Matrix3d::Identity();
  const int a = shape.axis_along_long_side ? 0 : 2;
  const int b = a == 0 ? 1 : 0;
  const int c = a == 0 ? 2 : 1;
  const double diameter = std::min(size_m[b], size_m[c]);
  const double radius = diameter / 2.0;
  const double length = size_m[a];
  std::vector<SuctionPoint> points;
  if (diameter < cup - kSizeTolerance) return points;
  if (length >= cup - kSizeTolerance) {
    for (int n = 0; n < 8; ++n) {
      const double theta = n * 45.0 * kDeg;
      const double cb = std::abs(std::cos(theta)) < 1e-12 ? 0.0 : std::cos(theta);
      const double sc = std::abs(std::sin(theta)) < 1e-12 ? 0.0 : std::sin(theta);
      const Eigen::Vector3d dir = cb * E.col(b) + sc * E.col(c);
      SuctionPoint p;
      p.name = "side";
      if (cb != 0.0) p.name += " " + Signed(cb, b);
      if (sc != 0.0) p.name += (cb != 0.0 ? "" : " ") + Signed(sc, c);
      p.p_ItemPoint = radius * dir;
      p.approach_Item = -dir;
      p.face_m = Eigen::Vector2d(std::max(length, diameter), std::min(length, diameter));
      p.quality = CurvatureQuality(radius, cup);
      points.push_back(p);
    }
  }
  for (double s : {1.0, -1.0}) {
    SuctionPoint p;
    p.name = Signed(s, a) + " end";
    p.p_ItemPoint = s * length / 2.0 * E.col(a);
    p.approach_Item = -s * E.col(a);
    p.face_m = Eigen::Vector2d(diameter, diameter);
    points.push_back(p);
  }
  return points;
}

// A sphere along its six axes and eight diagonals.
std::vector<SuctionPoint> SphereSuctionPoints(const Eigen::Vector3d& size_m, double cup) {
  const Eigen::Matrix3d E = Eigen::Matrix3d::Identity();
  const double diameter = size_m.minCoeff();
  const double radius = diameter / 2.0;
  std::vector<Eigen::Vector3d> dirs;
  for (int i = 0; i < 3; ++i) {
    dirs.push_back(E.col(i));
    dirs.push_back(-E.col(i));
  }
  for (double sz : {1.0, -1.0}) {
    for (double sy : {1.0, -1.0}) {
      for (double sx : {1.0, -1.0}) dirs.push_back(Eigen::Vector3d(sx, sy, sz));
    }
  }
  std::vector<SuctionPoint> points;
  for (const Eigen::Vector3d& d : dirs) {
    SuctionPoint p;
    for (int i = 0; i < 3; ++i) {
      if (d[i] != 0.0) p.name += Signed(d[i], i);
    }
    const Eigen::Vector3d u = d.normalized();
    p.p_ItemPoint = radius * u;
    p.approach_Item = -u;
    p.face_m = Eigen::Vector2d(diameter, diameter);
    p.quality = CurvatureQuality(radius, cup);
    points.push_back(p);
  }
  return points;
}

}  // namespace

std::vector<SuctionPoint> DefaultSuctionPoints(const Eigen::Vector3d& size_m,
                                               const world::ItemShape& shape,
                                               double cup_diameter_m) {
  if (!size_m.allFinite() || !(size_m.minCoeff() > 0.0)) {
    throw std::invalid_argument("DefaultSuctionPoints: size_m must be positive");
  }
  if (!(cup_diameter_m > 0.0) || !std::isfinite(cup_diameter_m)) {
    throw std::invalid_argument("DefaultSuctionPoints: cup_diameter_m must be positive");
  }
  switch (shape.kind) {
    case world::ShapeKind::kBox:
    case world::ShapeKind::kScan:
      return BoxSuctionPoints(size_m, cup_diameter_m);
    case world::ShapeKind::kCylinder:
      return CylinderSuctionPoints(size_m, shape, cup_diameter_m);
    case world::ShapeKind::kSphere:
      return SphereSuctionPoints(size_m, cup_diameter_m);
  }
  return {};
}

GraspContainer ShelfBinContainer(const world::CellModel& cell, const std::string& bin) {
  const world::BinGeometry& geometry = cell.bin(bin);
  GraspContainer container;
  container.name = geometry.name;
  container.kind = GraspContainerKind::kShelfBin;
  container.X_BaseContainer =
      cell.config.X_BaseShelf * Eigen::Translation3d(geometry.inner_S.center());
  container.inner_size_m = geometry.inner_S.sizes();
  container.opening_direction_Base =
      (cell.config.X_BaseShelf.linear() * Eigen::Vector3d::UnitX()).normalized();
  return container;
}

GraspContainer ToteContainer(const world::CellModel& cell, double wall_m) {
  if (!(wall_m >= 0.0) || !std::isfinite(wall_m)) {
    throw std::invalid_argument("ToteContainer: wall_m must be >= 0");
  }
  const Eigen::AlignedBox3d bounds = world::Bounds(cell.tote);
  if (bounds.isEmpty()) throw std::invalid_argument("ToteContainer: the tote mesh is empty");
  const Eigen::Vector3d wall(wall_m, wall_m, 0.0);
  const Eigen::AlignedBox3d inner(bounds.min() + wall, bounds.max() - wall);
  if (!(inner.sizes().minCoeff() > 0.0)) {
    throw std::invalid_argument("ToteContainer: wall_m leaves no inner volume");
  }
  GraspContainer container;
  container.name = "tote";
  container.kind = GraspContainerKind::kOpenTop;
  container.X_BaseContainer = cell.config.X_BaseTote * Eigen::Translation3d(inner.center());
  container.inner_size_m = inner.sizes();
  container.opening_direction_Base =
      (cell.config.X_BaseTote.linear() * Eigen::Vector3d::UnitZ()).normalized();
  return container;
}

GraspContainer TableContainer(const world::CellModel& cell, double height_m) {
  const Eigen::Vector3d size = cell.config.table_size_m;
  if (!(height_m > 0.0) || !std::isfinite(height_m) || !(size.head<2>().minCoeff() > 0.0)) {
    throw std::invalid_argument("TableContainer: height_m and the table's top must be > 0");
  }
  GraspContainer container;
  container.name = "table";
  container.kind = GraspContainerKind::kOpenTop;
  container.X_BaseContainer =
      cell.config.X_BaseTable * Eigen::Translation3d(0.0, 0.0, 0.5 * height_m);
  container.inner_size_m = Eigen::Vector3d(size.x(), size.y(), height_m);
  container.opening_direction_Base =
      (cell.config.X_BaseTable.linear() * Eigen::Vector3d::UnitZ()).normalized();
  return container;
}

const char* GraspRejectionName(GraspRejection reason) {
  switch (reason) {
    case GraspRejection::kOutsideContainer:
      return "outside container";
    case GraspRejection::kApproachAngle:
      return "approach angle";
    case GraspRejection::kBlocked:
      return "blocked";
  }
  return "unknown";
}

namespace {

// The approaches tried at a point whose surface normal (inward) is `normal_Base`: the normal,
// then tilted toward the ideal approach (into the container: -opening) by up to max_tilt_rad;
// in a shelf bin a near-horizontal approach also pitched down by the same tilts (low in a bin
// the tube then runs up and out over the floor's front lip, which stands above the inner
// box's floor). Each with its tilt, radians.
std::vector<std::pair<Eigen::Vector3d, double>> Approaches(const Eigen::Vector3d& normal_Base,
                                                           const GraspContainer& container,
                                                           const GraspOptions& options) {
  const Eigen::Vector3d& opening = container.opening_direction_Base;
  std::vector<std::pair<Eigen::Vector3d, double>> approaches = {{normal_Base, 0.0}};
  const double to_ideal = AngleBetween(normal_Base, -opening);
  if (options.max_tilt_rad > 0.0 && to_ideal > 1e-9 && to_ideal < EIGEN_PI - 1e-6) {
    const Eigen::Vector3d axis = normal_Base.cross(-opening).normalized();
    for (int k = 1; k <= options.tilt_steps; ++k) {
      const double tilt = std::min(to_ideal, options.max_tilt_rad * k / options.tilt_steps);
      approaches.emplace_back(Eigen::AngleAxisd(tilt, axis) * normal_Base, tilt);
      if (tilt >= to_ideal) break;
    }
  }
  const Eigen::Vector3d up = container.X_BaseContainer.linear().col(2);  // the bin's up
  const Eigen::Vector3d down_across = -(up - up.dot(normal_Base) * normal_Base);
  if (container.kind == GraspContainerKind::kShelfBin && options.max_tilt_rad > 0.0 &&
      std::abs(normal_Base.dot(up)) < std::sin(options.max_pitch_from_horizontal_rad) &&
      down_across.norm() > 1e-6) {
    const Eigen::Vector3d axis = normal_Base.cross(down_across.normalized()).normalized();
    for (int k = 1; k <= options.tilt_steps; ++k) {
      const double tilt = options.max_tilt_rad * k / options.tilt_steps;
      approaches.emplace_back(Eigen::AngleAxisd(tilt, axis) * normal_Base, tilt);
    }
  }
  return approaches;
}

// The point at the centre of a box face moved across the face toward the opening
// (opening_Item, the item frame) as far as the cup stays on the face by the margin, then the
// same point moved to the corners of the face's front edge: where a neighbour stands over the
// middle of a flat item's front edge, or the wrist cannot stand over it, one of its front
// corners may still be reached. Nothing for a point that is not a face centre listed with the
// face's full size, a face turned toward the opening, or a shift below the minimum; corners
// whose shift leans less than about 70 degrees toward the opening are not front corners.
std::vector<SuctionPoint> TowardTheOpening(const SuctionPoint& point, const ItemGrasps& grasps,
                                           const Eigen::Vector3d& opening_Item, double cup_radius_m,
                                           const GraspOptions& options) {
  std::vector<SuctionPoint> moved;
  if (options.edge_margin_toward_opening_m < 0.0) return moved;
  const Eigen::Vector3d& a = point.approach_Item;
  int i = 0;
  if (a.cwiseAbs().maxCoeff(&i) < 1.0 - 1e-9) return moved;  // not along an item axis
  const int j = (i + 1) % 3, k = (i + 2) % 3;
  const Eigen::Vector3d& size = grasps.size_m;
  const double tolerance = 1e-3;  // the table's millimetres
  const bool face_centre = std::abs(std::abs(point.p_ItemPoint[i]) - size[i] / 2.0) < tolerance &&
                           std::abs(point.p_ItemPoint[j]) < tolerance &&
                           std::abs(point.p_ItemPoint[k]) < tolerance;
  const bool whole_face = std::abs(point.face_m.x() - std::max(size[j], size[k])) < tolerance &&
                          std::abs(point.face_m.y() - std::min(size[j], size[k])) < tolerance;
  if (!face_centre || !whole_face) return moved;
  Eigen::Vector3d across = opening_Item;
  across[i] = 0.0;
  if (across.norm() < 0.5) return moved;  // the face looks toward the opening already
  across.normalize();
  // How far the cup may move from the centre along each of the face's axes.
  Eigen::Vector3d room = Eigen::Vector3d::Zero();
  double shift_m = std::numeric_limits<double>::infinity();
  for (const int axis : {j, k}) {
    room[axis] = size[axis] / 2.0 - cup_radius_m - options.edge_margin_toward_opening_m;
    if (std::abs(across[axis]) < 1e-9) continue;
    shift_m = std::min(shift_m, room[axis] / std::abs(across[axis]));
  }
  if (!(shift_m >= options.min_shift_toward_opening_m)) return moved;
  SuctionPoint front = point;
  front.name = point.name + ", toward the opening";
  front.p_ItemPoint += shift_m * across;
  moved.push_back(std::move(front));
  if (!(room[j] >= options.min_shift_toward_opening_m) ||
      !(room[k] >= options.min_shift_toward_opening_m)) {
    return moved;
  }
  constexpr double kFrontCos = 0.35;
  for (const double sj : {-1.0, 1.0}) {
    for (const double sk : {-1.0, 1.0}) {
      Eigen::Vector3d shift = Eigen::Vector3d::Zero();
      shift[j] = sj * room[j];
      shift[k] = sk * room[k];
      if (shift.normalized().dot(across) < kFrontCos) continue;
      SuctionPoint corner = point;
      corner.name = point.name + ", front corner " + Signed(sj, j) + Signed(sk, k);
      corner.p_ItemPoint += shift;
      moved.push_back(std::move(corner));
    }
  }
  return moved;
}

// The free distance behind the point along -approach (the options' callback, else the
// container's walls), clamped to [0, max_clearance_m].
double Clearance(const GraspContainer& container, const Eigen::Vector3d& p_BasePoint,
                 const Eigen::Vector3d& approach, const GraspOptions& options,
                 const std::string& item, const std::string& point) {
  if (!options.clearance) {
    return GeometricClearance(container, p_BasePoint, -approach, options.max_clearance_m);
  }
  const double clearance = options.clearance(p_BasePoint, -approach, options.max_clearance_m);
  if (!std::isfinite(clearance)) {
    throw std::runtime_error(
        "ComputeGrasps: the clearance callback returned a non-finite distance for item '" + item +
        "', point '" + point + "'");
  }
  return std::clamp(clearance, 0.0, options.max_clearance_m);
}

// A candidate at the point along `approach`, scored (`fixed`: the parts that do not depend
// on the approach).
GraspCandidate MakeCandidate(const SuctionPoint& point, int point_index,
                             const Eigen::Vector3d& p_BasePoint, const Eigen::Vector3d& normal_Base,
                             const Eigen::Vector3d& approach, double tilt, double angle,
                             double clearance, const GraspScore& fixed,
                             const GraspOptions& options) {
  GraspCandidate c;
  c.surface = point.name;
  c.point_index = point_index;
  c.p_BasePoint = p_BasePoint;
  c.approach_Base = approach;
  c.surface_approach_Base = normal_Base;
  c.tilt_rad = tilt;
  c.approach_angle_rad = angle;
  c.clearance_m = clearance;
  c.X_BaseTcp.setIdentity();
  c.X_BaseTcp.linear() = TcpRotation(approach, options.vertical_roll_threshold_rad);
  c.X_BaseTcp.translation() = p_BasePoint;
  c.X_BaseTcpPreGrasp = c.X_BaseTcp;
  c.X_BaseTcpPreGrasp.translation() = p_BasePoint - options.pregrasp_standoff_m * approach;
  c.score = fixed;
  c.score.clearance = std::min(1.0, clearance / options.required_clearance_m);
  c.score.approach = std::max(0.0, std::cos(angle));
  c.score.tilt = std::cos(tilt);
  c.score.total = c.score.quality * std::pow(c.score.face_size, options.face_size_weight) *
                  std::pow(c.score.centrality, options.centrality_weight) *
                  std::pow(c.score.clearance, options.clearance_weight) *
                  std::pow(c.score.approach, options.approach_weight) *
                  std::pow(c.score.tilt, options.tilt_weight);
  return c;
}

// Why no grasp was left, in the container's and the options' terms.
std::string NoGraspReason(const GraspTable& table, const std::string& item, std::size_t num_points,
                          int tried, const GraspResult& result, const GraspContainer& container,
                          double max_angle, const GraspOptions& options) {
  std::ostringstream msg;
  msg << "no suction grasp for '" << item << "' in '" << container.name << "': " << tried
      << " approaches to " << num_points << " suction points tried;";
  if (result.rejected_outside_container > 0) {
    msg << " " << result.rejected_outside_container
        << " points lie outside the container box (tolerance "
        << Fixed(options.container_tolerance_m, 3)
        << " m): check X_BaseItem and the container's pose and size;";
  }
  if (result.rejected_approach_angle > 0) {
    msg << " " << result.rejected_approach_angle << " approaches are more than "
        << Fixed(max_angle / kDeg, 1)
        << " deg from the opening direction (the item shows no listed surface toward the "
           "opening): re-detect or turn the item, allow a larger "
        << (container.kind == GraspContainerKind::kOpenTop ? "max_tote_approach_angle_rad"
                                                           : "max_approach_angle_rad")
        << " (max_tilt_rad cannot pass the cup's seal tolerance, "
        << Fixed(kSealAngleToleranceRad / kDeg, 0) << " deg), or add points in the grasp table '"
        << table.source() << "';";
  }
  if (result.rejected_blocked > 0) {
    msg << " " << result.rejected_blocked << " approaches have less than "
        << Fixed(options.min_clearance_m, 3)
        << " m free behind the point: clear the obstacle or lower min_clearance_m;";
  }
  std::string reason = msg.str();
  reason.pop_back();  // the last ';'
  return reason;
}

}  // namespace

GraspResult ComputeGrasps(const GraspTable& table, const std::string& item,
                          const Eigen::Isometry3d& X_BaseItem, const GraspContainer& container,
                          const GraspOptions& options) {
  const ItemGrasps& grasps = table.at(item);
  CheckRigid(X_BaseItem, "X_BaseItem");
  CheckContainer(container);
  CheckOptions(options);

  GraspResult result;
  result.item = item;
  result.container = container.name;

  const Eigen::Vector3d& opening = container.opening_direction_Base;
  const double max_angle = container.kind == GraspContainerKind::kOpenTop
                               ? options.max_tote_approach_angle_rad
                               : options.max_approach_angle_rad;
  const Eigen::Isometry3d X_ContainerBase = container.X_BaseContainer.inverse();
  const Eigen::Vector3d half_inner = container.inner_size_m / 2.0;
  const double half_diagonal = grasps.size_m.norm() / 2.0;
  const Eigen::Matrix3d R_BaseItem = X_BaseItem.linear();
  int tried = 0;

  // Each listed point, and in a shelf bin its variants moved toward the opening.
  std::vector<std::pair<SuctionPoint, int>> points;
  const Eigen::Vector3d opening_Item = R_BaseItem.transpose() * opening;
  for (std::size_t index = 0; index < grasps.points.size(); ++index) {
    points.emplace_back(grasps.points[index], static_cast<int>(index));
    if (container.kind != GraspContainerKind::kShelfBin) continue;
    for (auto& moved : TowardTheOpening(grasps.points[index], grasps, opening_Item,
                                        table.cup_diameter_m() / 2.0, options)) {
      points.emplace_back(std::move(moved), static_cast<int>(index));
    }
  }
  for (const auto& [point, point_index] : points) {
    const Eigen::Vector3d p_BasePoint = X_BaseItem * point.p_ItemPoint;
    const Eigen::Vector3d normal_Base = (R_BaseItem * point.approach_Item).normalized();

    ++tried;
    const double outside = ((X_ContainerBase * p_BasePoint).cwiseAbs() - half_inner).maxCoeff();
    if (outside > options.container_tolerance_m) {
      result.rejected.push_back({point.name, point_index, 0.0, GraspRejection::kOutsideContainer,
                                 Fixed(outside, 3) + " m outside the box"});
      ++result.rejected_outside_container;
      continue;
    }

    // Scores that do not depend on the approach tilt.
    const Eigen::Vector3d& p = point.p_ItemPoint;
    const Eigen::Vector3d& n = point.approach_Item;
    const double off_axis = (p - p.dot(n) * n).norm();
    GraspScore fixed;
    fixed.quality = grasps.quality * point.quality;
    fixed.face_size = std::min(1.0, point.face_m.minCoeff() / options.full_face_size_m);
    fixed.centrality = std::clamp(1.0 - off_axis / half_diagonal, 0.0, 1.0);

    const auto approaches = Approaches(normal_Base, container, options);
    for (std::size_t v = 0; v < approaches.size(); ++v) {
      const Eigen::Vector3d approach = approaches[v].first.normalized();
      const double tilt = approaches[v].second;
      if (v > 0) ++tried;
      const double angle = AngleBetween(-approach, opening);
      if (angle > max_angle + 1e-12) {
        result.rejected.push_back(
            {point.name, point_index, tilt, GraspRejection::kApproachAngle,
             "angle " + Fixed(angle / kDeg, 1) + " deg > " + Fixed(max_angle / kDeg, 1) + " deg"});
        ++result.rejected_approach_angle;
        continue;
      }
      const double clearance =
          Clearance(container, p_BasePoint, approach, options, item, point.name);
      if (clearance < options.min_clearance_m) {
        result.rejected.push_back({point.name, point_index, tilt, GraspRejection::kBlocked,
                                   "clearance " + Fixed(clearance, 3) + " m < " +
                                       Fixed(options.min_clearance_m, 3) + " m"});
        ++result.rejected_blocked;
        continue;
      }
      result.candidates.push_back(MakeCandidate(point, point_index, p_BasePoint, normal_Base,
                                                approach, tilt, angle, clearance, fixed, options));
    }
  }

  std::stable_sort(result.candidates.begin(), result.candidates.end(),
                   [](const GraspCandidate& a, const GraspCandidate& b) {
                     return a.score.total > b.score.total;
                   });
  if (result.candidates.empty()) {
    result.reason = NoGraspReason(table, item, grasps.points.size(), tried, result, container,
                                  max_angle, options);
  }
  return result;
}

}  // namespace picking::planner
