// A whole APC pick task in simulation, every service its own process: the simulator with
// pick_layout_1, the scanner, detector, planner, robot and gripper on their simulated
// backends, and the orchestrator running the task file. The output file it writes must say
// where every item really is (the simulator's ground truth), its score must be the rules'
// score of what really happened, and the events must tell the story of each target.
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>

#include "libs/apc/catalogue.h"
#include "libs/apc/scoring.h"
#include "libs/apc/task.h"
#include "libs/proto_convert/proto_convert.h"
#include "picking/orchestrator/v1/orchestrator.grpc.pb.h"
#include "picking/simulator/v1/simulator.grpc.pb.h"
#include "tests/harness/server_process.h"

namespace picking::testing {
namespace {

namespace sim = ::picking::simulator::v1;
namespace orch = ::picking::orchestrator::v1;
namespace pc = ::picking::proto_convert;

std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

// Runs the `picking` command line with `args` (split at spaces); returns its exit status,
// its output in `out`.
int RunCli(const std::string& args, std::string* out) {
  std::vector<std::string> words;
  std::stringstream in(args);
  for (std::string w; in >> w;) words.push_back(w);
  const ProgramResult result = RunProgram(ServerBinary("picking"), words);
  *out = result.output;
  return result.exit_status;
}

class TaskPickTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new std::string(::testing::TempDir() + "/task_pick_test");
    std::filesystem::remove_all(*dir_);
    std::filesystem::create_directories(*dir_ + "/calibration");
    simulator_ = new ServerProcess(ServerBinary("picking-simulator"));
    const std::string sim = "--sim.address=" + simulator_->address();
    robot_ = new ServerProcess(ServerBinary("picking-robot"),
                               {"--backend=sim", sim, "--sim.time_scale=20"});
    gripper_ = new ServerProcess(ServerBinary("picking-gripper"), {"--backend=sim", sim});
    scanner_ = new ServerProcess(ServerBinary("picking-scanner"),
                                 {sim, "--calibration.dir=" + *dir_ + "/calibration"});
    detector_ = new ServerProcess(ServerBinary("picking-detector"),
                                  {"--cache_dir=" + *dir_ + "/cache", "--time_budget_scale=10"},
                                  std::chrono::seconds(300));
    planner_ = new ServerProcess(ServerBinary("picking-planner"), {}, std::chrono::seconds(120));
    orchestrator_ = new ServerProcess(
        ServerBinary("picking-orchestrator"),
        {"--tasks_dir=" + *dir_ + "/tasks", "--scanner.address=" + scanner_->address(),
         "--detector.endpoints=" + detector_->address(), "--planner.address=" + planner_->address(),
         "--robot.address=" + robot_->address(), "--gripper.address=" + gripper_->address()});
  }
  static void TearDownTestSuite() {
    for (ServerProcess* s :
         {orchestrator_, planner_, detector_, scanner_, gripper_, robot_, simulator_}) {
      EXPECT_EQ(s->Stop(), 0);
      delete s;
    }
  }

  static sim::GetGroundTruthResponse Truth() {
    auto stub = sim::SimulatorService::NewStub(simulator_->Channel());
    grpc::ClientContext ctx;
    sim::GetGroundTruthResponse truth;
    EXPECT_TRUE(stub->GetGroundTruth(&ctx, {}, &truth).ok());
    return truth;
  }

  // Where the simulator says every item is, as a task (bins and tote).
  static apc::Task TrueContents(const sim::GetGroundTruthResponse& truth) {
    apc::Task contents;
    for (char b = 'A'; b <= 'L'; ++b) contents.bin_contents[std::string("bin_") + b] = {};
    for (const auto& item : truth.items()) {
      const std::string where = pc::ContainerName(item.container());
      if (where == "tote") {
        contents.tote_contents.push_back(item.item().name());
      } else if (contents.bin_contents.count(where)) {
        contents.bin_contents[where].push_back(item.item().name());
      }
    }
    for (auto& [bin, items] : contents.bin_contents) std::sort(items.begin(), items.end());
    std::sort(contents.tote_contents.begin(), contents.tote_contents.end());
    return contents;
  }

