#include "tests/harness/service_checks.h"

#include <grpcpp/client_context.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>

#include "grpc/health/v1/health.grpc.pb.h"
#include "tests/harness/reflection_client.h"
#include "tests/harness/server_process.h"

namespace picking::testing {
namespace {

using grpc::health::v1::Health;
using grpc::health::v1::HealthCheckRequest;
using grpc::health::v1::HealthCheckResponse;

grpc::Status Check(Health::Stub& stub, const std::string& service, HealthCheckResponse* out) {
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  HealthCheckRequest req;
  req.set_service(service);
  return stub.Check(&ctx, req, out);
}

bool Contains(const std::vector<std::string>& v, const std::string& s) {
  return std::find(v.begin(), v.end(), s) != v.end();
}

}  // namespace

void ExpectStandardServerBehaviour(const std::string& binary, const std::string& service_full_name,
                                   const std::string& proto_file) {
  ServerProcess server(binary);
  EXPECT_EQ(server.address().rfind("127.0.0.1:", 0), 0u) << server.address();
  EXPECT_GT(server.port(), 0);

  auto health = Health::NewStub(server.Channel());
  HealthCheckResponse response;
  grpc::Status status = Check(*health, "", &response);
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(response.status(), HealthCheckResponse::SERVING);
  status = Check(*health, service_full_name, &response);
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(response.status(), HealthCheckResponse::SERVING);
  status = Check(*health, "no.such.Service", &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND);

  // Both reflection versions list the server's services (themselves included) and resolve
  // its contract and the health service's.
  for (const ReflectionVersion version : {ReflectionVersion::kV1Alpha, ReflectionVersion::kV1}) {
    const char* name = version == ReflectionVersion::kV1 ? "v1" : "v1alpha";
    const auto services = ListServicesByReflection(server.Channel(), version);
    EXPECT_TRUE(Contains(services, service_full_name)) << name;
    EXPECT_TRUE(Contains(services, "grpc.health.v1.Health")) << name;
    EXPECT_TRUE(Contains(services, "grpc.reflection.v1.ServerReflection")) << name;
    EXPECT_TRUE(Contains(services, "grpc.reflection.v1alpha.ServerReflection")) << name;
    const auto files = FilesContainingSymbol(server.Channel(), service_full_name, version);
    EXPECT_TRUE(Contains(files, proto_file)) << name << " did not return " << proto_file;
    const auto health_files =
        FilesContainingSymbol(server.Channel(), "grpc.health.v1.Health", version);
    EXPECT_TRUE(Contains(health_files, "grpc/health/v1/health.proto")) << name;
  }

  EXPECT_EQ(server.Stop(), 0);
}

void ExpectRejectsBadFlags(const std::string& binary) {
  auto r = RunProgram(binary, {"--listen=127.0.0.1:0", "--no-such-setting=1"});
  EXPECT_EQ(r.exit_status, 2) << r.output;
  EXPECT_NE(r.output.find("no-such-setting"), std::string::npos) << r.output;
  r = RunProgram(binary, {"--listen=nonsense"});
  EXPECT_EQ(r.exit_status, 2) << r.output;
  EXPECT_NE(r.output.find("--listen"), std::string::npos) << r.output;
  r = RunProgram(binary, {"--config=/nonexistent/settings.yaml"});
  EXPECT_EQ(r.exit_status, 2) << r.output;
  EXPECT_NE(r.output.find("/nonexistent/settings.yaml"), std::string::npos) << r.output;
  r = RunProgram(binary, {"--help"});
  EXPECT_EQ(r.exit_status, 0) << r.output;
  EXPECT_NE(r.output.find("--listen"), std::string::npos) << r.output;
}

}  // namespace picking::testing
