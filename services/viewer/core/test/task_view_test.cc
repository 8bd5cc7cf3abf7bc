#include <gtest/gtest.h>

#include <chrono>
#include <thread>

#include "services/viewer/core/part_store.h"
#include "services/viewer/core/task_view.h"
#include "services/viewer/core/test/viewer_fixture.h"

namespace picking::viewer {
namespace {

TaskHeader TwoItems() {
  TaskHeader header;
  header.task_id = "task-1";
  header.work_order = {{"kleenex_tissue_box", "bin_A"}, {"crayola_64_ct", "bin_B"}};
  return header;
}

ViewEvent Event(const std::string& item, const std::string& step, bool ok = true,
                const std::string& message = "") {
  ViewEvent e;
  e.item = item;
  e.from = item == "crayola_64_ct" ? "bin_B" : "bin_A";
  e.step = step;
  e.ok = ok;
  e.message = message;
  e.items_total = 2;
  e.time_limit_s = 900;
  return e;
}

std::string StateOf(const TaskView& view, const std::string& item) {
  const nlohmann::json task = view.TaskJson();
  for (const nlohmann::json& i : task["items"]) {
    if (i["item"] == item) return i["state"];
  }
  return "?";
}

TEST(TaskViewTest, TheWorkOrderWaitsUntilItsItemsAreTried) {
  TaskView view(BundledModel(), TwoItems());
  const nlohmann::json task = view.TaskJson();
  ASSERT_EQ(task["items"].size(), 2u);
  EXPECT_EQ(task["items"][0]["state"], "waiting");
  EXPECT_EQ(task["task"]["items_total"], 2);
  EXPECT_TRUE(view.ScanJson().is_null());
  EXPECT_TRUE(view.PathJson().is_null());
}

TEST(TaskViewTest, AnItemGoesThroughTheStepsOfAPick) {
  TaskView view(BundledModel(), TwoItems());
  const std::string item = "kleenex_tissue_box";
  view.Apply(Event(item, "scan", true, "scanning bin_A"));
  EXPECT_EQ(StateOf(view, item), "scanning");

  ViewEvent scan = Event(item, "scan", true, "captured view 1");
  scan.scan_m = {1.0f, 0.0f, 0.8f, 1.1f, 0.1f, 0.8f};
  EXPECT_TRUE(view.Apply(scan) & TaskView::kScan);
  EXPECT_EQ(view.ScanJson()["points_m"].size(), 6u);

  view.Apply(Event(item, "detect", true, "detecting in 3 views"));
  EXPECT_EQ(StateOf(view, item), "scanning");
  ViewEvent found = Event(item, "detect", true, "found by ppf");
  found.detection = ViewEvent::Found{Eigen::Isometry3d::Identity(), 0.8, "ppf"};
  EXPECT_TRUE(view.Apply(found) & TaskView::kDetections);
  EXPECT_EQ(StateOf(view, item), "detected");
  ASSERT_EQ(view.DetectionsJson().size(), 1u);
  EXPECT_TRUE(view.DetectionsJson()[0]["current"].get<bool>());

  ViewEvent planned = Event(item, "plan", true, "planned grasp 'top'");
  planned.planned_path_q = {{0.0, -1.5, 1.5, -1.5, -1.57, 0.0}, {0.1, -1.4, 1.4, -1.6, -1.57, 0.0}};
  EXPECT_TRUE(view.Apply(planned) & TaskView::kPath);
  EXPECT_EQ(StateOf(view, item), "planned");
  EXPECT_EQ(view.PathJson()["tcp_m"].size(), 2u);

  view.Apply(Event(item, "grasp"));
  EXPECT_EQ(StateOf(view, item), "picking");
  view.Apply(Event(item, "place", true, "carrying to tote"));
  EXPECT_EQ(StateOf(view, item), "picking");
  ViewEvent placed = Event(item, "place", true, "in the tote");
  placed.to = "tote";
  placed.items_done = 1;
  placed.score = 20;
  EXPECT_TRUE(view.Apply(placed) & TaskView::kDetections);
  EXPECT_EQ(StateOf(view, item), "picked");
  EXPECT_TRUE(view.DetectionsJson().empty());  // it is in the tote now
  EXPECT_EQ(view.TaskJson()["task"]["score"], 20);
  EXPECT_EQ(view.TaskJson()["task"]["items_done"], 1);
}

TEST(TaskViewTest, AFailedItemShowsItsReasonUntilItIsTriedAgain) {
  TaskView view(BundledModel(), TwoItems());
  const std::string item = "crayola_64_ct";
  view.Apply(Event(item, "scan", true, "scanning bin_B"));
  view.Apply(Event(item, "", false, "no plan: wedged in"));
  const nlohmann::json task = view.TaskJson();
  const nlohmann::json& failed = task["items"][1];
  EXPECT_EQ(failed["state"], "failed");
  EXPECT_EQ(failed["reason"], "no plan: wedged in");
  EXPECT_EQ(failed["attempts"], 1);
  view.Apply(Event(item, "scan", true, "scanning bin_B"));
  EXPECT_EQ(StateOf(view, item), "scanning");
  EXPECT_EQ(view.TaskJson()["items"][1]["attempts"], 2);
}

TEST(TaskViewTest, TheLastEventEndsTheTask) {
  TaskView view(BundledModel(), TwoItems());
  ViewEvent end;
  end.state = "succeeded";
  end.score = 35;
  end.message = "score 35";
  view.Apply(end);
  EXPECT_EQ(view.TaskJson()["task"]["state"], "succeeded");
  EXPECT_EQ(view.TaskJson()["task"]["score"], 35);
  EXPECT_EQ(view.TaskJson()["log"].size(), 1u);
}

TEST(TaskViewTest, TheLogKeepsTheLastFiftyEvents) {
  TaskView view(BundledModel(), TwoItems());
  for (int i = 0; i < 80; ++i)
    view.Apply(Event("kleenex_tissue_box", "scan", true, std::to_string(i)));
  const nlohmann::json log = view.TaskJson()["log"];
  ASSERT_EQ(log.size(), 50u);
  EXPECT_EQ(log.back()["message"], "79");
}

TEST(PartStoreTest, AReaderGetsEveryPartOnceThenOnlyChanges) {
  PartStore store;
  store.Set("a", 1);
  store.Set("b", "x");
  PartStore::Seen seen;
  auto first = store.Changes(seen, std::chrono::milliseconds(0));
  EXPECT_EQ(first.size(), 2u);
  EXPECT_TRUE(store.Changes(seen, std::chrono::milliseconds(0)).empty());
  store.SetIfChanged("a", 1);  // the same value: no news
  EXPECT_TRUE(store.Changes(seen, std::chrono::milliseconds(0)).empty());
  store.Set("a", 2);
  auto second = store.Changes(seen, std::chrono::milliseconds(0));
  ASSERT_EQ(second.size(), 1u);
  EXPECT_EQ(second[0].first, "a");
  EXPECT_EQ(second[0].second, "2");
}

TEST(PartStoreTest, AWaitingReaderWakesOnAChange) {
  PartStore store;
  store.Set("a", 1);
  PartStore::Seen seen;
  store.Changes(seen, std::chrono::milliseconds(0));
  std::thread writer([&] { store.Set("a", 2); });
  // Waits for the writer's change (the timeout is only a bound if the wake-up were lost).
  std::vector<std::pair<std::string, std::string>> changes;
  while (changes.empty()) changes = store.Changes(seen, std::chrono::seconds(10));
  writer.join();
  EXPECT_EQ(changes[0].second, "2");
}

}  // namespace
}  // namespace picking::viewer
