#include "services/orchestrator/core/pick_task.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <optional>
#include <set>
#include <thread>

namespace picking::orchestrator {
namespace {

using Clock = std::chrono::steady_clock;

// A scan view as events carry it for a viewer: enough to see the bin's contents, small
// enough to journal every view of a task (about 60 KB each).
constexpr std::size_t kViewerScanPoints = 4000;

double Seconds(Clock::time_point since) {
  return std::chrono::duration<double>(Clock::now() - since).count();
}

void RemoveOne(std::vector<std::string>& items, const std::string& item) {
  const auto it = std::find(items.begin(), items.end(), item);
  if (it != items.end()) items.erase(it);
}

}  // namespace

std::string StepName(Step step) {
  switch (step) {
    case Step::kScan:
      return "scan";
    case Step::kDetect:
      return "detect";
    case Step::kPlan:
      return "plan";
    case Step::kGrasp:
      return "grasp";
    case Step::kVerify:
      return "verify";
    case Step::kPlace:
      return "place";
    case Step::kNone:
      break;
  }
  return "";
}

apc::ScoreReport ScoreBelief(const apc::Task& initial, const std::vector<apc::Event>& events,
                             const apc::Task& contents, const apc::Catalogue& catalogue) {
  apc::ScoringInput input;
  input.initial = initial;
  input.events = events;
  input.reported = apc::ToOutput(contents);
  input.true_final = contents;
  return apc::Score(input, catalogue);
}

PickTaskRunner::PickTaskRunner(apc::Task task, std::vector<Target> order,
                               const apc::Catalogue& catalogue, PickTaskOptions options,
                               CellPort& cell, Journal& journal,
                               std::function<void(const TaskEvent&)> emit,
                               const std::atomic<bool>& cancel)
    : task_(std::move(task)),
      contents_(task_),
      order_(std::move(order)),
      catalogue_(catalogue),
      options_(std::move(options)),
      cell_(cell),
      journal_(journal),
      emit_(std::move(emit)),
      cancel_(cancel) {}

std::string PickTaskRunner::Key(const Target& target, const std::string& action) const {
  const std::string kind = target.making_room                   ? "room/"
                           : task_.kind == apc::TaskKind::kStow ? "stow/"
                                                                : "pick/";
  const std::string copy = target.copy == 0 ? "" : "#" + std::to_string(target.copy);
  return kind + target.bin + "/" + target.item + copy + "/" + std::to_string(target.attempts) +
         "/" + action;
}

namespace {

// Catalogue volume of what `contents` holds in `bin`, m^3.
double HeldVolumeM3(const apc::Task& contents, const std::string& bin,
                    const apc::Catalogue& catalogue) {
  double held_m3 = 0.0;
  const auto held = contents.bin_contents.find(bin);
  if (held != contents.bin_contents.end()) {
    for (const std::string& item : held->second) held_m3 += catalogue.at(item).volume_cm3 * 1e-6;
  }
  return held_m3;
}

// The catalogue's box of `item`: long, middle and short side, metres.
Eigen::Vector3d CatalogueBoxM(const apc::Catalogue& catalogue, const std::string& item) {
  const apc::Item& it = catalogue.at(item);
  return Eigen::Vector3d(it.long_side_m, it.middle_side_m, it.short_side_m);
}

}  // namespace

std::vector<std::string> StowBins(const std::string& item, const apc::Task& initial,
                                  const apc::Task& contents, const apc::Catalogue& catalogue,
                                  const std::map<std::string, double>& bin_volume_m3,
                                  double max_fill) {
  struct Candidate {
    std::string bin;
    int points;
    double free_m3;
  };
  std::vector<Candidate> candidates;
  const double item_m3 = catalogue.at(item).volume_cm3 * 1e-6;
  for (const auto& [bin, volume_m3] : bin_volume_m3) {
    const double used_m3 = item_m3 + HeldVolumeM3(contents, bin, catalogue);
    if (used_m3 > max_fill * volume_m3) continue;
    const auto at_start = initial.bin_contents.find(bin);
    const std::size_t n = at_start == initial.bin_contents.end() ? 0 : at_start->second.size();
    const int points = n >= 5 ? 20 : n >= 3 ? 15 : 10;
    candidates.push_back({bin, points, volume_m3 - used_m3});
  }
  std::sort(candidates.begin(), candidates.end(), [](const Candidate& a, const Candidate& b) {
    if (a.points != b.points) return a.points > b.points;
    if (a.free_m3 != b.free_m3) return a.free_m3 > b.free_m3;
    return a.bin < b.bin;
  });
  std::vector<std::string> out;
  for (const Candidate& c : candidates) out.push_back(c.bin);
  return out;
}

std::vector<Eigen::Vector3f> ThinPoints(const geometry::PointCloud& cloud, std::size_t max_points) {
  std::vector<Eigen::Vector3f> valid;
  valid.reserve(cloud.points.size());
  for (const Eigen::Vector3f& p : cloud.points) {
    if (p.allFinite()) valid.push_back(p);
  }
  if (valid.size() <= max_points) return valid;
  std::vector<Eigen::Vector3f> out;
  out.reserve(max_points);
  const double step = static_cast<double>(valid.size()) / static_cast<double>(max_points);
  for (std::size_t i = 0; i < max_points; ++i) {
    out.push_back(valid[static_cast<std::size_t>(static_cast<double>(i) * step)]);
  }
  return out;
}

namespace {

// Journal numbers are rounded so that a scan of 4,000 points stays about 60 KB of text.
double Rounded(double value, double unit) { return std::round(value / unit) * unit; }

}  // namespace

nlohmann::json EventScene::ToJson() const {
  nlohmann::json out = nlohmann::json::object();
  if (!scan_Base.empty()) {
    std::vector<int> mm;
    mm.reserve(scan_Base.size() * 3);
    for (const Eigen::Vector3f& p : scan_Base) {
      for (int k = 0; k < 3; ++k) mm.push_back(static_cast<int>(std::lround(p[k] * 1000.0f)));
    }
    out["scan_mm"] = std::move(mm);
  }
  if (detected) {
    const Eigen::Quaterniond q(X_BaseItem.rotation());
    const Eigen::Vector3d& t = X_BaseItem.translation();
    out["detection"] = {{"position_m", {t.x(), t.y(), t.z()}},
                        {"orientation_wxyz", {q.w(), q.x(), q.y(), q.z()}},
                        {"score", detection_score},
                        {"method", method}};
  }
  if (!planned_path_q.empty()) {
    nlohmann::json path = nlohmann::json::array();
    for (const auto& q : planned_path_q) {
      nlohmann::json row = nlohmann::json::array();
      for (double v : q) row.push_back(Rounded(v, 1e-5));
      path.push_back(std::move(row));
    }
    out["path_rad"] = std::move(path);
    out["head_angle_rad"] = head_angle_rad;
  }
  return out;
}

EventScene EventScene::FromJson(const nlohmann::json& json) {
  EventScene scene;
  if (!json.is_object()) return scene;
  if (json.contains("scan_mm")) {
    const std::vector<int> mm = json.at("scan_mm").get<std::vector<int>>();
    for (std::size_t i = 0; i + 2 < mm.size(); i += 3) {
      scene.scan_Base.emplace_back(mm[i] * 1e-3f, mm[i + 1] * 1e-3f, mm[i + 2] * 1e-3f);
    }
  }
  if (json.contains("detection")) {
    const nlohmann::json& d = json.at("detection");
    const auto t = d.at("position_m").get<std::vector<double>>();
    const auto q = d.at("orientation_wxyz").get<std::vector<double>>();
    if (t.size() == 3 && q.size() == 4) {
      scene.detected = true;
      scene.X_BaseItem = Eigen::Isometry3d::Identity();
      scene.X_BaseItem.translation() = Eigen::Vector3d(t[0], t[1], t[2]);
      scene.X_BaseItem.linear() =
          Eigen::Quaterniond(q[0], q[1], q[2], q[3]).normalized().toRotationMatrix();
      scene.detection_score = d.value("score", 0.0);
      scene.method = d.value("method", "");
    }
  }
  if (json.contains("path_rad")) {
    for (const nlohmann::json& row : json.at("path_rad")) {
      const auto q = row.get<std::vector<double>>();
      if (q.size() != 6) continue;
      std::array<double, 6> joints{};
      std::copy(q.begin(), q.end(), joints.begin());
      scene.planned_path_q.push_back(joints);
    }
    scene.head_angle_rad = json.value("head_angle_rad", 0.0);
  }
  return scene;
}

double BoxOverlapFraction(const Eigen::Isometry3d& X_BaseA, const Eigen::Vector3d& size_a_m,
                          const Eigen::Isometry3d& X_BaseB, const Eigen::Vector3d& size_b_m) {
  const bool a_smaller = size_a_m.prod() <= size_b_m.prod();
  const Eigen::Isometry3d& X_small = a_smaller ? X_BaseA : X_BaseB;
  const Eigen::Vector3d half_small = 0.5 * (a_smaller ? size_a_m : size_b_m);
  const Eigen::Isometry3d X_LargeSmall = (a_smaller ? X_BaseB : X_BaseA).inverse() * X_small;
  const Eigen::Vector3d half_large = 0.5 * (a_smaller ? size_b_m : size_a_m);
  constexpr int kSteps = 6;  // cell centres of a 6 x 6 x 6 grid over the smaller box
  int inside = 0;
  for (int i = 0; i < kSteps; ++i) {
    for (int j = 0; j < kSteps; ++j) {
      for (int k = 0; k < kSteps; ++k) {
        const Eigen::Vector3d f((i + 0.5) / kSteps, (j + 0.5) / kSteps, (k + 0.5) / kSteps);
        const Eigen::Vector3d p_Small = (2.0 * f.array() - 1.0).matrix().cwiseProduct(half_small);
        const Eigen::Vector3d p_Large = X_LargeSmall * p_Small;
        inside += (p_Large.cwiseAbs().array() <= half_large.array()).all();
      }
    }
  }
  return double(inside) / (kSteps * kSteps * kSteps);
}

std::string ResolveAgainstOthers(const std::string& item, Detection* found,
                                 const apc::Catalogue& catalogue, double min_overlap, double margin,
                                 std::vector<std::string>* rivals) {
  auto size = [&](const std::string& name) { return CatalogueBoxM(catalogue, name); };
  const Eigen::Vector3d size_item = size(item);
  // Why `pose` of the target is doubtful, or ""; the items that fill its place into `who`.
  auto doubt = [&](const PoseHypothesis& pose, std::vector<std::string>* who) -> std::string {
    std::string why;
    for (const OtherDetection& other : found->others) {
      if (other.item == item || other.poses.empty()) continue;
      const PoseHypothesis& best = other.poses.front();
      if (best.score < pose.score - margin) continue;
      const Eigen::Vector3d size_other = size(other.item);
      const double overlap =
          BoxOverlapFraction(pose.X_BaseItem, size_item, best.X_BaseItem, size_other);
      // (That the other item also has a pose elsewhere about as good does not clear the
      // doubt: two cylinders or two flat boxes fit each other's places both ways round, and
      // a wrong item in the tote costs more than a target left for later.)
      if (overlap < min_overlap) continue;
      if (who) who->push_back(other.item);
      if (!why.empty()) continue;
      char text[300];
      std::snprintf(text, sizeof(text),
                    "the place %s was found at holds %s as well (score %.2f against %.2f, %.0f%% "
                    "of the smaller box shared): one of the two poses is wrong",
                    item.c_str(), other.item.c_str(), best.score, pose.score, 100.0 * overlap);
      why = text;
    }
    return why;
  };
  std::vector<PoseHypothesis> poses = {{found->X_BaseItem, found->score}};
  poses.insert(poses.end(), found->alternatives.begin(), found->alternatives.end());
  std::string first_doubt;
  for (std::size_t k = 0; k < poses.size(); ++k) {
    const std::string why = doubt(poses[k], k == 0 ? rivals : nullptr);
    if (why.empty()) {
      found->X_BaseItem = poses[k].X_BaseItem;
      found->score = poses[k].score;
      if (rivals) rivals->clear();
      return "";
    }
    if (first_doubt.empty()) first_doubt = why;
  }
  return first_doubt;
}

std::vector<std::string> PickTaskRunner::OtherItemsIn(const std::string& container,
                                                      const std::string& item) const {
  const auto bin = contents_.bin_contents.find(container);
  const std::vector<std::string> none;
  const std::vector<std::string>& in_container = container == apc::kToteLocation
                                                     ? contents_.tote_contents
                                                 : bin != contents_.bin_contents.end() ? bin->second
                                                                                       : none;
  std::vector<std::string> others;
  for (const std::string& other : in_container) {
    if (other != item && std::find(others.begin(), others.end(), other) == others.end()) {
      others.push_back(other);
    }
  }
  return others;
}

int PickTaskRunner::PlacedIn(const std::string& container) const {
  int placed = 0;
  for (const apc::Event& e : events_) {
    placed += e.kind == apc::EventKind::kMove && e.to == container;
  }
  return placed;
}

std::vector<std::string> PickTaskRunner::RoomBins(const std::string& item,
                                                  const std::string& from) const {
  // (free volume, bin), roomiest first: StowBins puts a stow's points first, which mean
  // nothing here.
  std::vector<std::pair<double, std::string>> by_room;
  for (const std::string& bin : StowBins(item, task_, contents_, catalogue_, options_.bin_volume_m3,
                                         options_.max_bin_fill)) {
    const bool target_left = std::any_of(order_.begin(), order_.end(), [&](const Target& t) {
      return t.bin == bin && !t.done && !t.given_up;
    });
    if (bin == from || target_left) continue;
    by_room.emplace_back(options_.bin_volume_m3.at(bin) - HeldVolumeM3(contents_, bin, catalogue_),
                         bin);
  }
  std::stable_sort(by_room.begin(), by_room.end(),
                   [](const auto& a, const auto& b) { return a.first > b.first; });
  std::vector<std::string> bins;
  for (const auto& [free_m3, bin] : by_room) bins.push_back(bin);
  return bins;
}

std::vector<std::string> PickTaskRunner::Destinations(const Target& target) const {
  if (target.making_room) return RoomBins(target.item, target.bin);
  if (task_.kind != apc::TaskKind::kStow) return {apc::kToteLocation};
  return StowBins(target.item, task_, contents_, catalogue_, options_.bin_volume_m3,
                  options_.max_bin_fill);
}

void PickTaskRunner::Emit(const Target* target, Step step, bool ok, const std::string& message,
                          const std::string& to, EventScene scene) {
  TaskEvent event;
  event.time_s = clock_s_;
  if (target != nullptr) event.item = target->item, event.from = target->bin;
  event.to = to;
  event.step = step;
  event.ok = ok;
  event.message = message;
  event.items_done = done_;
  event.items_total = static_cast<int>(order_.size());
  event.score = ScoreBelief(task_, events_, contents_, catalogue_).total;
  event.time_limit_s = options_.time_limit_s;
  event.scene = std::move(scene);
  nlohmann::json record = {{"item", event.item},
                           {"from", event.from},
                           {"to", event.to},
                           {"step", StepName(step)},
                           {"ok", ok},
                           {"message", message},
                           {"done", done_},
                           {"total", event.items_total},
                           {"score", event.score},
                           {"time_limit_s", event.time_limit_s}};
  nlohmann::json scene_json = event.scene.ToJson();
  if (!scene_json.empty()) record["scene"] = std::move(scene_json);
  journal_.Append("event", "", clock_s_, std::move(record));
  event.sequence = next_event_++;
  if (emit_) emit_(event);
}

template <typename F>
auto PickTaskRunner::WithRetries(const std::string& what, F&& operation) -> decltype(operation()) {
  double wait_s = options_.backoff_s;
  for (int attempt = 0;; ++attempt) {
    try {
      return operation();
    } catch (const CellError& e) {
      if (!e.retryable() || attempt >= options_.service_retries || TimeLeft() < wait_s) throw;
      Emit(nullptr, Step::kNone, false,
           what + ": " + e.what() + "; retrying in " + std::to_string(wait_s) + " s");
      std::this_thread::sleep_for(std::chrono::duration<double>(wait_s));
      clock_s_ += wait_s;
      wait_s *= 2.0;
    }
  }
}

void PickTaskRunner::AddTime(TargetReport& report, const std::string& step, double seconds) {
  clock_s_ += seconds;
  for (auto& [name, total] : report.step_times_s) {
    if (name == step) {
      total += seconds;
      return;
    }
  }
  report.step_times_s.emplace_back(step, seconds);
}

void PickTaskRunner::RecordPlaced(const Target& target, const std::string& to,
                                  double drop_height_m) {
  if (target.bin == apc::kToteLocation) {
    RemoveOne(contents_.tote_contents, target.item);
  } else {
    RemoveOne(contents_.bin_contents[target.bin], target.item);
  }
  if (to == apc::kToteLocation) {
    contents_.tote_contents.push_back(target.item);
  } else {
    contents_.bin_contents[to].push_back(target.item);
  }
  events_.push_back(apc::MoveEvent(target.item, target.bin, to));
  if (drop_height_m > 0.0) events_.push_back(apc::DropEvent(target.item, drop_height_m));
  if (!target.making_room) ++done_;
}

void PickTaskRunner::RecordLost(Target& target, const std::string& reason) {
  if (target.bin == apc::kToteLocation) {
    RemoveOne(contents_.tote_contents, target.item);
  } else {
    RemoveOne(contents_.bin_contents[target.bin], target.item);
  }
  events_.push_back(apc::OutsideEvent(target.item, target.bin));
  target.given_up = true;
  target.last_failure = reason;
}

// Actions the journal shows as done are not repeated: placed targets count as picked, and an
// attempt that grasped but never placed may still hold its item (FinishCarriedItem).
void PickTaskRunner::ResumeFromJournal() {
  // The journal read once, its action records by (type, key).
  JournalActions actions;
  const std::vector<JournalRecord> records = journal_.Records();
  for (const JournalRecord& r : records) {
    clock_s_ = std::max(clock_s_, r.time_s);
    if (r.type == "event") ++next_event_;  // a resumed task's events continue its numbering
    if (!r.key.empty()) actions[{r.type, r.key}] = &r;
  }
  auto has = [&](const char* type, const std::string& key) { return actions.count({type, key}); };
  ResumeRoomMoves(records, actions);
  for (Target& target : order_) {
    for (int attempt = 1; attempt <= options_.max_attempts + 1; ++attempt) {
      target.attempts = attempt;
      if (const auto placed = actions.find({"done", Key(target, "place")});
          placed != actions.end()) {
        target.done = true;
        RecordPlaced(target, placed->second->data.value("to", std::string(apc::kToteLocation)),
                     placed->second->data.value("drop_height_m", 0.0));
        break;
      }
      if (const auto lost = actions.find({"lost", Key(target, "place")}); lost != actions.end()) {
        RecordLost(target, lost->second->data.value("reason", std::string("let go on the way")));
        break;
      }
      if (has("begin", Key(target, "grasp")) && !has("failed", Key(target, "grasp"))) {
        carried_key_ = Key(target, "");
      }
      // Set down on the table and not yet told apart: the cup no longer holds it.
      if (const auto table = actions.find({"done", Key(target, "table")});
          table != actions.end() && !has("failed", Key(target, "table"))) {
        if (carried_key_ == Key(target, "")) carried_key_.clear();
        table_key_ = Key(target, "");
        table_candidates_ =
            table->second->data.value("candidates", std::vector<std::string>{target.item});
      }
      if (!has("begin", Key(target, "scan"))) {
        target.attempts = attempt - 1;
        break;
      }
    }
  }
}

namespace {

// The item moved aside that a "room/<bin>/<item>/<n>/<action>" journal key names: the key
// without its action, and the mover (nullopt for another key).
std::optional<std::pair<std::string, Target>> RoomMoveOf(const std::string& key) {
  if (key.rfind("room/", 0) != 0) return std::nullopt;
  std::vector<std::string> parts;
  std::size_t from = 0;
  for (std::size_t at = key.find('/'); at != std::string::npos; at = key.find('/', from)) {
    parts.push_back(key.substr(from, at - from));
    from = at + 1;
  }
  parts.push_back(key.substr(from));
  if (parts.size() != 5) return std::nullopt;
  Target mover{parts[2], parts[1], 0, 0.0};
  if (const std::size_t hash = mover.item.find('#'); hash != std::string::npos) {
    mover.copy = std::stoi(mover.item.substr(hash + 1));
    mover.item.resize(hash);
  }
  mover.making_room = true;
  mover.attempts = std::stoi(parts[3]);
  return std::make_pair(key.substr(0, key.size() - parts[4].size()), mover);
}

}  // namespace

// Items moved aside before the restart are where they went (or lost); one still on the cup
// is finished by FinishCarriedItem. Their numbering continues.
void PickTaskRunner::ResumeRoomMoves(const std::vector<JournalRecord>& records,
                                     const JournalActions& actions) {
  auto find = [&](const char* type, const std::string& key) -> const JournalRecord* {
    const auto it = actions.find({type, key});
    return it == actions.end() ? nullptr : it->second;
  };
  // In the journal's order: an item moved twice ends where the second move took it.
  std::set<std::string> seen;
  for (const JournalRecord& r : records) {
    const auto move = RoomMoveOf(r.key);
    if (!move || !seen.insert(move->first).second) continue;
    Target mover = move->second;
    room_moves_ = std::max(room_moves_, mover.attempts);
    const std::string place = Key(mover, "place");
    if (const JournalRecord* done = find("done", place)) {
      RecordPlaced(mover, done->data.value("to", std::string()),
                   done->data.value("drop_height_m", 0.0));
    }
    if (const JournalRecord* lost = find("lost", place)) {
      RecordLost(mover, lost->data.value("reason", std::string("let go")));
    }
    const bool ended = find("done", place) || find("lost", place) || find("failed", place);
    if (!ended && find("begin", Key(mover, "grasp")) && !find("failed", Key(mover, "grasp"))) {
      carried_room_ = mover;
    }
  }
}

// At resume an item of an interrupted stow attempt may lie on the table: it is told apart
// and stowed (or put back) as that attempt would have.
void PickTaskRunner::FinishItemOnTable() {
  if (table_key_.empty()) return;
  for (std::size_t i = 0; i < order_.size(); ++i) {
    Target& target = order_[i];
    if (target.done || Key(target, "") != table_key_) continue;
    const Attempt attempt = IdentifyAndStow(target, (*reports_)[i], table_candidates_);
    target.done = attempt == Attempt::kPicked;
    if (attempt == Attempt::kLostCarried) RecordLost(target, target.last_failure);
    return;
  }
}

// At resume the gripper may still hold the item of an interrupted attempt: carry it on to the
// tote if the vacuum still holds it, else it fell back (the attempt counts as failed).
void PickTaskRunner::FinishCarriedItem() {
  if (carried_room_) {
    Target mover = *carried_room_;
    carried_room_.reset();
    FinishCarried(mover);
  }
  if (carried_key_.empty()) return;
  for (Target& target : order_) {
    if (!target.done && Key(target, "") == carried_key_) {
      FinishCarried(target);
      return;
    }
  }
}

void PickTaskRunner::FinishCarried(Target& target) {
  const SealReading seal = WithRetries("gripper", [&] { return cell_.ReadSeal(); });
  if (!seal.attached) {
    journal_.Append("failed", Key(target, "grasp"), clock_s_,
                    {{"reason", "not held after the restart"}});
    return;
  }
  journal_.Append("begin", Key(target, "place"), clock_s_);
  for (const std::string& to : Destinations(target)) {
    const PlaceOutcome placed =
        WithRetries("place", [&] { return cell_.MoveToPlace(target.item, to, {}, PlacedIn(to)); });
    clock_s_ += placed.robot_s;
    if (!placed.ok) continue;
    cell_.VacuumOff();
    journal_.Append("done", Key(target, "place"), clock_s_,
                    {{"drop_height_m", placed.drop_height_m}, {"to", to}});
    target.done = true;
    RecordPlaced(target, to, placed.drop_height_m);
    Emit(&target, Step::kPlace, true, "placed in " + to + " after the restart", to);
    return;
  }
  cell_.VacuumOff();  // nowhere to go: let go where the arm is; the item counts as lost
}

bool PickTaskRunner::ScanViews(Target& target, TargetReport& report, std::vector<ScanView>& views) {
  Emit(&target, Step::kScan, true, "scanning " + target.bin);
  std::string missing;  // the first view missing, and why
  // Each view's capture holds the arm; its decoding runs on while the arm moves to the next.
  struct Pending {
    std::string pose;
    std::shared_future<ScanView> view;
    double held_s;  // the arm's wait for the capture
  };
  std::vector<Pending> pending;
  for (const std::string& pose : cell_.ScanPoses(target.bin)) {
    const StepOutcome moved = WithRetries("move", [&] { return cell_.MoveToNamed(pose); });
    AddTime(report, "scan", moved.robot_s);
    if (!moved.ok) {
      // The other views still show the bin: detection works on what they see.
      if (missing.empty()) missing = "cannot reach scan pose " + pose + ": " + moved.message;
      Emit(&target, Step::kScan, false,
           "view skipped: cannot reach " + pose + ": " + moved.message);
      continue;
    }
    const auto start = Clock::now();
    std::shared_future<ScanView> view = WithRetries("scan", [&] { return cell_.StartScan(); });
    pending.push_back({pose, std::move(view), Seconds(start)});
    AddTime(report, "scan", pending.back().held_s);
  }
  for (Pending& p : pending) {
    const auto start = Clock::now();
    try {
      views.push_back(p.view.get());
    } catch (const CellError& e) {
      if (missing.empty()) missing = "scan at " + p.pose + " failed: " + e.what();
      Emit(&target, Step::kScan, false, "view lost: " + p.pose + ": " + e.what());
      continue;
    }
    // What the arm waited for the decoding, and the capture's robot time beyond the wait.
    AddTime(report, "scan", Seconds(start) + std::max(0.0, views.back().capture_s - p.held_s));
    EventScene scene;
    if (views.back().cloud_Base) {
      scene.scan_Base = ThinPoints(*views.back().cloud_Base, kViewerScanPoints);
    }
    Emit(&target, Step::kScan, true,
         "captured view " + std::to_string(views.size()) + " (" + p.pose + ")", "",
         std::move(scene));
  }
  if (views.empty()) {
    target.last_failure = missing.empty() ? "no scan pose for " + target.bin : missing;
  }
  return !views.empty();
}

PickTaskRunner::PendingDetection PickTaskRunner::StartDetect(const Target& target,
                                                             const std::vector<ScanView>& views) {
  Emit(&target, Step::kDetect, true, "detecting in " + std::to_string(views.size()) + " views");
  const std::vector<std::string> others =
      options_.detect_others ? OtherItemsIn(target.bin, target.item) : std::vector<std::string>{};
  PendingDetection pending;
  pending.started_wall = Clock::now();
  pending.started_clock_s = clock_s_;
  // The call itself only: retries, events and the clock stay on the task's thread
  // (FinishDetect). The views are copied (their clouds are shared, not copied).
  pending.result =
      std::async(std::launch::async, [this, bin = target.bin, item = target.item, views, others] {
        return cell_.Detect(bin, item, views, others);
      });
  return pending;
}

bool PickTaskRunner::FinishDetect(Target& target, TargetReport& report, PendingDetection& pending,
                                  const std::vector<ScanView>& views) {
  Detection found;
  try {
    found = pending.result.get();
  } catch (const CellError& e) {
    if (!e.retryable()) throw;
    Emit(nullptr, Step::kNone, false, std::string("detect: ") + e.what() + "; retrying");
    const std::vector<std::string> others =
        options_.detect_others ? OtherItemsIn(target.bin, target.item) : std::vector<std::string>{};
    found =
        WithRetries("detect", [&] { return cell_.Detect(target.bin, target.item, views, others); });
  }
  // The arm waited for what the detection took beyond the motions and steps since it began.
  const double computed_s = Seconds(pending.started_wall);
  AddTime(report, "detect", std::max(0.0, computed_s - (clock_s_ - pending.started_clock_s)));
  if (!found.found) {
    target.last_failure = "not detected: " + found.message;
    return false;
  }
  report.poses_found = {{target.item, {found.X_BaseItem, found.score}}};
  for (const PoseHypothesis& pose : found.alternatives)
    report.poses_found.push_back({target.item, pose});
  for (const OtherDetection& other : found.others) {
    for (const PoseHypothesis& pose : other.poses) report.poses_found.push_back({other.item, pose});
  }
  std::vector<std::string> rivals;
  if (const std::string other =
          ResolveAgainstOthers(target.item, &found, catalogue_, options_.confusion_overlap,
                               options_.confusion_margin, &rivals);
      !other.empty()) {
    const PickTaskOptions::TableCheck table =
        task_.kind == apc::TaskKind::kStow ? options_.table_check : options_.pick_table_check;
    if (table == PickTaskOptions::TableCheck::kNever || rivals.empty()) {
      target.last_failure = "not taken: " + other;
      Emit(&target, Step::kDetect, false, target.last_failure);
      return false;
    }
    // Whichever it is, it is one of the container's items: the table will tell.
    rivals_ = rivals;
    Emit(&target, Step::kDetect, true, other + "; taken to the table to be told apart");
  }
  report.detected = true;
  report.method = found.method;
  report.detection_score = found.score;
  report.X_BaseItem_detected = found.X_BaseItem;
  EventScene scene;
  scene.detected = true;
  scene.X_BaseItem = found.X_BaseItem;
  scene.detection_score = found.score;
  scene.method = found.method;
  Emit(&target, Step::kDetect, true,
       "found by " + found.method + " (score " + std::to_string(found.score) + ", " +
           std::to_string(computed_s) + " s of detection)",
       "", std::move(scene));
  return true;
}

void PickTaskRunner::ScanAhead(const Target& current, Target& next, TargetReport& next_report) {
  if (!options_.detect_ahead || next.bin == current.bin || cancel_.load()) return;
  Ahead ahead;
  ahead.target = &next;
  if (!ScanViews(next, next_report, ahead.views)) return;  // its own attempt scans again
  ahead.detection = StartDetect(next, ahead.views);
  ahead_.emplace(std::move(ahead));
}

std::size_t PickTaskRunner::NextInRound(std::size_t i, int round) const {
  for (std::size_t k = i + 1; k < order_.size(); ++k) {
    const Target& t = order_[k];
    if (!t.done && !t.given_up && t.attempts <= round) return k;
  }
  return std::string::npos;
}

PickTaskRunner::Attempt PickTaskRunner::GraspAndPlace(Target& target, TargetReport& report,
                                                      const PlannedPick& plan,
                                                      const std::vector<ScanView>& views) {
  Emit(&target, Step::kGrasp, true, "approaching grasp '" + plan.grasp + "'");
  journal_.Append("begin", Key(target, "grasp"), clock_s_, {{"grasp", plan.grasp}});
  const StepOutcome approached =
      WithRetries("approach", [&] { return cell_.ExecuteApproach(plan); });
  AddTime(report, "grasp", approached.robot_s);
  if (!approached.ok) {
    target.last_failure = "approach: " + approached.message;
    journal_.Append("failed", Key(target, "grasp"), clock_s_, {{"reason", target.last_failure}});
    return Attempt::kFailed;
  }
  const TouchOutcome touched = WithRetries("touch", [&] { return cell_.Touch(plan); });
  AddTime(report, "grasp", touched.robot_s);
  const std::string early = EarlyContact(plan, touched);
  if (!touched.refused.empty() || !early.empty()) {
    const StepOutcome out = WithRetries("retreat", [&] { return cell_.ExecuteRetreat(plan); });
    AddTime(report, "grasp", out.robot_s);
    target.last_failure = touched.refused.empty() ? early : "touch: " + touched.refused;
    journal_.Append("failed", Key(target, "grasp"), clock_s_, {{"reason", target.last_failure}});
    return Attempt::kFailed;
  }
  // From here on the plan whose retreat starts where the cup is.
  const PlannedPick held_plan = ReplanAtContact(target, report, plan, touched, views);
  return HoldAndPlace(target, report, held_plan, touched);
}

PickTaskRunner::Attempt PickTaskRunner::HoldAndPlace(Target& target, TargetReport& report,
                                                     const PlannedPick& plan,
                                                     const TouchOutcome& touched) {
  const SealReading seal = WithRetries("vacuum", [&] { return cell_.VacuumOn(); });
  if (!seal.attached) {
    cell_.VacuumOff();
    const StepOutcome out = WithRetries("retreat", [&] { return cell_.ExecuteRetreat(plan); });
    AddTime(report, "grasp", out.robot_s);
    target.last_failure = std::string("no seal (") + (touched.contact ? "touched" : "no contact") +
                          ", vacuum " + std::to_string(seal.vacuum_kpa) + " kPa)";
    journal_.Append("failed", Key(target, "grasp"), clock_s_, {{"reason", target.last_failure}});
    return Attempt::kFailed;
  }
  journal_.Append("done", Key(target, "grasp"), clock_s_, {{"vacuum_kpa", seal.vacuum_kpa}});
  const StepOutcome out = WithRetries("retreat", [&] { return cell_.ExecuteRetreat(plan); });
  AddTime(report, "grasp", out.robot_s);
  // The vacuum level after the lift is the first sign of a held item; a seal lost on the way
  // out leaves the item in (or fallen inside) its bin.
  const SealReading lifted = WithRetries("gripper", [&] { return cell_.ReadSeal(); });
  if (!out.ok || !lifted.attached) {
    cell_.VacuumOff();
    target.last_failure = !out.ok ? "retreat: " + out.message : "seal lost during the lift";
    journal_.Append("failed", Key(target, "grasp"), clock_s_, {{"reason", target.last_failure}});
    return Attempt::kFailed;
  }
  if (!rivals_.empty() || (task_.kind == apc::TaskKind::kStow &&
                           options_.table_check == PickTaskOptions::TableCheck::kAlways)) {
    return SetDownAndIdentify(target, report, plan);
  }
  PendingLookBack look_back;
  if (options_.verify_after_lift) look_back = StartLookBack(target, report, plan);
  return PlaceHeld(target, report, plan, Destinations(target), &look_back);
}

PickTaskRunner::Attempt PickTaskRunner::PlaceHeld(Target& target, TargetReport& report,
                                                  const PlannedPick& plan,
                                                  const std::vector<std::string>& destinations,
                                                  PendingLookBack* look_back) {
  journal_.Append("begin", Key(target, "place"), clock_s_);
  PlaceOutcome placed{false, "no bin has room for it", 0.0, 0.0};
  std::string to;
  for (const std::string& destination : destinations) {
    Emit(&target, Step::kPlace, true, "carrying to " + destination);
    const auto start = Clock::now();
    placed = WithRetries("place", [&] {
      return cell_.MoveToPlace(target.item, destination, plan, PlacedIn(destination));
    });
    // A place that cannot be planned costs the planning time only.
    AddTime(report, "place", placed.ok ? placed.robot_s : Seconds(start));
    if (placed.ok) {
      to = destination;
      break;
    }
    if (placed.item_lost) {
      target.last_failure = "place: " + placed.message + "; the item was let go there";
      journal_.Append("failed", Key(target, "place"), clock_s_, {{"reason", target.last_failure}});
      return Attempt::kLostCarried;
    }
  }
  // Judged before the release (and before a put-back, which it would not change).
  const std::string wrong = FinishLookBack(target, report, look_back);
  if (placed.ok && !wrong.empty()) {
    // The wrong item over the destination: carried back the way it came and put back.
    const StepOutcome returned = WithRetries("return", [&] { return cell_.ReturnFromPlace(); });
    const StepOutcome back = WithRetries("put back", [&] { return cell_.PutBack(plan); });
    AddTime(report, "verify", returned.robot_s + back.robot_s);
    target.last_failure = "verification: " + wrong + " (put back)";
    journal_.Append("failed", Key(target, "place"), clock_s_, {{"reason", target.last_failure}});
    return returned.ok && back.ok ? Attempt::kFailed : Attempt::kLostCarried;
  }
  if (!placed.ok) {
    // No way to the tote with this item on the cup: it goes back where it was, not on the
    // floor (an item outside the bins and the tote costs points).
    const StepOutcome back = WithRetries("put back", [&] { return cell_.PutBack(plan); });
    AddTime(report, "place", back.robot_s);
    target.last_failure =
        "place: " + placed.message + (back.ok ? "; put back" : "; " + back.message);
    journal_.Append("failed", Key(target, "place"), clock_s_, {{"reason", target.last_failure}});
    return back.ok ? Attempt::kFailed : Attempt::kLostCarried;
  }
  const SealReading over_destination = WithRetries("gripper", [&] { return cell_.ReadSeal(); });
  cell_.VacuumOff();
  if (!over_destination.attached) {
    target.last_failure = "dropped on the way to " + to;
    journal_.Append("failed", Key(target, "place"), clock_s_, {{"reason", target.last_failure}});
    return Attempt::kLostCarried;
  }
  journal_.Append("done", Key(target, "place"), clock_s_,
                  {{"drop_height_m", placed.drop_height_m}, {"to", to}});
  report.drop_height_m = placed.drop_height_m;
  report.placed_in = to;
  RecordPlaced(target, to, placed.drop_height_m);
  return Attempt::kPicked;
}

namespace {

constexpr const char* kTableLocation = "table";

std::string Joined(const std::vector<std::string>& parts, const std::string& between) {
  std::string out;
  for (const std::string& part : parts) out += (out.empty() ? "" : between) + part;
  return out;
}

}  // namespace

Target* PickTaskRunner::TargetFor(const std::string& item, const std::string& container) {
  for (Target& t : order_) {
    if (t.item == item && t.bin == container && !t.done && !t.given_up) return &t;
  }
  return nullptr;
}

PickTaskRunner::Attempt PickTaskRunner::SetDownAndIdentify(Target& target, TargetReport& report,
                                                           const PlannedPick& plan) {
  std::vector<std::string> candidates = {target.item};
  candidates.insert(candidates.end(), rivals_.begin(), rivals_.end());
  Emit(&target, Step::kPlace, true, "setting it down on the table: " + Joined(candidates, " or "));
  journal_.Append("begin", Key(target, "table"), clock_s_, {{"candidates", candidates}});
  // The cup may hold any of them: the motion is planned for the one that reaches furthest
  // (its box at the pose the target was found at), not only for the target it was taken for.
  std::string carried_as = target.item;
  for (const std::string& candidate : candidates) {
    if (catalogue_.at(candidate).long_side_m > catalogue_.at(carried_as).long_side_m) {
      carried_as = candidate;
    }
  }
  const auto start = Clock::now();
  const PlaceOutcome placed =
      WithRetries("place", [&] { return cell_.MoveToPlace(carried_as, kTableLocation, plan, 0); });
  AddTime(report, "place", placed.ok ? placed.robot_s : Seconds(start));
  if (!placed.ok) {
    if (placed.item_lost) {
      target.last_failure = "to the table: " + placed.message + "; the item was let go there";
    } else {
      const StepOutcome back = WithRetries("put back", [&] { return cell_.PutBack(plan); });
      AddTime(report, "place", back.robot_s);
      target.last_failure = "to the table: " + placed.message + (back.ok ? "; put back" : "");
      if (back.ok) {
        journal_.Append("failed", Key(target, "table"), clock_s_,
                        {{"reason", target.last_failure}});
        return Attempt::kFailed;
      }
    }
    journal_.Append("failed", Key(target, "table"), clock_s_, {{"reason", target.last_failure}});
    return Attempt::kLostCarried;
  }
  const SealReading over_table = WithRetries("gripper", [&] { return cell_.ReadSeal(); });
  cell_.VacuumOff();
  if (!over_table.attached) {
    target.last_failure = "dropped on the way to the table";
    journal_.Append("failed", Key(target, "table"), clock_s_, {{"reason", target.last_failure}});
    return Attempt::kLostCarried;
  }
  journal_.Append("done", Key(target, "table"), clock_s_, {{"candidates", candidates}});
  return IdentifyAndStow(target, report, candidates);
}

std::string PickTaskRunner::IdentifyInView(const std::vector<std::string>& candidates,
                                           const ScanView& view, Detection* found,
                                           std::string* why) {
  const std::vector<std::string> others(candidates.begin() + 1, candidates.end());
  *found = WithRetries(
      "detect", [&] { return cell_.Detect(kTableLocation, candidates.front(), {view}, others); });
  // The best pose of each candidate the view shows, best first.
  std::vector<std::pair<double, std::string>> seen;
  if (found->found) seen.emplace_back(found->score, candidates.front());
  for (const OtherDetection& other : found->others) {
    if (!other.poses.empty()) seen.emplace_back(other.poses.front().score, other.item);
  }
  std::sort(seen.begin(), seen.end(), std::greater<>());
  if (seen.empty()) {
    *why = "none of " + Joined(candidates, ", ") + " is seen there";
    return "";
  }
  // The pose to pick it up by: the best candidate's.
  if (seen.front().second != candidates.front()) {
    for (const OtherDetection& other : found->others) {
      if (other.item != seen.front().second) continue;
      found->X_BaseItem = other.poses.front().X_BaseItem;
      found->score = other.poses.front().score;
      found->found = true;
    }
  }
  if (seen.size() > 1 && seen[0].first < seen[1].first + options_.table_identity_margin) {
    char text[200];
    std::snprintf(text, sizeof(text), "%s and %s score alike there (%.2f, %.2f)",
                  seen[0].second.c_str(), seen[1].second.c_str(), seen[0].first, seen[1].first);
    *why = text;
    return "";
  }
  return seen.front().second;
}

std::string PickTaskRunner::TakeFromTable(Target& target, TargetReport& report,
                                          const std::string& item, const Detection& found,
                                          const ScanView& view, PlannedPick* plan) {
  *plan = WithRetries(
      "plan", [&] { return cell_.PlanPick(kTableLocation, item, found.X_BaseItem, {view}); });
  if (!plan->ok) return "no plan from the table: " + plan->message;
  const StepOutcome approached =
      WithRetries("approach", [&] { return cell_.ExecuteApproach(*plan); });
  AddTime(report, "grasp", approached.robot_s);
  if (!approached.ok) return "approach to the table: " + approached.message;
  const TouchOutcome touched = WithRetries("touch", [&] { return cell_.Touch(*plan); });
  AddTime(report, "grasp", touched.robot_s);
  const SealReading seal = touched.refused.empty()
                               ? WithRetries("vacuum", [&] { return cell_.VacuumOn(); })
                               : SealReading{false, 0.0};
  const StepOutcome lifted = WithRetries("retreat", [&] { return cell_.ExecuteRetreat(*plan); });
  AddTime(report, "grasp", lifted.robot_s);
  const bool held = seal.attached && lifted.ok &&
                    WithRetries("gripper", [&] { return cell_.ReadSeal(); }).attached;
  if (held) return "";
  cell_.VacuumOff();
  return !touched.refused.empty() ? "touch on the table: " + touched.refused
         : !lifted.ok             ? "lift from the table: " + lifted.message
                                  : "no seal on the table";
}

PickTaskRunner::Attempt PickTaskRunner::IdentifyAndStow(
    Target& target, TargetReport& report, const std::vector<std::string>& candidates) {
  auto left_on_table = [&](const std::string& why) {
    target.last_failure = "on the table: " + why + "; left there";
    journal_.Append("failed", Key(target, "table"), clock_s_, {{"reason", target.last_failure}});
    return Attempt::kLostCarried;
  };
  const StepOutcome moved =
      WithRetries("move", [&] { return cell_.MoveToNamed(options_.verify_pose); });
  AddTime(report, "verify", moved.robot_s);
  if (!moved.ok)
    return left_on_table("cannot reach " + options_.verify_pose + ": " + moved.message);
  const auto scan_start = Clock::now();
  const ScanView view = WithRetries("scan", [&] { return cell_.Scan(); });
  AddTime(report, "verify", std::max(view.capture_s, Seconds(scan_start)));
  const auto detect_start = Clock::now();
  Detection found;
  std::string why;
  const std::string identity = IdentifyInView(candidates, view, &found, &why);
  AddTime(report, "verify", Seconds(detect_start));
  if (!found.found) return left_on_table(why);
  Emit(&target, Step::kVerify, !identity.empty(),
       identity.empty() ? "on the table: " + why : "on the table it is " + identity);
  PlannedPick plan;
  const std::string as = identity.empty() ? candidates.front() : identity;
  if (const std::string failed = TakeFromTable(target, report, as, found, view, &plan);
      !failed.empty()) {
    return left_on_table(failed);
  }
  Target* who = identity.empty() ? nullptr : TargetFor(identity, target.bin);
  if (!who) {
    // Not told apart, or an item that is no target (a pick's other item of the bin): back
    // where it came from, which the contents still say.
    const PlaceOutcome back = WithRetries(
        "place", [&] { return cell_.MoveToPlace(as, target.bin, plan, PlacedIn(target.bin)); });
    AddTime(report, "place", back.robot_s);
    cell_.VacuumOff();
    if (!back.ok) return left_on_table("no way back to the " + target.bin + ": " + back.message);
    target.last_failure =
        "on the table: " + (identity.empty() ? why : "it is " + identity + ", not a target") +
        "; back in the " + target.bin;
    journal_.Append("failed", Key(target, "table"), clock_s_, {{"reason", target.last_failure}});
    return Attempt::kFailed;
  }
  if (who == &target) return PlaceHeld(target, report, plan, Destinations(target));
  // It was another of the tote's items: stowed as that one, this target tried again later.
  ++who->attempts;
  TargetReport& who_report = (*reports_)[static_cast<std::size_t>(who - order_.data())];
  who_report.attempts = who->attempts;
  const Attempt placed = PlaceHeld(*who, who_report, plan, Destinations(*who));
  who->done = placed == Attempt::kPicked;
  if (placed == Attempt::kLostCarried) RecordLost(*who, who->last_failure);
  target.last_failure = "the item taken for " + target.item + " was " + identity +
                        (who->done ? ", stowed as such" : ": " + who->last_failure);
  journal_.Append("failed", Key(target, "table"), clock_s_, {{"reason", target.last_failure}});
  return Attempt::kFailed;
}

PlannedPick PickTaskRunner::ReplanAtContact(Target& target, TargetReport& report,
                                            const PlannedPick& plan, const TouchOutcome& touched,
                                            const std::vector<ScanView>& views) {
  const double early_m = plan.contact_distance_m - touched.distance_m;
  if (!(options_.replan_contact_m > 0.0) || !touched.contact || plan.contact_distance_m <= 0.0 ||
      early_m <= options_.replan_contact_m || plan.guarded_direction_Base.isZero()) {
    return plan;
  }
  Eigen::Isometry3d X_BaseItem = report.X_BaseItem_detected;
  X_BaseItem.translation() -= early_m * plan.guarded_direction_Base.normalized();
  const auto start = Clock::now();
  const PlannedPick again = WithRetries(
      "plan", [&] { return cell_.PlanPick(target.bin, target.item, X_BaseItem, views); });
  AddTime(report, "plan", Seconds(start));
  char text[160];
  // Another surface or head angle would start the retreat elsewhere than where the cup is.
  const bool taken =
      again.ok && again.grasp == plan.grasp && again.head_angle_rad == plan.head_angle_rad;
  std::snprintf(text, sizeof(text), "the cup met the item %.1f cm before its detected surface: %s",
                100.0 * early_m,
                taken ? "re-planned from there" : "kept the first plan (no plan for that grasp)");
  Emit(&target, Step::kGrasp, true, text);
  return taken ? again : plan;
}

// The cup's contact is a first sign of what it touches, before anything is taken: where the
// guarded move stops, compared with where the grasp's surface was detected along it.
std::string PickTaskRunner::EarlyContact(const PlannedPick& plan,
                                         const TouchOutcome& touched) const {
  if (!touched.contact || plan.contact_distance_m <= 0.0) return "";
  const double early_m = plan.contact_distance_m - touched.distance_m;
  if (early_m <= options_.early_contact_m) return "";
  char text[200];
  std::snprintf(text, sizeof(text),
                "the cup met something %.1f cm before the target's surface (another item over "
                "it, or the target moved); the vacuum was not tried",
                100.0 * early_m);
  return text;
}

// The vacuum says something is held, not what: a second sign from the wrist camera, which
// looks into the container from the end of the retreat. If the target is still where it was
// found, or the held item does not look like it, the cup holds something else. A look back
// that fails (nothing decodable in view, a service refusing) cannot tell: the vacuum decides.
// Only the capture holds the arm: the detectors judge the view while it carries the item on.
PickTaskRunner::PendingLookBack PickTaskRunner::StartLookBack(Target& target, TargetReport& report,
                                                              const PlannedPick& plan) {
  Emit(&target, Step::kVerify, true, "looking back into " + target.bin);
  auto start = Clock::now();
  PendingLookBack pending;
  try {
    // The arm holds still for the capture (a scan's time), not for the decoding.
    const std::shared_future<ScanView> pending_view =
        WithRetries("scan", [&] { return cell_.StartScan(); });
    double held_s = Seconds(start);
    // A scan that came back whole tells the capture's robot time; one still decoding was
    // captured within the wait.
    if (pending_view.wait_for(std::chrono::seconds(0)) == std::future_status::ready) {
      try {
        held_s = std::max(held_s, pending_view.get().capture_s);
      } catch (const CellError&) {
        // judged (inconclusive) with the view below
      }
    }
    AddTime(report, "scan", held_s);
    start = Clock::now();
    const Eigen::Vector3d p_found = report.X_BaseItem_detected.translation();
    // Copies only: the judgement runs on while the caller moves on. Its two questions go to
    // the detectors at once (another replica where there is one).
    pending.verdict = std::async(std::launch::async,
                                 [this, bin = target.bin, item = target.item, plan, pending_view,
                                  p_found]() -> LookBackVerdict {
                                   ScanView view;
                                   try {
                                     view = pending_view.get();
                                   } catch (const CellError& e) {
                                     return {"", e.what()};
                                   }
                                   return JudgeLookBack(bin, item, plan, view, p_found);
                                 });
  } catch (const CellError& e) {
    Emit(&target, Step::kVerify, true, std::string("look back inconclusive: ") + e.what());
  }
  AddTime(report, "verify", Seconds(start));
  return pending;
}

// The look back's two questions, judged apart: a view that shows nothing of the bin (the
// held item fills the wrist camera's view from the retreat's end) cannot say where the target
// is, but may still show what the cup holds.
PickTaskRunner::LookBackVerdict PickTaskRunner::JudgeLookBack(const std::string& bin,
                                                              const std::string& item,
                                                              const PlannedPick& plan,
                                                              const ScanView& view,
                                                              const Eigen::Vector3d& p_found) {
  auto verify = std::async(std::launch::async, [&]() -> std::optional<double> {
    try {
      return cell_.VerifyHeld(item, plan, view);
    } catch (const CellError&) {
      return std::nullopt;
    }
  });
  const std::optional<HeldSurface> held = cell_.MeasureHeld(bin, item, plan, view);
  std::string detect_error;
  Detection seen;
  try {
    seen = cell_.Detect(bin, item, {view}, {});
  } catch (const CellError& e) {
    detect_error = e.what();
  }
  const std::optional<double> score = verify.get();
  if (detect_error.empty() && seen.found &&
      (seen.X_BaseItem.translation() - p_found).norm() < options_.verify_same_pose_m) {
    return {"the target is still where it was found; the cup holds another item", ""};
  }
  if (held && held->total() >= options_.held_min_points &&
      held->BeyondFraction() > options_.held_max_beyond) {
    char text[200];
    std::snprintf(text, sizeof(text),
                  "the held item is larger than %s: %.0f%% of what hangs from the cup "
                  "lies outside its box",
                  item.c_str(), 100.0 * held->BeyondFraction());
    return {text, ""};
  }
  // What the view showed of the held item, for the event.
  char measured[160] = "";
  if (score && *score >= 0.0) {
    std::snprintf(measured, sizeof(measured), "Verify %.2f", *score);
  }
  if (held && held->total() > 0) {
    const std::size_t used = std::strlen(measured);
    std::snprintf(measured + used, sizeof(measured) - used,
                  "%s%.0f%% of %d points near the cup outside its box", used ? "; " : "",
                  100.0 * held->BeyondFraction(), held->total());
  }
  if (score && *score >= 0.0 && *score < options_.verify_min_score) {
    return {"the held item does not look like " + item + " (" + measured + ")", ""};
  }
  if (!detect_error.empty() && !(score && *score >= 0.0)) return {"", detect_error};
  return {"", "", measured};
}

std::string PickTaskRunner::FinishLookBack(Target& target, TargetReport& report,
                                           PendingLookBack* look_back) {
  if (!look_back || !look_back->verdict.valid()) return "";
  // What the arm waits for: the part of the judgement its motion did not cover.
  const auto start = Clock::now();
  const LookBackVerdict verdict = look_back->verdict.get();
  AddTime(report, "verify", Seconds(start));
  if (!verdict.inconclusive.empty()) {
    Emit(&target, Step::kVerify, true, "look back inconclusive: " + verdict.inconclusive);
    return "";
  }
  Emit(&target, Step::kVerify, verdict.wrong.empty(),
       verdict.wrong.empty() ? "the held item may be the target" +
                                   (verdict.measured.empty() ? "" : " (" + verdict.measured + ")")
                             : verdict.wrong);
  return verdict.wrong;
}

PickTaskRunner::Attempt PickTaskRunner::TryTarget(Target& target, TargetReport& report,
                                                  Target* next, TargetReport* next_report) {
  InTheWay in_the_way;
  Attempt attempt = AttemptTarget(target, report, next, next_report, &in_the_way);
  // Another item in the way: moved aside, and the target tried again at once (the bin has
  // changed; the views are taken again).
  while (attempt == Attempt::kFailed && !in_the_way.items.empty() && options_.make_room &&
         task_.kind == apc::TaskKind::kPick && target.room_moves < options_.max_room_moves &&
         !cancel_.load() && TimeLeft() >= 2.0 * options_.min_time_per_item_s) {
    const std::string failure = target.last_failure;
    if (!MakeRoom(target, report, in_the_way)) {
      target.last_failure = failure;
      break;
    }
    ++target.room_moves;
    in_the_way = {};
    attempt = AttemptTarget(target, report, nullptr, nullptr, &in_the_way, /*again=*/true);
  }
  return attempt;
}

PickTaskRunner::Attempt PickTaskRunner::AttemptTarget(Target& target, TargetReport& report,
                                                      Target* next, TargetReport* next_report,
                                                      InTheWay* in_the_way, bool again) {
  ++target.attempts;
  report.attempts = target.attempts;
  rivals_.clear();
  journal_.Append("begin", Key(target, "scan"), clock_s_);
  std::vector<ScanView> views;
  PendingDetection detection;
  if (ahead_ && ahead_->target == &target) {
    views = std::move(ahead_->views);
    detection = std::move(ahead_->detection);
    ahead_.reset();
  } else {
    // Views of another target not taken up: its own attempt scans again; but views taken
    // ahead for the next target stay while this one is tried again after making room.
    if (!again) ahead_.reset();
    if (!ScanViews(target, report, views)) return Attempt::kFailed;
    detection = StartDetect(target, views);
  }
  // The next target's views are taken while this detection runs, so that the arm waits for
  // neither: the detector judges its search budget by its own CPU time, so the scans' work on
  // the same cores costs the detection wall time, not search.
  if (next) ScanAhead(target, *next, *next_report);
  if (!FinishDetect(target, report, detection, views)) return Attempt::kFailed;
  Emit(&target, Step::kPlan, true, "planning the pick");
  const auto start = Clock::now();
  const PlannedPick plan = WithRetries("plan", [&] {
    return cell_.PlanPick(target.bin, target.item, report.X_BaseItem_detected, views);
  });
  AddTime(report, "plan", Seconds(start));
  if (!plan.ok) {
    target.last_failure = "no plan: " + plan.message;
    if (plan.others_in_the_way) {
      in_the_way->items = NearestOthers(report);
      in_the_way->views = views;
    }
    return Attempt::kFailed;
  }
  report.grasp = plan.grasp;
  EventScene scene;
  scene.planned_path_q = plan.path_q;
  scene.head_angle_rad = plan.head_angle_rad;
  Emit(&target, Step::kPlan, true, "planned grasp '" + plan.grasp + "'", "", std::move(scene));
  return GraspAndPlace(target, report, plan, views);
}

namespace {

// The best pose `item` was found at in the target's last detection, or null.
const PoseHypothesis* BestPoseOf(const TargetReport& report, const std::string& item) {
  for (const auto& [name, pose] : report.poses_found) {
    if (name == item) return &pose;  // best first per item
  }
  return nullptr;
}

}  // namespace

std::vector<std::string> PickTaskRunner::NearestOthers(const TargetReport& report) const {
  // The other items found, nearest to where the target was found first: the one over it or
  // beside it is most likely what the planner met. One found in the target's own place is
  // left: the place holds one of the two, and it may be the target.
  auto size = [&](const std::string& name) { return CatalogueBoxM(catalogue_, name); };
  std::vector<std::pair<double, std::string>> by_distance;
  for (const auto& [item, pose] : report.poses_found) {
    if (item == report.item || BestPoseOf(report, item) != &pose) continue;
    if (BoxOverlapFraction(pose.X_BaseItem, size(item), report.X_BaseItem_detected,
                           size(report.item)) > options_.room_max_overlap) {
      continue;
    }
    by_distance.emplace_back(
        (pose.X_BaseItem.translation() - report.X_BaseItem_detected.translation()).norm(), item);
  }
  std::sort(by_distance.begin(), by_distance.end());
  std::vector<std::string> items;
  for (const auto& [distance, item] : by_distance) items.push_back(item);
  return items;
}

bool PickTaskRunner::MakeRoom(Target& target, TargetReport& report, const InTheWay& in_the_way) {
  for (const std::string& item : in_the_way.items) {
    const PoseHypothesis* pose = BestPoseOf(report, item);
    // A target itself is taken in its own turn; an item nowhere to go stays.
    if (pose == nullptr || TargetFor(item, target.bin) != nullptr) continue;
    if (RoomBins(item, target.bin).empty()) continue;
    Target mover{item, target.bin, 0, 0.0};
    mover.making_room = true;
    mover.attempts = ++room_moves_;
    Emit(&target, Step::kPlan, true, "making room: planning to move " + item + " aside");
    journal_.Append("begin", Key(mover, "scan"), clock_s_, {{"for", target.item}});
    TargetReport moved;  // its steps' times go to the target's report as "room"
    moved.item = item;
    moved.bin = target.bin;
    moved.X_BaseItem_detected = pose->X_BaseItem;
    const auto start = Clock::now();
    const PlannedPick plan = WithRetries("plan", [&] {
      return cell_.PlanPick(target.bin, item, pose->X_BaseItem, in_the_way.views);
    });
    AddTime(moved, "plan", Seconds(start));
    Attempt attempt = Attempt::kFailed;
    if (plan.ok) attempt = GraspAndPlace(mover, moved, plan, in_the_way.views);
    double seconds = 0.0;
    for (const auto& [step, s] : moved.step_times_s) seconds += s;
    report.step_times_s.emplace_back("room", seconds);
    if (attempt == Attempt::kPicked) {
      Emit(&target, Step::kPlace, true, "made room: " + item + " moved to " + moved.placed_in);
      return true;
    }
    const std::string why = plan.ok ? mover.last_failure : "no plan: " + plan.message;
    if (attempt == Attempt::kLostCarried) {
      journal_.Append("lost", Key(mover, "place"), clock_s_, {{"reason", why}});
      RecordLost(mover, why);
    }
    Emit(&target, Step::kNone, false, "could not move " + item + " aside: " + why);
    return false;  // one try per failure: the time is the target's
  }
  return false;
}

PickTaskResult PickTaskRunner::Run() {
  PickTaskResult result;
  ResumeFromJournal();
  std::vector<TargetReport> reports;
  for (const Target& t : order_) reports.push_back({t.item, t.bin, t.ease, t.attempts, t.done});
  reports_ = &reports;
  try {
    FinishCarriedItem();
    FinishItemOnTable();
    for (std::size_t i = 0; i < order_.size(); ++i) reports[i].picked = order_[i].done;
    // Rounds over the targets: a failed one is retried after the others, up to max_attempts.
    for (int round = 0; round < options_.max_attempts; ++round) {
      for (std::size_t i = 0; i < order_.size(); ++i) {
        Target& target = order_[i];
        if (target.done || target.given_up || target.attempts > round) continue;
        if (cancel_.load()) break;
        if (TimeLeft() < options_.min_time_per_item_s) {
          target.given_up = true;
          target.last_failure = "skipped: " + std::to_string(TimeLeft()) + " s left on the clock";
          Emit(&target, Step::kNone, false, target.last_failure);
          continue;
        }
        const std::size_t next = NextInRound(i, round);
        const Attempt attempt = next == std::string::npos
                                    ? TryTarget(target, reports[i], nullptr, nullptr)
                                    : TryTarget(target, reports[i], &order_[next], &reports[next]);
        target.done = attempt == Attempt::kPicked;
        // (An attempt may also have moved another target's item: stowed as what it was.)
        for (std::size_t k = 0; k < order_.size(); ++k) {
          reports[k].picked = order_[k].done;
          if (order_[k].done) reports[k].failure.clear();
        }
        reports[i].failure = target.done ? "" : target.last_failure;
        if (attempt == Attempt::kLostCarried) {
          journal_.Append("lost", Key(target, "place"), clock_s_,
                          {{"reason", target.last_failure}});
          RecordLost(target, target.last_failure);
        }
        Emit(&target, target.done ? Step::kPlace : Step::kNone, target.done,
             target.done
                 ? (reports[i].placed_in == apc::kToteLocation ? "in the tote"
                                                               : "in " + reports[i].placed_in)
                 : target.last_failure,
             target.done ? reports[i].placed_in : "");
      }
    }
    // The safe pose at the end, also when cancelled (no item is held between targets).
    clock_s_ += WithRetries("move", [&] { return cell_.MoveToNamed(options_.home_pose); }).robot_s;
    result.state = cancel_.load() ? TaskState::kCancelled : TaskState::kSucceeded;
  } catch (const std::exception& e) {
    result.state = TaskState::kFailed;
    result.error = e.what();
  }
  for (std::size_t i = 0; i < order_.size(); ++i) {
    if (!order_[i].done) reports[i].failure = order_[i].last_failure;
  }
  result.final_contents = contents_;
  result.events = events_;
  result.score = ScoreBelief(task_, events_, contents_, catalogue_);
  result.targets = reports;
  result.items_moved = done_;
  result.items_failed = static_cast<int>(order_.size()) - done_;
  result.duration_s = clock_s_;
  reports_ = nullptr;
  return result;
}

}  // namespace picking::orchestrator
