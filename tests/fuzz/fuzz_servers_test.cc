// Fuzz tests of every server: seeded mutated calls against the real binary (see
// fuzz_runner.h for what is sent and checked). The default budget keeps the test command
// short; `PICKING_FUZZ_CALLS=20000 ctest -L fuzz` runs the long campaign, and
// PICKING_FUZZ_SEED picks another sequence.
#include <google/protobuf/text_format.h>
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <set>
#include <sstream>

#include "picking/detector/v1/detector.grpc.pb.h"
#include "picking/gripper/v1/gripper.grpc.pb.h"
#include "picking/orchestrator/v1/orchestrator.grpc.pb.h"
#include "picking/planner/v1/planner.grpc.pb.h"
#include "picking/robot/v1/robot.grpc.pb.h"
#include "picking/scanner/v1/scanner.grpc.pb.h"
#include "picking/simulator/v1/simulator.grpc.pb.h"
#include "tests/fuzz/fuzz_runner.h"
#include "tests/harness/server_process.h"

namespace picking::testing {
namespace {

namespace common = picking::common::v1;
namespace sim = picking::simulator::v1;

constexpr int kDefaultCalls = 250;
constexpr const char* kHomeJoints =
    "positions_rad: [3.14159265358979, -2.0, 2.0, -1.5707963267949, -1.5707963267949, 0.0]";

std::string Text(const google::protobuf::Message& message) {
  std::string text;
  google::protobuf::TextFormat::PrintToString(message, &text);
  return text;
}

std::string ReadFile(const std::string& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

std::string TaskJson() {
  return ReadFile(std::string(PICKING_TEST_DATA_DIR) + "/tasks/pick_layout_1_tissue_box.json");
}

// The simulator's ground truth, serialized: what a refused call must leave as it was.
std::function<std::string()> SimTruth(const ServerProcess& simulator) {
  auto stub = std::shared_ptr<sim::SimulatorService::Stub>(
      sim::SimulatorService::NewStub(simulator.Channel()));
  return [stub] {
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    sim::GetGroundTruthResponse truth;
    const grpc::Status status = stub->GetGroundTruth(&context, {}, &truth);
    return status.ok() ? truth.SerializeAsString() : "unavailable: " + status.error_message();
  };
}

void LoadLayout(const ServerProcess& simulator) {
  auto stub = sim::SimulatorService::NewStub(simulator.Channel());
  grpc::ClientContext context;
  sim::LoadLayoutRequest request;
  request.set_task_json(TaskJson());
  request.set_seed(1);
  sim::LoadLayoutResponse response;
  ASSERT_TRUE(stub->LoadLayout(&context, request, &response).ok());
}

// A camera 0.6 m above the base and 0.2 m in front of it, looking at the shelf along +x.
std::string ShelfCamera(const std::string& field, int width, int height, double f, double y) {
  std::ostringstream text;
  text << field << " { width: " << width << " height: " << height << " fx: " << f << " fy: " << f
       << " cx: " << 0.5 * (width - 1) << " cy: " << 0.5 * (height - 1) << " }"
       << " X_base_" << field << " { position { x: 0.2 y: " << y
       << " z: 0.6 } orientation { w: 0.5 x: -0.5 y: 0.5 z: -0.5 } }";
  return text.str();
}

// A flat patch of `n` x `n` points 1 m in front of the base, as a one-chunk cloud.
std::string PlaneCloudChunk(int n) {
  std::string positions;
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) {
      const float p[3] = {1.0f, -0.1f + 0.2f * i / (n - 1), 0.7f + 0.2f * j / (n - 1)};
      positions.append(reinterpret_cast<const char*>(p), sizeof p);
    }
  }
  common::PointCloudChunk chunk;
  chunk.mutable_header()->set_frame_id("base");
  chunk.mutable_header()->set_point_count(n * n);
  chunk.mutable_header()->set_width(n);
  chunk.mutable_header()->set_height(n);
  chunk.mutable_header()->mutable_x_frame_sensor()->mutable_orientation()->set_w(1.0);
  chunk.set_point_count(n * n);
  chunk.set_positions(positions);
  return Text(chunk);
}

void ExpectClean(const FuzzReport& report, ServerProcess& server) {
  std::cout << report.Summary();
  EXPECT_EQ(report.failure_count, 0) << report.Summary();
  EXPECT_TRUE(server.Alive()) << "exit status " << server.exit_status();
  EXPECT_EQ(server.Stop(), 0) << "the server did not stop cleanly within its grace period";
}

// `request_type` is any request message of the service: naming a generated type links its
// descriptors into the test, where the fuzzer finds them by reflection.
FuzzTarget TargetFor(const google::protobuf::Descriptor* request_type, ServerProcess& server) {
  FuzzTarget target;
  target.service = request_type->file()->service(0)->full_name();
  target.channel = server.Channel();
  target.alive = [&server] { return server.Alive(); };
  return target;
}

TEST(FuzzServers, Simulator) {
  ServerProcess simulator(ServerBinary("picking-simulator"));
  LoadLayout(simulator);
  FuzzTarget target = TargetFor(sim::LoadLayoutRequest::descriptor(), simulator);
  sim::LoadLayoutRequest load;
  load.set_task_json(TaskJson());
  load.set_seed(7);
  const std::string view = ShelfCamera("camera", 160, 120, 150.0, 0.0) + " " +
                           ShelfCamera("projector", 128, 96, 110.0, 0.1);
  target.seeds = {
      {"LoadLayout", {Text(load)}},
      {"GetGroundTruth", {""}},
      {"GetCell", {""}},
      {"SetArmJoints", {std::string("joints { ") + kHomeJoints + " }"}},
      {"ProbeContact",
       {"X_base_tool { position { x: 0.6 y: 0 z: 0.8 } orientation { w: 0.7071068 y: 0.7071068 "
        "} } direction_tcp { z: 1 } max_distance_m: 0.2"}},
      {"SetSuction", {"on: true"}},
      {"SetSuction", {"on: false"}},
      {"RenderPatterns",
       {view + " patterns { solid_level: 1 } patterns { gray_code { bit: 1 bit_count: 7 } }"
               " options { ambient: 0.05 noise_sigma: 1 seed: 3 }"}},
      {"RenderDepth", {ShelfCamera("camera", 160, 120, 150.0, 0.0)}},
  };
  target.dictionary = {"bin_A", "kleenex_tissue_box", TaskJson()};
  target.truth = SimTruth(simulator);
  ExpectClean(RunFuzz(target, FuzzOptionsFromEnvironment(kDefaultCalls)), simulator);
}

TEST(FuzzServers, Gripper) {
  ServerProcess simulator(ServerBinary("picking-simulator"));
  LoadLayout(simulator);
  ServerProcess gripper(ServerBinary("picking-gripper"),
                        {"--backend=sim", "--sim.address=" + simulator.address()});
  FuzzTarget target = TargetFor(gripper::v1::SetVacuumRequest::descriptor(), gripper);
  target.seeds = {
      {"SetVacuum", {"on: true"}},
      {"SetVacuum", {"on: false"}},
      {"GetState", {""}},
      {"SetJointMode", {"mode: JOINT_MODE_UNACTUATED"}, /*must_succeed=*/false},
  };
  target.truth = SimTruth(simulator);
  ExpectClean(RunFuzz(target, FuzzOptionsFromEnvironment(kDefaultCalls)), gripper);
  EXPECT_TRUE(simulator.Alive());
}

// The robot: moves that stay near the start pose, so that fuzzed variants of them reach
// the limit, workspace and collision checks rather than only the argument checks.
std::vector<FuzzSeed> RobotSeeds(robot::v1::RobotService::Stub& stub) {
  grpc::ClientContext context;
  robot::v1::GetStateResponse state;
  EXPECT_TRUE(stub.GetState(&context, {}, &state).ok());
  common::Pose target = state.x_base_tcp();
  target.mutable_position()->set_z(target.position().z() - 0.03);
  robot::v1::ExecuteTrajectoryRequest trajectory;
  for (int k = 0; k < 3; ++k) {
    common::TrajectoryPoint* point = trajectory.mutable_trajectory()->add_points();
    point->set_time_from_start_s(0.5 * k);
    for (int j = 0; j < 6; ++j) {
      point->add_positions_rad(state.joints().positions_rad(j) + (j == 0 ? 0.02 * k : 0.0));
    }
  }
  std::string start = "target { ";
  for (int j = 0; j < 6; ++j) {
    start +=
        "positions_rad: " + std::to_string(state.joints().positions_rad(j) + (j == 5 ? 0.3 : 0.0)) +
        " ";
  }
  return {
      {"GetState", {""}},
      {"StreamState", {"rate_hz: 200"}, /*must_succeed=*/false},  // Ends at its deadline.
      {"GetLimits", {""}},
      {"MoveJoints", {start + "} options { speed_fraction: 0.5 }"}},
      {"MoveLinear",
       {"X_base_tcp_target { " + Text(target) + " } options { speed_fraction: 0.3 }"}},
      {"ExecuteTrajectory", {Text(trajectory)}},
      {"GuardedMove",
       {"direction { z: 1 } in_tool_frame: true max_distance_m: 0.02 force_threshold_n: 15 "
        "speed_m_s: 0.05"}},
      {"Stop", {""}},
      {"ProtectiveStop", {"reason: 'fuzz'"}},
      {"ResetProtectiveStop", {""}, /*must_succeed=*/false},  // Only after a stop.
  };
}

TEST(FuzzServers, Robot) {
  ServerProcess simulator(ServerBinary("picking-simulator"));
  LoadLayout(simulator);
  ServerProcess robot(
      ServerBinary("picking-robot"),
      {"--backend=sim", "--sim.address=" + simulator.address(), "--sim.time_scale=1000"});
  auto stub = std::shared_ptr<robot::v1::RobotService::Stub>(
      robot::v1::RobotService::NewStub(robot.Channel()));
  FuzzTarget target = TargetFor(robot::v1::MoveJointsRequest::descriptor(), robot);
  target.seeds = RobotSeeds(*stub);
  target.deadlines = {{"StreamState", std::chrono::milliseconds(300)}};
  target.truth = SimTruth(simulator);
  // A fuzzed ProtectiveStop is accepted: reset it so later motions are not all refused.
  // Accepted motions are taken back, so that every call starts where the seeds do.
  grpc::ClientContext state_context;
  robot::v1::GetStateResponse start;
  ASSERT_TRUE(stub->GetState(&state_context, {}, &start).ok());
  robot::v1::MoveJointsRequest back;
  *back.mutable_target()->mutable_positions_rad() = start.joints().positions_rad();
  target.restore = [stub, back] {
    // A cancelled call ends for its client at once, but the server may finish it a moment
    // later (a motion still running, a protective stop arriving after the reset): retry
    // both until the move back is accepted.
    grpc::Status status;
    for (int attempt = 0; attempt < 2000; ++attempt) {
      grpc::ClientContext reset_context;
      robot::v1::ResetProtectiveStopResponse reset;
      stub->ResetProtectiveStop(&reset_context, {}, &reset);
      grpc::ClientContext move_context;
      robot::v1::MoveJointsResponse moved;
      status = stub->MoveJoints(&move_context, back, &moved);
      if (status.error_code() != grpc::StatusCode::FAILED_PRECONDITION) break;
    }
    EXPECT_TRUE(status.ok()) << "could not return to the start: " << status.error_message();
  };
  ExpectClean(RunFuzz(target, FuzzOptionsFromEnvironment(kDefaultCalls)), robot);
  EXPECT_TRUE(simulator.Alive());
}

TEST(FuzzServers, Planner) {
  ServerProcess simulator(ServerBinary("picking-simulator"));
  LoadLayout(simulator);
  ServerProcess planner(ServerBinary("picking-planner"), {}, std::chrono::seconds(120));
  // The tissue box where the simulator placed it, as a detection would report it.
  auto sim_stub = sim::SimulatorService::NewStub(simulator.Channel());
  grpc::ClientContext context;
  sim::GetGroundTruthResponse truth;
  ASSERT_TRUE(sim_stub->GetGroundTruth(&context, {}, &truth).ok());
  std::string item_pose;
  for (const sim::ItemState& item : truth.items()) {
    if (item.item().name() == "kleenex_tissue_box") item_pose = Text(item.x_base_item());
  }
  ASSERT_FALSE(item_pose.empty());
  const std::string home = std::string("{ ") + kHomeJoints + " }";
  const std::string cloud = "cloud { " + PlaneCloudChunk(30) + " }";
  FuzzTarget target = TargetFor(planner::v1::ComputeFkRequest::descriptor(), planner);
  target.seeds = {
      {"ComputeFk", {"joints " + home}},
      {"ComputeIk",
       {"X_base_tcp { position { x: 0.9 y: 0.1 z: 0.9 } orientation { w: 0.7071068 y: "
        "0.7071068 } } seed " +
        home}},
      {"ListNamedPoses", {""}},
      {"PlanJointMotion", {"start " + home + " goal_name: 'above_tote'"}},
      {"ComputeGrasps",
       {"item: 'kleenex_tissue_box' container: CONTAINER_BIN_A X_base_item { " + item_pose + " }"}},
      {"UpdateScene",
       {"params { container: CONTAINER_BIN_A item: 'kleenex_tissue_box' "
        "X_base_item { " +
            item_pose + " } }",
        cloud}},
      {"PlanPick",
       {"params { item: 'kleenex_tissue_box' container: CONTAINER_BIN_A start " + home +
            " X_base_item { " + item_pose + " } }",
        cloud},
       /*must_succeed=*/false},
      {"PlanPlace", {"item: 'kleenex_tissue_box' start " + home}, /*must_succeed=*/false},
  };
  target.dictionary = {"kleenex_tissue_box", "fuzz", "home", "above_tote"};
  target.default_deadline = std::chrono::seconds(20);
  ExpectClean(RunFuzz(target, FuzzOptionsFromEnvironment(kDefaultCalls)), planner);
}

TEST(FuzzServers, Scanner) {
  const std::string dir = ::testing::TempDir() + "/fuzz_scanner";
  std::filesystem::remove_all(dir);
  ServerProcess simulator(ServerBinary("picking-simulator"));
  LoadLayout(simulator);
  {  // The arm at its start pose, where the scanner's simulated camera looks from.
    auto stub = sim::SimulatorService::NewStub(simulator.Channel());
    grpc::ClientContext context;
    sim::SetArmJointsRequest request;
    ASSERT_TRUE(google::protobuf::TextFormat::ParseFromString(
        std::string("joints { ") + kHomeJoints + " }", &request));
    sim::SetArmJointsResponse response;
    ASSERT_TRUE(stub->SetArmJoints(&context, request, &response).ok());
  }
  ServerProcess scanner(ServerBinary("picking-scanner"),
                        {"--sim.address=" + simulator.address(), "--calibration.dir=" + dir});
  FuzzTarget target = TargetFor(scanner::v1::ScanRequest::descriptor(), scanner);
  target.seeds = {
      {"Scan", {"views { } merge_voxel_m: 0.005 with_normals: true"}},
      {"CaptureImages", {"exposure_s: 0.01"}},
      {"CaptureCalibrationView", {"session: 'fuzz'"}, /*must_succeed=*/false},
      {"Calibrate",
       {"kind: CALIBRATION_KIND_CAMERA session: 'fuzz' board { inner_corners_cols: 9 "
        "inner_corners_rows: 6 square_size_m: 0.025 }"},
       /*must_succeed=*/false},  // One view is too few.
      {"GetCalibration", {""}},
  };
  target.dictionary = {"fuzz", dir, dir + "/sessions/fuzz"};
  target.default_deadline = std::chrono::seconds(60);
  target.truth = SimTruth(simulator);
  ExpectClean(RunFuzz(target, FuzzOptionsFromEnvironment(kDefaultCalls / 2)), scanner);
  EXPECT_TRUE(simulator.Alive());
}

TEST(FuzzServers, Detector) {
  const std::string dir = ::testing::TempDir() + "/fuzz_detector";
  std::filesystem::remove_all(dir);
  ServerProcess detector(ServerBinary("picking-detector"), {"--cache_dir=" + dir});
  const std::string cloud = "cloud { " + PlaneCloudChunk(40) + " }";
  FuzzTarget target = TargetFor(detector::v1::DetectRequest::descriptor(), detector);
  target.seeds = {
      {"ListModels", {""}},
      {"Detect",
       {"params { queries { item: 'kleenex_tissue_box' method: METHOD_PPF max_results: 1 } "
        "region { X_frame_region { position { x: 1.05 z: 0.8 } orientation { w: 1 } } "
        "size_m { x: 0.3 y: 0.4 z: 0.4 } } }",
        cloud}},
      {"Verify",
       {"params { item: 'kleenex_tissue_box' X_frame_item { position { x: 1.06 z: 0.8 } "
        "orientation { w: 1 } } X_frame_sensor { orientation { w: 1 } } }",
        cloud}},
  };
  target.dictionary = {"kleenex_tissue_box", "crayola_64_ct"};
  target.default_deadline = std::chrono::seconds(120);  // The first use builds the model.
  ExpectClean(RunFuzz(target, FuzzOptionsFromEnvironment(kDefaultCalls / 2)), detector);
}

TEST(FuzzServers, Orchestrator) {
  const std::string dir = ::testing::TempDir() + "/fuzz_orchestrator";
  std::filesystem::remove_all(dir);
  // Every cell service is a detector, which answers none of the other services' RPCs:
  // started tasks fail at their first step, so the fuzzer reaches the task-file parsing and
  // the task bookkeeping without running a whole cell.
  ServerProcess stand_in(ServerBinary("picking-detector"),
                         {"--cache_dir=" + dir + "/detector_cache"});
  const std::string peer = stand_in.address();
  ServerProcess orchestrator(
      ServerBinary("picking-orchestrator"),
      {"--tasks_dir=" + dir, "--scanner.address=" + peer, "--detector.endpoints=" + peer,
       "--planner.address=" + peer, "--robot.address=" + peer, "--gripper.address=" + peer});
  auto stub = std::shared_ptr<orchestrator::v1::OrchestratorService::Stub>(
      orchestrator::v1::OrchestratorService::NewStub(orchestrator.Channel()));
  orchestrator::v1::StartTaskRequest start;
  start.set_task_json(TaskJson());
  start.set_kind(orchestrator::v1::TASK_KIND_PICK);
  start.set_time_limit_s(30);
  grpc::ClientContext context;
  orchestrator::v1::StartTaskResponse started;
  const grpc::Status status = stub->StartTask(&context, start, &started);
  ASSERT_TRUE(status.ok()) << status.error_message();
  const std::string id = "task_id: '" + started.task_id() + "'";
  // One task at a time: let the first end (at its first step) before the seeds are checked.
  grpc::ClientContext watch_context;
  orchestrator::v1::WatchTaskRequest watch;
  watch.set_task_id(started.task_id());
  auto events = stub->WatchTask(&watch_context, watch);
  orchestrator::v1::WatchTaskResponse event;
  while (events->Read(&event)) {
  }
  ASSERT_TRUE(events->Finish().ok());
  FuzzTarget target = TargetFor(orchestrator::v1::StartTaskRequest::descriptor(), orchestrator);
  target.seeds = {
      {"StartTask", {Text(start)}},
      {"GetTask", {id}},
      {"WatchTask", {id}},
      {"ListTasks", {""}},
      {"CancelTask", {id}, /*must_succeed=*/false},  // The task may have ended already.
  };
  target.dictionary = {started.task_id(), TaskJson(), "bin_A", "kleenex_tissue_box"};
  // A refused call creates no task: the task ids are the truth here.
  target.truth = [stub] {
    grpc::ClientContext list_context;
    orchestrator::v1::ListTasksResponse tasks;
    stub->ListTasks(&list_context, {}, &tasks);
    std::set<std::string> ids;  // In any order.
    for (const auto& task : tasks.tasks()) ids.insert(task.task_id());
    std::string text;
    for (const std::string& task_id : ids) text += task_id + ",";
    return text;
  };
  ExpectClean(RunFuzz(target, FuzzOptionsFromEnvironment(kDefaultCalls)), orchestrator);
}

}  // namespace
}  // namespace picking::testing
