// Integration test of the picking-robot server binary through its generated client, against
// an in-process fake simulator (sim backend) and an in-process fake UR controller (ur
// backend).
#include <grpcpp/client_context.h>
#include <grpcpp/security/server_credentials.h>
#include <grpcpp/server.h>
#include <grpcpp/server_builder.h>
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <limits>
#include <mutex>
#include <optional>
#include <thread>

#include <unistd.h>

#include "libs/ur10/kinematics.h"
#include "libs/world/cell_config.h"
#include "picking/robot/v1/robot.grpc.pb.h"
#include "picking/simulator/v1/simulator.grpc.pb.h"
#include "services/robot/core/test/fake_ur_controller.h"
#include "services/robot/core/trajectory.h"
#include "tests/harness/server_process.h"
#include "tests/harness/service_checks.h"

namespace picking::testing {
namespace {

namespace rb = ::picking::robot::v1;
namespace sim = ::picking::simulator::v1;
using ur10::JointVector;

const char kBinary[] = "picking-robot";

ur10::Ur10Kinematics Kinematics() {
  return ur10::Ur10Kinematics(ur10::Ur10Model::Load(std::string(PICKING_DATA_DIR) + "/ur10"));
}

// A tool-down pose in front of the robot, inside the default workspace.
JointVector StartJoints() {
  JointVector q;
  q << 0.2, -1.6, 1.8, -1.8, -1.57, 0.3;
  return q;
}

JointVector Joints(const google::protobuf::RepeatedField<double>& values) {
  JointVector q = JointVector::Constant(std::numeric_limits<double>::quiet_NaN());
  for (int i = 0; i < std::min(6, values.size()); ++i) q[i] = values[i];
  return q;
}

void SetJoints(const JointVector& q, common::v1::JointPositions* out) {
  out->clear_positions_rad();
  for (int i = 0; i < 6; ++i) out->add_positions_rad(q[i]);
}

void SetPose(const Eigen::Isometry3d& X, common::v1::Pose* out) {
  out->mutable_position()->set_x(X.translation().x());
  out->mutable_position()->set_y(X.translation().y());
  out->mutable_position()->set_z(X.translation().z());
  const Eigen::Quaterniond r(X.linear());
  auto* o = out->mutable_orientation();
  o->set_w(r.w()), o->set_x(r.x()), o->set_y(r.y()), o->set_z(r.z());
}

// The tool centre point of the test cell: 0.1 m along the flange's z axis.
const Eigen::Isometry3d kTestTcp(Eigen::Translation3d(0.0, 0.0, 0.1));

// A cell description like the bundled one with the test cell's gripper (kTestTcp), written
// once per test process.
std::string TestCellPath() {
  static const std::string path = [] {
    const std::string data = PICKING_DATA_DIR;
    const std::filesystem::path file =
        std::filesystem::temp_directory_path() /
        ("picking_robot_test_cell_" + std::to_string(::getpid()) + ".yaml");
    std::ofstream out(file);
    out << "version: 1\n"
        << "robot_base: {X_WorldBase: {position: [0, 0, 0.7], orientation: [1, 0, 0, 0]}}\n"
        << "shelf:\n  X_BaseShelf: {position: [1.25, 0, -0.7], orientation: [0, 0, 0, 1]}\n"
        << "  mesh: " << data << "/apc2016/shelf/pod_lowres.stl\n"
        << "tote:\n  X_BaseTote: {position: [0.2, -0.75, -0.7], orientation: [1, 0, 0, 0]}\n"
        << "  mesh: " << data << "/apc2016/shelf/tote_delft.stl\n"
        << "table:\n  X_BaseTable: {position: [0.2, 0.8, -0.2], orientation: [1, 0, 0, 0]}\n"
        << "  size_m: [0.6, 0.6, 0.5]\n"
        << "gripper:\n"
        << "  X_ToolTcp: {position: [0, 0, " << kTestTcp.translation().z()
        << "], orientation: [1, 0, 0, 0]}\n"
        << "  tube_radius_m: 0.02\n  cup_length_m: 0.02\n";
    return file.string();
  }();
  return path;
}

// The simulator as far as the robot service uses it: the arm's joints, an obstacle box the
// tool flange collides with, and a horizontal surface (2000 N/m) the TCP can press on.
class FakeSimulator final : public sim::SimulatorService::Service {
 public:
  FakeSimulator() : kin_(Kinematics()), q_(StartJoints()) {
    grpc::ServerBuilder builder;
    builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port_);
    builder.RegisterService(this);
    server_ = builder.BuildAndStart();
  }
  ~FakeSimulator() override { server_->Shutdown(); }

  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }

