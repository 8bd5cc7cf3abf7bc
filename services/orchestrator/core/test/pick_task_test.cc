// The pick sequence over a scripted cell: order, retries, attachment checks, the clock, and
// resuming from the journal without repeating a pick.
#include "services/orchestrator/core/pick_task.h"

#include <gtest/gtest.h>

#include <algorithm>

#include <limits>

#include <filesystem>
#include <map>
#include <mutex>
#include <set>

namespace picking::orchestrator {
namespace {

const apc::Catalogue& Catalogue() {
  static const apc::Catalogue catalogue = apc::Catalogue::FromCsvFile(apc::DefaultCataloguePath());
  return catalogue;
}

// What the scripted cell does with each item.
struct Script {
  bool found = true;
  bool plannable = true;
  int no_seal_attempts = 0;         // the first n vacuum-ons do not seal
  bool lose_in_lift = false;        // seal lost during the retreat (once)
  bool drop_on_the_way = false;     // seal lost on the way to the tote
  bool no_place = false;            // no motion to the tote can be planned
  bool wrong_item_held = false;     // the look back after the lift still sees the target
  int early_touches = 0;            // the first n guarded moves stop 4 cm before the surface
  double touch_short_m = 0.0;       // the guarded moves stop this much before the surface
  bool replan_other_grasp = false;  // a second plan of the pick grasps another surface
  bool touch_refused = false;       // the robot refuses the guarded move
  std::string confused_with;        // the first detection finds this item at the same place
  std::string found_beside;         // every detection finds this item beside it:
  double beside_m = 0.3;            // ... this far along y,
  double beside_score = 0.9;        // ... with this score
  bool in_the_way_once = false;     // the first plan fails: another item in the way
};

class ScriptedCell final : public CellPort {
 public:
  std::map<std::string, Script> scripts;
  int unavailable_scans = 0;              // the scanner answers UNAVAILABLE this many times first
  std::vector<std::string> placed;        // items released over the tote
  std::vector<std::string> put_back;      // items put back where they were grasped
  std::vector<std::string> destinations;  // every MoveToPlace's container
  std::vector<int> placed_before_each;    // ... and how many items it held from this task
  std::set<std::string> refused_destinations;  // no place can be planned there
  bool held_looks_wrong = false;               // Verify of the held item scores low (once)
  bool look_back_sees_no_bin = false;  // the look back's Detect refuses its view (no bin in it)
  std::map<std::string, int> vacuum_ons;
  std::map<std::string, int> touches;
  std::map<std::string, std::vector<std::string>> others_asked;  // per target, last Detect
  std::string current;                                           // item being worked on
  bool held = false;
  std::map<std::string, std::vector<Eigen::Isometry3d>> planned_at;  // X_BaseItem per PlanPick
  std::map<std::string, std::vector<int>> plan_handles;              // per item, every PlanPick's
  std::map<std::string, std::vector<int>> retreat_handles;  // per item, every retreat's plan
  int plans = 0;
  // Detections run beside the arm (PickTaskOptions::detect_ahead): every call holds this.
  std::mutex mu;

