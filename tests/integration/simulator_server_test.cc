// Integration test of the picking-simulator server binary through its generated client.
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>

#include "picking/simulator/v1/simulator.grpc.pb.h"
#include "tests/harness/server_process.h"
#include "tests/harness/service_checks.h"

namespace picking::testing {
namespace {

const char kBinary[] = "picking-simulator";

TEST(SimulatorServerTest, ServesHealthAndReflectionAndStopsCleanly) {
  ExpectStandardServerBehaviour(ServerBinary(kBinary), "picking.simulator.v1.SimulatorService",
                                "picking/simulator/v1/simulator.proto");
}

TEST(SimulatorServerTest, RejectsBadFlags) { ExpectRejectsBadFlags(ServerBinary(kBinary)); }

TEST(SimulatorServerTest, UnfinishedRpcAnswersUnimplemented) {
  ServerProcess server(ServerBinary(kBinary));
  auto stub = simulator::v1::SimulatorService::NewStub(server.Channel());
  grpc::ClientContext ctx;
  simulator::v1::GetCellRequest request;
  simulator::v1::GetCellResponse response;
  const grpc::Status status = stub->GetCell(&ctx, request, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNIMPLEMENTED) << status.error_message();
  EXPECT_EQ(server.Stop(), 0);
}

}  // namespace
}  // namespace picking::testing