  grpc::Status GetGroundTruth(grpc::ServerContext*, const sim::GetGroundTruthRequest*,
                              sim::GetGroundTruthResponse* response) override {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!layout_loaded_) {
      return grpc::Status(grpc::StatusCode::FAILED_PRECONDITION, "no layout loaded yet");
    }
    SetJoints(q_, response->mutable_arm_joints());
    return grpc::Status::OK;
  }

  grpc::Status SetArmJoints(grpc::ServerContext*, const sim::SetArmJointsRequest* request,
                            sim::SetArmJointsResponse* response) override {
    const JointVector q = Joints(request->joints().positions_rad());
    if (!q.allFinite()) return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, "bad joints");
    std::lock_guard<std::mutex> lock(mutex_);
    q_ = q;
    ++placements_;
    const Eigen::Isometry3d X = kin_.ForwardKinematics(q);
    const Eigen::Vector3d p = X.translation();
    if (has_obstacle_ && (p.array() >= obstacle_min_.array()).all() &&
        (p.array() <= obstacle_max_.array()).all()) {
      response->set_in_collision(true);
      response->set_collision_detail("wrist_3_link hit the table");
    } else if (p.z() < surface_z_) {
      response->set_in_collision(true);
      response->set_collision_detail("suction cup touches the item");
    }
    SetPose(X, response->mutable_x_base_tool());
    if (X_ToolTcp_) SetPose(X * *X_ToolTcp_, response->mutable_x_base_tcp());
    placed_.notify_all();
    return grpc::Status::OK;
  }

  grpc::Status ProbeContact(grpc::ServerContext*, const sim::ProbeContactRequest* request,
                            sim::ProbeContactResponse* response) override {
    std::lock_guard<std::mutex> lock(mutex_);
    ++probes_;
    const auto& o = request->x_base_tool().orientation();
    const Eigen::Quaterniond r(o.w(), o.x(), o.y(), o.z());
    const Eigen::Vector3d d(request->direction_tcp().x(), request->direction_tcp().y(),
                            request->direction_tcp().z());
    const Eigen::Vector3d axis = r * d;
    const double height = request->x_base_tool().position().z() - surface_z_;
    if (axis.z() < -1e-9 && height >= 0.0 && height / -axis.z() <= request->max_distance_m()) {
      response->set_contact(true);
      response->set_distance_m(height / -axis.z());
      response->mutable_item()->set_name("crayola_64_ct");
      response->set_surface(sim::CONTACT_SURFACE_ITEM);
      response->set_stiffness_n_per_m(2000.0);
    }
    return grpc::Status::OK;
  }

  void SetObstacle(const Eigen::Vector3d& min, const Eigen::Vector3d& max) {
    std::lock_guard<std::mutex> lock(mutex_);
    has_obstacle_ = true;
    obstacle_min_ = min;
    obstacle_max_ = max;
  }
  void set_surface_z(double z) {
    std::lock_guard<std::mutex> lock(mutex_);
    surface_z_ = z;
  }
  // The tool centre point the fake reports in SetArmJoints (X_base_tcp); none if nullopt.
  void set_tcp(const std::optional<Eigen::Isometry3d>& X_ToolTcp) {
    std::lock_guard<std::mutex> lock(mutex_);
    X_ToolTcp_ = X_ToolTcp;
  }
  void set_layout_loaded(bool loaded) {
    std::lock_guard<std::mutex> lock(mutex_);
    layout_loaded_ = loaded;
  }
  JointVector q() {
    std::lock_guard<std::mutex> lock(mutex_);
    return q_;
  }
  int placements() {
    std::lock_guard<std::mutex> lock(mutex_);
    return placements_;
  }
  int probes() {
    std::lock_guard<std::mutex> lock(mutex_);
    return probes_;
  }
  // Waits until at least `n` placements were made; false after `timeout`.
  bool WaitForPlacements(int n, std::chrono::seconds timeout) {
    std::unique_lock<std::mutex> lock(mutex_);
    return placed_.wait_for(lock, timeout, [&] { return placements_ >= n; });
  }

 private:
  ur10::Ur10Kinematics kin_;
  std::mutex mutex_;
  std::condition_variable placed_;
  JointVector q_;
  int placements_ = 0;
  int probes_ = 0;
  bool has_obstacle_ = false;
  Eigen::Vector3d obstacle_min_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d obstacle_max_ = Eigen::Vector3d::Zero();
  double surface_z_ = -10.0;
  bool layout_loaded_ = true;
  std::optional<Eigen::Isometry3d> X_ToolTcp_;
  int port_ = 0;
  std::unique_ptr<grpc::Server> server_;
};

// Client helpers shared by both backends' tests.
class RobotClient {
 public:
  explicit RobotClient(std::shared_ptr<grpc::Channel> channel)
      : stub_(rb::RobotService::NewStub(std::move(channel))) {}

  grpc::Status State(rb::GetStateResponse* out) {
    grpc::ClientContext ctx;
    return stub_->GetState(&ctx, rb::GetStateRequest(), out);
  }
  rb::GetStateResponse State() {
    rb::GetStateResponse out;
    const grpc::Status s = State(&out);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return out;
  }
  grpc::Status MoveJoints(const std::vector<double>& q, rb::MoveJointsResponse* out,
                          double speed_fraction = 0.0) {
    grpc::ClientContext ctx;
    rb::MoveJointsRequest request;
    for (double v : q) request.mutable_target()->add_positions_rad(v);
    request.mutable_options()->set_speed_fraction(speed_fraction);
    return stub_->MoveJoints(&ctx, request, out);
  }
  grpc::Status MoveJoints(const JointVector& q, rb::MoveJointsResponse* out,
                          double speed_fraction = 0.0) {
    return MoveJoints(std::vector<double>(q.data(), q.data() + 6), out, speed_fraction);
  }
  grpc::Status ProtectiveStop(const std::string& reason) {
    grpc::ClientContext ctx;
    rb::ProtectiveStopRequest request;
    request.set_reason(reason);
    rb::ProtectiveStopResponse response;
    return stub_->ProtectiveStop(&ctx, request, &response);
  }
  grpc::Status Reset() {
    grpc::ClientContext ctx;
    rb::ResetProtectiveStopResponse response;
    return stub_->ResetProtectiveStop(&ctx, rb::ResetProtectiveStopRequest(), &response);
  }
  grpc::Status Stop() {
    grpc::ClientContext ctx;
    rb::StopResponse response;
    return stub_->Stop(&ctx, rb::StopRequest(), &response);
  }
  grpc::Status Guarded(double distance_m, double force_n, rb::GuardedMoveResponse* out) {
    grpc::ClientContext ctx;
    rb::GuardedMoveRequest request;
    request.mutable_direction()->set_z(1.0);
    request.set_in_tool_frame(true);
    request.set_max_distance_m(distance_m);
    request.set_force_threshold_n(force_n);
    request.set_speed_m_s(0.05);
    return stub_->GuardedMove(&ctx, request, out);
  }
  // Runs a trajectory and collects its progress messages.
  grpc::Status Execute(const robot::JointTrajectory& trajectory,
                       std::vector<rb::ExecuteTrajectoryResponse>* progress) {
    grpc::ClientContext ctx;
    rb::ExecuteTrajectoryRequest request;
    for (const auto& p : trajectory.points) {
      auto* point = request.mutable_trajectory()->add_points();
      point->set_time_from_start_s(p.time_s);
      for (int j = 0; j < 6; ++j) point->add_positions_rad(p.q_rad[j]);
    }
    auto reader = stub_->ExecuteTrajectory(&ctx, request);
    rb::ExecuteTrajectoryResponse message;
    while (reader->Read(&message)) progress->push_back(message);
    return reader->Finish();
  }
  rb::RobotService::Stub& stub() { return *stub_; }

