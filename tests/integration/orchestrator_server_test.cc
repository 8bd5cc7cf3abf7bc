// Integration test of the picking-orchestrator server binary through its generated client.
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>

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

TEST(OrchestratorServerTest, UnfinishedRpcAnswersUnimplemented) {
  ServerProcess server(ServerBinary(kBinary));
  auto stub = orchestrator::v1::OrchestratorService::NewStub(server.Channel());
  grpc::ClientContext ctx;
  orchestrator::v1::ListTasksRequest request;
  orchestrator::v1::ListTasksResponse response;
  const grpc::Status status = stub->ListTasks(&ctx, request, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNIMPLEMENTED) << status.error_message();
  EXPECT_EQ(server.Stop(), 0);
}

}  // namespace
}  // namespace picking::testing
