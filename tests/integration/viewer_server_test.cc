// picking-viewer as a process: the page and its files, what it says before and after the
// orchestrator answers, a finished task shown from the orchestrator's journal, event streams
// whose clients leave, and a clean stop with a stream open.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <functional>
#include <nlohmann/json.hpp>
#include <thread>

#include "services/orchestrator/core/journal.h"
#include "tests/harness/server_process.h"

// Last: it brings in <resolv.h>, whose _res macro breaks Eigen's headers included after it.
#include <httplib.h>

namespace picking::testing {
namespace {

constexpr char kBinary[] = "picking-viewer";

// A port nothing listens on now (the kernel's pick, released at once).
int FreePort() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr);
  socklen_t length = sizeof addr;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &length);
  const int port = ntohs(addr.sin_port);
  ::close(fd);
  return port;
}

// Polls `condition` until it holds; the bound only ends a test whose condition never comes.
bool Eventually(const std::function<bool()>& condition,
                std::chrono::seconds bound = std::chrono::seconds(60)) {
  const auto end = std::chrono::steady_clock::now() + bound;
  while (std::chrono::steady_clock::now() < end) {
    if (condition()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return false;
}

class ViewerServerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    orchestrator_port_ = FreePort();
    http_port_ = FreePort();
    viewer_ = std::make_unique<ServerProcess>(
        ServerBinary(kBinary),
        std::vector<std::string>{
            "--http_listen=127.0.0.1:" + std::to_string(http_port_),
            "--orchestrator.address=127.0.0.1:" + std::to_string(orchestrator_port_),
            "--robot.address=127.0.0.1:1"});
    http_ = std::make_unique<httplib::Client>("127.0.0.1", http_port_);
    http_->set_read_timeout(10, 0);
  }
  void TearDown() override {
    if (viewer_) EXPECT_EQ(viewer_->Stop(), 0);
    if (orchestrator_) EXPECT_EQ(orchestrator_->Stop(), 0);
  }

  // The orchestrator on the port the viewer was told, its peers nowhere.
  void StartOrchestrator(const std::string& tasks_dir) {
    orchestrator_ = std::make_unique<ServerProcess>(
        ServerBinary("picking-orchestrator"),
        std::vector<std::string>{"--listen=127.0.0.1:" + std::to_string(orchestrator_port_),
                                 "--tasks_dir=" + tasks_dir, "--scanner.address=127.0.0.1:1",
                                 "--detector.endpoints=127.0.0.1:1",
                                 "--planner.address=127.0.0.1:1", "--robot.address=127.0.0.1:1",
                                 "--gripper.address=127.0.0.1:1"});
  }

  nlohmann::json Get(const std::string& path, int expected_status = 200) {
    const auto res = http_->Get(path.c_str());
    EXPECT_TRUE(res) << path;
    if (!res) return nullptr;
    EXPECT_EQ(res->status, expected_status) << path << ": " << res->body;
    return nlohmann::json::parse(res->body, nullptr, false);
  }

  int orchestrator_port_ = 0, http_port_ = 0;
  std::unique_ptr<ServerProcess> viewer_, orchestrator_;
  std::unique_ptr<httplib::Client> http_;
};

TEST_F(ViewerServerTest, ServesThePageItsFilesAndTheCellAndNothingElse) {
  const auto page = http_->Get("/");
  ASSERT_TRUE(page);
  EXPECT_EQ(page->status, 200);
  EXPECT_NE(page->get_header_value("Content-Type").find("text/html"), std::string::npos);
  EXPECT_NE(page->body.find("viewer.js"), std::string::npos);
  for (const char* path :
       {"/viewer.js", "/viewer.css", "/three/three.min.js", "/three/STLLoader.js",
        "/three/OrbitControls.js", "/files/items/kleenex_tissue_box.stl"}) {
    const auto res = http_->Get(path);
    ASSERT_TRUE(res) << path;
    EXPECT_EQ(res->status, 200) << path;
    EXPECT_GT(res->body.size(), 100u) << path;
  }
  const nlohmann::json cell = Get("/api/cell");
  ASSERT_EQ(cell["bins"].size(), 12u);
  for (const nlohmann::json& link : cell["arm"]["links"]) {
    const auto res = http_->Get(link["mesh"].get<std::string>().c_str());
    ASSERT_TRUE(res);
    EXPECT_EQ(res->status, 200) << link["mesh"];
  }
  for (const char* path : {"/files/../../etc/passwd", "/files/cell/../../cell/default_cell.yaml",
                           "/files/items/no_such_item.stl", "/etc/passwd", "/index.htm"}) {
    const auto res = http_->Get(path);
    ASSERT_TRUE(res) << path;
    EXPECT_EQ(res->status, 404) << path;
  }
  Get("/api/view?task=../../x", 400);
}