 private:
  std::unique_ptr<rb::RobotService::Stub> stub_;
};

robot::JointTrajectory SlowPath(const JointVector& q0, const JointVector& q1) {
  robot::TimeParametrizationOptions options;
  options.max_velocity_rad_s = JointVector::Constant(0.3);
  options.max_acceleration_rad_s2 = JointVector::Constant(1.0);
  return robot::TimeParametrizePath({q0, q1}, options);
}

TEST(RobotServerTest, ServesHealthAndReflectionAndStopsCleanly) {
  ExpectStandardServerBehaviour(ServerBinary(kBinary), "picking.robot.v1.RobotService",
                                "picking/robot/v1/robot.proto");
}

TEST(RobotServerTest, RejectsBadFlags) { ExpectRejectsBadFlags(ServerBinary(kBinary)); }

TEST(RobotServerTest, RejectsBadSettings) {
  for (const std::vector<std::string>& args : {std::vector<std::string>{"--backend=kuka"},
                                               {"--safety.workspace_min_m=1,2"},
                                               {"--safety.forbidden_zones=nowhere"},
                                               {"--sim.time_scale=0"},
                                               {"--motion.default_speed_fraction=1.5"}}) {
    const ProgramResult result = RunProgram(ServerBinary(kBinary), args);
    EXPECT_EQ(result.exit_status, 2) << args[0] << ": " << result.output;
  }
}

TEST(RobotServerTest, UnreachableSimulatorAnswersUnavailableButTheServerRuns) {
  ServerProcess server(ServerBinary(kBinary), {"--sim.address=127.0.0.1:1", "--sim.timeout_s=1"});
  RobotClient client(server.Channel());
  rb::GetStateResponse state;
  EXPECT_EQ(client.State(&state).error_code(), grpc::StatusCode::UNAVAILABLE);
  rb::MoveJointsResponse move;
  const grpc::Status s = client.MoveJoints(StartJoints(), &move);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::UNAVAILABLE) << s.error_message();
  EXPECT_NE(s.error_message().find("127.0.0.1:1"), std::string::npos) << s.error_message();
  grpc::ClientContext ctx;
  rb::GetLimitsResponse limits;
  EXPECT_TRUE(client.stub().GetLimits(&ctx, rb::GetLimitsRequest(), &limits).ok());
  EXPECT_EQ(server.Stop(), 0);
}

TEST(RobotServerTest, StartsWithTheBundledSettingsFile) {
  FakeSimulator sim;
  ServerProcess server(ServerBinary(kBinary),
                       {"--config=" + std::string(PICKING_DATA_DIR) + "/cell/robot_cell.yaml",
                        "--sim.address=" + sim.address()});
  RobotClient client(server.Channel());
  grpc::ClientContext ctx;
  rb::GetLimitsResponse limits;
  ASSERT_TRUE(client.stub().GetLimits(&ctx, rb::GetLimitsRequest(), &limits).ok());
  EXPECT_EQ(limits.workspace().max().z(), 1.5);
  ASSERT_EQ(limits.forbidden_zones_size(), 2);
  EXPECT_EQ(limits.forbidden_zones(1).max().z(), 0.07);
  EXPECT_EQ(limits.max_contact_force_n(), 50.0);
  const rb::GetStateResponse state = client.State();
  EXPECT_EQ(state.status(), rb::ROBOT_STATUS_IDLE);
  // Its `cell` (beside the settings file) is the bundled cell description: the TCP is its
  // gripper's.
  const Eigen::Isometry3d X_ToolTcp =
      world::ReadCellConfig(world::DefaultCellConfigPath()).gripper.X_ToolTcp;
  const Eigen::Vector3d p_BaseTcp =
      Kinematics().ForwardKinematics(Joints(state.joints().positions_rad())) *
      X_ToolTcp.translation();
  EXPECT_NEAR(state.x_base_tcp().position().x(), p_BaseTcp.x(), 1e-9);
  EXPECT_NEAR(state.x_base_tcp().position().y(), p_BaseTcp.y(), 1e-9);
  EXPECT_NEAR(state.x_base_tcp().position().z(), p_BaseTcp.z(), 1e-9);
  EXPECT_EQ(server.Stop(), 0);
}

TEST(RobotServerTest, RefusesACellDescriptionWithoutAGripper) {
  const std::filesystem::path file =
      std::filesystem::temp_directory_path() /
      ("picking_robot_test_no_gripper_" + std::to_string(::getpid()) + ".yaml");
  {
    std::ifstream in(TestCellPath());
    std::ofstream out(file);
    std::string line;
    while (std::getline(in, line) && line != "gripper:") out << line << "\n";
  }
  const ProgramResult r =
      RunProgram(ServerBinary(kBinary), {"--listen=127.0.0.1:0", "--cell=" + file.string()});
  EXPECT_EQ(r.exit_status, 2) << r.output;
  EXPECT_NE(r.output.find("gripper"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find(file.string()), std::string::npos) << r.output;
  std::filesystem::remove(file);
}

TEST(RobotServerTest, AMotionFailsWhenTheSimulatorPutsTheTcpElsewhere) {
  // The simulator's gripper is 0.25 m longer than the robot's cell description says.
  FakeSimulator sim;
  sim.set_tcp(Eigen::Isometry3d(Eigen::Translation3d(0.0, 0.0, 0.35)));
  ServerProcess server(ServerBinary(kBinary), {"--sim.address=" + sim.address(),
                                               "--cell=" + TestCellPath(), "--sim.time_scale=100"});
  RobotClient client(server.Channel());
  JointVector target = StartJoints();
  target[0] += 0.05;
  rb::MoveJointsResponse move;
  const grpc::Status s = client.MoveJoints(target, &move);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::UNAVAILABLE) << s.error_message();
  EXPECT_NE(s.error_message().find("cell description"), std::string::npos) << s.error_message();
  // Put back where it was; nothing else moved.
  EXPECT_TRUE(sim.q().isApprox(StartJoints(), 1e-12));
  EXPECT_TRUE(Joints(client.State().joints().positions_rad()).isApprox(StartJoints(), 1e-12));
  EXPECT_EQ(sim.placements(), 2);
  EXPECT_EQ(server.Stop(), 0);
}

