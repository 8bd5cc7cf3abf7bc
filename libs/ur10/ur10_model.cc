#include "libs/ur10/ur10_model.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <map>
#include <sstream>
#include <stdexcept>
#include <tuple>

namespace picking::ur10 {
namespace {

constexpr double kPi = 3.14159265358979323846;

const char* const kLinkNames[kNumLinks] = {"base",    "shoulder", "upper_arm", "forearm",
                                           "wrist_1", "wrist_2",  "wrist_3"};

YAML::Node LoadYamlFile(const std::string& path) {
  try {
    return YAML::LoadFile(path);
  } catch (const YAML::Exception& e) {
    throw std::runtime_error(path + ": cannot read yaml: " + e.what());
  }
}

// Walks `keys` from `root`; throws naming the file and the dotted key path.
YAML::Node Child(const YAML::Node& root, const std::string& file,
                 std::initializer_list<const char*> keys) {
  YAML::Node node;
  node.reset(root);  // YAML::Node assignment would overwrite the referenced node
  std::string dotted;
  for (const char* key : keys) {
    dotted += dotted.empty() ? key : std::string(".") + key;
    if (!node.IsMap() || !node[key]) {
      throw std::runtime_error(file + ": missing field '" + dotted + "'");
    }
    const YAML::Node next = node[key];
    node.reset(next);
  }
  return node;
}

std::string Dotted(std::initializer_list<const char*> keys) {
  std::string dotted;
  for (const char* key : keys) dotted += dotted.empty() ? key : std::string(".") + key;
  return dotted;
}

// A scalar in the file's unit; a `!degrees` tag converts degrees to radians.
double Number(const YAML::Node& root, const std::string& file,
              std::initializer_list<const char*> keys) {
  const YAML::Node node = Child(root, file, keys);
  const std::string where =
      file + ":" + std::to_string(node.Mark().line + 1) + ": field '" + Dotted(keys) + "'";
  if (!node.IsScalar()) throw std::runtime_error(where + " is not a number");
  double value = 0.0;
  try {
    value = node.as<double>();
  } catch (const YAML::Exception&) {
    throw std::runtime_error(where + " is not a number: '" + node.Scalar() + "'");
  }
  const std::string& tag = node.Tag();
  if (tag == "!degrees") {
    value *= kPi / 180.0;
  } else if (!tag.empty() && tag != "?" && tag != "!" && tag != "tag:yaml.org,2002:float" &&
             tag != "tag:yaml.org,2002:int") {
    throw std::runtime_error(where + " has an unknown tag '" + tag + "'");
  }
  if (!std::isfinite(value)) throw std::runtime_error(where + " is not finite");
  return value;
}

Eigen::Isometry3d OriginFromYaml(const YAML::Node& root, const std::string& file,
                                 const char* joint) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(Number(root, file, {"kinematics", joint, "x"}),
                                    Number(root, file, {"kinematics", joint, "y"}),
                                    Number(root, file, {"kinematics", joint, "z"}));
  X.linear() = RotationFromRpy(Number(root, file, {"kinematics", joint, "roll"}),
                               Number(root, file, {"kinematics", joint, "pitch"}),
                               Number(root, file, {"kinematics", joint, "yaw"}));
  return X;
}

Eigen::Isometry3d Pose(double x, double y, double z, double roll, double pitch, double yaw) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(x, y, z);
  X.linear() = RotationFromRpy(roll, pitch, yaw);
  return X;
}

std::string FileName(const std::string& mesh_uri) {
  const auto slash = mesh_uri.find_last_of('/');
  return slash == std::string::npos ? mesh_uri : mesh_uri.substr(slash + 1);
}

}  // namespace