  // Checks that the output file says where every item really is (no misreport penalty);
  // returns what it reports, each list sorted.
  static apc::Task ExpectOutputMatchesTruth(const std::string& output_file,
                                            const sim::GetGroundTruthResponse& truth) {
    const apc::Catalogue catalogue = apc::Catalogue::FromCsvFile(apc::DefaultCataloguePath());
    apc::Task reported = apc::ParseTask(ReadText(output_file), catalogue, "output");
    for (auto& [bin, items] : reported.bin_contents) std::sort(items.begin(), items.end());
    std::sort(reported.tote_contents.begin(), reported.tote_contents.end());
    const apc::Task true_contents = TrueContents(truth);
    EXPECT_EQ(reported.tote_contents, true_contents.tote_contents);
    for (const auto& [bin, items] : true_contents.bin_contents) {
      EXPECT_EQ(reported.bin_contents[bin], items) << bin;
    }
    return reported;
  }

  // Checks that the output file holds as many items in every bin and the tote as the
  // simulator's truth (nothing lost, nothing counted twice); prints where an item's identity
  // differs (a wrong item taken for the target when the look back could not tell). Returns
  // the output file's contents.
  static apc::Task ExpectOutputCountsMatchTruth(const std::string& output_file,
                                                const sim::GetGroundTruthResponse& truth) {
    const apc::Catalogue catalogue = apc::Catalogue::FromCsvFile(apc::DefaultCataloguePath());
    const apc::Task reported = apc::ParseTask(ReadText(output_file), catalogue, "output");
    const apc::Task true_contents = TrueContents(truth);
    EXPECT_EQ(reported.tote_contents.size(), true_contents.tote_contents.size());
    for (const auto& [bin, items] : true_contents.bin_contents) {
      EXPECT_EQ(reported.bin_contents.at(bin).size(), items.size()) << bin;
      std::vector<std::string> said = reported.bin_contents.at(bin);
      std::sort(said.begin(), said.end());
      if (said != items) std::printf("%s: identity differs from the truth\n", bin.c_str());
    }
    return reported;
  }

  // Loads `task_json` into the simulator (seed 7); false when the simulator refuses it.
  static bool LoadIntoSimulator(const std::string& task_json) {
    auto stub = sim::SimulatorService::NewStub(simulator_->Channel());
    grpc::ClientContext ctx;
    sim::LoadLayoutRequest request;
    request.set_task_json(task_json);
    request.set_seed(7);
    sim::LoadLayoutResponse loaded;
    const grpc::Status status = stub->LoadLayout(&ctx, request, &loaded);
    EXPECT_TRUE(status.ok()) << status.error_message();
    return status.ok();
  }

  // Runs `task_json` as a stow task (300 s) through `orchestrator` to its end, printing its
  // events; the finished task (empty, with a failure recorded, when a call fails).
  static orch::GetTaskResponse RunStowToEnd(ServerProcess& orchestrator,
                                            const std::string& task_json) {
    auto stub = orch::OrchestratorService::NewStub(orchestrator.Channel());
    orch::StartTaskResponse started;
    {
      grpc::ClientContext ctx;
      orch::StartTaskRequest request;
      request.set_task_json(task_json);
      request.set_kind(orch::TASK_KIND_STOW);
      request.set_time_limit_s(300.0);
      const grpc::Status status = stub->StartTask(&ctx, request, &started);
      EXPECT_TRUE(status.ok()) << status.error_message();
      if (!status.ok()) return {};
    }
    {
      grpc::ClientContext ctx;
      orch::WatchTaskRequest request;
      request.set_task_id(started.task_id());
      auto reader = stub->WatchTask(&ctx, request);
      orch::WatchTaskResponse response;
      while (reader->Read(&response)) {
        const orch::TaskEvent& event = response.event();
        std::printf("[%7.1f s] %-36s %s\n", event.time_s(), event.item().c_str(),
                    event.message().c_str());
      }
      EXPECT_TRUE(reader->Finish().ok());
    }
    orch::GetTaskResponse task;
    grpc::ClientContext ctx;
    orch::GetTaskRequest request;
    request.set_task_id(started.task_id());
    EXPECT_TRUE(stub->GetTask(&ctx, request, &task).ok());
    return task;
  }

  static std::string* dir_;
  static ServerProcess *simulator_, *robot_, *gripper_, *scanner_, *detector_, *planner_,
      *orchestrator_;
};
std::string* TaskPickTest::dir_ = nullptr;
ServerProcess *TaskPickTest::simulator_ = nullptr, *TaskPickTest::robot_ = nullptr,
              *TaskPickTest::gripper_ = nullptr, *TaskPickTest::scanner_ = nullptr,
              *TaskPickTest::detector_ = nullptr, *TaskPickTest::planner_ = nullptr,
              *TaskPickTest::orchestrator_ = nullptr;

