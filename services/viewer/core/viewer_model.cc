#include "services/viewer/core/viewer_model.h"

#include <filesystem>
#include <fstream>
#include <sstream>

#include "libs/world/stl_io.h"

namespace picking::viewer {
namespace {

namespace fs = std::filesystem;

nlohmann::json VectorJson(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }

// A URL for a mesh file: "/files/" + `folder` + its file name.
std::string MeshUrl(const std::string& folder, const std::string& path) {
  return "/files/" + folder + fs::path(path).filename().string();
}

}  // namespace

std::string ReadBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot read '" + path + "'");
  std::ostringstream out;
  out << in.rdbuf();
  return out.str();
}

nlohmann::json PoseJson(const Eigen::Isometry3d& X) {
  nlohmann::json out = nlohmann::json::array();
  const Eigen::Matrix4d& m = X.matrix();
  for (int column = 0; column < 4; ++column) {
    for (int row = 0; row < 4; ++row) out.push_back(m(row, column));
  }
  return out;
}

ViewerModel::ViewerModel(world::CellModel cell, ur10::Ur10Kinematics kinematics,
                         std::shared_ptr<const world::ItemModelLibrary> items)
    : cell_(std::move(cell)), kinematics_(std::move(kinematics)), items_(std::move(items)) {
  const world::CellConfig& config = cell_.config;
  mesh_paths_[MeshUrl("cell/", config.shelf_mesh_path)] = config.shelf_mesh_path;
  if (!config.tote_mesh_path.empty()) {
    mesh_paths_[MeshUrl("cell/", config.tote_mesh_path)] = config.tote_mesh_path;
  }
  for (int i = 0; i < ur10::kNumLinks; ++i) {
    const std::string& path = kinematics_.model().collision_mesh_path(static_cast<ur10::Link>(i));
    if (!path.empty()) mesh_paths_[MeshUrl("ur10/", path)] = path;
  }
}

nlohmann::json ViewerModel::CellJson() const {
  const world::CellConfig& config = cell_.config;
  nlohmann::json bins = nlohmann::json::array();
  for (const world::BinGeometry& bin : cell_.bins) {
    Eigen::Isometry3d X_BaseBin = config.X_BaseShelf * Eigen::Translation3d(bin.inner_S.center());
    bins.push_back({{"name", bin.name},
                    {"X", PoseJson(X_BaseBin)},
                    {"size_m", VectorJson(bin.inner_S.sizes())}});
  }
  const Eigen::AlignedBox3d tote_inner_T = cell_.tote_inner_T();
  nlohmann::json links = nlohmann::json::array();
  for (int i = 0; i < ur10::kNumLinks; ++i) {
    const auto link = static_cast<ur10::Link>(i);
    const std::string& path = kinematics_.model().collision_mesh_path(link);
    links.push_back(
        {{"name", ur10::LinkName(link)},
         {"mesh", path.empty() ? nlohmann::json() : nlohmann::json(MeshUrl("ur10/", path))}});
  }
  return {
      {"shelf",
       {{"mesh", MeshUrl("cell/", config.shelf_mesh_path)}, {"X", PoseJson(config.X_BaseShelf)}}},
      {"tote",
       {{"mesh", config.tote_mesh_path.empty()
                     ? nlohmann::json()
                     : nlohmann::json(MeshUrl("cell/", config.tote_mesh_path))},
        {"X", PoseJson(config.X_BaseTote)},
        {"inner_X", PoseJson(config.X_BaseTote * Eigen::Translation3d(tote_inner_T.center()))},
        {"inner_size_m", VectorJson(tote_inner_T.sizes())}}},
      {"table", {{"X", PoseJson(config.X_BaseTable)}, {"size_m", VectorJson(config.table_size_m)}}},
      {"bins", bins},
      {"arm", {{"links", links}}},
  };
}