Eigen::Matrix3d RotationFromRpy(double roll, double pitch, double yaw) {
  return (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

const char* LinkName(Link link) { return kLinkNames[static_cast<int>(link)]; }

Ur10Model::Ur10Model(const DhParameters& dh, const std::array<JointLimit, kNumJoints>& limits)
    : dh_(dh) {
  const std::pair<const char*, double> values[] = {{"d1", dh.d1}, {"a2", dh.a2}, {"a3", dh.a3},
                                                   {"d4", dh.d4}, {"d5", dh.d5}, {"d6", dh.d6}};
  for (const auto& [name, value] : values) {
    if (!std::isfinite(value)) {
      throw std::invalid_argument(std::string("Ur10Model: DH parameter ") + name +
                                  " is not finite");
    }
  }
  if (dh.d4 <= 0.0 || dh.d6 <= 0.0 || dh.a2 == 0.0 || dh.a3 == 0.0) {
    throw std::invalid_argument("Ur10Model: DH parameters need d4 > 0, d6 > 0, a2 != 0, a3 != 0");
  }
  ValidateLimits(limits);
  limits_ = limits;
  // The URDF chain of ur_description expressed with the DH values (default_kinematics.yaml
  // has exactly this form); Load() replaces it by the file's values.
  X_parent_link_[0] = Eigen::Isometry3d::Identity();
  X_parent_link_[1] = Pose(0, 0, dh.d1, 0, 0, 0);
  X_parent_link_[2] = Pose(0, 0, 0, kPi / 2, 0, 0);
  X_parent_link_[3] = Pose(dh.a2, 0, 0, 0, 0, 0);
  X_parent_link_[4] = Pose(dh.a3, 0, dh.d4, 0, 0, 0);
  X_parent_link_[5] = Pose(0, -dh.d5, 0, kPi / 2, 0, 0);
  X_parent_link_[6] = Pose(0, dh.d6, 0, kPi / 2, kPi, kPi);
  // wrist_3_link -> flange (rpy 0, -pi/2, -pi/2) -> tool0 (rpy pi/2, 0, pi/2), ur_macro.xacro.
  X_wrist3_tool_ = Pose(0, 0, 0, 0, -kPi / 2, -kPi / 2) * Pose(0, 0, 0, kPi / 2, 0, kPi / 2);
  for (auto& X : X_link_mesh_) X = Eigen::Isometry3d::Identity();
}

void Ur10Model::ValidateLimits(const std::array<JointLimit, kNumJoints>& limits) const {
  for (int i = 0; i < kNumJoints; ++i) {
    const JointLimit& l = limits[i];
    const std::string joint = std::string("Ur10Model: joint ") + kJointNames[i];
    if (!std::isfinite(l.min_position_rad) || !std::isfinite(l.max_position_rad) ||
        !(l.min_position_rad < l.max_position_rad)) {
      throw std::invalid_argument(joint + ": position limits must be finite with min < max");
    }
    if (!std::isfinite(l.max_velocity_rad_s) || l.max_velocity_rad_s <= 0.0) {
      throw std::invalid_argument(joint + ": max velocity must be finite and > 0");
    }
    if (!std::isfinite(l.max_acceleration_rad_s2) || l.max_acceleration_rad_s2 <= 0.0) {
      throw std::invalid_argument(joint + ": max acceleration must be finite and > 0");
    }
    if (!std::isfinite(l.max_effort_nm) || l.max_effort_nm < 0.0) {
      throw std::invalid_argument(joint + ": max effort must be finite and >= 0");
    }
  }
}

void Ur10Model::set_limits(const std::array<JointLimit, kNumJoints>& limits) {
  ValidateLimits(limits);
  limits_ = limits;
}

Ur10Model Ur10Model::Load(const std::string& data_dir, const Ur10ModelOptions& options) {
  const std::string physical_file = data_dir + "/physical_parameters.yaml";
  const std::string kinematics_file = data_dir + "/default_kinematics.yaml";
  const std::string limits_file = data_dir + "/joint_limits.yaml";
  const std::string visual_file = data_dir + "/visual_parameters.yaml";

  const YAML::Node physical = LoadYamlFile(physical_file);
  DhParameters dh;
  dh.d1 = Number(physical, physical_file, {"dh_parameters", "d1"});
  dh.a2 = Number(physical, physical_file, {"dh_parameters", "a2"});
  dh.a3 = Number(physical, physical_file, {"dh_parameters", "a3"});
  dh.d4 = Number(physical, physical_file, {"dh_parameters", "d4"});
  dh.d5 = Number(physical, physical_file, {"dh_parameters", "d5"});
  dh.d6 = Number(physical, physical_file, {"dh_parameters", "d6"});

  const YAML::Node limits_yaml = LoadYamlFile(limits_file);
  std::array<JointLimit, kNumJoints> limits;
  for (int i = 0; i < kNumJoints; ++i) {
    const char* joint = kJointNames[i];
    limits[i].min_position_rad =
        Number(limits_yaml, limits_file, {"joint_limits", joint, "min_position"});
    limits[i].max_position_rad =
        Number(limits_yaml, limits_file, {"joint_limits", joint, "max_position"});
    limits[i].max_velocity_rad_s =
        Number(limits_yaml, limits_file, {"joint_limits", joint, "max_velocity"});
    limits[i].max_effort_nm =
        Number(limits_yaml, limits_file, {"joint_limits", joint, "max_effort"});
    limits[i].max_acceleration_rad_s2 = options.max_acceleration_rad_s2;
  }
  Ur10Model model(dh, limits);

  const YAML::Node kinematics = LoadYamlFile(kinematics_file);
  const char* const kJointOrigins[kNumLinks] = {nullptr,   "shoulder", "upper_arm", "forearm",
                                                "wrist_1", "wrist_2",  "wrist_3"};
  for (int i = 1; i < kNumLinks; ++i) {
    model.X_parent_link_[i] = OriginFromYaml(kinematics, kinematics_file, kJointOrigins[i]);
  }

  // Mesh origins of ur_macro.xacro: base and shoulder rotated by pi about z, upper arm and
  // forearm lifted by the shoulder / elbow offsets, wrists shifted by their visual offsets.
  const double shoulder_offset = Number(physical, physical_file, {"offsets", "shoulder_offset"});
  const double elbow_offset = Number(physical, physical_file, {"offsets", "elbow_offset"});
  const YAML::Node visual = LoadYamlFile(visual_file);
  const double wrist_1_offset =
      Number(visual, visual_file, {"mesh_files", "wrist_1", "visual_offset"});
  const double wrist_2_offset =
      Number(visual, visual_file, {"mesh_files", "wrist_2", "visual_offset"});
  const double wrist_3_offset =
      Number(visual, visual_file, {"mesh_files", "wrist_3", "visual_offset"});
  model.X_link_mesh_[0] = Pose(0, 0, 0, 0, 0, kPi);
  model.X_link_mesh_[1] = Pose(0, 0, 0, 0, 0, kPi);
  model.X_link_mesh_[2] = Pose(0, 0, shoulder_offset, kPi / 2, 0, -kPi / 2);
  model.X_link_mesh_[3] = Pose(0, 0, elbow_offset, kPi / 2, 0, -kPi / 2);
  model.X_link_mesh_[4] = Pose(0, 0, wrist_1_offset, kPi / 2, 0, 0);
  model.X_link_mesh_[5] = Pose(0, 0, wrist_2_offset, 0, 0, 0);
  model.X_link_mesh_[6] = Pose(0, 0, wrist_3_offset, kPi / 2, 0, 0);

  for (int i = 0; i < kNumLinks; ++i) {
    const YAML::Node mesh =
        Child(visual, visual_file, {"mesh_files", kLinkNames[i], "collision", "mesh"});
    if (!mesh.IsScalar()) {
      throw std::runtime_error(visual_file + ": field 'mesh_files." + kLinkNames[i] +
                               ".collision.mesh' is not a string");
    }
    model.mesh_paths_[i] = data_dir + "/collision/" + FileName(mesh.Scalar());
  }
  return model;
}

JointVector Ur10Model::min_position_rad() const {
  JointVector v;
  for (int i = 0; i < kNumJoints; ++i) v[i] = limits_[i].min_position_rad;
  return v;
}
JointVector Ur10Model::max_position_rad() const {
  JointVector v;
  for (int i = 0; i < kNumJoints; ++i) v[i] = limits_[i].max_position_rad;
  return v;
}
JointVector Ur10Model::max_velocity_rad_s() const {
  JointVector v;
  for (int i = 0; i < kNumJoints; ++i) v[i] = limits_[i].max_velocity_rad_s;
  return v;
}
JointVector Ur10Model::max_acceleration_rad_s2() const {
  JointVector v;
  for (int i = 0; i < kNumJoints; ++i) v[i] = limits_[i].max_acceleration_rad_s2;
  return v;
}

bool Ur10Model::WithinPositionLimits(const JointVector& q) const {
  for (int i = 0; i < kNumJoints; ++i) {
    if (!std::isfinite(q[i]) || q[i] < limits_[i].min_position_rad ||
        q[i] > limits_[i].max_position_rad) {
      return false;
    }
  }
  return true;
}

std::string Ur10Model::PositionLimitViolation(const JointVector& q) const {
  for (int i = 0; i < kNumJoints; ++i) {
    if (!std::isfinite(q[i]) || q[i] < limits_[i].min_position_rad ||
        q[i] > limits_[i].max_position_rad) {
      std::ostringstream os;
      os << "joint " << kJointNames[i] << " at " << q[i] << " rad is outside ["
         << limits_[i].min_position_rad << ", " << limits_[i].max_position_rad << "] rad";
      return os.str();
    }
  }
  return {};
}

world::TriangleMesh Ur10Model::LoadCollisionMesh(Link link) const {
  const std::string& path = collision_mesh_path(link);
  if (path.empty()) {
    throw std::runtime_error(std::string("Ur10Model: no collision mesh file for link ") +
                             LinkName(link));
  }
  world::TriangleMesh mesh = ReadStl(path);
  mesh.name = LinkName(link);
  return mesh;
}

namespace {

struct VertexKey {
  float x, y, z;
  bool operator<(const VertexKey& o) const { return std::tie(x, y, z) < std::tie(o.x, o.y, o.z); }
};

class MeshBuilder {
 public:
  void AddTriangle(const std::array<Eigen::Vector3f, 3>& v) {
    std::array<std::uint32_t, 3> tri;
    for (int k = 0; k < 3; ++k) {
      const VertexKey key{v[k].x(), v[k].y(), v[k].z()};
      auto [it, inserted] = index_.emplace(key, static_cast<std::uint32_t>(mesh_.vertices.size()));
      if (inserted) mesh_.vertices.push_back(v[k]);
      tri[k] = it->second;
    }
    mesh_.triangles.push_back(tri);
  }
  world::TriangleMesh Take() { return std::move(mesh_); }

 private:
  world::TriangleMesh mesh_;
  std::map<VertexKey, std::uint32_t> index_;
};

float ReadLeFloat(const unsigned char* p) {
  std::uint32_t bits = static_cast<std::uint32_t>(p[0]) | (static_cast<std::uint32_t>(p[1]) << 8) |
                       (static_cast<std::uint32_t>(p[2]) << 16) |
                       (static_cast<std::uint32_t>(p[3]) << 24);
  float f;
  std::memcpy(&f, &bits, sizeof(f));
  return f;
}

}  // namespace

world::TriangleMesh ReadStl(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path + ": cannot open STL file");
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  MeshBuilder builder;
  if (bytes.size() >= 84) {
    const auto* data = reinterpret_cast<const unsigned char*>(bytes.data());
    const std::uint32_t count =
        static_cast<std::uint32_t>(data[80]) | (static_cast<std::uint32_t>(data[81]) << 8) |
        (static_cast<std::uint32_t>(data[82]) << 16) | (static_cast<std::uint32_t>(data[83]) << 24);
    if (84 + 50ull * count == bytes.size()) {
      for (std::uint32_t t = 0; t < count; ++t) {
        const unsigned char* rec = data + 84 + 50ull * t + 12;  // skip the normal
        std::array<Eigen::Vector3f, 3> v;
        for (int k = 0; k < 3; ++k) {
          v[k] = Eigen::Vector3f(ReadLeFloat(rec + 12 * k), ReadLeFloat(rec + 12 * k + 4),
                                 ReadLeFloat(rec + 12 * k + 8));
          if (!v[k].allFinite()) {
            throw std::runtime_error(path + ": triangle " + std::to_string(t) +
                                     " has a non-finite vertex");
          }
        }
        builder.AddTriangle(v);
      }
      return builder.Take();
    }
  }
  // ASCII STL: "facet normal ... outer loop vertex x y z (x3) endloop endfacet".
  if (bytes.compare(0, 5, "solid") != 0) {
    throw std::runtime_error(path + ": neither a binary STL (size does not match the triangle " +
                             "count) nor an ASCII STL");
  }
  std::istringstream text(bytes);
  std::string word;
  std::array<Eigen::Vector3f, 3> v;
  int k = 0;
  int line_triangles = 0;
  while (text >> word) {
    if (word == "vertex") {
      float x, y, z;
      if (!(text >> x >> y >> z)) {
        throw std::runtime_error(path + ": malformed vertex in triangle " +
                                 std::to_string(line_triangles));
      }
      if (k >= 3) throw std::runtime_error(path + ": facet with more than 3 vertices");
      v[k++] = Eigen::Vector3f(x, y, z);
    } else if (word == "endloop") {
      if (k != 3) throw std::runtime_error(path + ": facet with fewer than 3 vertices");
      builder.AddTriangle(v);
      k = 0;
      ++line_triangles;
    }
  }
  world::TriangleMesh mesh = builder.Take();
  if (mesh.empty()) throw std::runtime_error(path + ": ASCII STL without triangles");
  return mesh;
}

}  // namespace picking::ur10