// The moves that take `initial` to `final` (bins and tote): per item, each place it left
// paired with a place it arrived at (an item moved aside into another bin is one of them).
std::vector<apc::Event> MovesBetween(const apc::Task& initial, const apc::Task& final) {
  std::map<std::string, std::map<std::string, int>> change;  // item -> place -> final - initial
  auto count = [&](const apc::Task& task, int sign) {
    for (const auto& [bin, items] : task.bin_contents) {
      for (const std::string& item : items) change[item][bin] += sign;
    }
    for (const std::string& item : task.tote_contents) change[item]["tote"] += sign;
  };
  count(initial, -1);
  count(final, +1);
  std::vector<apc::Event> moves;
  for (const auto& [item, places] : change) {
    std::vector<std::string> from, to;
    for (const auto& [place, n] : places) {
      for (int k = 0; k < -n; ++k) from.push_back(place);
      for (int k = 0; k < n; ++k) to.push_back(place);
    }
    for (std::size_t k = 0; k < std::min(from.size(), to.size()); ++k) {
      moves.push_back(apc::MoveEvent(item, from[k], to[k]));
    }
  }
  return moves;
}

// Loads pick_layout_1 into the simulator (seed 7); returns the task file's text.
std::string LoadLayout1(ServerProcess& simulator) {
  const std::string task_json =
      ReadText(std::string(PICKING_DATA_DIR) + "/apc2016/tasks/pick_layout_1.json");
  auto stub = sim::SimulatorService::NewStub(simulator.Channel());
  grpc::ClientContext ctx;
  sim::LoadLayoutRequest request;
  request.set_task_json(task_json);
  request.set_seed(7);
  sim::LoadLayoutResponse loaded;
  EXPECT_TRUE(stub->LoadLayout(&ctx, request, &loaded).ok());
  return task_json;
}

