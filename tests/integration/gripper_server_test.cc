// Integration test of the picking-gripper server binary through its generated client.
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>

#include "picking/gripper/v1/gripper.grpc.pb.h"
#include "tests/harness/server_process.h"
#include "tests/harness/service_checks.h"

namespace picking::testing {
namespace {

const char kBinary[] = "picking-gripper";

TEST(GripperServerTest, ServesHealthAndReflectionAndStopsCleanly) {
  ExpectStandardServerBehaviour(ServerBinary(kBinary), "picking.gripper.v1.GripperService",
                                "picking/gripper/v1/gripper.proto");
}

TEST(GripperServerTest, RejectsBadFlags) { ExpectRejectsBadFlags(ServerBinary(kBinary)); }

TEST(GripperServerTest, UnfinishedRpcAnswersUnimplemented) {
  ServerProcess server(ServerBinary(kBinary));
  auto stub = gripper::v1::GripperService::NewStub(server.Channel());
  grpc::ClientContext ctx;
  gripper::v1::GetStateRequest request;
  gripper::v1::GetStateResponse response;
  const grpc::Status status = stub->GetState(&ctx, request, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNIMPLEMENTED) << status.error_message();
  EXPECT_EQ(server.Stop(), 0);
}

}  // namespace
}  // namespace picking::testing
