#include "services/viewer/core/task_view.h"

#include <cmath>

namespace picking::viewer {
namespace {

constexpr std::size_t kLogLines = 50;

}  // namespace

TaskView::ItemState TaskView::NewItem(const std::string& item, const std::string& bin) {
  ItemState state;
  state.item = item;
  state.bin = bin;
  return state;
}

TaskView::TaskView(const ViewerModel& model, TaskHeader header)
    : model_(model), header_(std::move(header)) {
  for (const auto& [item, bin] : header_.work_order) items_.push_back(NewItem(item, bin));
  last_.state = header_.state;
  last_.items_total = static_cast<int>(items_.size());
}

TaskView::ItemState& TaskView::Item(const std::string& item, const std::string& bin) {
  for (ItemState& s : items_) {
    if (s.item == item && (bin.empty() || s.bin == bin)) return s;
  }
  // Not in the work order the orchestrator listed (an older orchestrator): add it.
  items_.push_back(NewItem(item, bin));
  return items_.back();
}

// The item's state after `event`: the steps of one attempt in order, the last attempt's
// outcome (placed: picked; a failure: failed with its reason) until the next attempt starts.
std::string TaskView::NextState(const ItemState& item, const ViewEvent& event) {
  if (event.step.empty()) return event.ok ? item.state : "failed";
  if (event.step == "scan") return "scanning";
  if (event.step == "detect") return event.detection ? "detected" : "scanning";
  if (event.step == "plan") return event.planned_path_q.empty() ? "detected" : "planned";
  if (event.step == "place") return event.ok && !event.to.empty() ? "picked" : "picking";
  return "picking";  // grasp, verify
}

unsigned TaskView::Apply(const ViewEvent& event) {
  unsigned changed = kTask;
  // The current target's detection is drawn apart from the others.
  if (event.item != last_.item) changed |= kDetections;
  const bool had_items = last_.items_total > 0;
  last_ = event;
  if (!had_items || event.items_total == 0) last_.items_total = static_cast<int>(items_.size());
  log_.push_back({{"time_s", event.time_s},
                  {"item", event.item},
                  {"step", event.step},
                  {"ok", event.ok},
                  {"message", event.message}});
  if (log_.size() > kLogLines) log_.pop_front();
  if (event.item.empty()) return changed;

  ItemState& item = Item(event.item, event.from);
  const std::string state = NextState(item, event);
  if (state == "scanning" && item.state != "scanning") ++item.attempts;
  item.state = state;
  if (state == "failed") item.reason = event.message;
  if (event.detection) {
    item.method = event.detection->method;
    item.score = event.detection->score;
    detections_[event.item] = model_.DetectionJson(event.item, event.detection->X_BaseItem,
                                                   event.detection->score, event.detection->method);
    changed |= kDetections;
  }
  if (state == "picked" && detections_.erase(event.item) > 0) changed |= kDetections;
  if (!event.scan_m.empty()) {
    ++scan_seq_;
    scan_item_ = event.item;
    scan_m_ = event.scan_m;
    changed |= kScan;
  }
  if (!event.planned_path_q.empty()) {
    path_item_ = event.item;
    path_tcp_ = model_.TcpPath(event.planned_path_q, event.planned_head_angle_rad);
    changed |= kPath;
  }
  return changed;
}

nlohmann::json TaskView::TaskJson() const {
  nlohmann::json items = nlohmann::json::array();
  for (const ItemState& s : items_) {
    items.push_back({{"item", s.item},
                     {"bin", s.bin},
                     {"state", s.state},
                     {"reason", s.reason},
                     {"method", s.method},
                     {"score", s.score},
                     {"attempts", s.attempts}});
  }
  nlohmann::json task = {{"task_id", header_.task_id},
                         {"kind", header_.kind},
                         {"state", last_.state},
                         {"items_done", last_.items_done},
                         {"items_total", last_.items_total},
                         {"score", last_.score},
                         {"time_s", last_.time_s},
                         {"time_limit_s", last_.time_limit_s},
                         {"step", last_.step},
                         {"item", last_.item},
                         {"message", last_.message}};
  return {{"task", task}, {"items", items}, {"log", nlohmann::json(log_)}};
}

nlohmann::json TaskView::ScanJson() const {
  if (scan_seq_ == 0) return nullptr;
  // Millimetres are what the page can show; shorter numbers keep a view about 60 KB.
  nlohmann::json points = nlohmann::json::array();
  for (float v : scan_m_) points.push_back(std::round(static_cast<double>(v) * 1000.0) / 1000.0);
  return {{"seq", scan_seq_}, {"item", scan_item_}, {"points_m", std::move(points)}};
}

nlohmann::json TaskView::DetectionsJson() const {
  nlohmann::json out = nlohmann::json::array();
  for (const auto& [item, detection] : detections_) {
    nlohmann::json d = detection;
    d["current"] = item == last_.item;
    out.push_back(std::move(d));
  }
  return out;
}

nlohmann::json TaskView::PathJson() const {
  if (path_tcp_.empty()) return nullptr;
  nlohmann::json points = nlohmann::json::array();
  for (const Eigen::Vector3d& p : path_tcp_) points.push_back({p.x(), p.y(), p.z()});
  return {{"item", path_item_}, {"tcp_m", points}};
}

}  // namespace picking::viewer