  std::vector<std::string> ScanPoses(const std::string& c) override {
    std::lock_guard<std::mutex> lock(mu);
    if (c == "tote") return {"scan/tote/0", "scan/tote/1"};
    return {"scan/" + c + "/0", "scan/" + c + "/1", "scan/" + c + "/2"};
  }
  std::vector<std::string> calls;  // "move <pose>", "detect <item>", "plan <item>", in order
  std::set<std::string> crash_at;  // a move to one of these poses fails the task (once)
  std::map<std::string, int> crash_at_visit;  // ... at the n-th move to the pose
  std::map<std::string, int> visits;
  std::set<std::string> unreachable;  // the planner finds no motion to these poses
  StepOutcome MoveToNamed(const std::string& pose) override {
    std::lock_guard<std::mutex> lock(mu);
    calls.push_back("move " + pose);
    if (unreachable.count(pose)) return {false, "no collision-free joint motion", 0.0};
    if (crash_at.erase(pose)) throw CellError("robot", false, "the orchestrator's host died");
    if (crash_at_visit.count(pose) && ++visits[pose] == crash_at_visit[pose]) {
      throw CellError("robot", false, "the orchestrator's host died");
    }
    return {true, "", 2.0};
  }
  ScanView Scan() override {
    std::lock_guard<std::mutex> lock(mu);
    if (unavailable_scans > 0) {
      --unavailable_scans;
      throw CellError("scanner", true, "connection refused");
    }
    ScanView v;
    auto cloud = std::make_shared<geometry::PointCloud>();
    const float nan = std::numeric_limits<float>::quiet_NaN();
    cloud->points = {{1.0f, 0.2f, 0.9f}, {nan, nan, nan}, {1.1f, 0.25f, 0.95f}};
    v.cloud_Base = cloud;
    v.capture_s = 1.0;
    return v;
  }
  // StartScan returns at once and each view is decoded only when it is asked for (as a
  // scanner still decoding while the arm moves on); the n-th view (1-based, over the whole
  // task) fails after its capture.
  bool decode_later = false;
  int lost_view = 0;
  int started_scans = 0;
  std::shared_future<ScanView> StartScan() override {
    if (!decode_later) return CellPort::StartScan();
    int n = 0;
    {
      std::lock_guard<std::mutex> lock(mu);
      n = ++started_scans;
      calls.push_back("capture " + std::to_string(n));
    }
    return std::async(std::launch::deferred,
                      [this, n] {
                        {
                          std::lock_guard<std::mutex> lock(mu);
                          calls.push_back("decoded " + std::to_string(n));
                        }
                        if (n == lost_view) throw CellError("scanner", false, "decoding failed");
                        return Scan();
                      })
        .share();
  }
  Detection Detect(const std::string& container, const std::string& item,
                   const std::vector<ScanView>& views,
                   const std::vector<std::string>& others) override {
    std::lock_guard<std::mutex> lock(mu);
    if (container == "table") return OnTable(item, others);
    if (views.size() > 1) calls.push_back("detect " + item);
    EXPECT_GE(views.size(), 1u);
    if (views.size() > 1) others_asked[item] = others;
    Detection d;
    if (!scripts[item].confused_with.empty()) {  // the other item found where this one is
      d.others.push_back({scripts[item].confused_with, {{Eigen::Isometry3d::Identity(), 0.95}}});
      scripts[item].confused_with.clear();  // the next attempt tells them apart
    }
    const std::string& beside = scripts[item].found_beside;
    if (!beside.empty() && std::count(others.begin(), others.end(), beside)) {
      const Script& script = scripts[item];
      d.others.push_back({beside,
                          {{Eigen::Isometry3d(Eigen::Translation3d(0.0, script.beside_m, 0.0)),
                            script.beside_score}}});
    }
    if (views.size() == 1 && look_back_sees_no_bin) {
      throw CellError("detector", false, "point cloud has no finite point");
    }
    if (views.size() == 1) {  // the look back after the lift
      d.found = held && scripts[item].wrong_item_held;
      if (d.found) scripts[item].wrong_item_held = false;  // the next attempt takes the right one
      return d;
    }
    d.found = scripts[item].found;
    d.method = "ppf";
    d.score = 0.9;
    d.message = d.found ? "" : "no pose above the threshold";
    return d;
  }
  // The item set down on the table shows as `on_table_is`; empty: every candidate alike.
  std::string on_table_is;
  Detection OnTable(const std::string& item, const std::vector<std::string>& others) {
    calls.push_back("look at the table");
    Detection d;
    const double alike = 0.8;
    d.found = on_table_is.empty() || item == on_table_is;
    d.score = on_table_is.empty() ? alike : 0.9;
    for (const std::string& other : others) {
      if (on_table_is.empty() || other == on_table_is) {
        d.others.push_back(
            {other, {{Eigen::Isometry3d::Identity(), on_table_is.empty() ? alike : 0.9}}});
      }
    }
    return d;
  }
  PlannedPick PlanPick(const std::string&, const std::string& item,
                       const Eigen::Isometry3d& X_BaseItem, const std::vector<ScanView>&) override {
    std::lock_guard<std::mutex> lock(mu);
    current = item;  // every attempt plans before it touches (detections may run ahead)
    calls.push_back("plan " + item);
    PlannedPick p;
    p.ok = scripts[item].plannable;
    p.message = p.ok ? "" : "descend: gripper hits shelf";
    if (scripts[item].in_the_way_once) {
      scripts[item].in_the_way_once = false;
      p.ok = false;
      p.others_in_the_way = true;
      p.message = "retreat: lifting the item: its box meets the scan";
    }
    p.grasp = scripts[item].replan_other_grasp && !planned_at[item].empty() ? "+z face" : "+x face";
    planned_at[item].push_back(X_BaseItem);
    p.handle = ++plans;
    plan_handles[item].push_back(p.handle);
    p.guarded_direction_Base = Eigen::Vector3d::UnitX();
    if (p.ok) p.path_q = {{0.0, -1.5, 1.5, -1.5, -1.57, 0.0}, {0.1, -1.4, 1.4, -1.6, -1.57, 0.0}};
    p.head_angle_rad = 0.5;
    p.contact_distance_m = 0.035;
    return p;
  }
  StepOutcome ExecuteApproach(const PlannedPick&) override { return {true, "", 3.0}; }
  TouchOutcome Touch(const PlannedPick& plan) override {
    std::lock_guard<std::mutex> lock(mu);
    ++touches[current];
    if (scripts[current].touch_refused) return {false, 0.0, 0.0, "the swept path collides"};
    if (scripts[current].early_touches > 0) {
      --scripts[current].early_touches;
      return {true, plan.contact_distance_m - 0.04, 1.0};
    }
    if (scripts[current].touch_short_m > 0.0) {
      return {true, plan.contact_distance_m - scripts[current].touch_short_m, 1.0};
    }
    return {true, plan.contact_distance_m + 0.005, 1.0};  // the cup compressed
  }
  SealReading VacuumOn() override {
    std::lock_guard<std::mutex> lock(mu);
    Script& s = scripts[current];
    held = ++vacuum_ons[current] > s.no_seal_attempts;
    return {held, held ? 40.0 : 2.0};
  }
  SealReading ReadSeal() override { return {held, held ? 40.0 : 1.0}; }
  StepOutcome ExecuteRetreat(const PlannedPick& plan) override {
    std::lock_guard<std::mutex> lock(mu);
    retreat_handles[current].push_back(plan.handle);
    if (held && scripts[current].lose_in_lift) {
      scripts[current].lose_in_lift = false;
      held = false;
    }
    return {true, "", 3.0};
  }
  PlaceOutcome MoveToPlace(const std::string& item, const std::string& container,
                           const PlannedPick&, int placed_before) override {
    std::lock_guard<std::mutex> lock(mu);
    destinations.push_back(container);
    placed_before_each.push_back(placed_before);
    if (refused_destinations.count(container)) return {false, "no free motion", 0.0, 0.0};
    if (scripts[item].drop_on_the_way) held = false;
    if (scripts[item].no_place) return {false, "no free motion to the release pose", 0.0, 0.0};
    return {true, "", 0.1, 4.0};
  }
  double VerifyHeld(const std::string&, const PlannedPick&, const ScanView&) override {
    std::lock_guard<std::mutex> lock(mu);
    return held_looks_wrong ? 0.05 : -1.0;
  }
  // What the look back shows of the held item's space (once per entry, then nothing).
  std::vector<HeldSurface> held_surfaces;
  std::optional<HeldSurface> MeasureHeld(const std::string&, const std::string&, const PlannedPick&,
                                         const ScanView&) override {
    std::lock_guard<std::mutex> lock(mu);
    if (held_surfaces.empty()) return std::nullopt;
    const HeldSurface next = held_surfaces.front();
    held_surfaces.erase(held_surfaces.begin());
    return next;
  }
  StepOutcome PutBack(const PlannedPick&) override {
    std::lock_guard<std::mutex> lock(mu);
    put_back.push_back(current);
    held = false;
    return {true, "", 6.0};
  }
  StepOutcome ReturnFromPlace() override {
    std::lock_guard<std::mutex> lock(mu);
    calls.push_back("return from the place");
    return {true, "", 4.0};
  }
  void VacuumOff() override {
    std::lock_guard<std::mutex> lock(mu);
    if (held) placed.push_back(current);
    held = false;
  }
};

apc::Task ThreeItemTask() {
  return apc::ParseTask(R"({"bin_contents": {"bin_A": ["kleenex_tissue_box", "dove_beauty_bar"],
      "bin_B": ["rawlings_baseball"], "bin_C": ["hanes_tube_socks"], "bin_D": [], "bin_E": [], "bin_F": [],
      "bin_G": [], "bin_H": [], "bin_I": [], "bin_J": [], "bin_K": [], "bin_L": []},
      "tote_contents": [], "work_order": [{"bin": "bin_A", "item": "kleenex_tissue_box"},
      {"bin": "bin_B", "item": "rawlings_baseball"}, {"bin": "bin_C", "item": "hanes_tube_socks"}]})",
                        Catalogue(), "test");
}

std::vector<Target> InFileOrder(const apc::Task& task) {
  std::vector<Target> order;
  for (const auto& e : task.work_order) order.push_back({e.item, e.bin, 0, 1.0});
  return order;
}

class PickTaskTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("pick_task_test_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::remove_all(dir_);
    std::filesystem::create_directories(dir_);
    options_.backoff_s = 0.0;  // the scripted cell needs no wait
  }
  PickTaskResult Run(ScriptedCell& cell, std::vector<TaskEvent>* events = nullptr) {
    Journal journal((dir_ / "journal.jsonl").string());
    const apc::Task task = ThreeItemTask();
    PickTaskRunner runner(
        task, InFileOrder(task), Catalogue(), options_, cell, journal,
        [&](const TaskEvent& e) {
          if (events) events->push_back(e);
        },
        cancel_);
    return runner.Run();
  }
  // A stow of every tote item of `stow`, in the tote's order, journaled in dir_.
  PickTaskResult RunStow(ScriptedCell& cell, const apc::Task& stow) {
    Journal journal((dir_ / "journal.jsonl").string());
    std::vector<Target> order;
    for (const std::string& item : stow.tote_contents) order.push_back({item, "tote", 0, 1.0});
    PickTaskRunner runner(stow, order, Catalogue(), options_, cell, journal, nullptr, cancel_);
    return runner.Run();
  }
  // The task with the table for targets in doubt: bin_A's tissue box is first found where
  // the soap is as well, and the table shows it to be `on_table_is`.
  PickTaskResult RunInDoubtPick(ScriptedCell& cell, const std::string& on_table_is) {
    options_.pick_table_check = PickTaskOptions::TableCheck::kInDoubt;
    cell.scripts["kleenex_tissue_box"].confused_with = "dove_beauty_bar";
    cell.on_table_is = on_table_is;
    return Run(cell);
  }
  std::filesystem::path dir_;
  PickTaskOptions options_;
  std::atomic<bool> cancel_{false};
};