TEST(RobotServerTest, AFreshSimulatorGetsTheInitialJoints) {
  FakeSimulator sim;
  sim.set_layout_loaded(false);
  ServerProcess server(ServerBinary(kBinary),
                       {"--sim.address=" + sim.address(),
                        "--sim.initial_joints_rad=" + std::string("3.1,-2,2,-1.5,-1.5,0")});
  RobotClient client(server.Channel());
  const rb::GetStateResponse state = client.State();
  JointVector expected;
  expected << 3.1, -2, 2, -1.5, -1.5, 0;
  EXPECT_TRUE(Joints(state.joints().positions_rad()).isApprox(expected));
  EXPECT_EQ(sim.placements(), 1);
  EXPECT_TRUE(sim.q().isApprox(expected));
  EXPECT_EQ(server.Stop(), 0);
}

TEST(RobotServerTest, GetStateAnswersUnavailableOnceTheSimulatorIsGone) {
  auto sim = std::make_unique<FakeSimulator>();
  sim->set_tcp(kTestTcp);
  const std::string address = sim->address();
  ServerProcess server(ServerBinary(kBinary),
                       {"--sim.address=" + address, "--cell=" + TestCellPath(), "--sim.timeout_s=1",
                        "--sim.link_check_period_s=0"});
  RobotClient client(server.Channel());
  ASSERT_EQ(client.State().status(), rb::ROBOT_STATUS_IDLE);
  sim.reset();  // the simulator goes away
  // A link check period of 0 reads the world at every GetState: the first call after the
  // simulator left finds it gone (within the call's 1 s timeout), no waiting on a clock.
  rb::GetStateResponse state;
  const grpc::Status s = client.State(&state);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::UNAVAILABLE)
      << (s.ok() ? "still answering status " + rb::RobotStatus_Name(state.status())
                 : s.error_message());
  EXPECT_NE(s.error_message().find(address), std::string::npos) << s.error_message();
  EXPECT_EQ(server.Stop(), 0);
}

class SimRobotTest : public ::testing::Test {
 protected:
  explicit SimRobotTest(std::vector<std::string> extra = {"--sim.time_scale=1000"})
      : kin_(Kinematics()),
        server_(ServerBinary(kBinary), Args(extra)),
        client_(server_.Channel()) {
    sim_.set_tcp(kTestTcp);
  }
  ~SimRobotTest() override { EXPECT_EQ(server_.Stop(), 0); }

  std::vector<std::string> Args(std::vector<std::string> extra) {
    extra.push_back("--backend=sim");
    extra.push_back("--sim.address=" + sim_.address());
    extra.push_back("--cell=" + TestCellPath());
    extra.push_back("--safety.workspace_max_m=1.3,1.4,1.2");
    return extra;
  }

  ur10::Ur10Kinematics kin_;
  FakeSimulator sim_;
  ServerProcess server_;
  RobotClient client_;
};

TEST_F(SimRobotTest, GetStateReportsTheSimulatedArm) {
  const rb::GetStateResponse state = client_.State();
  EXPECT_EQ(state.backend(), rb::ROBOT_BACKEND_SIM);
  EXPECT_EQ(state.status(), rb::ROBOT_STATUS_IDLE);
  EXPECT_TRUE(Joints(state.joints().positions_rad()).isApprox(StartJoints()));
  const Eigen::Isometry3d X = kin_.ForwardKinematics(StartJoints());
  const Eigen::Vector3d tcp = X * kTestTcp.translation();
  EXPECT_NEAR(state.x_base_tool().position().z(), X.translation().z(), 1e-9);
  EXPECT_NEAR(state.x_base_tcp().position().x(), tcp.x(), 1e-9);
  EXPECT_NEAR(state.x_base_tcp().position().z(), tcp.z(), 1e-9);
  EXPECT_GT(state.stamp_unix_ns(), 0);

  grpc::ClientContext ctx;
  rb::GetLimitsResponse limits;
  ASSERT_TRUE(client_.stub().GetLimits(&ctx, rb::GetLimitsRequest(), &limits).ok());
  ASSERT_EQ(limits.joints_size(), 6);
  EXPECT_EQ(limits.joints(2).name(), "elbow_joint");
  EXPECT_GT(limits.max_tcp_speed_m_s(), 0.0);
  EXPECT_EQ(limits.workspace().max().z(), 1.2);
  EXPECT_LT(limits.workspace().min().z(), limits.workspace().max().z());
  EXPECT_EQ(limits.forbidden_zones_size(), 2);
}