TEST_F(TaskPickTest, PickLayout1EndToEndTheOutputFileMatchesTheSimulatorsTruth) {
  const std::string task_json = LoadLayout1(*simulator_);
  auto stub = orch::OrchestratorService::NewStub(orchestrator_->Channel());
  orch::StartTaskResponse started;
  {
    grpc::ClientContext ctx;
    orch::StartTaskRequest request;
    request.set_task_json(task_json);
    const grpc::Status status = stub->StartTask(&ctx, request, &started);
    ASSERT_TRUE(status.ok()) << status.error_message();
  }
  // Watch it to the end; a second StartTask meanwhile is refused.
  {
    grpc::ClientContext ctx;
    orch::StartTaskRequest request;
    request.set_task_json(task_json);
    orch::StartTaskResponse second;
    EXPECT_EQ(stub->StartTask(&ctx, request, &second).error_code(),
              grpc::StatusCode::FAILED_PRECONDITION);
  }
  std::vector<orch::TaskEvent> events;
  {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::minutes(20));
    orch::WatchTaskRequest request;
    request.set_task_id(started.task_id());
    auto reader = stub->WatchTask(&ctx, request);
    orch::WatchTaskResponse response;
    while (reader->Read(&response)) {
      const orch::TaskEvent& event = response.event();
      std::printf("[%7.1f s] %-36s %-7s %s %s\n", event.time_s(), event.item().c_str(),
                  orch::Step_Name(event.step()).c_str() + 5, event.step_ok() ? "" : "FAIL",
                  event.message().c_str());
      events.push_back(event);
    }
    ASSERT_TRUE(reader->Finish().ok());
  }
  ASSERT_FALSE(events.empty());
  for (std::size_t i = 0; i < events.size(); ++i) EXPECT_EQ(events[i].sequence(), i);
  EXPECT_EQ(events.back().state(), orch::TASK_STATE_SUCCEEDED) << events.back().message();

  orch::GetTaskResponse task;
  {
    grpc::ClientContext ctx;
    orch::GetTaskRequest request;
    request.set_task_id(started.task_id());
    ASSERT_TRUE(stub->GetTask(&ctx, request, &task).ok());
  }
  ASSERT_EQ(task.state(), orch::TASK_STATE_SUCCEEDED) << task.error();
  const orch::TaskResult& result = task.result();
  std::printf("%u items moved, %u failed, score %d, %.0f s task clock\n", result.items_moved(),
              result.items_failed(), result.score(), result.duration_s());
  EXPECT_EQ(result.items_moved() + result.items_failed(), 12u);
  EXPECT_GE(result.items_moved(), 1u);
  EXPECT_TRUE(std::filesystem::exists(result.report_file()));

  // The output file says where every item really is: no misreport penalty.
  const apc::Catalogue catalogue = apc::Catalogue::FromCsvFile(apc::DefaultCataloguePath());
  const sim::GetGroundTruthResponse truth = Truth();
  const apc::Task reported = ExpectOutputMatchesTruth(result.output_file(), truth);
  const apc::Task true_contents = TrueContents(truth);
  EXPECT_FALSE(truth.has_attached_item() && !truth.attached_item().name().empty());
  // The score the orchestrator reports is the rules' score of what is really in the tote.
  apc::ScoringInput input;
  input.initial = apc::ParseTask(task_json, catalogue, "task");
  input.events = MovesBetween(input.initial, true_contents);
  input.reported = reported;
  input.true_final = true_contents;
  for (auto& [bin, items] : input.true_final.bin_contents) std::sort(items.begin(), items.end());
  const apc::ScoreReport score = apc::Score(input, catalogue);
  EXPECT_EQ(result.score(), score.total);
  EXPECT_GT(score.total, 0);

  // The command line on the finished task: the replayed events, its status and its score.
  const std::string at = " --address " + orchestrator_->address() + " ";
  std::string out;
  EXPECT_EQ(RunCli("watch --json" + at + started.task_id(), &out), 0) << out;
  EXPECT_EQ(static_cast<std::size_t>(std::count(out.begin(), out.end(), '\n')), events.size() + 1)
      << out;
  EXPECT_EQ(RunCli("status --json" + at + started.task_id(), &out), 0) << out;
  EXPECT_NE(out.find("\"score\":" + std::to_string(score.total)), std::string::npos) << out;
  EXPECT_EQ(RunCli("score" + at + started.task_id(), &out), 0) << out;
  EXPECT_NE(out.find(std::to_string(score.total) + "  total"), std::string::npos) << out;
  // --out writes the results from the answer (as a remote client or a container gets them).
  const std::string results = ::testing::TempDir() + "/task_pick_results";
  EXPECT_EQ(RunCli("watch" + at + started.task_id() + " --out " + results, &out), 0) << out;
  EXPECT_EQ(ReadText(results + "/output.json"), result.output_json());
  EXPECT_NE(ReadText(results + "/score.txt").find(std::to_string(score.total) + "\ttotal\n"),
            std::string::npos);
  EXPECT_NE(ReadText(results + "/task.json").find("\"state\": \"succeeded\""), std::string::npos);
}

// A stow task: stow_layout_1's tote items into the bins. Nothing may be lost: the output
// file's count of items in each bin and the tote must be the simulator's. (Which item went
// where is printed: the look back's Verify rejects only clear mismatches, so a held item
// mistaken for another can still be reported under the other's name.)
TEST_F(TaskPickTest, StowLayout1TheOutputFileMatchesTheSimulatorsTruth) {
  const std::string task_json =
      ReadText(std::string(PICKING_DATA_DIR) + "/apc2016/tasks/stow_layout_1.json");
  ASSERT_TRUE(LoadIntoSimulator(task_json));
  const orch::GetTaskResponse task = RunStowToEnd(*orchestrator_, task_json);
  ASSERT_EQ(task.state(), orch::TASK_STATE_SUCCEEDED) << task.error();
  EXPECT_EQ(task.kind(), orch::TASK_KIND_STOW);
  std::printf("stowed %u of %u, score %d\n", task.result().items_moved(), task.items_total(),
              task.result().score());
  ExpectOutputCountsMatchTruth(task.result().output_file(), Truth());
}

