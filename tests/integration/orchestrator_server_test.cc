// Integration test of the picking-orchestrator server binary through its generated client.
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>
#include <chrono>

#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>

#include "picking/orchestrator/v1/orchestrator.grpc.pb.h"
#include "tests/harness/server_process.h"
#include "tests/harness/service_checks.h"

namespace picking::testing {
namespace {

const char kBinary[] = "picking-orchestrator";

TEST(OrchestratorServerTest, ServesHealthAndReflectionAndStopsCleanly) {
  ExpectStandardServerBehaviour(ServerBinary(kBinary),
                                "picking.orchestrator.v1.OrchestratorService",
                                "picking/orchestrator/v1/orchestrator.proto");
}

TEST(OrchestratorServerTest, RejectsBadFlags) { ExpectRejectsBadFlags(ServerBinary(kBinary)); }

// The orchestrator alone, its peers not started: requests are checked before anything moves.
class OrchestratorAloneTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = ::testing::TempDir() + "/orchestrator_alone";
    std::filesystem::remove_all(dir_);
    // Peers on a port nothing listens on.
    server_ = std::make_unique<ServerProcess>(
        ServerBinary(kBinary),
        std::vector<std::string>{"--tasks_dir=" + dir_, "--scanner.address=127.0.0.1:1",
                                 "--detector.endpoints=127.0.0.1:1",
                                 "--planner.address=127.0.0.1:1", "--robot.address=127.0.0.1:1",
                                 "--gripper.address=127.0.0.1:1"});
    stub_ = orchestrator::v1::OrchestratorService::NewStub(server_->Channel());
  }
  void TearDown() override { EXPECT_EQ(server_->Stop(), 0); }

  grpc::Status Start(const std::string& json, std::vector<std::string> ease_order = {}) {
    grpc::ClientContext ctx;
    orchestrator::v1::StartTaskRequest request;
    request.set_task_json(json);
    for (const auto& e : ease_order) request.add_ease_order(e);
    orchestrator::v1::StartTaskResponse response;
    return stub_->StartTask(&ctx, request, &response);
  }

  std::string dir_;
  std::unique_ptr<ServerProcess> server_;
  std::unique_ptr<orchestrator::v1::OrchestratorService::Stub> stub_;
};

std::string Layout1() {
  std::ifstream in(std::string(PICKING_DATA_DIR) + "/apc2016/tasks/pick_layout_1.json");
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

TEST_F(OrchestratorAloneTest, ListsNoTasksAndDoesNotKnowUnknownOnes) {
  grpc::ClientContext ctx;
  orchestrator::v1::ListTasksResponse list;
  ASSERT_TRUE(stub_->ListTasks(&ctx, {}, &list).ok());
  EXPECT_EQ(list.tasks_size(), 0);
  grpc::ClientContext get_ctx;
  orchestrator::v1::GetTaskRequest get;
  get.set_task_id("task-nope");
  orchestrator::v1::GetTaskResponse task;
  EXPECT_EQ(stub_->GetTask(&get_ctx, get, &task).error_code(), grpc::StatusCode::NOT_FOUND);
  grpc::ClientContext cancel_ctx;
  orchestrator::v1::CancelTaskRequest cancel;
  cancel.set_task_id("task-nope");
  orchestrator::v1::CancelTaskResponse cancelled;
  EXPECT_EQ(stub_->CancelTask(&cancel_ctx, cancel, &cancelled).error_code(),
            grpc::StatusCode::NOT_FOUND);
}

TEST_F(OrchestratorAloneTest, RefusesBadTaskFilesNamingTheField) {
  grpc::Status s = Start("");
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  s = Start("{\"bin_contents\": ");
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("malformed JSON"), std::string::npos) << s.error_message();
  std::string unknown = Layout1();
  unknown.replace(unknown.find("kleenex_tissue_box"), 18, "no_such_item_at_all");
  s = Start(unknown);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::NOT_FOUND) << s.error_message();
  EXPECT_NE(s.error_message().find("no_such_item_at_all"), std::string::npos);
  s = Start(Layout1(), {"rawlings_baseball_not_in_the_order"});
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_NE(s.error_message().find("ease_order[0]"), std::string::npos) << s.error_message();
}

