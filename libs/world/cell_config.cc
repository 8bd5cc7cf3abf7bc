#include "libs/world/cell_config.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include "libs/apc/catalogue.h"
#include "libs/world/mesh_utils.h"
#include "libs/world/stl_io.h"

namespace picking::world {

CellConfigError::CellConfigError(const std::string& source, const std::string& field,
                                 const std::string& what)
    : std::runtime_error("cell config '" + source + "'" +
                         (field.empty() ? std::string() : ", field '" + field + "'") + ": " + what),
      field_(field) {}

namespace {

class Reader {
 public:
  Reader(std::string source, std::string base_dir)
      : source_(std::move(source)), base_dir_(std::move(base_dir)) {}

  [[noreturn]] void Fail(const std::string& field, const std::string& what) const {
    throw CellConfigError(source_, field, what);
  }

  YAML::Node Map(const YAML::Node& parent, const std::string& key, const std::string& field,
                 const std::set<std::string>& allowed) const {
    const YAML::Node node = parent[key];
    if (!node) Fail(field, "missing");
    if (!node.IsMap()) Fail(field, "must be a mapping");
    for (const auto& kv : node) {
      const auto name = kv.first.as<std::string>();
      if (!allowed.count(name)) Fail(field + "." + name, "unknown key");
    }
    return node;
  }

  std::vector<double> Numbers(const YAML::Node& parent, const std::string& key,
                              const std::string& field, std::size_t n) const {
    const YAML::Node node = parent[key];
    if (!node) Fail(field, "missing");
    if (!node.IsSequence() || node.size() != n) {
      Fail(field, "must be a list of " + std::to_string(n) + " numbers");
    }
    std::vector<double> values;
    for (std::size_t i = 0; i < n; ++i) {
      double v = 0.0;
      try {
        v = node[i].as<double>();
      } catch (const YAML::Exception&) {
        Fail(field + "[" + std::to_string(i) + "]", "not a number");
      }
      if (!std::isfinite(v)) Fail(field + "[" + std::to_string(i) + "]", "not finite");
      values.push_back(v);
    }
    return values;
  }

  Eigen::Isometry3d Pose(const YAML::Node& parent, const std::string& key,
                         const std::string& field) const {
    const YAML::Node node = Map(parent, key, field, {"position", "orientation"});
    const auto p = Numbers(node, "position", field + ".position", 3);
    const auto q = Numbers(node, "orientation", field + ".orientation", 4);
    Eigen::Quaterniond quat(q[0], q[1], q[2], q[3]);
    if (std::abs(quat.norm() - 1.0) > 1e-3) {
      std::ostringstream msg;
      msg << "quaternion [w, x, y, z] must have unit norm, has " << quat.norm();
      Fail(field + ".orientation", msg.str());
    }
    quat.normalize();
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() = quat.toRotationMatrix();
    X.translation() = Eigen::Vector3d(p[0], p[1], p[2]);
    return X;
  }

  double Number(const YAML::Node& parent, const std::string& key, const std::string& field) const {
    const YAML::Node node = parent[key];
    if (!node) Fail(field, "missing");
    if (!node.IsScalar()) Fail(field, "must be a number");
    double v = 0.0;
    try {
      v = node.as<double>();
    } catch (const YAML::Exception&) {
      Fail(field, "not a number");
    }
    if (!std::isfinite(v)) Fail(field, "not finite");
    return v;
  }

  std::string Path(const YAML::Node& parent, const std::string& key,
                   const std::string& field) const {
    const YAML::Node node = parent[key];
    if (!node) Fail(field, "missing");
    if (!node.IsScalar()) Fail(field, "must be a path");
    std::filesystem::path p = node.as<std::string>();
    if (p.is_relative()) p = std::filesystem::path(base_dir_) / p;
    p = p.lexically_normal();
    if (!std::filesystem::is_regular_file(p)) Fail(field, "file '" + p.string() + "' not found");
    return p.string();
  }