// The stow's table, with a second orchestrator set to take every item there first: each
// item is set down on the table, looked at from the verification pose, picked from the
// table again and stowed; the output file says where every item is.
TEST_F(TaskPickTest, AStowOverTheTableSetsEachItemDownTellsItAndStowsIt) {
  const std::string task_json = R"({"bin_contents": {
      "bin_A": ["dove_beauty_bar"], "bin_B": [], "bin_C": ["hanes_tube_socks"], "bin_D": [],
      "bin_E": [], "bin_F": [], "bin_G": [], "bin_H": [], "bin_I": [], "bin_J": [], "bin_K": [],
      "bin_L": []}, "tote_contents": ["kleenex_tissue_box", "folgers_classic_roast_coffee"]})";
  ASSERT_TRUE(LoadIntoSimulator(task_json));
  ServerProcess over_table(
      ServerBinary("picking-orchestrator"),
      {"--tasks_dir=" + *dir_ + "/tasks_table", "--stow.table=always",
       "--scanner.address=" + scanner_->address(), "--detector.endpoints=" + detector_->address(),
       "--planner.address=" + planner_->address(), "--robot.address=" + robot_->address(),
       "--gripper.address=" + gripper_->address()});
  const orch::GetTaskResponse task = RunStowToEnd(over_table, task_json);
  ASSERT_EQ(task.state(), orch::TASK_STATE_SUCCEEDED) << task.error();
  std::printf("stowed over the table: %u of 2\n", task.result().items_moved());
  const sim::GetGroundTruthResponse truth = Truth();
  // Wherever the items ended (stowed, back in the tote, or left on the table when no pick
  // from it could be planned), the output file says where they are.
  ExpectOutputMatchesTruth(task.result().output_file(), truth);
  // The simulator saw an item set down on the table, and every stowed item went there first.
  int on_table = 0;
  for (const sim::WorldEvent& e : truth.events()) {
    on_table +=
        e.kind() == sim::EVENT_KIND_RELEASED && e.detail().find("table") != std::string::npos;
  }
  EXPECT_GE(on_table, 1);
  EXPECT_GE(on_table, static_cast<int>(task.result().items_moved()));
  EXPECT_EQ(over_table.Stop(), 0);
}

// Watches the task: kills the second detector replica at the first detection, then the
// orchestrator at the first grasp step (the approach under way). Returns the item it was
// grasping ("" if no grasp came).
std::string KillReplicaThenOrchestrator(orch::OrchestratorService::Stub& stub,
                                        const std::string& task_id,
                                        std::unique_ptr<ServerProcess>* second_detector,
                                        ServerProcess& orchestrator) {
  grpc::ClientContext ctx;
  orch::WatchTaskRequest watch;
  watch.set_task_id(task_id);
  auto reader = stub.WatchTask(&ctx, watch);
  orch::WatchTaskResponse response;
  std::string grasped;
  while (reader->Read(&response)) {
    const orch::TaskEvent& event = response.event();
    if (event.step() == orch::STEP_DETECT && *second_detector) {
      ::kill((*second_detector)->pid(), SIGKILL);
      EXPECT_EQ((*second_detector)->Stop(), 128 + SIGKILL);
      second_detector->reset();
    }
    if (event.step() == orch::STEP_GRASP) {
      grasped = event.item();
      ::kill(orchestrator.pid(), SIGKILL);
      break;
    }
  }
  ctx.TryCancel();
  return grasped;
}

// Completed places per item in a task journal (its "done" records of ".../<item>/<n>/place").
std::map<std::string, int> CompletedPlaces(const std::string& journal) {
  std::map<std::string, int> placed;
  std::stringstream lines(journal);
  for (std::string line; std::getline(lines, line);) {
    // Targets' places into the tote ("pick/..."), not items moved aside ("room/...").
    if (line.find("\"type\":\"done\"") == std::string::npos) continue;
    if (line.find("\"key\":\"pick/") == std::string::npos) continue;
    const std::size_t end = line.find("/place\"");
    if (end == std::string::npos) continue;
    const std::size_t start = line.rfind("/", line.rfind("/", end - 1) - 1) + 1;
    ++placed[line.substr(start, line.find('/', start) - start)];
  }
  return placed;
}

