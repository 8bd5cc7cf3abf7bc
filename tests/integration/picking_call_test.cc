// Reflection v1 and `picking call` against a real server (picking-planner): the command line
// resolves a method through the server's reflection, sends the request it reads as JSON and
// prints the reply as JSON; unknown names and bad requests are refused with exit status 2.
#include <arpa/inet.h>
#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <mutex>
#include <nlohmann/json.hpp>
#include <stdexcept>

#include "tests/harness/reflection_client.h"
#include "tests/harness/server_process.h"

namespace picking::testing {
namespace {

bool Contains(const std::vector<std::string>& v, const std::string& s) {
  return std::find(v.begin(), v.end(), s) != v.end();
}

class PickingCallTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    planner_ = new ServerProcess(ServerBinary("picking-planner"), {}, std::chrono::seconds(120));
  }
  static void TearDownTestSuite() {
    EXPECT_EQ(planner_->Stop(), 0);
    delete planner_;
  }

  // Runs `picking call <planner> METHOD [JSON]`.
  static ProgramResult Call(const std::string& method, const std::string& json = "") {
    std::vector<std::string> args = {"call", planner_->address(), method};
    if (!json.empty()) args.push_back(json);
    return RunProgram(ServerBinary("picking"), args);
  }

  static ServerProcess* planner_;
};
ServerProcess* PickingCallTest::planner_ = nullptr;

TEST_F(PickingCallTest, ReflectionV1ListsEveryServiceAndResolvesTheHealthContract) {
  const auto services = ListServicesByReflection(planner_->Channel(), ReflectionVersion::kV1);
  for (const char* name :
       {"picking.planner.v1.PlannerService", "grpc.health.v1.Health",
        "grpc.reflection.v1.ServerReflection", "grpc.reflection.v1alpha.ServerReflection"}) {
    EXPECT_TRUE(Contains(services, name)) << name;
  }
  // A service and a message of the health contract both resolve to its file.
  for (const char* symbol : {"grpc.health.v1.Health", "grpc.health.v1.HealthCheckResponse"}) {
    EXPECT_EQ(FilesContainingSymbol(planner_->Channel(), symbol, ReflectionVersion::kV1),
              std::vector<std::string>{"grpc/health/v1/health.proto"})
        << symbol;
  }
  // The planner's file comes with the files it imports.
  const auto files = FilesContainingSymbol(planner_->Channel(), "picking.planner.v1.PlannerService",
                                           ReflectionVersion::kV1);
  ASSERT_FALSE(files.empty());
  EXPECT_EQ(files.front(), "picking/planner/v1/planner.proto");
  EXPECT_TRUE(Contains(files, "picking/common/v1/geometry.proto"));
}

TEST_F(PickingCallTest, ReflectionV1ReportsAnUnknownSymbol) {
  try {
    FilesContainingSymbol(planner_->Channel(), "no.such.Symbol", ReflectionVersion::kV1);
    FAIL() << "an unknown symbol resolved";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("'no.such.Symbol' not found"), std::string::npos)
        << e.what();
  }
}

TEST_F(PickingCallTest, CallsTheHealthCheck) {
  ProgramResult r = Call("grpc.health.v1.Health/Check", "{}");
  EXPECT_EQ(r.exit_status, 0) << r.output;
  EXPECT_EQ(r.output, "{\"status\":\"SERVING\"}\n");
  r = Call("grpc.health.v1.Health/Check", R"({"service": "picking.planner.v1.PlannerService"})");
  EXPECT_EQ(r.exit_status, 0) << r.output;
  EXPECT_EQ(r.output, "{\"status\":\"SERVING\"}\n");
  // No JSON argument is the empty request; grpcurl's "Service.Method" spelling works too.
  r = Call("grpc.health.v1.Health.Check");
  EXPECT_EQ(r.exit_status, 0) << r.output;
  EXPECT_EQ(r.output, "{\"status\":\"SERVING\"}\n");
}

TEST_F(PickingCallTest, CallsForwardKinematicsAndPrintsTheReplyAsJson) {
  const ProgramResult r = Call("picking.planner.v1.PlannerService/ComputeFk",
                               R"({"joints": {"positions_rad": [0, 0, 0, 0, 0, 0]}})");
  ASSERT_EQ(r.exit_status, 0) << r.output;
  const nlohmann::json reply = nlohmann::json::parse(r.output);
  // UR10 factory DH chain at zero joints: x = a2 + a3, y = -(d4 + d6), z = d1 - d5.
  const auto& tool = reply.at("X_base_tool").at("position");
  EXPECT_NEAR(tool.at("x").get<double>(), -1.1843, 1e-4);
  EXPECT_NEAR(tool.at("y").get<double>(), -0.2561, 1e-4);
  EXPECT_NEAR(tool.at("z").get<double>(), 0.0116, 1e-4);
  // The suction cup's lip, 0.35 m along the flange's z axis.
  const auto& tcp = reply.at("X_base_tcp").at("position");
  const double d = std::hypot(tcp.value("x", 0.0) - tool.at("x").get<double>(),
                              tcp.value("y", 0.0) - tool.at("y").get<double>(),
                              tcp.value("z", 0.0) - tool.at("z").get<double>());
  EXPECT_NEAR(d, 0.35, 1e-3);
}

