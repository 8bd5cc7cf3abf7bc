// Integration test of the picking-robot server binary through its generated client.
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>

#include "picking/robot/v1/robot.grpc.pb.h"
#include "tests/harness/server_process.h"
#include "tests/harness/service_checks.h"

namespace picking::testing {
namespace {

const char kBinary[] = "picking-robot";

TEST(RobotServerTest, ServesHealthAndReflectionAndStopsCleanly) {
  ExpectStandardServerBehaviour(ServerBinary(kBinary), "picking.robot.v1.RobotService",
                                "picking/robot/v1/robot.proto");
}

TEST(RobotServerTest, RejectsBadFlags) { ExpectRejectsBadFlags(ServerBinary(kBinary)); }

TEST(RobotServerTest, UnfinishedRpcAnswersUnimplemented) {
  ServerProcess server(ServerBinary(kBinary));
  auto stub = robot::v1::RobotService::NewStub(server.Channel());
  grpc::ClientContext ctx;
  robot::v1::GetStateRequest request;
  robot::v1::GetStateResponse response;
  const grpc::Status status = stub->GetState(&ctx, request, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNIMPLEMENTED) << status.error_message();
  EXPECT_EQ(server.Stop(), 0);
}

}  // namespace
}  // namespace picking::testing