// Faults mid-task: one of two detector replicas is killed at the first detection, then the
// orchestrator itself in the middle of its first grasp's approach (the arm moving). A new
// orchestrator on the same task folder resumes the task: nothing is lost (the output file
// counts the items of every bin and the tote as the truth has them; which item is which is
// the detection's and the look back's matter, held exactly by the pick test above) and
// nothing is repeated (every item in the tote was grasped once).
TEST_F(TaskPickTest, AKilledReplicaAndAKilledOrchestratorCostNothingAndRepeatNoPick) {
  const std::string task_json = LoadLayout1(*simulator_);
  auto second_detector = std::make_unique<ServerProcess>(
      ServerBinary("picking-detector"),
      std::vector<std::string>{"--cache_dir=" + *dir_ + "/cache", "--time_budget_scale=10"},
      std::chrono::seconds(300));
  const std::vector<std::string> flags = {
      "--tasks_dir=" + *dir_ + "/fault_tasks",
      "--detector.endpoints=" + second_detector->address() + "," + detector_->address(),
      "--detector.health_period_s=1",
      "--scanner.address=" + scanner_->address(),
      "--planner.address=" + planner_->address(),
      "--robot.address=" + robot_->address(),
      "--gripper.address=" + gripper_->address()};
  auto orchestrator = std::make_unique<ServerProcess>(ServerBinary("picking-orchestrator"), flags);
  auto stub = orch::OrchestratorService::NewStub(orchestrator->Channel());
  orch::StartTaskRequest request;
  request.set_task_json(task_json);
  request.set_time_limit_s(240.0);  // the first targets; the clock skips the rest
  orch::StartTaskResponse started;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(stub->StartTask(&ctx, request, &started).ok());
  }
  const std::string first_grasped =
      KillReplicaThenOrchestrator(*stub, started.task_id(), &second_detector, *orchestrator);
  ASSERT_FALSE(first_grasped.empty()) << "no grasp was tried before the time limit";
  EXPECT_EQ(orchestrator->Stop(), 128 + SIGKILL);
  orchestrator = std::make_unique<ServerProcess>(ServerBinary("picking-orchestrator"), flags);
  stub = orch::OrchestratorService::NewStub(orchestrator->Channel());
  {
    grpc::ClientContext ctx;
    orch::ListTasksResponse list;
    ASSERT_TRUE(stub->ListTasks(&ctx, {}, &list).ok());
    ASSERT_EQ(list.tasks_size(), 1);
    EXPECT_EQ(list.tasks(0).task_id(), started.task_id());
    EXPECT_NE(list.tasks(0).error().find("interrupted"), std::string::npos);
  }
  orch::StartTaskRequest resume;
  resume.set_resume_task_id(started.task_id());
  resume.set_time_limit_s(240.0);
  {
    grpc::ClientContext ctx;
    orch::StartTaskResponse resumed;
    const grpc::Status status = stub->StartTask(&ctx, resume, &resumed);
    ASSERT_TRUE(status.ok()) << status.error_message();
    EXPECT_EQ(resumed.task_id(), started.task_id());
  }
  {
    grpc::ClientContext ctx;
    orch::WatchTaskRequest watch;
    watch.set_task_id(started.task_id());
    auto reader = stub->WatchTask(&ctx, watch);
    orch::WatchTaskResponse response;
    std::uint64_t expected = 0;
    while (reader->Read(&response)) EXPECT_EQ(response.event().sequence(), expected++);
    EXPECT_EQ(response.event().state(), orch::TASK_STATE_SUCCEEDED) << response.event().message();
  }
  orch::GetTaskResponse task;
  {
    grpc::ClientContext ctx;
    orch::GetTaskRequest get;
    get.set_task_id(started.task_id());
    ASSERT_TRUE(stub->GetTask(&ctx, get, &task).ok());
  }
  // Nothing lost: the output file counts every container's items as the truth has them.
  const apc::Task reported = ExpectOutputCountsMatchTruth(task.result().output_file(), Truth());
  // Nothing repeated: the journal records one completed place per item in the tote, and none
  // for any other.
  std::map<std::string, int> placed =
      CompletedPlaces(ReadText(*dir_ + "/fault_tasks/" + started.task_id() + "/journal.jsonl"));
  for (const std::string& item : reported.tote_contents) EXPECT_EQ(placed[item], 1) << item;
  int placed_total = 0;
  for (const auto& [item, n] : placed) placed_total += n;
  EXPECT_EQ(placed_total, static_cast<int>(reported.tote_contents.size()));

  std::printf("resumed after a kill during the approach to %s: %zu items in the tote\n",
              first_grasped.c_str(), reported.tote_contents.size());
  EXPECT_EQ(orchestrator->Stop(), 0);
}

}  // namespace
}  // namespace picking::testing
