// Integration test of the picking-scanner server binary through its generated client.
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>

#include "picking/scanner/v1/scanner.grpc.pb.h"
#include "tests/harness/server_process.h"
#include "tests/harness/service_checks.h"

namespace picking::testing {
namespace {

const char kBinary[] = "picking-scanner";

TEST(ScannerServerTest, ServesHealthAndReflectionAndStopsCleanly) {
  ExpectStandardServerBehaviour(ServerBinary(kBinary), "picking.scanner.v1.ScannerService",
                                "picking/scanner/v1/scanner.proto");
}

TEST(ScannerServerTest, RejectsBadFlags) { ExpectRejectsBadFlags(ServerBinary(kBinary)); }

TEST(ScannerServerTest, UnfinishedRpcAnswersUnimplemented) {
  ServerProcess server(ServerBinary(kBinary));
  auto stub = scanner::v1::ScannerService::NewStub(server.Channel());
  grpc::ClientContext ctx;
  scanner::v1::GetCalibrationRequest request;
  scanner::v1::GetCalibrationResponse response;
  const grpc::Status status = stub->GetCalibration(&ctx, request, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNIMPLEMENTED) << status.error_message();
  EXPECT_EQ(server.Stop(), 0);
}

}  // namespace
}  // namespace picking::testing