TEST_F(PickingCallTest, CallsAStreamingMethodAndPrintsEachReply) {
  // The reflection service itself: a bidirectional stream, given one request.
  const ProgramResult r =
      Call("grpc.reflection.v1.ServerReflection/ServerReflectionInfo", R"({"list_services": ""})");
  ASSERT_EQ(r.exit_status, 0) << r.output;
  EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
  const nlohmann::json reply = nlohmann::json::parse(r.output);
  std::vector<std::string> names;
  for (const auto& s : reply.at("list_services_response").at("service")) {
    names.push_back(s.at("name"));
  }
  EXPECT_TRUE(Contains(names, "picking.planner.v1.PlannerService")) << r.output;
}

TEST_F(PickingCallTest, AnUnknownMethodOrServiceIsABadCommandLine) {
  ProgramResult r = Call("picking.planner.v1.PlannerService/NoSuchMethod", "{}");
  EXPECT_EQ(r.exit_status, 2) << r.output;
  EXPECT_NE(r.output.find("unknown method 'NoSuchMethod' of picking.planner.v1.PlannerService"),
            std::string::npos)
      << r.output;
  EXPECT_NE(r.output.find("ComputeFk"), std::string::npos) << r.output;  // What there is.
  r = Call("no.such.Service/Method", "{}");
  EXPECT_EQ(r.exit_status, 2) << r.output;
  EXPECT_NE(r.output.find("unknown service 'no.such.Service'"), std::string::npos) << r.output;
  r = Call("NoSlashOrDot", "{}");
  EXPECT_EQ(r.exit_status, 2) << r.output;
  EXPECT_NE(r.output.find("expected SERVICE/METHOD"), std::string::npos) << r.output;
  r = RunProgram(ServerBinary("picking"), {"call", planner_->address()});
  EXPECT_EQ(r.exit_status, 2) << r.output;
  EXPECT_NE(r.output.find("call needs ADDRESS SERVICE/METHOD"), std::string::npos) << r.output;
}

// gRPC answers a method nobody serves with UNIMPLEMENTED and no message at all; the server
// says which method it did not find and what it serves instead.
TEST_F(PickingCallTest, AMethodNoServiceHasIsUnimplementedWithAMessage) {
  auto channel = grpc::CreateChannel(planner_->address(), grpc::InsecureChannelCredentials());
  grpc::GenericStub stub(channel);
  for (const std::string method :
       {"/picking.planner.v1.PlannerService/NoSuchMethod", "/no.such.Service/Method"}) {
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    grpc::Slice empty_message("");  // An empty request message, valid for any method.
    grpc::ByteBuffer request(&empty_message, 1), response;
    grpc::Status status;
    std::mutex mutex;
    std::condition_variable done_cv;
    bool done = false;
    stub.UnaryCall(&context, method, grpc::StubOptions(), &request, &response, [&](grpc::Status s) {
      std::lock_guard<std::mutex> lock(mutex);
      status = std::move(s);
      done = true;
      done_cv.notify_all();
    });
    std::unique_lock<std::mutex> lock(mutex);
    done_cv.wait(lock, [&] { return done; });
    EXPECT_EQ(status.error_code(), grpc::StatusCode::UNIMPLEMENTED) << method;
    EXPECT_NE(status.error_message().find("no method " + method), std::string::npos)
        << status.error_message();
    EXPECT_NE(status.error_message().find("picking.planner.v1.PlannerService"), std::string::npos)
        << status.error_message();
  }
}

TEST_F(PickingCallTest, ARequestThatIsNotTheMethodsTypeIsABadCommandLine) {
  ProgramResult r = Call("picking.planner.v1.PlannerService/ComputeFk", R"({"no_such_field": 1})");
  EXPECT_EQ(r.exit_status, 2) << r.output;
  EXPECT_NE(r.output.find("not a picking.planner.v1.ComputeFkRequest"), std::string::npos)
      << r.output;
  r = Call("picking.planner.v1.PlannerService/ComputeFk", "{not json");
  EXPECT_EQ(r.exit_status, 2) << r.output;
}

TEST_F(PickingCallTest, TheServersRefusalIsReportedWithItsCode) {
  const ProgramResult r = Call("picking.planner.v1.PlannerService/ComputeFk",
                               R"({"joints": {"positions_rad": [0, 0]}})");
  EXPECT_EQ(r.exit_status, 3) << r.output;
  EXPECT_NE(r.output.find("INVALID_ARGUMENT"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("6"), std::string::npos) << r.output;
}

// A port that refuses connections for as long as it lives: bound, never listened on (nobody
// else can take it meanwhile).
class RefusingPort {
 public:
  RefusingPort() : fd_(socket(AF_INET, SOCK_STREAM, 0)) {
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    socklen_t size = sizeof(addr);
    if (fd_ < 0 || bind(fd_, reinterpret_cast<sockaddr*>(&addr), size) != 0 ||
        getsockname(fd_, reinterpret_cast<sockaddr*>(&addr), &size) != 0) {
      throw std::runtime_error("cannot bind a local port");
    }
    port_ = ntohs(addr.sin_port);
  }
  ~RefusingPort() { close(fd_); }
  RefusingPort(const RefusingPort&) = delete;
  RefusingPort& operator=(const RefusingPort&) = delete;
  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }

 private:
  int fd_;
  int port_ = 0;
};

TEST_F(PickingCallTest, AnUnreachableServerIsAnRpcError) {
  const RefusingPort refusing;
  const ProgramResult r = RunProgram(ServerBinary("picking"),
                                     {"call", refusing.address(), "grpc.health.v1.Health/Check"});
  EXPECT_EQ(r.exit_status, 3) << r.output;
  EXPECT_NE(r.output.find("UNAVAILABLE"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace picking::testing