TEST_F(PickTaskTest, PicksEveryTargetAndScoresTheRules) {
  ScriptedCell cell;
  std::vector<TaskEvent> events;
  const PickTaskResult result = Run(cell, &events);
  EXPECT_EQ(result.state, TaskState::kSucceeded) << result.error;
  EXPECT_EQ(result.items_moved, 3);
  EXPECT_EQ(cell.placed, (std::vector<std::string>{"kleenex_tissue_box", "rawlings_baseball",
                                                   "hanes_tube_socks"}));
  EXPECT_EQ(result.final_contents.tote_contents.size(), 3u);
  EXPECT_EQ(result.final_contents.bin_contents.at("bin_A"),
            std::vector<std::string>{"dove_beauty_bar"});
  EXPECT_GT(result.score.total, 0);
  // Robot time: per item 3 moves + 3 captures + approach, touch, retreat, the look back
  // (a capture), place; and home.
  EXPECT_GE(result.duration_s, 3 * (3 * 2.0 + 3 * 1.0 + 3.0 + 1.0 + 3.0 + 1.0 + 4.0) + 2.0);
  ASSERT_FALSE(events.empty());
  EXPECT_EQ(events.back().items_done, 3);
  // Each item let go over its own spot: the count of those before it in the tote.
  EXPECT_EQ(cell.placed_before_each, (std::vector<int>{0, 1, 2}));
  for (std::size_t i = 1; i < events.size(); ++i) {
    EXPECT_EQ(events[i].sequence, events[i - 1].sequence + 1);
  }
}

TEST_F(PickTaskTest, AScanViewTheArmCannotReachIsSkippedAndTheOthersServe) {
  ScriptedCell cell;
  cell.unreachable = {"scan/bin_A/2"};
  std::vector<TaskEvent> events;
  const PickTaskResult result = Run(cell, &events);
  EXPECT_EQ(result.items_moved, 3) << result.error;
  bool said = false;
  for (const TaskEvent& e : events) {
    said |= !e.ok && e.message.find("view skipped: cannot reach scan/bin_A/2") != std::string::npos;
  }
  EXPECT_TRUE(said);
  // With no view reachable, the target fails with the reason.
  std::filesystem::remove_all(dir_);
  std::filesystem::create_directories(dir_);
  ScriptedCell blocked;
  blocked.unreachable = {"scan/bin_A/0", "scan/bin_A/1", "scan/bin_A/2"};
  const PickTaskResult none = Run(blocked);
  EXPECT_EQ(none.items_moved, 2);  // the baseball and the socks; the tissue box is in bin_A
  bool reason = false;
  for (const auto& t : none.targets) {
    reason |= t.failure.find("cannot reach scan pose scan/bin_A/0") != std::string::npos;
  }
  EXPECT_TRUE(reason);
}

TEST_F(PickTaskTest, TheArmMovesToTheNextViewWhileTheLastOneIsDecoded) {
  ScriptedCell cell;
  cell.decode_later = true;
  cell.lost_view = 2;  // the first target's second view fails after its capture
  std::vector<TaskEvent> events;
  const PickTaskResult result = Run(cell, &events);
  EXPECT_EQ(result.items_moved, 3) << result.error;
  const std::vector<std::string>& c = cell.calls;
  auto at = [&](const std::string& call) {
    return std::find(c.begin(), c.end(), call) - c.begin();
  };
  EXPECT_LT(at("capture 1"), at("move scan/bin_A/1"));
  EXPECT_LT(at("move scan/bin_A/2"), at("decoded 1"));  // decoded after the arm moved on
  EXPECT_LT(at("decoded 3"), at("detect kleenex_tissue_box"));
  bool said = false;
  for (const TaskEvent& e : events) {
    said |= !e.ok && e.message.find("view lost: scan/bin_A/1: scanner: decoding failed") !=
                         std::string::npos;
  }
  EXPECT_TRUE(said);
}

TEST_F(PickTaskTest, EventsCarryWhatAViewerDrawsAndTheJournalKeepsIt) {
  ScriptedCell cell;
  std::vector<TaskEvent> events;
  const PickTaskResult result = Run(cell, &events);
  int scans = 0, detections = 0, paths = 0, last_score = 0;
  for (const TaskEvent& e : events) {
    EXPECT_EQ(e.time_limit_s, options_.time_limit_s);
    EXPECT_GE(e.score, last_score);  // nothing is lost in this task
    last_score = e.score;
    if (!e.scene.scan_Base.empty()) {
      ++scans;
      EXPECT_EQ(e.step, Step::kScan);
      EXPECT_EQ(e.scene.scan_Base.size(), 2u);  // the invalid point is left out
    }
    if (e.scene.detected) {
      ++detections;
      EXPECT_EQ(e.step, Step::kDetect);
      EXPECT_EQ(e.scene.method, "ppf");
    }
    if (!e.scene.planned_path_q.empty()) {
      ++paths;
      EXPECT_EQ(e.step, Step::kPlan);
      EXPECT_EQ(e.scene.head_angle_rad, 0.5);
    }
  }
  EXPECT_EQ(scans, 9);  // three views of each of three bins
  EXPECT_EQ(detections, 3);
  EXPECT_EQ(paths, 3);
  EXPECT_EQ(last_score, result.score.total);
  // The journal holds the same scenes (points to the millimetre): a replay shows them.
  std::size_t next = 0;
  for (const JournalRecord& r : Journal::Read((dir_ / "journal.jsonl").string())) {
    if (r.type != "event") continue;
    ASSERT_LT(next, events.size());
    const EventScene& live = events[next++].scene;
    const EventScene replayed = EventScene::FromJson(r.data.value("scene", nlohmann::json()));
    ASSERT_EQ(replayed.scan_Base.size(), live.scan_Base.size());
    for (std::size_t i = 0; i < live.scan_Base.size(); ++i) {
      EXPECT_LT((replayed.scan_Base[i] - live.scan_Base[i]).norm(), 1e-3);
    }
    EXPECT_EQ(replayed.detected, live.detected);
    EXPECT_TRUE(replayed.X_BaseItem.isApprox(live.X_BaseItem, 1e-9));
    EXPECT_EQ(replayed.planned_path_q.size(), live.planned_path_q.size());
    EXPECT_EQ(r.data.value("score", -1), events[next - 1].score);
  }
  EXPECT_EQ(next, events.size());
}

std::size_t IndexOf(const std::vector<std::string>& calls, const std::string& call) {
  const auto it = std::find(calls.begin(), calls.end(), call);
  return it == calls.end() ? calls.size() : static_cast<std::size_t>(it - calls.begin());
}

TEST_F(PickTaskTest, TheNextBinIsScannedWhileATargetIsDetectedAndDetectedWhileItIsPicked) {
  ScriptedCell cell;
  const PickTaskResult result = Run(cell);
  EXPECT_EQ(result.items_moved, 3);
  // Each bin scanned once: the views taken ahead are the ones detected in.
  EXPECT_EQ(std::count_if(cell.calls.begin(), cell.calls.end(),
                          [](const std::string& c) { return c.rfind("move scan/", 0) == 0; }),
            9);
  // bin_B's views are taken right after bin_A's, while bin_A's detection runs, and before
  // bin_A's pick is planned (bin_B's detection then runs beside that pick: when each
  // detection starts is its thread's affair).
  const auto& c = cell.calls;
  const auto next_move =
      std::find_if(c.begin() + IndexOf(c, "move scan/bin_A/2") + 1, c.end(),
                   [](const std::string& call) { return call.rfind("move ", 0) == 0; });
  ASSERT_NE(next_move, c.end());
  EXPECT_EQ(*next_move, "move scan/bin_B/0");
  EXPECT_LT(IndexOf(c, "move scan/bin_B/2"), IndexOf(c, "plan kleenex_tissue_box"));
  EXPECT_LT(IndexOf(c, "move scan/bin_B/2"), IndexOf(c, "plan kleenex_tissue_box"));
  EXPECT_LT(IndexOf(c, "plan kleenex_tissue_box"), IndexOf(c, "plan rawlings_baseball"));
  EXPECT_LT(IndexOf(c, "move scan/bin_C/2"), IndexOf(c, "plan rawlings_baseball"));
  // Without it, each target is scanned, detected and picked in turn.
  options_.detect_ahead = false;
  std::filesystem::remove(dir_ / "journal.jsonl");  // a new task, not a resumed one
  ScriptedCell in_turn;
  EXPECT_EQ(Run(in_turn).items_moved, 3);
  const auto& t = in_turn.calls;
  EXPECT_LT(IndexOf(t, "plan kleenex_tissue_box"), IndexOf(t, "move scan/bin_B/0"));
  EXPECT_LT(IndexOf(t, "detect kleenex_tissue_box"), IndexOf(t, "move scan/bin_B/0"));
}