TEST_F(ViewerServerTest, SaysTheOrchestratorIsMissingAndFindsItWhenItComes) {
  // Started before the orchestrator: the page is told so, and the viewer keeps trying.
  ASSERT_TRUE(Eventually([&] {
    const nlohmann::json view = Get("/api/view");
    return view["status"]["orchestrator"] == "unreachable" &&
           view["status"]["message"].get<std::string>().find("retrying") != std::string::npos;
  }));
  EXPECT_TRUE(Get("/api/view")["task"].is_null());
  EXPECT_EQ(Get("/api/tasks", 503)["error"].get<std::string>().rfind("orchestrator", 0), 0u);

  StartOrchestrator(::testing::TempDir() + "/viewer_no_tasks");
  EXPECT_TRUE(Eventually([&] {
    const nlohmann::json view = Get("/api/view");
    return view["status"]["orchestrator"] == "connected" &&
           view["status"]["message"].get<std::string>().find("waiting for a task") !=
               std::string::npos;
  })) << Get("/api/view")["status"];
  EXPECT_TRUE(Eventually([&] {
    const nlohmann::json view = Get("/api/view?task=task-nope");
    return view["status"]["message"].get<std::string>().find("no task 'task-nope'") !=
           std::string::npos;
  })) << Get("/api/view?task=task-nope")["status"];
  // The robot is not there either: said, and the arm is not drawn.
  EXPECT_EQ(Get("/api/view")["status"]["robot"], "unreachable");
  EXPECT_TRUE(Get("/api/view")["arm"].is_null());
}