TEST_F(SimRobotTest, MoveJointsReachesTheTarget) {
  JointVector target = StartJoints();
  target[0] += 0.3;
  target[3] -= 0.2;
  rb::MoveJointsResponse response;
  const grpc::Status s = client_.MoveJoints(target, &response);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_LT(
      (Joints(response.final_state().joints().positions_rad()) - target).cwiseAbs().maxCoeff(),
      1e-9);
  EXPECT_LT((sim_.q() - target).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_GT(sim_.placements(), 10);  // streamed, not jumped
  // Simulated seconds (one command period per sample sent), not wall time: the same on a busy
  // machine.
  EXPECT_GT(response.duration_s(), 0.3);
  EXPECT_EQ(client_.State().status(), rb::ROBOT_STATUS_IDLE);
}

TEST_F(SimRobotTest, RefusedRequestsMoveNothing) {
  const rb::GetStateResponse before = client_.State();
  const int placed = sim_.placements();
  rb::MoveJointsResponse response;
  JointVector q = StartJoints();
  q[2] = 3.5;  // beyond the elbow's +-pi
  grpc::Status s = client_.MoveJoints(q, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("elbow_joint"), std::string::npos) << s.error_message();
  q = StartJoints();
  q[1] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(client_.MoveJoints(q, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(client_.MoveJoints(std::vector<double>{0, 0, 0, 0, 0}, &response).error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);
  // Straight up: the TCP is above the workspace box.
  s = client_.MoveJoints(std::vector<double>{0, -1.5708, 0, -1.5708, 0, 0}, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("workspace"), std::string::npos) << s.error_message();
  // A speed fraction above 1.
  q = StartJoints();
  s = client_.MoveJoints(q, &response, 1.5);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("speed_fraction"), std::string::npos) << s.error_message();
  // A linear move leaving the workspace.
  {
    grpc::ClientContext ctx;
    rb::MoveLinearRequest request;
    *request.mutable_x_base_tcp_target() = before.x_base_tcp();
    request.mutable_x_base_tcp_target()->mutable_position()->set_z(2.5);
    rb::MoveLinearResponse linear;
    s = client_.stub().MoveLinear(&ctx, request, &linear);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  }
  // A guarded move asking for too much force.
  rb::GuardedMoveResponse guarded;
  EXPECT_EQ(client_.Guarded(0.1, 1000.0, &guarded).error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(sim_.placements(), placed);
  EXPECT_EQ(sim_.probes(), 0);
  const rb::GetStateResponse after = client_.State();
  EXPECT_TRUE(
      Joints(after.joints().positions_rad()).isApprox(Joints(before.joints().positions_rad())));
  EXPECT_EQ(after.status(), rb::ROBOT_STATUS_IDLE);
}

// Joints with the tcp inside the board under bin_H of the test cell (3 cm behind the opening,
// 1 cm below the bin's lowest floor point), the tool pointing into the shelf, nearest to the
// start.
JointVector JointsInsideAShelfBoard(const ur10::Ur10Kinematics& kinematics) {
  const world::CellModel cell = world::LoadCellModel(world::ReadCellConfig(TestCellPath()));
  const world::BinGeometry& bin = cell.bin("bin_H");
  Eigen::Isometry3d X_BaseTcp = Eigen::Isometry3d::Identity();
  X_BaseTcp.linear().col(0) = -Eigen::Vector3d::UnitZ();
  X_BaseTcp.linear().col(1) = Eigen::Vector3d::UnitY();
  X_BaseTcp.linear().col(2) = Eigen::Vector3d::UnitX();
  X_BaseTcp.translation() =
      cell.config.X_BaseShelf * Eigen::Vector3d(bin.opening_x_m - 0.03, bin.inner_S.center().y(),
                                                bin.inner_S.min().z() - 0.01);
  const auto ik = kinematics.NearestSolution(X_BaseTcp * kTestTcp.inverse(), StartJoints());
  EXPECT_TRUE(ik.has_value());
  return ik ? ik->q_rad : StartJoints();
}

TEST_F(SimRobotTest, MotionsIntoTheShelfOrTheArmAreRefusedAndNothingMoves) {
  const int placed = sim_.placements();
  const JointVector q_board = JointsInsideAShelfBoard(kin_);
  rb::MoveJointsResponse response;
  grpc::Status s = client_.MoveJoints(q_board, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_NE(s.error_message().find("hits shelf"), std::string::npos) << s.error_message();
  // A trajectory there, whatever its timing.
  std::vector<rb::ExecuteTrajectoryResponse> progress;
  s = client_.Execute(SlowPath(StartJoints(), q_board), &progress);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_NE(s.error_message().find("hits shelf"), std::string::npos) << s.error_message();
  EXPECT_TRUE(progress.empty());
  // The elbow folding the forearm back onto the upper arm.
  JointVector folded = StartJoints();
  folded[2] = 3.0;
  s = client_.MoveJoints(folded, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_NE(s.error_message().find("hits self: "), std::string::npos) << s.error_message();
  // Nothing moved.
  EXPECT_EQ(sim_.placements(), placed);
  EXPECT_TRUE(sim_.q().isApprox(StartJoints(), 1e-12));
  EXPECT_EQ(client_.State().status(), rb::ROBOT_STATUS_IDLE);
  // A motion clear of the cell still runs.
  JointVector target = StartJoints();
  target[0] += 0.3;
  s = client_.MoveJoints(target, &response);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_LT((sim_.q() - target).cwiseAbs().maxCoeff(), 1e-9);
}

TEST_F(SimRobotTest, ProtectiveStopBlocksMovesUntilReset) {
  ASSERT_TRUE(client_.ProtectiveStop("operator opened the door").ok());
  rb::GetStateResponse state = client_.State();
  EXPECT_EQ(state.status(), rb::ROBOT_STATUS_PROTECTIVE_STOP);
  EXPECT_NE(state.status_detail().find("operator opened the door"), std::string::npos);
  JointVector target = StartJoints();
  target[0] += 0.2;
  rb::MoveJointsResponse response;
  const grpc::Status s = client_.MoveJoints(target, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << s.error_message();
  EXPECT_EQ(sim_.placements(), 0);
  ASSERT_TRUE(client_.Reset().ok());
  EXPECT_EQ(client_.State().status(), rb::ROBOT_STATUS_IDLE);
  EXPECT_TRUE(client_.MoveJoints(target, &response).ok());
  // Resetting when there is no stop is refused.
  EXPECT_EQ(client_.Reset().error_code(), grpc::StatusCode::FAILED_PRECONDITION);
}

// Motions slow enough to last hours were planned sample by sample before the deadline was
// looked at: the server wedged (memory growing, every later motion refused, no exit on
// SIGTERM). They are refused up front now.
TEST_F(SimRobotTest, TinySpeedsAreRefusedAndTheServerStaysUsable) {
  auto deadline = [] { return std::chrono::system_clock::now() + std::chrono::seconds(20); };
  JointVector target = StartJoints();
  target[0] += 1.5;
  for (double fraction : {1e-6, 1e-300}) {
    grpc::ClientContext ctx;
    ctx.set_deadline(deadline());
    rb::MoveJointsRequest request;
    SetJoints(target, request.mutable_target());
    request.mutable_options()->set_speed_fraction(fraction);
    rb::MoveJointsResponse response;
    const grpc::Status s = client_.stub().MoveJoints(&ctx, request, &response);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
    EXPECT_NE(s.error_message().find("speed_fraction"), std::string::npos) << s.error_message();
  }
  {
    // Allowed fractions, but 1.5 rad at 0.1 % of the joint speed takes over 600 s.
    grpc::ClientContext ctx;
    ctx.set_deadline(deadline());
    rb::MoveJointsRequest request;
    SetJoints(target, request.mutable_target());
    request.mutable_options()->set_speed_fraction(1e-3);
    rb::MoveJointsResponse response;
    const grpc::Status s = client_.stub().MoveJoints(&ctx, request, &response);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
    EXPECT_NE(s.error_message().find("600 s"), std::string::npos) << s.error_message();
  }
  {
    grpc::ClientContext ctx;
    ctx.set_deadline(deadline());
    rb::MoveLinearRequest request;
    *request.mutable_x_base_tcp_target() = client_.State().x_base_tcp();
    request.mutable_x_base_tcp_target()->mutable_position()->set_z(
        request.x_base_tcp_target().position().z() - 0.1);
    request.mutable_options()->set_speed_fraction(1e-6);
    rb::MoveLinearResponse response;
    const grpc::Status s = client_.stub().MoveLinear(&ctx, request, &response);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  }
  {
    grpc::ClientContext ctx;
    ctx.set_deadline(deadline());
    rb::GuardedMoveRequest request;
    request.mutable_direction()->set_z(1.0);
    request.set_in_tool_frame(true);
    request.set_max_distance_m(0.1);
    request.set_force_threshold_n(5.0);
    request.set_speed_m_s(1e-300);
    rb::GuardedMoveResponse response;
    const grpc::Status s = client_.stub().GuardedMove(&ctx, request, &response);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
    EXPECT_NE(s.error_message().find("speed_m_s"), std::string::npos) << s.error_message();
  }
  EXPECT_EQ(sim_.placements(), 0);
  EXPECT_EQ(client_.State().status(), rb::ROBOT_STATUS_IDLE);
  target = StartJoints();
  target[0] += 0.2;
  rb::MoveJointsResponse response;
  const grpc::Status s = client_.MoveJoints(target, &response);
  EXPECT_TRUE(s.ok()) << s.error_message();
}

// A 10 kB reason used to be quoted in full by every refused motion, beyond the client's
// default 8 KB metadata limit (RESOURCE_EXHAUSTED instead of FAILED_PRECONDITION).
TEST_F(SimRobotTest, ALongProtectiveStopReasonIsStoredCut) {
  ASSERT_TRUE(client_.ProtectiveStop("door " + std::string(10000, 'd')).ok());
  const rb::GetStateResponse state = client_.State();
  EXPECT_EQ(state.status(), rb::ROBOT_STATUS_PROTECTIVE_STOP);
  EXPECT_NE(state.status_detail().find("door ddd"), std::string::npos);
  EXPECT_LT(state.status_detail().size(), 400u);
  JointVector target = StartJoints();
  target[0] += 0.2;
  rb::MoveJointsResponse response;
  const grpc::Status s = client_.MoveJoints(target, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << s.error_message();
  EXPECT_NE(s.error_message().find("door ddd"), std::string::npos);
  EXPECT_LE(s.error_message().size(), 1024u);
}

TEST_F(SimRobotTest, CollisionIsAProtectiveStopNamingWhatHit) {
  JointVector mid = StartJoints();
  mid[0] += 0.3;
  const Eigen::Vector3d p = kin_.ForwardKinematics(mid).translation();
  sim_.SetObstacle(p - Eigen::Vector3d::Constant(0.03), p + Eigen::Vector3d::Constant(0.03));
  JointVector target = StartJoints();
  target[0] += 0.6;
  rb::MoveJointsResponse response;
  const grpc::Status s = client_.MoveJoints(target, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::ABORTED);
  EXPECT_NE(s.error_message().find("wrist_3_link hit the table"), std::string::npos)
      << s.error_message();
  const rb::GetStateResponse state = client_.State();
  EXPECT_EQ(state.status(), rb::ROBOT_STATUS_PROTECTIVE_STOP);
  EXPECT_NE(state.status_detail().find("collision"), std::string::npos) << state.status_detail();
  EXPECT_EQ(client_.MoveJoints(StartJoints(), &response).error_code(),
            grpc::StatusCode::FAILED_PRECONDITION);
  ASSERT_TRUE(client_.Reset().ok());
  const grpc::Status back = client_.MoveJoints(StartJoints(), &response);
  EXPECT_TRUE(back.ok()) << back.error_message();
}

TEST_F(SimRobotTest, ExecuteTrajectoryStreamsProgressEndingWithDone) {
  JointVector q1 = StartJoints();
  q1[0] += 0.3;
  q1[4] += 0.2;
  const robot::JointTrajectory trajectory = SlowPath(StartJoints(), q1);
  std::vector<rb::ExecuteTrajectoryResponse> progress;
  const grpc::Status s = client_.Execute(trajectory, &progress);
  ASSERT_TRUE(s.ok()) << s.error_message();
  ASSERT_GE(progress.size(), 3u);
  for (std::size_t i = 1; i < progress.size(); ++i) {
    EXPECT_GE(progress[i].fraction_done(), progress[i - 1].fraction_done());
    EXPECT_FALSE(progress[i - 1].done());
  }
  EXPECT_TRUE(progress.back().done());
  EXPECT_DOUBLE_EQ(progress.back().fraction_done(), 1.0);
  EXPECT_NEAR(progress.back().time_from_start_s(), trajectory.duration_s(), 1e-9);
  EXPECT_LT((Joints(progress.back().joints().positions_rad()) - q1).cwiseAbs().maxCoeff(), 1e-9);

  // A trajectory that does not start at the arm is refused before anything moves.
  const int placed = sim_.placements();
  progress.clear();
  const grpc::Status far = client_.Execute(SlowPath(StartJoints(), q1), &progress);
  EXPECT_EQ(far.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << far.error_message();
  EXPECT_TRUE(progress.empty());
  EXPECT_EQ(sim_.placements(), placed);
}

TEST_F(SimRobotTest, GuardedMoveStopsOnContactWithTheForceReported) {
  const rb::GetStateResponse state = client_.State();
  // The tool points down; the fake's surface is met by the flange 3 cm further down.
  sim_.set_surface_z(state.x_base_tool().position().z() - 0.03);
  rb::GuardedMoveResponse response;
  const grpc::Status s = client_.Guarded(0.1, 10.0, &response);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_TRUE(response.contact());
  EXPECT_NEAR(response.contact_force_n(), 10.0, 1e-3);
  // 3 cm of height to the first touch along the slightly tilted tool axis, then
  // 10 N / 2000 N/m = 5 mm of press.
  const double axis_z = kin_.ForwardKinematics(StartJoints()).linear().col(2).z();
  EXPECT_NEAR(response.distance_travelled_m(), 0.03 / -axis_z + 0.005, 1e-6);
  EXPECT_EQ(sim_.probes(), 1);
  EXPECT_NEAR(response.final_state().tcp_wrench().force_n().z(), 10.0 * -axis_z, 1e-3);

  // Without anything in reach: the full distance, no contact.
  sim_.set_surface_z(-10.0);
  const grpc::Status up = [&] {
    grpc::ClientContext ctx;
    rb::GuardedMoveRequest request;
    request.mutable_direction()->set_z(1.0);  // base frame: straight up
    request.set_max_distance_m(0.05);
    request.set_force_threshold_n(10.0);
    return client_.stub().GuardedMove(&ctx, request, &response);
  }();
  ASSERT_TRUE(up.ok()) << up.error_message();
  EXPECT_FALSE(response.contact());
  EXPECT_NEAR(response.distance_travelled_m(), 0.05, 1e-6);
  EXPECT_EQ(response.contact_force_n(), 0.0);
}

TEST_F(SimRobotTest, StreamStateEndsWhenTheClientCancels) {
  grpc::ClientContext ctx;
  rb::StreamStateRequest request;
  request.set_rate_hz(200.0);
  auto reader = client_.stub().StreamState(&ctx, request);
  rb::StreamStateResponse message;
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(reader->Read(&message));
    EXPECT_EQ(message.state().backend(), rb::ROBOT_BACKEND_SIM);
  }
  ctx.TryCancel();
  while (reader->Read(&message)) {
  }
  EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::CANCELLED);

  grpc::ClientContext bad_ctx;
  request.set_rate_hz(1000.0);
  auto bad = client_.stub().StreamState(&bad_ctx, request);
  while (bad->Read(&message)) {
  }
  EXPECT_EQ(bad->Finish().error_code(), grpc::StatusCode::INVALID_ARGUMENT);
}

// Real time: a long move that Stop interrupts, and moves are exclusive meanwhile.
class SimRobotRealTimeTest : public SimRobotTest {
 protected:
  SimRobotRealTimeTest() : SimRobotTest({"--sim.time_scale=1"}) {}

  // The first state other than MOVING that the server streams: the client waits on the
  // server's word that a motion has ended, in blocking reads rather than a polling loop (the
  // deadline only bounds a hang). The state as read, MOVING if the stream ended first.
  rb::GetStateResponse FirstStateNotMoving() {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
    rb::StreamStateRequest request;
    request.set_rate_hz(100.0);
    auto stream = client_.stub().StreamState(&ctx, request);
    rb::GetStateResponse state;
    state.set_status(rb::ROBOT_STATUS_MOVING);
    rb::StreamStateResponse read;
    while (stream->Read(&read)) {
      state = read.state();
      if (state.status() != rb::ROBOT_STATUS_MOVING) break;
    }
    ctx.TryCancel();
    while (stream->Read(&read)) {
    }
    stream->Finish();
    return state;
  }
};

TEST_F(SimRobotRealTimeTest, StopInterruptsAMoveAndMovesAreExclusive) {
  JointVector target = StartJoints();
  target[0] += 1.5;
  grpc::Status move_status;
  std::thread mover([&] {
    rb::MoveJointsResponse response;
    move_status = client_.MoveJoints(target, &response, 0.2);
  });
  ASSERT_TRUE(sim_.WaitForPlacements(5, std::chrono::seconds(30)));
  rb::MoveJointsResponse other;
  EXPECT_EQ(client_.MoveJoints(StartJoints(), &other).error_code(),
            grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_EQ(client_.State().status(), rb::ROBOT_STATUS_MOVING);
  ASSERT_TRUE(client_.Stop().ok());
  mover.join();
  EXPECT_EQ(move_status.error_code(), grpc::StatusCode::ABORTED) << move_status.error_message();
  const rb::GetStateResponse state = client_.State();
  EXPECT_EQ(state.status(), rb::ROBOT_STATUS_IDLE);
  EXPECT_GT(std::abs(state.joints().positions_rad(0) - target[0]), 0.1);
}

// A move past its deadline is stopped by the server. The contract a client relies on:
// GetState answers MOVING until the stopped motion has ended (the server's motion slot
// outlives the backend's motion by the few steps that end a call), and once it says IDLE
// the next move is accepted at the first try.
TEST_F(SimRobotRealTimeTest, AMovePastItsDeadlineIsStoppedAndIdleMeansReady) {
  JointVector target = StartJoints();
  target[0] += 1.5;
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::milliseconds(300));
  rb::MoveJointsRequest request;
  SetJoints(target, request.mutable_target());
  request.mutable_options()->set_speed_fraction(0.2);
  rb::MoveJointsResponse response;
  ASSERT_EQ(client_.stub().MoveJoints(&ctx, request, &response).error_code(),
            grpc::StatusCode::DEADLINE_EXCEEDED);
  const rb::GetStateResponse state = FirstStateNotMoving();
  ASSERT_EQ(state.status(), rb::ROBOT_STATUS_IDLE);
  rb::MoveJointsResponse back;
  const grpc::Status next = client_.MoveJoints(StartJoints(), &back);
  EXPECT_TRUE(next.ok()) << next.error_message();
}

// The ur backend against the in-process fake controller.
class UrRobotTest : public ::testing::Test {
 protected:
  UrRobotTest()
      : kin_(Kinematics()),
        fake_(kin_),
        server_(ServerBinary(kBinary),
                {"--backend=ur", "--ur.host=127.0.0.1",
                 "--ur.rtde_port=" + std::to_string(fake_.rtde_port()),
                 "--ur.dashboard_port=" + std::to_string(fake_.dashboard_port()),
                 "--ur.script_port=" + std::to_string(fake_.script_port()),
                 "--ur.rtde_frequency_hz=500", "--ur.power_on=true",
                 "--safety.workspace_max_m=1.3,1.4,1.2"}),
        client_(server_.Channel()) {}
  ~UrRobotTest() override { EXPECT_EQ(server_.Stop(), 0); }

  ur10::Ur10Kinematics kin_;
  robot::testing::FakeUrController fake_;
  ServerProcess server_;
  RobotClient client_;
};

TEST_F(UrRobotTest, PowersOnAndReportsTheControllerState) {
  EXPECT_EQ(fake_.dashboard_commands(), (std::vector<std::string>{"power on", "brake release"}));
  const rb::GetStateResponse state = client_.State();
  EXPECT_EQ(state.backend(), rb::ROBOT_BACKEND_UR);
  EXPECT_EQ(state.status(), rb::ROBOT_STATUS_IDLE);
  EXPECT_LT((Joints(state.joints().positions_rad()) - fake_.q()).cwiseAbs().maxCoeff(), 1e-9);
}

TEST_F(UrRobotTest, MoveJointsReachesTheTarget) {
  JointVector target = fake_.q();
  target[0] += 0.2;
  target[3] -= 0.1;
  rb::MoveJointsResponse response;
  const grpc::Status s = client_.MoveJoints(target, &response);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_LT(
      (Joints(response.final_state().joints().positions_rad()) - target).cwiseAbs().maxCoeff(),
      1e-3);
  ASSERT_EQ(fake_.script_lines().size(), 1u);
  EXPECT_EQ(fake_.script_lines()[0].rfind("movej(", 0), 0u) << fake_.script_lines()[0];
}

TEST_F(UrRobotTest, RefusedRequestsSendNothingToTheController) {
  JointVector q = fake_.q();
  q[2] = 3.5;
  rb::MoveJointsResponse response;
  EXPECT_EQ(client_.MoveJoints(q, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  q = fake_.q();
  q[0] = std::numeric_limits<double>::infinity();
  EXPECT_EQ(client_.MoveJoints(q, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  const grpc::Status s =
      client_.MoveJoints(std::vector<double>{0, -1.5708, 0, -1.5708, 0, 0}, &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("workspace"), std::string::npos) << s.error_message();
  EXPECT_TRUE(fake_.script_lines().empty());
}

TEST_F(UrRobotTest, ProtectiveStopBlocksMovesUntilReset) {
  // The call returns once the controller reports the stop.
  ASSERT_TRUE(client_.ProtectiveStop("light curtain").ok());
  EXPECT_EQ(fake_.script_lines().back(), "protective_stop()");
  const rb::GetStateResponse stopped = client_.State();
  EXPECT_EQ(stopped.status(), rb::ROBOT_STATUS_PROTECTIVE_STOP);
  EXPECT_NE(stopped.status_detail().find("light curtain"), std::string::npos);
  JointVector target = fake_.q();
  target[0] += 0.1;
  rb::MoveJointsResponse response;
  EXPECT_EQ(client_.MoveJoints(target, &response).error_code(),
            grpc::StatusCode::FAILED_PRECONDITION);
  ASSERT_TRUE(client_.Reset().ok());
  EXPECT_EQ(client_.State().status(), rb::ROBOT_STATUS_IDLE);
  const grpc::Status s = client_.MoveJoints(target, &response);
  EXPECT_TRUE(s.ok()) << s.error_message();
}

TEST_F(UrRobotTest, ExecuteTrajectoryStreamsProgressEndingWithDone) {
  JointVector q1 = fake_.q();
  q1[0] += 0.2;
  const robot::JointTrajectory trajectory = SlowPath(fake_.q(), q1);
  std::vector<rb::ExecuteTrajectoryResponse> progress;
  const grpc::Status s = client_.Execute(trajectory, &progress);
  ASSERT_TRUE(s.ok()) << s.error_message();
  ASSERT_GE(progress.size(), 2u);
  EXPECT_TRUE(progress.back().done());
  EXPECT_DOUBLE_EQ(progress.back().fraction_done(), 1.0);
  EXPECT_LT((Joints(progress.back().joints().positions_rad()) - q1).cwiseAbs().maxCoeff(), 1e-3);
  EXPECT_EQ(fake_.script_lines().front(), "def picking_trajectory():");
}

TEST_F(UrRobotTest, GuardedMoveStopsOnContactWithTheForceReported) {
  const Eigen::Isometry3d X = kin_.ForwardKinematics(fake_.q());
  fake_.set_surface_z(X.translation().z() - 0.03);
  rb::GuardedMoveResponse response;
  const grpc::Status s = client_.Guarded(0.1, 10.0, &response);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_TRUE(response.contact());
  EXPECT_GE(response.contact_force_n(), 10.0);
  EXPECT_GT(response.distance_travelled_m(), 0.03);
  EXPECT_LT(response.distance_travelled_m(), 0.05);
}

}  // namespace
}  // namespace picking::testing