TEST_F(PickTaskTest, ViewsTakenAheadAreUsedByTheRetryRoundOnlyWhenTheyAreTheTargets) {
  // bin_A's target fails its first attempt; the second round scans it again (its views were
  // taken before its failed pick), and bin_B's views, taken ahead, serve bin_B once.
  ScriptedCell cell;
  cell.scripts["kleenex_tissue_box"].no_seal_attempts = 1;
  const PickTaskResult result = Run(cell);
  EXPECT_EQ(result.items_moved, 3);
  EXPECT_EQ(std::count(cell.calls.begin(), cell.calls.end(), "move scan/bin_A/0"), 2);
  EXPECT_EQ(std::count(cell.calls.begin(), cell.calls.end(), "move scan/bin_B/0"), 1);
  EXPECT_EQ(std::count(cell.calls.begin(), cell.calls.end(), "detect rawlings_baseball"), 1);
}

TEST(ThinPoints, KeepsAtMostTheAskedNumberSpreadOverTheCloud) {
  geometry::PointCloud cloud;
  for (int i = 0; i < 1000; ++i) cloud.points.emplace_back(i * 0.001f, 0.0f, 1.0f);
  const std::vector<Eigen::Vector3f> thin = ThinPoints(cloud, 100);
  ASSERT_EQ(thin.size(), 100u);
  EXPECT_FLOAT_EQ(thin.front().x(), 0.0f);
  EXPECT_GT(thin.back().x(), 0.98f);  // the whole cloud, not its first tenth
  EXPECT_EQ(ThinPoints(cloud, 5000).size(), 1000u);
}

TEST_F(PickTaskTest, AFailedTargetIsRetriedAfterTheOthersAndGivenUpAtTheLimit) {
  ScriptedCell cell;
  cell.scripts["kleenex_tissue_box"].no_seal_attempts = 1;  // seals the second time
  cell.scripts["rawlings_baseball"].plannable = false;
  const PickTaskResult result = Run(cell);
  EXPECT_EQ(result.items_moved, 2);
  EXPECT_EQ(cell.placed, (std::vector<std::string>{"hanes_tube_socks", "kleenex_tissue_box"}));
  EXPECT_EQ(result.targets[1].attempts, 2);
  EXPECT_NE(result.targets[1].failure.find("descend: gripper hits shelf"), std::string::npos);
}

TEST_F(PickTaskTest, ASealLostDuringTheLiftIsNoticedAndTheItemRetried) {
  ScriptedCell cell;
  cell.scripts["rawlings_baseball"].lose_in_lift = true;
  const PickTaskResult result = Run(cell);
  EXPECT_EQ(result.items_moved, 3);
  EXPECT_EQ(result.targets[1].attempts, 2);
  EXPECT_EQ(cell.vacuum_ons["rawlings_baseball"], 2);
}

// A guarded move that stops well before the grasp's surface has met another item: the
// vacuum is not tried there (it would take that item), the target is tried again later.
TEST_F(PickTaskTest, ATouchFarShortOfTheSurfaceTakesNothing) {
  ScriptedCell cell;
  cell.scripts["rawlings_baseball"].early_touches = 1;
  std::vector<TaskEvent> events;
  const PickTaskResult result = Run(cell, &events);
  EXPECT_EQ(result.items_moved, 3);
  EXPECT_EQ(result.targets[1].attempts, 2);
  EXPECT_EQ(cell.touches["rawlings_baseball"], 2);
  EXPECT_EQ(cell.vacuum_ons["rawlings_baseball"], 1);
  bool said = false;
  for (const TaskEvent& e : events) said |= e.message.find("4.0 cm before") != std::string::npos;
  EXPECT_TRUE(said);
}

// A cup that meets the item a centimetre before its detected surface: the pick is planned
// again for the item a centimetre nearer along the guarded move, and the retreat is that
// plan's (the first would push the held item on by the centimetre first).
TEST_F(PickTaskTest, AnEarlyContactReplansTheRetreatFromWhereTheCupMetTheItem) {
  ScriptedCell cell;
  cell.scripts["rawlings_baseball"].touch_short_m = 0.01;
  std::vector<TaskEvent> events;
  const PickTaskResult result = Run(cell, &events);
  EXPECT_EQ(result.items_moved, 3);
  const auto& planned = cell.planned_at["rawlings_baseball"];
  ASSERT_EQ(planned.size(), 2u);
  const Eigen::Vector3d moved = planned[1].translation() - planned[0].translation();
  EXPECT_NEAR(moved.x(), -0.01, 1e-9);
  EXPECT_NEAR(moved.tail<2>().norm(), 0.0, 1e-12);
  EXPECT_EQ(cell.vacuum_ons["rawlings_baseball"], 1);
  // The baseball's retreat is the second plan's.
  EXPECT_EQ(cell.retreat_handles["rawlings_baseball"],
            std::vector<int>{cell.plan_handles["rawlings_baseball"].at(1)});
  bool said = false;
  for (const TaskEvent& e : events)
    said |= e.message.find("re-planned from there") != std::string::npos;
  EXPECT_TRUE(said);
  // Contacts within the tolerance and the other items: one plan each.
  EXPECT_EQ(cell.planned_at["kleenex_tissue_box"].size(), 1u);
}

// A second plan that grasps another surface would start its retreat somewhere else: the first
// plan is kept.
TEST_F(PickTaskTest, AnEarlyContactKeepsTheFirstPlanWhenTheNewOneGraspsElsewhere) {
  ScriptedCell cell;
  cell.scripts["rawlings_baseball"].touch_short_m = 0.01;
  cell.scripts["rawlings_baseball"].replan_other_grasp = true;
  std::vector<TaskEvent> events;
  const PickTaskResult result = Run(cell, &events);
  EXPECT_EQ(result.items_moved, 3);
  EXPECT_EQ(cell.planned_at["rawlings_baseball"].size(), 2u);
  bool said = false;
  for (const TaskEvent& e : events)
    said |= e.message.find("kept the first plan") != std::string::npos;
  EXPECT_TRUE(said);
}

TEST_F(PickTaskTest, AGuardedMoveTheRobotRefusesFailsTheItemNotTheTask) {
  ScriptedCell cell;
  cell.scripts["rawlings_baseball"].touch_refused = true;
  const PickTaskResult result = Run(cell);
  EXPECT_EQ(result.state, TaskState::kSucceeded) << result.error;
  EXPECT_EQ(result.items_moved, 2);
  EXPECT_FALSE(result.targets[1].picked);
  EXPECT_NE(result.targets[1].failure.find("touch: the swept path collides"), std::string::npos)
      << result.targets[1].failure;
  EXPECT_EQ(cell.vacuum_ons.count("rawlings_baseball"), 0u);  // no vacuum without a touch
}

