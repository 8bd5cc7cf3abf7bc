// Integration test of the picking-gripper server binary through its generated client. The
// serial backend talks to a fake micro controller on the master side of a pseudo-terminal
// in this process; the server opens the slave side as its serial device.
#include <arpa/inet.h>
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "picking/gripper/v1/gripper.grpc.pb.h"
#include "services/gripper/core/keep_vertical.h"
#include "services/gripper/core/testing/fake_micro_controller.h"
#include "tests/harness/server_process.h"
#include "tests/harness/service_checks.h"

namespace picking::testing {
namespace {

namespace pb = ::picking::gripper::v1;
using gripper::testing::FakeMicroController;

const char kBinary[] = "picking-gripper";

TEST(GripperServerTest, ServesHealthAndReflectionAndStopsCleanly) {
  ExpectStandardServerBehaviour(ServerBinary(kBinary), "picking.gripper.v1.GripperService",
                                "picking/gripper/v1/gripper.proto");
}

TEST(GripperServerTest, RejectsBadFlags) { ExpectRejectsBadFlags(ServerBinary(kBinary)); }

// A TCP port on which nothing listens: bound once by the kernel's choice, then released.
int ClosedPort() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  addr.sin_port = 0;
  EXPECT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)), 0);
  socklen_t len = sizeof(addr);
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
  ::close(fd);
  return ntohs(addr.sin_port);
}

TEST(GripperServerTest, SimBackendWithoutSimulatorStartsAndAnswersUnavailable) {
  ServerProcess server(ServerBinary(kBinary),
                       {"--sim.address=127.0.0.1:" + std::to_string(ClosedPort()), "--kind=tote"});
  auto stub = pb::GripperService::NewStub(server.Channel());
  for (int i = 0; i < 2; ++i) {
    grpc::ClientContext ctx;
    pb::GetStateResponse response;
    const grpc::Status status = stub->GetState(&ctx, pb::GetStateRequest(), &response);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAVAILABLE) << status.error_message();
  }
  EXPECT_EQ(server.Stop(), 0);
}

TEST(GripperServerTest, SerialBackendWithoutDeviceRefusesToStart) {
  const ProgramResult result = RunProgram(
      ServerBinary(kBinary),
      {"--listen=127.0.0.1:0", "--backend=serial", "--serial.device=/nonexistent/ttyUSB9"});
  EXPECT_EQ(result.exit_status, 1) << result.output;
  EXPECT_NE(result.output.find("/nonexistent/ttyUSB9"), std::string::npos) << result.output;
}

Eigen::Vector3d ToolGravity(double phi) {
  return gripper::kGravity_m_s2 * Eigen::Vector3d(0.0, std::sin(phi), std::cos(phi));
}

