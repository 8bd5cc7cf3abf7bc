// The GripperService adapter served in-process over the simulator backend (against a fake
// simulator), and the server's settings.
#include "services/gripper/service/gripper_service.h"

#include <grpcpp/client_context.h>
#include <grpcpp/create_channel.h>
#include <grpcpp/server.h>
#include <grpcpp/server_builder.h>
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <memory>

#include "libs/errors/errors.h"
#include "services/gripper/core/testing/fake_clock.h"
#include "services/gripper/service/sim_gripper.h"
#include "services/gripper/service/test/fake_simulator.h"

namespace picking::gripper {
namespace {

namespace pb = ::picking::gripper::v1;
using testing::FakeClock;
using testing::FakeSimulator;
using testing::TiltedDownTool;

// The adapter over a Gripper on the fake simulator, served on a free port.
class GripperServiceTest : public ::testing::Test {
 protected:
  void Start(GripperKind kind, const std::string& sim_address = "") {
    SimGripperOptions sim_options;
    sim_options.kind = kind;
    sim_options.timeout_s = 2.0;
    GripperOptions options;
    options.kind = kind;
    auto gripper = std::make_shared<Gripper>(
        SimGripper::Connect(sim_address.empty() ? sim_.address() : sim_address, sim_options),
        options, clock_);
    service_ = MakeGripperService(gripper);
    grpc::ServerBuilder builder;
    int port = 0;
    builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port);
    builder.RegisterService(service_.get());
    server_ = builder.BuildAndStart();
    stub_ = pb::GripperService::NewStub(grpc::CreateChannel("127.0.0.1:" + std::to_string(port),
                                                            grpc::InsecureChannelCredentials()));
  }
  ~GripperServiceTest() override {
    if (server_) server_->Shutdown();
  }

  grpc::Status SetVacuum(bool on, double wait_s, pb::SetVacuumResponse* out) {
    grpc::ClientContext ctx;
    pb::SetVacuumRequest request;
    request.set_on(on);
    request.set_wait_for_seal_s(wait_s);
    return stub_->SetVacuum(&ctx, request, out);
  }
  grpc::Status SetJointMode(pb::JointMode mode, double angle, pb::SetJointModeResponse* out) {
    grpc::ClientContext ctx;
    pb::SetJointModeRequest request;
    request.set_mode(mode);
    request.set_angle_rad(angle);
    return stub_->SetJointMode(&ctx, request, out);
  }
  grpc::Status GetState(pb::GetStateResponse* out) {
    grpc::ClientContext ctx;
    return stub_->GetState(&ctx, pb::GetStateRequest(), out);
  }