// Boxes that share their place, that touch, that cross.
TEST(BoxOverlapFraction, IsTheShareOfTheSmallerBoxInsideTheOther) {
  const Eigen::Vector3d book(0.178, 0.109, 0.010), hooks(0.166, 0.120, 0.046);
  Eigen::Isometry3d X_hooks = Eigen::Isometry3d::Identity();
  X_hooks.translation() = Eigen::Vector3d(1.0, 0.0, 0.63);
  // The book matched on the hooks' top: inside them but for its ends.
  Eigen::Isometry3d X_book = X_hooks;
  X_book.translation().z() += 0.5 * (hooks.z() - book.z()) - 0.001;
  EXPECT_GT(BoxOverlapFraction(X_book, book, X_hooks, hooks), 0.8);
  EXPECT_DOUBLE_EQ(BoxOverlapFraction(X_book, book, X_hooks, hooks),
                   BoxOverlapFraction(X_hooks, hooks, X_book, book));
  // The book lying on the hooks: they touch, nothing shared.
  X_book.translation().z() = 0.63 + 0.5 * (hooks.z() + book.z()) + 0.0005;
  EXPECT_EQ(BoxOverlapFraction(X_book, book, X_hooks, hooks), 0.0);
  // Side by side.
  X_book.translation() = Eigen::Vector3d(1.0, 0.12, 0.63);
  EXPECT_EQ(BoxOverlapFraction(X_book, book, X_hooks, hooks), 0.0);
  EXPECT_DOUBLE_EQ(BoxOverlapFraction(X_hooks, hooks, X_hooks, hooks), 1.0);
}

PoseHypothesis At(double x, double y, double z, double score) {
  PoseHypothesis h;
  h.X_BaseItem.translation() = Eigen::Vector3d(x, y, z);
  h.score = score;
  return h;
}

TEST(ResolveAgainstOthers, KeepsThePoseNoOtherItemFillsAsWell) {
  const std::string item = "kleenex_tissue_box";
  Detection found;
  found.found = true;
  found.X_BaseItem = At(1.0, 0.0, 0.65, 0.92).X_BaseItem;
  found.score = 0.92;
  // The other item's best pose is the target's place, and it has none elsewhere.
  found.others = {{"dove_beauty_bar", {At(1.0, 0.0, 0.65, 0.95)}}};
  Detection doubtful = found;
  EXPECT_NE(ResolveAgainstOthers(item, &doubtful, Catalogue(), 0.3, 0.05).find("dove_beauty_bar"),
            std::string::npos);
  // ... but the target was also found elsewhere, where nothing else is: that pose is kept.
  Detection moved = found;
  moved.alternatives = {At(1.0, 0.2, 0.65, 0.88)};
  EXPECT_EQ(ResolveAgainstOthers(item, &moved, Catalogue(), 0.3, 0.05), "");
  EXPECT_NEAR(moved.X_BaseItem.translation().y(), 0.2, 1e-12);
  EXPECT_EQ(moved.score, 0.88);
  // The other item also has a pose about as good elsewhere: the doubt stands (the two may
  // fit each other's places both ways round).
  Detection both_ways = found;
  both_ways.others[0].poses.push_back(At(1.0, -0.2, 0.65, 0.93));
  EXPECT_NE(ResolveAgainstOthers(item, &both_ways, Catalogue(), 0.3, 0.05), "");
  // The target scores clearly better: its pose stands.
  Detection better = found;
  better.others[0].poses[0].score = 0.80;
  EXPECT_EQ(ResolveAgainstOthers(item, &better, Catalogue(), 0.3, 0.05), "");
  // Found elsewhere: no doubt.
  Detection apart = found;
  apart.others[0].poses[0] = At(1.0, 0.3, 0.65, 0.99);
  EXPECT_EQ(ResolveAgainstOthers(item, &apart, Catalogue(), 0.3, 0.05), "");
}

TEST_F(PickTaskTest, ATargetWhosePlaceAnotherItemFillsAsWellIsNotTaken) {
  ScriptedCell cell;
  cell.scripts["kleenex_tissue_box"].confused_with = "dove_beauty_bar";
  std::vector<TaskEvent> events;
  const PickTaskResult result = Run(cell, &events);
  // The other items of bin_A were looked for with the target.
  EXPECT_EQ(cell.others_asked["kleenex_tissue_box"], std::vector<std::string>{"dove_beauty_bar"});
  EXPECT_TRUE(cell.others_asked["rawlings_baseball"].empty());
  // The first attempt took nothing; the second, told apart, picked it.
  EXPECT_EQ(result.items_moved, 3);
  EXPECT_EQ(result.targets[0].attempts, 2);
  EXPECT_EQ(cell.touches["kleenex_tissue_box"], 1);
  // The report keeps the poses the last detection gave, the target's first.
  ASSERT_FALSE(result.targets[0].poses_found.empty());
  EXPECT_EQ(result.targets[0].poses_found.front().first, "kleenex_tissue_box");
  bool said = false;
  for (const TaskEvent& e : events)
    said |= e.message.find("holds dove_beauty_bar") != std::string::npos;
  EXPECT_TRUE(said);
}

TEST_F(PickTaskTest, AnItemDroppedOnTheWayIsNotReportedInTheTote) {
  ScriptedCell cell;
  cell.scripts["hanes_tube_socks"].drop_on_the_way = true;
  const PickTaskResult result = Run(cell);
  EXPECT_EQ(result.items_moved, 2);
  EXPECT_NE(result.targets[2].failure.find("dropped on the way"), std::string::npos);
  const auto& tote = result.final_contents.tote_contents;
  EXPECT_EQ(std::count(tote.begin(), tote.end(), "hanes_tube_socks"), 0);
  // Nor in its bin: it left it for somewhere outside the containers.
  for (const auto& [bin, items] : result.final_contents.bin_contents) {
    EXPECT_EQ(std::count(items.begin(), items.end(), "hanes_tube_socks"), 0) << bin;
  }
  bool outside = false;
  for (const apc::Event& e : result.events) {
    outside |= e.kind == apc::EventKind::kOutside && e.item == "hanes_tube_socks";
  }
  EXPECT_TRUE(outside);
}

TEST_F(PickTaskTest, AnItemThatCannotBeCarriedToTheToteIsPutBackNotDropped) {
  ScriptedCell cell;
  cell.scripts["rawlings_baseball"].no_place = true;
  const PickTaskResult result = Run(cell);
  EXPECT_EQ(result.items_moved, 2);
  EXPECT_EQ(cell.put_back, (std::vector<std::string>{"rawlings_baseball", "rawlings_baseball"}));
  EXPECT_EQ(result.final_contents.bin_contents.at("bin_B"),
            std::vector<std::string>{"rawlings_baseball"});
  EXPECT_NE(result.targets[1].failure.find("put back"), std::string::npos);
}

TEST(StowBins, PrefersTheBinsThatScoreMostWhileTheyHaveRoom) {
  apc::Task initial = ThreeItemTask();
  initial.bin_contents["bin_D"] = {"dove_beauty_bar", "dove_beauty_bar", "dove_beauty_bar"};
  std::map<std::string, double> volume_m3;
  for (const auto& [bin, items] : initial.bin_contents) volume_m3[bin] = 0.012;
  apc::Task contents = initial;
  std::vector<std::string> bins =
      StowBins("hanes_tube_socks", initial, contents, Catalogue(), volume_m3, 0.6);
  ASSERT_FALSE(bins.empty());
  EXPECT_EQ(bins.front(), "bin_D");  // 3 items at the start: 15 points, others 10
  // A bin filled beyond the limit is no candidate.
  contents.bin_contents["bin_D"].push_back("kleenex_paper_towels");
  contents.bin_contents["bin_D"].push_back("kleenex_paper_towels");
  bins = StowBins("hanes_tube_socks", initial, contents, Catalogue(), volume_m3, 0.6);
  EXPECT_EQ(std::count(bins.begin(), bins.end(), "bin_D"), 0);
  EXPECT_TRUE(StowBins("hanes_tube_socks", initial, contents, Catalogue(), volume_m3, 0.0).empty());
}