class GripperSerialServerTest : public ::testing::Test {
 protected:
  void Start(const std::string& kind) {
    server_ = std::make_unique<ServerProcess>(
        ServerBinary(kBinary),
        std::vector<std::string>{"--backend=serial", "--serial.device=" + mcu_.device_path(),
                                 "--kind=" + kind, "--serial.reply_timeout_s=0.1"});
    stub_ = pb::GripperService::NewStub(server_->Channel());
  }
  void TearDown() override {
    if (server_) {
      EXPECT_EQ(server_->Stop(), 0);
    }
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
  pb::GetStateResponse State() {
    grpc::ClientContext ctx;
    pb::GetStateResponse response;
    const grpc::Status status = stub_->GetState(&ctx, pb::GetStateRequest(), &response);
    EXPECT_TRUE(status.ok()) << status.error_message();
    return response;
  }

  FakeMicroController mcu_;  // Outlives the server (members are destroyed in reverse).
  std::unique_ptr<ServerProcess> server_;
  std::unique_ptr<pb::GripperService::Stub> stub_;
};

TEST_F(GripperSerialServerTest, VacuumReachesASeal) {
  Start("tote");
  pb::SetVacuumResponse response;
  const grpc::Status status = SetVacuum(true, 2.0, &response);
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_TRUE(response.state().item_attached());
  EXPECT_TRUE(response.state().vacuum_on());
  EXPECT_GE(response.state().vacuum_kpa(), 15.0);
  EXPECT_EQ(response.state().backend(), pb::GRIPPER_BACKEND_SERIAL);
  EXPECT_EQ(response.state().kind(), pb::GRIPPER_KIND_TOTE);
  EXPECT_TRUE(mcu_.relay_on());

  ASSERT_TRUE(SetVacuum(false, 0.0, &response).ok());
  EXPECT_FALSE(response.state().item_attached());
  EXPECT_FALSE(mcu_.relay_on());
}

TEST_F(GripperSerialServerTest, AGripperThatNeverReachesVacuumAnswersDeadlineExceeded) {
  Start("tote");
  mcu_.SetItemUnderCup(false);
  pb::SetVacuumResponse response;
  const grpc::Status status = SetVacuum(true, 0.3, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << status.error_message();
  EXPECT_NE(status.error_message().find("seal threshold"), std::string::npos);
  // The server keeps running and the pump stays on.
  const pb::GetStateResponse state = State();
  EXPECT_TRUE(state.vacuum_on());
  EXPECT_FALSE(state.item_attached());
  EXPECT_LT(state.vacuum_kpa(), 15.0);
  EXPECT_TRUE(mcu_.relay_on());
  // Once an item is under the cup, the same request succeeds.
  mcu_.SetItemUnderCup(true);
  ASSERT_TRUE(SetVacuum(true, 2.0, &response).ok());
  EXPECT_TRUE(response.state().item_attached());
}

TEST_F(GripperSerialServerTest, ToteGripperJointInAllThreeModes) {
  Start("tote");
  pb::SetJointModeResponse response;
  // Fixed.
  ASSERT_TRUE(SetJointMode(pb::JOINT_MODE_FIXED, 0.5, &response).ok());
  EXPECT_EQ(response.state().joint_mode(), pb::JOINT_MODE_FIXED);
  pb::GetStateResponse state;
  for (int i = 0; i < 3; ++i) state = State();
  EXPECT_NEAR(state.joint_angle_rad(), 0.5, 1e-3);

  // Keep vertical while the tool is tilted, with the vacuum locking the joint's play.
  pb::SetVacuumResponse vacuum;
  ASSERT_TRUE(SetVacuum(true, 0.0, &vacuum).ok());
  mcu_.SetToolGravity(ToolGravity(-0.6));
  ASSERT_TRUE(SetJointMode(pb::JOINT_MODE_KEEP_VERTICAL, 0.0, &response).ok());
  EXPECT_EQ(response.state().joint_mode(), pb::JOINT_MODE_KEEP_VERTICAL);
  for (int i = 0; i < 10; ++i) state = State();
  EXPECT_NEAR(state.joint_angle_rad(), 0.6, 0.01);
  EXPECT_NEAR(gripper::HeadTilt(Eigen::Vector3d(state.accel_x_m_s2(), state.accel_y_m_s2(),
                                                state.accel_z_m_s2())),
              0.0, 0.01);

  // Unactuated: the vacuum holds the joint where it is; without it the head hangs.
  ASSERT_TRUE(SetJointMode(pb::JOINT_MODE_UNACTUATED, 0.0, &response).ok());
  EXPECT_EQ(response.state().joint_mode(), pb::JOINT_MODE_UNACTUATED);
  mcu_.SetToolGravity(ToolGravity(0.2));
  for (int i = 0; i < 3; ++i) state = State();
  EXPECT_NEAR(state.joint_angle_rad(), 0.6, 0.01);
  ASSERT_TRUE(SetVacuum(false, 0.0, &vacuum).ok());
  for (int i = 0; i < 3; ++i) state = State();
  EXPECT_NEAR(state.joint_angle_rad(), -0.2, 1e-3);

  // Bad requests change nothing.
  EXPECT_EQ(SetJointMode(pb::JOINT_MODE_FIXED, std::nan(""), &response).error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(SetJointMode(pb::JOINT_MODE_FIXED, 2.0, &response).error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(SetJointMode(pb::JOINT_MODE_UNSPECIFIED, 0.0, &response).error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(State().joint_mode(), pb::JOINT_MODE_UNACTUATED);
}

TEST_F(GripperSerialServerTest, ShelfGripperAnswersFailedPrecondition) {
  Start("shelf");
  pb::SetJointModeResponse response;
  const grpc::Status status = SetJointMode(pb::JOINT_MODE_KEEP_VERTICAL, 0.0, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << status.error_message();
  const pb::GetStateResponse state = State();
  EXPECT_EQ(state.kind(), pb::GRIPPER_KIND_SHELF);
  EXPECT_EQ(state.joint_mode(), pb::JOINT_MODE_UNSPECIFIED);
  for (const std::string& command : mcu_.commands()) {
    EXPECT_TRUE(command[0] != 'M' && command[0] != 'S') << command;
  }
}

TEST_F(GripperSerialServerTest, GarbledLinesAndLostRepliesAreHandled) {
  Start("tote");
  mcu_.SetToolGravity(ToolGravity(0.1));
  // Noise, an overlong line and a stale reply arrive before the server asks anything.
  mcu_.SendRaw("garbage\n" + std::string(400, '~') + "\n$OK 4242*00\n");
  pb::GetStateResponse state = State();
  EXPECT_EQ(state.backend(), pb::GRIPPER_BACKEND_SERIAL);

  mcu_.GarbleNextReplies(1);
  state = State();
  EXPECT_EQ(state.joint_mode(), pb::JOINT_MODE_UNACTUATED);
  mcu_.TruncateNextReplies(1);
  pb::SetVacuumResponse vacuum;
  ASSERT_TRUE(SetVacuum(true, 2.0, &vacuum).ok());
  EXPECT_TRUE(vacuum.state().item_attached());
  mcu_.DropNextReplies(2);
  pb::SetJointModeResponse joint;
  ASSERT_TRUE(SetJointMode(pb::JOINT_MODE_FIXED, -0.3, &joint).ok());
  EXPECT_EQ(joint.state().joint_mode(), pb::JOINT_MODE_FIXED);

  // A controller that stops answering makes calls UNAVAILABLE; the server recovers with it.
  mcu_.SetSilent(true);
  grpc::ClientContext ctx;
  pb::GetStateResponse response;
  EXPECT_EQ(stub_->GetState(&ctx, pb::GetStateRequest(), &response).error_code(),
            grpc::StatusCode::UNAVAILABLE);
  mcu_.SetSilent(false);
  state = State();
  EXPECT_EQ(state.joint_mode(), pb::JOINT_MODE_FIXED);
  EXPECT_TRUE(state.vacuum_on());
}

}  // namespace
}  // namespace picking::testing