TEST_F(OrchestratorAloneTest, AValidTaskWithItsServicesDownIsUnavailableAndNothingStarts) {
  const grpc::Status s = Start(Layout1());
  EXPECT_EQ(s.error_code(), grpc::StatusCode::UNAVAILABLE) << s.error_message();
  EXPECT_NE(s.error_message().find("does not answer"), std::string::npos) << s.error_message();
  grpc::ClientContext ctx;
  orchestrator::v1::ListTasksResponse list;
  ASSERT_TRUE(stub_->ListTasks(&ctx, {}, &list).ok());
  EXPECT_EQ(list.tasks_size(), 0);
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

TEST_F(OrchestratorAloneTest, TheCommandLineExitCodesTellUsageFromRefusals) {
  const std::string at = " --address " + server_->address();
  std::string out;
  EXPECT_EQ(RunCli("list" + at, &out), 0) << out;
  EXPECT_EQ(RunCli("list --json" + at, &out), 0) << out;
  EXPECT_EQ(RunCli("status task-nope" + at, &out), 3) << out;
  EXPECT_NE(out.find("no task 'task-nope'"), std::string::npos) << out;
  EXPECT_EQ(RunCli("cancel task-nope" + at, &out), 3) << out;
  EXPECT_EQ(RunCli("--bogus" + at, &out), 2) << out;
  EXPECT_EQ(RunCli("" + at, &out), 2) << out;
  EXPECT_EQ(RunCli("run /no/such/task.json" + at, &out), 2) << out;
  EXPECT_EQ(RunCli("run --time-limit -3 x.json" + at, &out), 2) << out;
  EXPECT_NE(out.find("--time-limit"), std::string::npos) << out;
  // A valid task with the cell's services down: refused, nothing started.
  EXPECT_EQ(
      RunCli("run " + std::string(PICKING_DATA_DIR) + "/apc2016/tasks/pick_layout_1.json" + at,
             &out),
      3)
      << out;
  EXPECT_NE(out.find("does not answer"), std::string::npos) << out;
  // No orchestrator at all.
  EXPECT_EQ(RunCli("list --address 127.0.0.1:1", &out), 3) << out;
  EXPECT_EQ(RunCli("run --wait 0 x.json" + at, &out), 2) << out;
  EXPECT_EQ(RunCli("run --wait 1e9 x.json" + at, &out), 2) << out;
}

// `picking health` asks any server's grpc.health.v1 service (the containers' health check).
TEST_F(OrchestratorAloneTest, TheCommandLineAsksTheHealthService) {
  const std::string at = " --address " + server_->address();
  std::string out;
  EXPECT_EQ(RunCli("health" + at, &out), 0) << out;
  EXPECT_NE(out.find("SERVING"), std::string::npos) << out;
  EXPECT_EQ(
      RunCli("health --service picking.orchestrator.v1.OrchestratorService --json" + at, &out), 0)
      << out;
  EXPECT_NE(out.find("\"status\":\"SERVING\""), std::string::npos) << out;
  EXPECT_EQ(RunCli("health --service no.such.Service" + at, &out), 3) << out;
  EXPECT_EQ(RunCli("health --address 127.0.0.1:1", &out), 3) << out;
}

// `picking run --wait` keeps asking while the cell is not up, then gives up with the reason.
TEST_F(OrchestratorAloneTest, RunWithWaitRetriesAnUnavailableCellThenGivesUp) {
  std::string out;
  const auto started = std::chrono::steady_clock::now();
  EXPECT_EQ(RunCli("run " + std::string(PICKING_DATA_DIR) +
                       "/apc2016/tasks/pick_layout_1.json --wait 4 --address " + server_->address(),
                   &out),
            3)
      << out;
  EXPECT_GE(std::chrono::steady_clock::now() - started, std::chrono::seconds(4));
  EXPECT_NE(out.find("waiting up to 4 s for the cell"), std::string::npos) << out;
  EXPECT_NE(out.find("does not answer"), std::string::npos) << out;
}

}  // namespace
}  // namespace picking::testing