TEST_F(PickTaskTest, AStowTaskPutsEveryToteItemIntoTheBestBinThatCanBePlannedInto) {
  const apc::Task stow = apc::ParseTask(R"({"bin_contents": {"bin_A": ["kleenex_tissue_box"],
      "bin_B": ["rawlings_baseball", "dove_beauty_bar", "hanes_tube_socks"], "bin_C": [],
      "bin_D": [], "bin_E": [], "bin_F": [], "bin_G": [], "bin_H": [], "bin_I": [], "bin_J": [],
      "bin_K": [], "bin_L": []}, "tote_contents": ["dove_beauty_bar", "kleenex_tissue_box"]})",
                                        Catalogue(), "stow");
  options_.bin_volume_m3 = {{"bin_A", 0.012}, {"bin_B", 0.012}, {"bin_C", 0.012}};
  ScriptedCell cell;
  cell.refused_destinations = {"bin_B"};  // the best by points, but no place plans there
  const PickTaskResult result = RunStow(cell, stow);
  EXPECT_EQ(result.state, TaskState::kSucceeded) << result.error;
  EXPECT_EQ(result.items_moved, 2);
  EXPECT_TRUE(result.final_contents.tote_contents.empty());
  EXPECT_EQ(cell.destinations.front(), "bin_B");
  for (const TargetReport& t : result.targets) EXPECT_NE(t.placed_in, "bin_B") << t.item;
  EXPECT_GT(result.score.total, 0);
}

TEST_F(PickTaskTest, APickTargetInDoubtIsToldApartOnTheTableAndPickedFromThere) {
  ScriptedCell cell;
  const PickTaskResult result = RunInDoubtPick(cell, "kleenex_tissue_box");
  EXPECT_EQ(result.state, TaskState::kSucceeded) << result.error;
  // Taken at once, set down, told apart and picked from the table into the tote.
  ASSERT_GE(cell.destinations.size(), 2u);
  EXPECT_EQ(cell.destinations[0], "table");
  EXPECT_EQ(cell.destinations[1], "tote");
  EXPECT_EQ(std::count(cell.calls.begin(), cell.calls.end(), "look at the table"), 1);
  EXPECT_EQ(result.items_moved, 3);
  EXPECT_EQ(result.targets[0].attempts, 1);
  const auto& bin_a = result.final_contents.bin_contents.at("bin_A");
  EXPECT_EQ(bin_a, std::vector<std::string>{"dove_beauty_bar"});
}

TEST_F(PickTaskTest, APickTargetInDoubtThatIsTheOtherItemGoesBackIntoItsBin) {
  ScriptedCell cell;
  const PickTaskResult result = RunInDoubtPick(cell, "dove_beauty_bar");
  EXPECT_EQ(result.state, TaskState::kSucceeded) << result.error;
  // The soap went back into bin_A; the tissue box, told apart the next time, was picked.
  ASSERT_GE(cell.destinations.size(), 3u);
  EXPECT_EQ(cell.destinations[0], "table");
  EXPECT_EQ(cell.destinations[1], "bin_A");
  EXPECT_EQ(result.targets[0].attempts, 2);
  EXPECT_TRUE(result.targets[0].picked);
  EXPECT_EQ(result.items_moved, 3);
  const auto& bin_a = result.final_contents.bin_contents.at("bin_A");
  EXPECT_EQ(bin_a, std::vector<std::string>{"dove_beauty_bar"});
  EXPECT_EQ(std::count(result.final_contents.tote_contents.begin(),
                       result.final_contents.tote_contents.end(), "dove_beauty_bar"),
            0);
}

apc::Task TwoItemStow() {
  return apc::ParseTask(R"({"bin_contents": {"bin_A": ["kleenex_tissue_box"],
      "bin_B": [], "bin_C": [], "bin_D": [], "bin_E": [], "bin_F": [], "bin_G": [], "bin_H": [],
      "bin_I": [], "bin_J": [], "bin_K": [], "bin_L": []},
      "tote_contents": ["dove_beauty_bar", "kleenex_tissue_box"]})",
                        Catalogue(), "stow");
}

TEST_F(PickTaskTest, AStowItemInDoubtIsToldApartOnTheTableAndStowedAsWhatItIs) {
  const apc::Task stow = TwoItemStow();
  options_.bin_volume_m3 = {{"bin_A", 0.012}, {"bin_B", 0.012}};
  options_.table_check = PickTaskOptions::TableCheck::kInDoubt;
  ScriptedCell cell;
  cell.scripts["dove_beauty_bar"].confused_with = "kleenex_tissue_box";  // the first detection
  cell.on_table_is = "kleenex_tissue_box";
  const PickTaskResult result = RunStow(cell, stow);
  EXPECT_EQ(result.state, TaskState::kSucceeded) << result.error;
  // The item taken for the soap was the tissue box: stowed as such; the soap the next round.
  EXPECT_EQ(cell.destinations.front(), "table");
  EXPECT_EQ(std::count(cell.calls.begin(), cell.calls.end(), "look at the table"), 1);
  EXPECT_EQ(result.items_moved, 2);
  EXPECT_TRUE(result.final_contents.tote_contents.empty());
  ASSERT_EQ(result.targets.size(), 2u);
  EXPECT_TRUE(result.targets[0].picked);
  EXPECT_EQ(result.targets[0].attempts, 2);
  EXPECT_TRUE(result.targets[1].picked);
  EXPECT_EQ(result.targets[1].attempts, 1);  // the attempt that took it for the soap
  // Each stowed item's move is reported as that item's.
  int moves = 0;
  for (const apc::Event& e : result.events) moves += e.kind == apc::EventKind::kMove;
  EXPECT_EQ(moves, 2);
}

TEST_F(PickTaskTest, AStowItemTheTableCannotTellApartGoesBackIntoTheTote) {
  const apc::Task stow = TwoItemStow();
  options_.bin_volume_m3 = {{"bin_A", 0.012}, {"bin_B", 0.012}};
  options_.table_check = PickTaskOptions::TableCheck::kInDoubt;
  ScriptedCell cell;
  cell.scripts["dove_beauty_bar"].confused_with = "kleenex_tissue_box";
  cell.on_table_is = "";  // both look alike there
  const PickTaskResult result = RunStow(cell, stow);
  ASSERT_GE(cell.destinations.size(), 2u);
  EXPECT_EQ(cell.destinations[0], "table");
  EXPECT_EQ(cell.destinations[1], "tote");  // back where it came from
  // Nothing was believed moved by that attempt; both are stowed afterwards.
  EXPECT_EQ(result.items_moved, 2);
  EXPECT_TRUE(result.final_contents.tote_contents.empty());
  EXPECT_EQ(result.targets[0].attempts, 2);
}

TEST_F(PickTaskTest, AStowMaySetEveryItemDownOnTheTableFirst) {
  const apc::Task stow = TwoItemStow();
  options_.bin_volume_m3 = {{"bin_A", 0.012}, {"bin_B", 0.012}};
  options_.table_check = PickTaskOptions::TableCheck::kAlways;
  ScriptedCell cell;
  const PickTaskResult result = RunStow(cell, stow);
  EXPECT_EQ(result.items_moved, 2);
  ASSERT_EQ(cell.destinations.size(), 4u);
  EXPECT_EQ(cell.destinations[0], "table");
  EXPECT_NE(cell.destinations[1], "table");
  EXPECT_EQ(cell.destinations[2], "table");
  EXPECT_EQ(std::count(cell.calls.begin(), cell.calls.end(), "look at the table"), 2);
  for (const TargetReport& t : result.targets) EXPECT_EQ(t.attempts, 1) << t.item;
}

