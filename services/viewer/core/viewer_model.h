#pragma once

#include <Eigen/Geometry>

#include <array>
#include <map>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "libs/ur10/kinematics.h"
#include "libs/world/cell_config.h"
#include "libs/world/item_models.h"

namespace picking::viewer {

/// The whole file at `path`; throws std::runtime_error naming it when it cannot be read.
std::string ReadBytes(const std::string& path);

/// A 4x4 pose as the page takes it: 16 numbers, column-major (three.js Matrix4.fromArray).
nlohmann::json PoseJson(const Eigen::Isometry3d& X);

/// A file the page may load, served under its URL.
struct ServedFile {
  std::string content_type;
  std::string bytes;
};

/// What the viewer knows of the cell without asking anyone: the cell description every
/// service loads (shelf, tote, table, bins, gripper), the UR10's links and meshes, and the
/// item models the detector and the simulator use. Turns joint angles into what the page
/// draws. Thread-safe (item meshes are built on first request and kept).
class ViewerModel final {
 public:
  ViewerModel(world::CellModel cell, ur10::Ur10Kinematics kinematics,
              std::shared_ptr<const world::ItemModelLibrary> items);

  /// The static cell for the page: shelf, tote and table poses and meshes, the bins, the
  /// arm's link meshes (GET /api/cell).
  nlohmann::json CellJson() const;

  /// The arm at joints `q_rad`: every link mesh's pose, and the gripper's tube from the
  /// flange to the head's joint and the head from there to `p_Base_tcp` (where the robot
  /// says its tool centre point is: that follows the head's angle).
  nlohmann::json ArmJson(const ur10::JointVector& q_rad,
                         const std::optional<Eigen::Vector3d>& p_Base_tcp) const;

  /// The tool centre point along joint waypoints, with the head at `head_angle_rad`.
  std::vector<Eigen::Vector3d> TcpPath(const std::vector<std::array<double, 6>>& path_q,
                                       double head_angle_rad) const;

  /// A detected item for the page: its pose, score and method, its model's URL and the
  /// bounds of the model in the item frame. Unknown items are drawn as a 5 cm box.
  nlohmann::json DetectionJson(const std::string& item, const Eigen::Isometry3d& X_BaseItem,
                               double score, const std::string& method) const;

  /// The file served at `url` ("/files/..."), or nullopt: only the cell's and the arm's
  /// meshes and the catalogue's item models are served, nothing else from the disk.
  std::optional<ServedFile> File(const std::string& url) const;

  const world::CellModel& cell() const { return cell_; }

 private:
  world::CellModel cell_;
  ur10::Ur10Kinematics kinematics_;
  std::shared_ptr<const world::ItemModelLibrary> items_;
  std::map<std::string, std::string> mesh_paths_;  ///< URL -> file, for the fixed meshes.
  mutable std::mutex mutex_;
  mutable std::map<std::string, std::shared_ptr<const std::string>> item_stl_;
};

}  // namespace picking::viewer
