// The files a finished task leaves: the APC output file, a machine-readable report and an
// HTML page a person opens.
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "services/orchestrator/core/task_manager.h"

namespace picking::orchestrator {
namespace fs = std::filesystem;
namespace {

std::string Escape(const std::string& text) {
  std::string out;
  for (char c : text) {
    switch (c) {
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '&':
        out += "&amp;";
        break;
      case '"':
        out += "&quot;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

std::string StateName(TaskState state) {
  switch (state) {
    case TaskState::kRunning:
      return "running";
    case TaskState::kSucceeded:
      return "succeeded";
    case TaskState::kFailed:
      return "failed";
    case TaskState::kCancelled:
      return "cancelled";
  }
  return "";
}

nlohmann::json PoseJson(const Eigen::Isometry3d& X_BaseItem) {
  const Eigen::Vector3d p = X_BaseItem.translation();
  const Eigen::Quaterniond q(X_BaseItem.rotation());
  return {{"position", {p.x(), p.y(), p.z()}}, {"orientation", {q.w(), q.x(), q.y(), q.z()}}};
}

nlohmann::json TargetJson(const TargetReport& t) {
  nlohmann::json j = {{"item", t.item},     {"bin", t.bin},
                      {"ease", t.ease},     {"attempts", t.attempts},
                      {"picked", t.picked}, {"failure", t.failure},
                      {"method", t.method}, {"detection_score", t.detection_score},
                      {"grasp", t.grasp},   {"drop_height_m", t.drop_height_m}};
  if (t.detected) j["X_base_item_detected"] = PoseJson(t.X_BaseItem_detected);
  if (!t.poses_found.empty()) {
    nlohmann::json found = nlohmann::json::array();
    for (const auto& [item, pose] : t.poses_found) {
      nlohmann::json entry = PoseJson(pose.X_BaseItem);
      entry["item"] = item;
      entry["score"] = pose.score;
      found.push_back(std::move(entry));
    }
    j["poses_found"] = std::move(found);
  }
  nlohmann::json steps = nlohmann::json::object();
  for (const auto& [name, seconds] : t.step_times_s) steps[name] = seconds;
  j["step_times_s"] = steps;
  return j;
}

// The viewer's page for one item of a task (names and ids are URL-safe: [a-z0-9_-]).
std::string ViewLink(const std::string& viewer_url, const std::string& task_id,
                     const std::string& item) {
  return viewer_url + (viewer_url.find('?') == std::string::npos ? "?" : "&") + "task=" + task_id +
         "&item=" + item;
}

std::string Html(const std::string& task_id, const PickTaskResult& result,
                 const std::vector<TaskEvent>& events, const std::string& viewer_url) {
  std::ostringstream h;
  h << "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>" << Escape(task_id)
    << "</title><style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
       "td,th{border:1px solid #ccc;padding:4px 8px;text-align:left}.ok{color:#080}"
       ".no{color:#b00}</style></head><body>\n";
  h << "<h1>Task " << Escape(task_id) << "</h1>\n<p>State: <b>" << StateName(result.state) << "</b>"
    << (result.error.empty() ? "" : " (" + Escape(result.error) + ")") << "; score <b>"
    << result.score.total << "</b>; " << result.items_moved << " of " << result.targets.size()
    << " items in the tote; task clock " << result.duration_s
    << " s.</p>\n<h2>Items</h2>\n<table><tr><th>item</th><th>bin</th><th>result</th><th>"
       "attempts</th><th>method (score)</th><th>grasp</th><th>time per step (s)</th></tr>\n";
  for (const TargetReport& t : result.targets) {
    const std::string name = viewer_url.empty()
                                 ? Escape(t.item)
                                 : "<a href=\"" + Escape(ViewLink(viewer_url, task_id, t.item)) +
                                       "\">" + Escape(t.item) + "</a>";
    h << "<tr><td>" << name << "</td><td>" << t.bin << "</td><td class=\""
      << (t.picked ? "ok\">picked" : "no\">" + Escape(t.failure)) << "</td><td>" << t.attempts
      << "</td><td>" << Escape(t.method)
      << (t.detected ? " (" + std::to_string(t.detection_score) + ")" : "") << "</td><td>"
      << Escape(t.grasp) << "</td><td>";
    for (const auto& [name, seconds] : t.step_times_s) h << name << " " << seconds << "; ";
    h << "</td></tr>\n";
  }
  h << "</table>\n<h2>Score</h2>\n<table><tr><th>points</th><th>reason</th></tr>\n";
  for (const apc::ScoreLine& line : result.score.lines) {
    h << "<tr><td>" << line.points << "</td><td>" << Escape(line.reason) << "</td></tr>\n";
  }
  h << "</table>\n<h2>Events</h2>\n<table><tr><th>t (s)</th><th>item</th><th>step</th><th>"
       "message</th></tr>\n";
  for (const TaskEvent& e : events) {
    h << "<tr><td>" << e.time_s << "</td><td>" << Escape(e.item) << "</td><td>" << StepName(e.step)
      << "</td><td class=\"" << (e.ok ? "ok" : "no") << "\">" << Escape(e.message)
      << "</td></tr>\n";
  }
  h << "</table></body></html>\n";
  return h.str();
}

void Write(const fs::path& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
  if (!out) throw std::runtime_error(path.string() + ": write failed");
}

}  // namespace

std::pair<std::string, std::string> WriteTaskFiles(const std::string& dir,
                                                   const std::string& task_id,
                                                   const PickTaskResult& result,
                                                   const std::vector<TaskEvent>& events,
                                                   const std::string& viewer_url) {
  const fs::path output = fs::path(dir) / "output.json";
  apc::WriteTaskFile(output.string(), apc::ToOutput(result.final_contents));
  nlohmann::json report = {{"task_id", task_id},
                           {"state", StateName(result.state)},
                           {"error", result.error},
                           {"score", result.score.total},
                           {"items_moved", result.items_moved},
                           {"items_failed", result.items_failed},
                           {"duration_s", result.duration_s}};
  report["score_lines"] = nlohmann::json::array();
  for (const apc::ScoreLine& line : result.score.lines) {
    report["score_lines"].push_back({{"points", line.points},
                                     {"item", line.item},
                                     {"rule", std::string(apc::ScoreRuleName(line.rule))},
                                     {"reason", line.reason}});
  }
  report["items"] = nlohmann::json::array();
  for (const TargetReport& t : result.targets) {
    report["items"].push_back(TargetJson(t));
    if (!viewer_url.empty()) report["items"].back()["view"] = ViewLink(viewer_url, task_id, t.item);
  }
  Write(fs::path(dir) / "report.json", report.dump(2) + "\n");
  const fs::path html = fs::path(dir) / "report.html";
  Write(html, Html(task_id, result, events, viewer_url));
  return {output.string(), html.string()};
}

}  // namespace picking::orchestrator