// A finished task as the orchestrator journaled it: the viewer shows it through WatchTask's
// replay, with its items' states, the detection still in its bin, the scan and the path.
TEST_F(ViewerServerTest, ShowsAFinishedTaskFromTheOrchestratorsJournal) {
  const std::string dir = ::testing::TempDir() + "/viewer_finished";
  std::filesystem::remove_all(dir);
  const std::string task_dir = dir + "/task-20260101-000000-1";
  std::filesystem::create_directories(task_dir);
  {
    orchestrator::Journal journal(task_dir + "/journal.jsonl");
    journal.Append("task", "", 0.0,
                   {{"kind", "pick"},
                    {"work_order",
                     nlohmann::json::array({nlohmann::json::array({"kleenex_tissue_box", "bin_A"}),
                                            nlohmann::json::array({"crayola_64_ct", "bin_B"})})}});
    auto event = [&](double t, const std::string& item, const std::string& bin,
                     const std::string& step, bool ok, const std::string& message,
                     nlohmann::json scene = nullptr, const std::string& to = "", int done = 0,
                     int score = 0) {
      nlohmann::json data = {{"item", item},         {"from", bin}, {"to", to},
                             {"step", step},         {"ok", ok},    {"message", message},
                             {"done", done},         {"total", 2},  {"score", score},
                             {"time_limit_s", 900.0}};
      if (!scene.is_null()) data["scene"] = scene;
      journal.Append("event", "", t, data);
    };
    event(1, "kleenex_tissue_box", "bin_A", "scan", true, "captured view 1",
          {{"scan_mm", {1000, 200, 900, 1010, 210, 905}}});
    event(2, "kleenex_tissue_box", "bin_A", "detect", true, "found by ppf",
          {{"detection",
            {{"position_m", {1.0, 0.2, 0.9}},
             {"orientation_wxyz", {1, 0, 0, 0}},
             {"score", 0.9},
             {"method", "METHOD_PPF"}}}});
    event(3, "kleenex_tissue_box", "bin_A", "plan", true, "planned",
          {{"path_rad", {{0.0, -1.5, 1.5, -1.5, -1.57, 0.0}, {0.1, -1.4, 1.4, -1.6, -1.57, 0.0}}},
           {"head_angle_rad", 0.0}});
    event(10, "kleenex_tissue_box", "bin_A", "place", true, "in the tote", nullptr, "tote", 1, 20);
    event(11, "crayola_64_ct", "bin_B", "detect", true, "found by sift",
          {{"detection",
            {{"position_m", {1.0, -0.1, 0.9}},
             {"orientation_wxyz", {1, 0, 0, 0}},
             {"score", 0.5},
             {"method", "METHOD_SIFT"}}}});
    event(12, "crayola_64_ct", "bin_B", "", false, "no plan: wedged in", nullptr, "", 1, 20);
    journal.Append("end", "", 15.0, {{"state", 1}, {"error", ""}, {"score", 20}, {"moved", 1}});
  }
  StartOrchestrator(dir);
  nlohmann::json view;
  ASSERT_TRUE(Eventually([&] {
    view = Get("/api/view");
    return view["task"].is_object() && view["task"]["state"] == "succeeded";
  })) << view.dump();
  EXPECT_EQ(view["task"]["task_id"], "task-20260101-000000-1");
  EXPECT_EQ(view["task"]["score"], 20);
  EXPECT_EQ(view["task"]["time_limit_s"], 900.0);
  ASSERT_EQ(view["items"].size(), 2u);
  EXPECT_EQ(view["items"][0]["state"], "picked");
  EXPECT_EQ(view["items"][0]["method"], "ppf");
  EXPECT_EQ(view["items"][1]["state"], "failed");
  EXPECT_EQ(view["items"][1]["reason"], "no plan: wedged in");
  // The picked item left its bin; the failed one is still where it was found.
  ASSERT_EQ(view["detections"].size(), 1u);
  EXPECT_EQ(view["detections"][0]["item"], "crayola_64_ct");
  EXPECT_NEAR(view["detections"][0]["X"][12].get<double>(), 1.0, 1e-9);
  EXPECT_EQ(view["scan"]["points_m"].size(), 6u);
  EXPECT_EQ(view["path"]["tcp_m"].size(), 2u);
  // The same by task id.
  EXPECT_TRUE(Eventually([&] {
    return Get("/api/view?task=task-20260101-000000-1")["task"]["state"] == "succeeded";
  }));
  const nlohmann::json tasks = Get("/api/tasks");
  ASSERT_EQ(tasks["tasks"].size(), 1u);
  EXPECT_EQ(tasks["tasks"][0]["state"], "succeeded");
}

TEST_F(ViewerServerTest, StreamsSurviveClientsThatLeaveAndEndAtShutdown) {
  // Clients that read a little of the stream and hang up.
  for (int i = 0; i < 20; ++i) {
    httplib::Client client("127.0.0.1", http_port_);
    int events = 0;
    client.Get("/api/stream", [&](const char* data, std::size_t size) {
      events += static_cast<int>(std::count(data, data + size, '\n'));
      return events < 4;  // leaves mid-stream
    });
    EXPECT_GE(events, 4);
  }
  ASSERT_TRUE(viewer_->Alive());
  const auto health = http_->Get("/healthz");
  ASSERT_TRUE(health);
  EXPECT_EQ(health->body, "ok\n");
  // A stream open while the viewer is asked to stop: it stops within its grace period.
  std::atomic<bool> streaming{false};
  std::thread reader([&] {
    httplib::Client client("127.0.0.1", http_port_);
    client.set_read_timeout(60, 0);
    client.Get("/api/stream", [&](const char*, std::size_t) {
      streaming = true;
      return true;
    });
  });
  ASSERT_TRUE(Eventually([&] { return streaming.load(); }));
  const auto start = std::chrono::steady_clock::now();
  EXPECT_EQ(viewer_->Stop(), 0);
  EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(10));
  viewer_.reset();
  reader.join();
}

TEST(ViewerServerFlagsTest, RefusesBadSettings) {
  for (const std::vector<std::string>& args : {std::vector<std::string>{"--http_listen=nonsense"},
                                               {"--arm_rate_hz=0"},
                                               {"--max_tasks=1000"},
                                               {"--web_dir=/nonexistent"},
                                               {"--orchestrator.address="}}) {
    const ProgramResult result = RunProgram(ServerBinary(kBinary), args);
    EXPECT_NE(result.exit_status, 0) << args[0] << ": " << result.output;
  }
}

}  // namespace
}  // namespace picking::testing
