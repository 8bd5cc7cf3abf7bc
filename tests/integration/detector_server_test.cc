// Integration test of the picking-detector server binary through its generated client.
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>

#include "picking/detector/v1/detector.grpc.pb.h"
#include "tests/harness/server_process.h"
#include "tests/harness/service_checks.h"

namespace picking::testing {
namespace {

const char kBinary[] = "picking-detector";

TEST(DetectorServerTest, ServesHealthAndReflectionAndStopsCleanly) {
  ExpectStandardServerBehaviour(ServerBinary(kBinary), "picking.detector.v1.DetectorService",
                                "picking/detector/v1/detector.proto");
}

TEST(DetectorServerTest, RejectsBadFlags) { ExpectRejectsBadFlags(ServerBinary(kBinary)); }

TEST(DetectorServerTest, UnfinishedRpcAnswersUnimplemented) {
  ServerProcess server(ServerBinary(kBinary));
  auto stub = detector::v1::DetectorService::NewStub(server.Channel());
  grpc::ClientContext ctx;
  detector::v1::ListModelsRequest request;
  detector::v1::ListModelsResponse response;
  const grpc::Status status = stub->ListModels(&ctx, request, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNIMPLEMENTED) << status.error_message();
  EXPECT_EQ(server.Stop(), 0);
}

}  // namespace
}  // namespace picking::testing