 private:
  std::string source_;
  std::string base_dir_;
};

}  // namespace

CellConfig ParseCellConfig(const std::string& yaml_text, const std::string& source_name,
                           const std::string& base_dir) {
  const Reader rd(source_name, base_dir);
  YAML::Node root;
  try {
    root = YAML::Load(yaml_text);
  } catch (const YAML::Exception& e) {
    rd.Fail("", std::string("YAML syntax error: ") + e.what());
  }
  if (!root.IsMap()) rd.Fail("", "top level must be a mapping");
  for (const auto& kv : root) {
    const auto name = kv.first.as<std::string>();
    if (name != "version" && name != "robot_base" && name != "shelf" && name != "tote" &&
        name != "table" && name != "gripper") {
      rd.Fail(name, "unknown key");
    }
  }
  if (!root["version"]) rd.Fail("version", "missing");
  int version = 0;
  try {
    version = root["version"].as<int>();
  } catch (const YAML::Exception&) {
    rd.Fail("version", "not an integer");
  }
  if (version != 1) rd.Fail("version", "unsupported version " + std::to_string(version));

  CellConfig config;
  config.source = source_name;
  const YAML::Node robot = rd.Map(root, "robot_base", "robot_base", {"X_WorldBase"});
  config.X_WorldBase = rd.Pose(robot, "X_WorldBase", "robot_base.X_WorldBase");
  const YAML::Node shelf = rd.Map(root, "shelf", "shelf", {"X_BaseShelf", "mesh"});
  config.X_BaseShelf = rd.Pose(shelf, "X_BaseShelf", "shelf.X_BaseShelf");
  config.shelf_mesh_path = rd.Path(shelf, "mesh", "shelf.mesh");
  const YAML::Node tote = rd.Map(root, "tote", "tote", {"X_BaseTote", "mesh"});
  config.X_BaseTote = rd.Pose(tote, "X_BaseTote", "tote.X_BaseTote");
  config.tote_mesh_path = rd.Path(tote, "mesh", "tote.mesh");
  const YAML::Node table = rd.Map(root, "table", "table", {"X_BaseTable", "size_m"});
  config.X_BaseTable = rd.Pose(table, "X_BaseTable", "table.X_BaseTable");
  const auto size = rd.Numbers(table, "size_m", "table.size_m", 3);
  for (int i = 0; i < 3; ++i) {
    if (size[i] <= 0.0) rd.Fail("table.size_m[" + std::to_string(i) + "]", "must be positive");
  }
  config.table_size_m = Eigen::Vector3d(size[0], size[1], size[2]);

  const YAML::Node gripper =
      rd.Map(root, "gripper", "gripper",
             {"X_ToolTcp", "tube_radius_m", "cup_length_m", "head_length_m", "max_head_angle_deg"});
  GripperConfig& g = config.gripper;
  g.X_ToolTcp = rd.Pose(gripper, "X_ToolTcp", "gripper.X_ToolTcp");
  g.tube_radius_m = rd.Number(gripper, "tube_radius_m", "gripper.tube_radius_m");
  if (!(g.tube_radius_m > 0.0)) rd.Fail("gripper.tube_radius_m", "must be positive");
  g.cup_length_m = rd.Number(gripper, "cup_length_m", "gripper.cup_length_m");
  if (g.cup_length_m < 0.0) rd.Fail("gripper.cup_length_m", "must not be negative");
  const double tube_length_m = g.X_ToolTcp.translation().norm();
  if (!(g.cup_length_m < tube_length_m)) {
    std::ostringstream msg;
    msg << "must be shorter than the tube (" << tube_length_m
        << " m from the flange to the TCP of X_ToolTcp)";
    rd.Fail("gripper.cup_length_m", msg.str());
  }
  if (gripper["head_length_m"]) {
    g.head_length_m = rd.Number(gripper, "head_length_m", "gripper.head_length_m");
    if (!(g.head_length_m > g.cup_length_m && g.head_length_m < tube_length_m)) {
      std::ostringstream msg;
      msg << "must be longer than the cup (" << g.cup_length_m << " m) and shorter than the tube ("
          << tube_length_m << " m)";
      rd.Fail("gripper.head_length_m", msg.str());
    }
    const double max_deg = rd.Number(gripper, "max_head_angle_deg", "gripper.max_head_angle_deg");
    if (!(max_deg >= 0.0 && max_deg <= 180.0)) {
      rd.Fail("gripper.max_head_angle_deg", "must lie in [0, 180]");
    }
    g.max_head_angle_rad = max_deg * M_PI / 180.0;
  } else if (gripper["max_head_angle_deg"]) {
    rd.Fail("gripper.max_head_angle_deg", "needs head_length_m (a gripper without a joint)");
  }
  return config;
}

std::string HeadAngleProblem(double head_angle_rad, double max_head_angle_rad) {
  if (std::isfinite(head_angle_rad) && std::abs(head_angle_rad) <= max_head_angle_rad + 1e-12) {
    return "";
  }
  std::ostringstream msg;
  msg << head_angle_rad << " rad is outside the servo's range";
  if (max_head_angle_rad == 0.0) {
    msg << " (the gripper has no joint)";
  } else {
    msg << " of +-" << max_head_angle_rad << " rad";
  }
  return msg.str();
}

Eigen::Vector3d GripperConfig::p_ToolJoint() const {
  return X_ToolTcp * Eigen::Vector3d(0.0, 0.0, -head_length_m);
}

Eigen::Isometry3d GripperConfig::X_ToolTcpAt(double head_angle_rad) const {
  if (head_angle_rad == 0.0 || head_length_m == 0.0) return X_ToolTcp;
  // The head turns about the joint's x axis (the tcp's x at angle 0).
  const Eigen::Isometry3d X_ToolJoint = X_ToolTcp * Eigen::Translation3d(0.0, 0.0, -head_length_m);
  return X_ToolJoint * Eigen::AngleAxisd(head_angle_rad, Eigen::Vector3d::UnitX()) *
         Eigen::Translation3d(0.0, 0.0, head_length_m);
}

CellConfig ReadCellConfig(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw CellConfigError(path, "", "cannot open");
  std::stringstream text;
  text << in.rdbuf();
  return ParseCellConfig(text.str(), path, std::filesystem::absolute(path).parent_path().string());
}

std::string DefaultCellConfigPath() { return DefaultCellConfigPath(apc::DefaultDataDir()); }

std::string DefaultCellConfigPath(const std::string& data_dir) {
  return (std::filesystem::path(data_dir) / "cell" / "default_cell.yaml").string();
}

const BinGeometry& CellModel::bin(const std::string& name) const {
  for (const auto& b : bins) {
    if (b.name == name) return b;
  }
  throw std::invalid_argument("unknown bin '" + name + "'");
}

CellModel LoadCellModel(const CellConfig& config) {
  CellModel model;
  model.config = config;
  model.shelf = ReadStl(config.shelf_mesh_path);
  model.shelf.name = "shelf";
  model.shelf.albedo = 0.35f;
  model.tote = ReadStl(config.tote_mesh_path);
  model.tote.name = "tote";
  model.tote.albedo = 0.25f;
  // The table top at z = 0 of the table frame.
  model.table = Transformed(
      MakeBox(config.table_size_m),
      Eigen::Isometry3d(Eigen::Translation3d(0.0, 0.0, -0.5 * config.table_size_m.z())));
  model.table.name = "table";
  model.table.albedo = 0.7f;
  model.bins = MeasureBins(model.shelf);
  model.measured_tote_inner_T = MeasureToteInner(model.tote);
  return model;
}

}  // namespace picking::world
