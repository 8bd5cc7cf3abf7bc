#pragma once

#include <Eigen/Geometry>

#include <array>
#include <deque>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "services/viewer/core/viewer_model.h"

namespace picking::viewer {

/// One orchestrator progress event, as the viewer reads it (the adapter converts the
/// contract's TaskEvent into this).
struct ViewEvent {
  double time_s = 0.0;
  std::string item, from, to;
  std::string step;  ///< "scan", "detect", "plan", "grasp", "verify", "place" or "".
  bool ok = true;
  std::string message;
  int items_done = 0, items_total = 0;
  std::string state = "running";  ///< running, succeeded, failed, cancelled.
  int score = 0;
  double time_limit_s = 0.0;
  std::vector<float> scan_m;  ///< A view's points: x, y, z, ... (base frame).
  struct Found {
    Eigen::Isometry3d X_BaseItem = Eigen::Isometry3d::Identity();
    double score = 0.0;
    std::string method;
  };
  std::optional<Found> detection;
  std::vector<std::array<double, 6>> planned_path_q;
  double planned_head_angle_rad = 0.0;
};

/// The task as the orchestrator lists it.
struct TaskHeader {
  std::string task_id;
  std::string kind = "pick";
  std::string state = "running";
  std::vector<std::pair<std::string, std::string>> work_order;  ///< (item, container).
};

/// The state of one task as the page shows it, folded from its events: each target's state
/// (waiting, scanning, detected, planned, picking, picked, failed with the reason), the step
/// under way, the score and the clock, the latest scan view, where each target was found,
/// and the last planned path. Not thread-safe: the owner serialises access.
class TaskView final {
 public:
  /// Which parts of the page an event changed.
  enum Part : unsigned { kTask = 1, kScan = 2, kDetections = 4, kPath = 8 };

  TaskView(const ViewerModel& model, TaskHeader header);

  /// Folds one event in; returns the parts it changed (a mask of Part).
  unsigned Apply(const ViewEvent& event);

  /// {"task": {...}, "items": [...], "log": [...]}.
  nlohmann::json TaskJson() const;
  /// {"seq", "item", "points_m"} or null before the first view.
  nlohmann::json ScanJson() const;
  /// Where each target still in its container was last found.
  nlohmann::json DetectionsJson() const;
  /// {"item", "tcp_m"} or null before the first plan.
  nlohmann::json PathJson() const;

  const TaskHeader& header() const { return header_; }

 private:
  struct ItemState {
    std::string item, bin;
    std::string state = "waiting";
    std::string reason, method;
    double score = 0.0;
    int attempts = 0;
  };
  static ItemState NewItem(const std::string& item, const std::string& bin);
  ItemState& Item(const std::string& item, const std::string& bin);
  static std::string NextState(const ItemState& item, const ViewEvent& event);

  const ViewerModel& model_;
  TaskHeader header_;
  std::vector<ItemState> items_;
  ViewEvent last_;  ///< The latest event's task-level fields.
  std::deque<nlohmann::json> log_;
  int scan_seq_ = 0;
  std::string scan_item_;
  std::vector<float> scan_m_;
  std::map<std::string, nlohmann::json> detections_;
  std::string path_item_;
  std::vector<Eigen::Vector3d> path_tcp_;
};

}  // namespace picking::viewer