TEST_F(PickTaskTest, AResumedStowTellsApartTheItemItLeftOnTheTable) {
  const apc::Task stow = TwoItemStow();
  options_.bin_volume_m3 = {{"bin_A", 0.012}, {"bin_B", 0.012}};
  options_.table_check = PickTaskOptions::TableCheck::kInDoubt;
  ScriptedCell cell;
  cell.scripts["dove_beauty_bar"].confused_with = "kleenex_tissue_box";
  cell.on_table_is = "kleenex_tissue_box";
  cell.crash_at = {"verify"};  // the task ends with the item on the table
  std::vector<Target> order;
  for (const std::string& item : stow.tote_contents) order.push_back({item, "tote", 0, 1.0});
  {
    Journal journal((dir_ / "journal.jsonl").string());
    PickTaskRunner first(stow, order, Catalogue(), options_, cell, journal, nullptr, cancel_);
    EXPECT_EQ(first.Run().state, TaskState::kFailed);
  }
  EXPECT_EQ(cell.destinations, std::vector<std::string>{"table"});
  Journal journal((dir_ / "journal.jsonl").string());
  PickTaskRunner resumed(stow, order, Catalogue(), options_, cell, journal, nullptr, cancel_);
  const PickTaskResult result = resumed.Run();
  EXPECT_EQ(result.state, TaskState::kSucceeded) << result.error;
  EXPECT_EQ(std::count(cell.calls.begin(), cell.calls.end(), "look at the table"), 1);
  EXPECT_EQ(result.items_moved, 2);
  EXPECT_TRUE(result.final_contents.tote_contents.empty());
}

TEST_F(PickTaskTest, TheLookBackCatchesTheWrongItemOnTheCupAndPutsItBack) {
  ScriptedCell cell;
  cell.scripts["rawlings_baseball"].wrong_item_held = true;
  const PickTaskResult result = Run(cell);
  EXPECT_EQ(result.items_moved, 3);
  EXPECT_EQ(cell.put_back, std::vector<std::string>{"rawlings_baseball"});
  // The look back is judged while the arm carries the item on: the wrong item came back from
  // over the tote, unreleased, and went back into its bin.
  EXPECT_EQ(std::count(cell.calls.begin(), cell.calls.end(), "return from the place"), 1);
  EXPECT_EQ(cell.destinations.size(), 4u);
  EXPECT_EQ(result.targets[1].attempts, 2);
  const auto& tote = result.final_contents.tote_contents;
  EXPECT_EQ(std::count(tote.begin(), tote.end(), "rawlings_baseball"), 1);
}

TEST_F(PickTaskTest, AHeldItemIsJudgedByItsLooksWhenTheLookBackShowsNothingOfTheBin) {
  ScriptedCell cell;
  cell.look_back_sees_no_bin = true;
  cell.held_looks_wrong = true;
  const PickTaskResult wrong = Run(cell);
  EXPECT_EQ(wrong.items_moved, 0);
  EXPECT_NE(wrong.targets[0].failure.find("does not look like"), std::string::npos);
  // A held item the view cannot show either (Verify: -1) is placed on the vacuum's reading,
  // and the look back says it could not judge.
  std::filesystem::remove_all(dir_);
  std::filesystem::create_directories(dir_);
  ScriptedCell blind;
  blind.look_back_sees_no_bin = true;
  std::vector<TaskEvent> events;
  EXPECT_EQ(Run(blind, &events).items_moved, 3);
  bool said = false;
  for (const TaskEvent& e : events) said |= e.message.find("inconclusive") != std::string::npos;
  EXPECT_TRUE(said);
}

TEST_F(PickTaskTest, AHeldItemThatDoesNotLookLikeTheTargetIsPutBack) {
  ScriptedCell cell;
  cell.held_looks_wrong = true;
  const PickTaskResult result = Run(cell);
  // Every look back scores low: nothing is carried to the tote, everything is put back.
  EXPECT_EQ(result.items_moved, 0);
  EXPECT_EQ(cell.put_back.size(), 6u);
  EXPECT_NE(result.targets[0].failure.find("does not look like"), std::string::npos);
  EXPECT_EQ(result.state, TaskState::kSucceeded);
}

TEST_F(PickTaskTest, AHeldItemLargerThanTheTargetIsPutBack) {
  ScriptedCell cell;
  HeldSurface larger;
  larger.on_item = 600;
  larger.beyond = 900;  // 60 % outside the target's box: a larger item hangs from the cup
  HeldSurface right;
  right.on_item = 1000;
  right.beyond = 50;  // 5 %: the grasp's pose error
  HeldSurface glimpse;
  glimpse.beyond = 150;  // too little in view to tell
  cell.held_surfaces = {larger, right, glimpse};
  const PickTaskResult result = Run(cell);
  EXPECT_EQ(result.items_moved, 3) << result.error;  // the first one at its second attempt
  ASSERT_EQ(cell.put_back.size(), 1u);
  EXPECT_EQ(cell.put_back[0], "kleenex_tissue_box");
  EXPECT_EQ(result.targets[0].attempts, 2);
}

TEST_F(PickTaskTest, AServiceThatDoesNotAnswerIsRetriedWithBackoff) {
  ScriptedCell cell;
  cell.unavailable_scans = 2;
  const PickTaskResult result = Run(cell);
  EXPECT_EQ(result.state, TaskState::kSucceeded) << result.error;
  EXPECT_EQ(result.items_moved, 3);
  cell.unavailable_scans = 100;
  std::filesystem::remove(dir_ / "journal.jsonl");
  ScriptedCell down;
  down.unavailable_scans = 100;
  const PickTaskResult failed = Run(down);
  EXPECT_EQ(failed.state, TaskState::kFailed);
  EXPECT_NE(failed.error.find("scanner"), std::string::npos);
}

TEST_F(PickTaskTest, TargetsAreSkippedWhenTheClockRunsOut) {
  options_.time_limit_s = 30.0;  // about one pick
  ScriptedCell cell;
  const PickTaskResult result = Run(cell);
  EXPECT_EQ(result.items_moved, 1);
  EXPECT_NE(result.targets[2].failure.find("skipped"), std::string::npos);
}

TEST_F(PickTaskTest, AResumedTaskRepeatsNoPick) {
  ScriptedCell first;
  first.scripts["rawlings_baseball"].found = false;  // ends the first run with two placed
  options_.max_attempts = 1;
  EXPECT_EQ(Run(first).items_moved, 2);
  options_.max_attempts = 2;  // the resumed run may try the missing one again
  ScriptedCell second;
  const PickTaskResult result = Run(second);
  EXPECT_EQ(second.placed, std::vector<std::string>{"rawlings_baseball"});
  EXPECT_EQ(result.items_moved, 3);
  EXPECT_EQ(result.final_contents.tote_contents.size(), 3u);
}

TEST_F(PickTaskTest, AResumedTaskKeepsAnItemLostOnTheWayOutOfItsBin) {
  ScriptedCell first;
  first.scripts["hanes_tube_socks"].drop_on_the_way = true;
  EXPECT_EQ(Run(first).items_moved, 2);
  ScriptedCell second;
  const PickTaskResult result = Run(second);
  EXPECT_TRUE(second.placed.empty());  // nothing tried again, the socks' place is unknown
  for (const auto& [bin, items] : result.final_contents.bin_contents) {
    EXPECT_EQ(std::count(items.begin(), items.end(), "hanes_tube_socks"), 0) << bin;
  }
  EXPECT_EQ(result.final_contents.tote_contents.size(), 2u);
}