nlohmann::json ViewerModel::ArmJson(const ur10::JointVector& q_rad,
                                    const std::optional<Eigen::Vector3d>& p_Base_tcp) const {
  const auto X_BaseLinks = kinematics_.LinkFrames(q_rad);
  nlohmann::json links = nlohmann::json::array();
  for (int i = 0; i < ur10::kNumLinks; ++i) {
    links.push_back(
        PoseJson(X_BaseLinks[i] * kinematics_.model().X_LinkMesh(static_cast<ur10::Link>(i))));
  }
  const world::GripperConfig& gripper = cell_.config.gripper;
  const Eigen::Isometry3d X_BaseTool = kinematics_.ForwardKinematics(q_rad);
  const Eigen::Vector3d p_Base_joint = X_BaseTool * gripper.p_ToolJoint();
  const Eigen::Vector3d p_Base_lip =
      p_Base_tcp ? *p_Base_tcp : Eigen::Vector3d(X_BaseTool * gripper.X_ToolTcp.translation());
  nlohmann::json tube = nlohmann::json::array();
  tube.push_back({{"from", VectorJson(X_BaseTool.translation())},
                  {"to", VectorJson(p_Base_joint)},
                  {"radius_m", gripper.tube_radius_m}});
  if ((p_Base_lip - p_Base_joint).norm() > 1e-6) {
    tube.push_back({{"from", VectorJson(p_Base_joint)},
                    {"to", VectorJson(p_Base_lip)},
                    {"radius_m", gripper.tube_radius_m}});
  }
  nlohmann::json q = nlohmann::json::array();
  for (int i = 0; i < 6; ++i) q.push_back(q_rad[i]);
  return {{"q", q}, {"links", links}, {"gripper", tube}};
}

std::vector<Eigen::Vector3d> ViewerModel::TcpPath(const std::vector<std::array<double, 6>>& path_q,
                                                  double head_angle_rad) const {
  const Eigen::Isometry3d X_ToolTcp = cell_.config.gripper.X_ToolTcpAt(head_angle_rad);
  std::vector<Eigen::Vector3d> out;
  out.reserve(path_q.size());
  for (const auto& q : path_q) {
    const ur10::JointVector joints = Eigen::Map<const ur10::JointVector>(q.data());
    out.push_back((kinematics_.ForwardKinematics(joints) * X_ToolTcp).translation());
  }
  return out;
}

nlohmann::json ViewerModel::DetectionJson(const std::string& item,
                                          const Eigen::Isometry3d& X_BaseItem, double score,
                                          const std::string& method) const {
  nlohmann::json out = {{"item", item},
                        {"method", method},
                        {"score", score},
                        {"X", PoseJson(X_BaseItem)},
                        {"model", nullptr},
                        {"box_m", {0.05, 0.05, 0.05}},
                        {"box_center_m", {0.0, 0.0, 0.0}}};
  if (items_ && items_->catalogue().find(item) != nullptr) {
    try {
      const std::shared_ptr<const world::ItemModel> model = items_->Get(item);
      out["model"] = "/files/items/" + item + ".stl";
      out["box_m"] = VectorJson(model->box_I.sizes());
      out["box_center_m"] = VectorJson(model->box_I.center());
    } catch (const std::exception&) {
      // A model that cannot be built (an unreadable scan file): the item is drawn as a box.
    }
  }
  return out;
}

std::optional<ServedFile> ViewerModel::File(const std::string& url) const {
  const auto fixed = mesh_paths_.find(url);
  if (fixed != mesh_paths_.end()) return ServedFile{"model/stl", ReadBytes(fixed->second)};
  const std::string prefix = "/files/items/", suffix = ".stl";
  if (!items_ || url.size() <= prefix.size() + suffix.size() || url.rfind(prefix, 0) != 0 ||
      url.compare(url.size() - suffix.size(), suffix.size(), suffix) != 0) {
    return std::nullopt;
  }
  const std::string item = url.substr(prefix.size(), url.size() - prefix.size() - suffix.size());
  if (items_->catalogue().find(item) == nullptr) return std::nullopt;
  std::shared_ptr<const std::string> bytes;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = item_stl_.find(item);
    if (it != item_stl_.end()) bytes = it->second;
  }
  if (!bytes) {
    bytes = std::make_shared<const std::string>(world::EncodeStlBinary(items_->Get(item)->mesh));
    std::lock_guard<std::mutex> lock(mutex_);
    item_stl_.emplace(item, bytes);
  }
  return ServedFile{"model/stl", *bytes};
}

}  // namespace picking::viewer
