// Integration test of the picking-planner server binary through its generated client.
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>

#include "picking/planner/v1/planner.grpc.pb.h"
#include "tests/harness/server_process.h"
#include "tests/harness/service_checks.h"

namespace picking::testing {
namespace {

const char kBinary[] = "picking-planner";

TEST(PlannerServerTest, ServesHealthAndReflectionAndStopsCleanly) {
  ExpectStandardServerBehaviour(ServerBinary(kBinary), "picking.planner.v1.PlannerService",
                                "picking/planner/v1/planner.proto");
}

TEST(PlannerServerTest, RejectsBadFlags) { ExpectRejectsBadFlags(ServerBinary(kBinary)); }

TEST(PlannerServerTest, UnfinishedRpcAnswersUnimplemented) {
  ServerProcess server(ServerBinary(kBinary));
  auto stub = planner::v1::PlannerService::NewStub(server.Channel());
  grpc::ClientContext ctx;
  planner::v1::ListNamedPosesRequest request;
  planner::v1::ListNamedPosesResponse response;
  const grpc::Status status = stub->ListNamedPoses(&ctx, request, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNIMPLEMENTED) << status.error_message();
  EXPECT_EQ(server.Stop(), 0);
}

}  // namespace
}  // namespace picking::testing