TEST_F(PickTaskTest, AResumeWithTheItemStillOnTheCupCarriesItToTheTote) {
  {
    Journal journal((dir_ / "journal.jsonl").string());
    journal.Append("begin", "pick/bin_A/kleenex_tissue_box/1/scan", 1.0);
    journal.Append("begin", "pick/bin_A/kleenex_tissue_box/1/grasp", 20.0);
    journal.Append("done", "pick/bin_A/kleenex_tissue_box/1/grasp", 22.0);
  }
  ScriptedCell cell;
  cell.held = true, cell.current = "kleenex_tissue_box";  // still sealed after the crash
  const PickTaskResult result = Run(cell);
  EXPECT_EQ(cell.vacuum_ons["kleenex_tissue_box"], 0);  // not grasped again
  EXPECT_EQ(result.items_moved, 3);
  EXPECT_GE(result.duration_s, 22.0);
}

// bin_D (no target) has room; the soap is found 30 cm beside the tissue box.
TEST_F(PickTaskTest, AnItemThePlannerMeetsIsMovedAsideAndTheTargetPickedAtOnce) {
  options_.bin_volume_m3 = {{"bin_A", 0.012}, {"bin_B", 0.012}, {"bin_D", 0.012}};
  ScriptedCell cell;
  cell.scripts["kleenex_tissue_box"].found_beside = "dove_beauty_bar";
  cell.scripts["kleenex_tissue_box"].in_the_way_once = true;
  std::vector<TaskEvent> events;
  const PickTaskResult result = Run(cell, &events);
  // The soap went into bin_D (not bin_B: its target was still there), then the target was
  // scanned again and picked in the same turn.
  EXPECT_EQ(cell.destinations.front(), "bin_D");
  EXPECT_EQ(cell.placed.front(), "dove_beauty_bar");
  EXPECT_EQ(cell.touches["kleenex_tissue_box"], 1);
  EXPECT_TRUE(result.targets[0].picked);
  EXPECT_EQ(result.targets[0].attempts, 2);
  EXPECT_EQ(result.items_moved, 3);  // the soap is not a target
  EXPECT_TRUE(result.final_contents.bin_contents.at("bin_A").empty());
  EXPECT_EQ(result.final_contents.bin_contents.at("bin_D"),
            std::vector<std::string>{"dove_beauty_bar"});
  // Planned for where the detection found it.
  ASSERT_EQ(cell.planned_at["dove_beauty_bar"].size(), 1u);
  EXPECT_TRUE(cell.planned_at["dove_beauty_bar"][0].isApprox(
      Eigen::Isometry3d(Eigen::Translation3d(0.0, 0.3, 0.0))));
  bool room = false;
  for (const auto& [step, seconds] : result.targets[0].step_times_s) room |= step == "room";
  EXPECT_TRUE(room);
  bool said = false;
  for (const TaskEvent& e : events) said |= e.message.find("made room") != std::string::npos;
  EXPECT_TRUE(said);
  // No points lost: moving an item between bins is no penalty when it is reported there.
  for (const auto& line : result.score.lines) EXPECT_GE(line.points, 0) << line.reason;
}

TEST_F(PickTaskTest, AnItemFoundInTheTargetsOwnPlaceIsNotMovedAside) {
  // It may be the target itself: moved into another bin, the target would be lost to the
  // task (and the output file wrong).
  options_.bin_volume_m3 = {{"bin_A", 0.012}, {"bin_D", 0.012}};
  ScriptedCell cell;
  Script& box = cell.scripts["kleenex_tissue_box"];
  box.found_beside = "dove_beauty_bar";
  box.beside_m = 0.0;      // in the target's place,
  box.beside_score = 0.5;  // too poorly for the target to be in doubt
  box.in_the_way_once = true;
  const PickTaskResult result = Run(cell);
  EXPECT_TRUE(cell.planned_at["dove_beauty_bar"].empty());
  EXPECT_EQ(result.targets[0].attempts, 2);  // its second attempt in the second round
  EXPECT_EQ(result.final_contents.bin_contents.at("bin_A"),
            std::vector<std::string>{"dove_beauty_bar"});
}

TEST_F(PickTaskTest, NothingIsMovedAsideWhereNoBinWithoutATargetHasRoom) {
  options_.bin_volume_m3 = {{"bin_A", 0.012}, {"bin_B", 0.012}, {"bin_C", 0.012}};
  ScriptedCell cell;
  cell.scripts["kleenex_tissue_box"].found_beside = "dove_beauty_bar";
  cell.scripts["kleenex_tissue_box"].in_the_way_once = true;
  const PickTaskResult result = Run(cell);
  EXPECT_TRUE(cell.planned_at["dove_beauty_bar"].empty());
  EXPECT_EQ(result.final_contents.bin_contents.at("bin_A").size(), 1u);  // the soap stays
  EXPECT_TRUE(result.targets[0].picked);  // at its second attempt, after the others
  EXPECT_EQ(result.targets[0].attempts, 2);
}

TEST_F(PickTaskTest, AnItemMovedAsideBeforeARestartStaysWhereItWentAndIsNotMovedAgain) {
  options_.bin_volume_m3 = {{"bin_A", 0.012}, {"bin_D", 0.012}};
  ScriptedCell first;
  first.scripts["kleenex_tissue_box"].found_beside = "dove_beauty_bar";
  first.scripts["kleenex_tissue_box"].in_the_way_once = true;
  first.crash_at_visit["scan/bin_A/0"] = 2;  // the host dies as the target is scanned again
  EXPECT_EQ(Run(first).state, TaskState::kFailed);
  EXPECT_EQ(first.placed, std::vector<std::string>{"dove_beauty_bar"});
  options_.max_attempts = 3;  // the attempt the crash cut short counts as one
  ScriptedCell second;
  const PickTaskResult result = Run(second);
  EXPECT_TRUE(second.planned_at["dove_beauty_bar"].empty());  // not moved twice
  // The resumed run knows the soap is in bin_D: bin_A's detection no longer looks for it.
  EXPECT_TRUE(second.others_asked["kleenex_tissue_box"].empty());
  EXPECT_EQ(result.final_contents.bin_contents.at("bin_D"),
            std::vector<std::string>{"dove_beauty_bar"});
  EXPECT_EQ(result.items_moved, 3);
}

TEST_F(PickTaskTest, AResumeWithAnItemBeingMovedAsideOnTheCupCarriesItOn) {
  options_.bin_volume_m3 = {{"bin_A", 0.012}, {"bin_D", 0.012}};
  {
    Journal journal((dir_ / "journal.jsonl").string());
    journal.Append("begin", "pick/bin_A/kleenex_tissue_box/1/scan", 1.0);
    journal.Append("begin", "room/bin_A/dove_beauty_bar/1/scan", 10.0);
    journal.Append("begin", "room/bin_A/dove_beauty_bar/1/grasp", 20.0);
    journal.Append("done", "room/bin_A/dove_beauty_bar/1/grasp", 22.0);
  }
  ScriptedCell cell;
  cell.held = true, cell.current = "dove_beauty_bar";  // still sealed after the crash
  const PickTaskResult result = Run(cell);
  EXPECT_EQ(cell.destinations.front(), "bin_D");
  EXPECT_EQ(cell.placed.front(), "dove_beauty_bar");
  EXPECT_EQ(result.final_contents.bin_contents.at("bin_D"),
            std::vector<std::string>{"dove_beauty_bar"});
  EXPECT_EQ(result.items_moved, 3);
}

}  // namespace
}  // namespace picking::orchestrator