  FakeSimulator sim_;
  std::shared_ptr<FakeClock> clock_ = std::make_shared<FakeClock>();
  std::shared_ptr<grpc::Service> service_;
  std::unique_ptr<grpc::Server> server_;
  std::unique_ptr<pb::GripperService::Stub> stub_;
};

TEST_F(GripperServiceTest, SetVacuumWaitsForTheSealOrAnswersDeadlineExceeded) {
  Start(GripperKind::kTote);
  pb::SetVacuumResponse response;
  grpc::Status status = SetVacuum(true, 0.5, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << status.error_message();
  EXPECT_TRUE(sim_.suction_on());  // The pump stays as commanded.

  sim_.SetItemUnderCup("crayola_64_ct");
  ASSERT_TRUE(SetVacuum(false, 0.0, &response).ok());
  status = SetVacuum(true, 0.5, &response);
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_TRUE(response.state().item_attached());
  EXPECT_TRUE(response.state().vacuum_on());
  EXPECT_GT(response.state().vacuum_kpa(), 15.0);
  EXPECT_EQ(response.state().backend(), pb::GRIPPER_BACKEND_SIM);
  EXPECT_EQ(response.state().kind(), pb::GRIPPER_KIND_TOTE);

  for (double bad : {std::nan(""), -1.0, 11.0}) {
    EXPECT_EQ(SetVacuum(true, bad, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  }
}

TEST_F(GripperServiceTest, JointModesOnTheToteGripper) {
  Start(GripperKind::kTote);
  sim_.SetToolPose(TiltedDownTool(0.25));
  pb::SetJointModeResponse response;
  ASSERT_TRUE(SetJointMode(pb::JOINT_MODE_KEEP_VERTICAL, 0.0, &response).ok());
  EXPECT_EQ(response.state().joint_mode(), pb::JOINT_MODE_KEEP_VERTICAL);
  EXPECT_NEAR(response.state().joint_angle_rad(), -0.25, 1e-9);
  EXPECT_NEAR(response.state().accel_y_m_s2(), 0.0, 1e-9);
  EXPECT_NEAR(response.state().accel_z_m_s2(), kGravity_m_s2, 1e-9);

  ASSERT_TRUE(SetJointMode(pb::JOINT_MODE_FIXED, -1.2, &response).ok());
  EXPECT_EQ(response.state().joint_mode(), pb::JOINT_MODE_FIXED);
  EXPECT_DOUBLE_EQ(response.state().joint_angle_rad(), -1.2);

  ASSERT_TRUE(SetJointMode(pb::JOINT_MODE_UNACTUATED, 0.0, &response).ok());
  EXPECT_EQ(response.state().joint_mode(), pb::JOINT_MODE_UNACTUATED);

  pb::GetStateResponse state;
  ASSERT_TRUE(GetState(&state).ok());
  EXPECT_EQ(state.joint_mode(), pb::JOINT_MODE_UNACTUATED);
  EXPECT_NEAR(state.joint_angle_rad(), -0.25, 1e-9);

  EXPECT_EQ(SetJointMode(pb::JOINT_MODE_UNSPECIFIED, 0.0, &response).error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(SetJointMode(static_cast<pb::JointMode>(17), 0.0, &response).error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(SetJointMode(pb::JOINT_MODE_FIXED, std::nan(""), &response).error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(SetJointMode(pb::JOINT_MODE_FIXED, 1.6, &response).error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);
  ASSERT_TRUE(GetState(&state).ok());
  EXPECT_EQ(state.joint_mode(), pb::JOINT_MODE_UNACTUATED);  // Refusals changed nothing.
}

TEST_F(GripperServiceTest, ShelfGripperAnswersFailedPrecondition) {
  Start(GripperKind::kShelf);
  pb::SetJointModeResponse response;
  const grpc::Status status = SetJointMode(pb::JOINT_MODE_KEEP_VERTICAL, 0.0, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << status.error_message();
  pb::GetStateResponse state;
  ASSERT_TRUE(GetState(&state).ok());
  EXPECT_EQ(state.kind(), pb::GRIPPER_KIND_SHELF);
  EXPECT_EQ(state.joint_mode(), pb::JOINT_MODE_UNSPECIFIED);
}

TEST_F(GripperServiceTest, UnreachableSimulatorAnswersUnavailablePerCall) {
  std::string address;
  {
    FakeSimulator gone;
    address = gone.address();
  }
  Start(GripperKind::kTote, address);
  pb::GetStateResponse state;
  EXPECT_EQ(GetState(&state).error_code(), grpc::StatusCode::UNAVAILABLE);
  pb::SetVacuumResponse vacuum;
  EXPECT_EQ(SetVacuum(true, 0.0, &vacuum).error_code(), grpc::StatusCode::UNAVAILABLE);
}

TEST(BuildGripperServicesTest, ReadsEverySettingAndStartsWithoutASimulator) {
  runtime::Config config;
  for (const auto& [key, value] :
       std::vector<std::pair<std::string, std::string>>{{"backend", "sim"},
                                                        {"kind", "tote"},
                                                        {"serial.device", "/dev/ttyUSB3"},
                                                        {"serial.baud", "115200"},
                                                        {"serial.reply_timeout_s", "0.3"},
                                                        {"serial.max_attempts", "4"},
                                                        {"sim.address", "127.0.0.1:1"},
                                                        {"sim.timeout_s", "1.5"},
                                                        {"seal.attach_kpa", "20"},
                                                        {"seal.release_kpa", "12"},
                                                        {"poll_interval_s", "0.05"}}) {
    config.Set(key, value);
  }
  const runtime::ServiceSet set = BuildGripperServices(config);
  ASSERT_EQ(set.services.size(), 1u);
  EXPECT_EQ(set.full_names.front(), "picking.gripper.v1.GripperService");
  EXPECT_TRUE(config.UnusedKeys().empty());
}

TEST(BuildGripperServicesTest, RejectsBadSettings) {
  auto build = [](const std::string& key, const std::string& value) {
    runtime::Config config;
    config.Set(key, value);
    return BuildGripperServices(config);
  };
  EXPECT_THROW(build("backend", "usb"), std::invalid_argument);
  EXPECT_THROW(build("kind", "bin"), std::invalid_argument);
  EXPECT_THROW(build("serial.max_attempts", "0"), std::invalid_argument);
  EXPECT_THROW(build("sim.timeout_s", "-1"), std::invalid_argument);
  EXPECT_THROW(build("seal.release_kpa", "30"), std::invalid_argument);
  EXPECT_THROW(build("sim.address", "nowhere"), std::invalid_argument);
  runtime::Config serial;
  serial.Set("backend", "serial");
  serial.Set("serial.device", "/nonexistent/ttyUSB7");
  EXPECT_THROW(BuildGripperServices(serial), UnavailableError);
  serial.Set("serial.baud", "1234");
  EXPECT_THROW(BuildGripperServices(serial), std::invalid_argument);
}

}  // namespace
}  // namespace picking::gripper
