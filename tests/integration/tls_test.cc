// Mutual TLS between the real server binaries, their clients and the `picking` command line,
// with certificates made at test time by scripts/make-certs.sh.
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>

#include <chrono>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "grpc/health/v1/health.grpc.pb.h"
#include "libs/runtime/channel.h"
#include "picking/planner/v1/planner.grpc.pb.h"
#include "picking/robot/v1/robot.grpc.pb.h"
#include "tests/harness/certificates.h"
#include "tests/harness/server_process.h"

namespace picking::testing {
namespace {

using grpc::health::v1::Health;
using grpc::health::v1::HealthCheckRequest;
using grpc::health::v1::HealthCheckResponse;

// Long enough for a loaded machine; a refused handshake fails well before it.
constexpr std::chrono::seconds kCallDeadline(20);

void SetDeadline(grpc::ClientContext* ctx) {
  ctx->set_deadline(std::chrono::system_clock::now() + kCallDeadline);
}

grpc::Status HealthCheck(const std::shared_ptr<grpc::Channel>& channel, const std::string& service,
                         HealthCheckResponse* response) {
  grpc::ClientContext ctx;
  SetDeadline(&ctx);
  HealthCheckRequest request;
  request.set_service(service);
  return Health::NewStub(channel)->Check(&ctx, request, response);
}

grpc::Status ComputeFkAtZero(const std::shared_ptr<grpc::Channel>& channel,
                             planner::v1::ComputeFkResponse* response) {
  grpc::ClientContext ctx;
  SetDeadline(&ctx);
  planner::v1::ComputeFkRequest request;
  for (int j = 0; j < 6; ++j) request.mutable_joints()->add_positions_rad(0.0);
  return planner::v1::PlannerService::NewStub(channel)->ComputeFk(&ctx, request, response);
}

grpc::Status RobotState(const std::shared_ptr<grpc::Channel>& channel,
                        robot::v1::GetStateResponse* response) {
  grpc::ClientContext ctx;
  SetDeadline(&ctx);
  return robot::v1::RobotService::NewStub(channel)->GetState(&ctx, robot::v1::GetStateRequest(),
                                                             response);
}

// TLS files trusting `ca` and presenting no certificate.
runtime::TlsFiles TrustOnly(const std::string& ca) {
  runtime::TlsFiles files;
  files.ca_path = ca;
  return files;
}

std::vector<std::string> Concat(std::vector<std::string> a, const std::vector<std::string>& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}

// The lines of `text` that start with `prefix`.
std::vector<std::string> LinesStartingWith(const std::string& text, const std::string& prefix) {
  std::vector<std::string> lines;
  std::stringstream in(text);
  for (std::string line; std::getline(in, line);) {
    if (line.rfind(prefix, 0) == 0) lines.push_back(line);
  }
  return lines;
}

class TlsTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    certs_ = new TestCertificates(::testing::TempDir() + "/tls_test_certs",
                                  {"planner", "simulator", "robot", "orchestrator"});
    // Same names, another CA: what an impostor or another deployment would hold.
    other_certs_ =
        new TestCertificates(::testing::TempDir() + "/tls_test_other_certs", {"planner"});
  }
  static void TearDownTestSuite() {
    delete certs_;
    delete other_certs_;
    certs_ = nullptr;
    other_certs_ = nullptr;
  }

  static TestCertificates* certs_;
  static TestCertificates* other_certs_;
};

TestCertificates* TlsTest::certs_ = nullptr;
TestCertificates* TlsTest::other_certs_ = nullptr;

class PlannerTlsTest : public TlsTest {
 protected:
  PlannerTlsTest() : planner_(ServerBinary("picking-planner"), certs_->ServerFlags("planner")) {}
  ~PlannerTlsTest() override { EXPECT_EQ(planner_.Stop(), 0); }

  ServerProcess planner_;
};

TEST_F(PlannerTlsTest, AClientWithACertificateFromTheCaIsServed) {
  const auto channel = planner_.Channel(runtime::ChannelFactory(certs_->Client("picking"), ""));
  HealthCheckResponse health;
  grpc::Status status = HealthCheck(channel, "", &health);
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(health.status(), HealthCheckResponse::SERVING);
  status = HealthCheck(channel, "picking.planner.v1.PlannerService", &health);
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(health.status(), HealthCheckResponse::SERVING);
  planner::v1::ComputeFkResponse fk;
  status = ComputeFkAtZero(channel, &fk);
  ASSERT_TRUE(status.ok()) << status.error_message();
  // The UR10 DH chain at zero joints (as planner_server_test): x = a2 + a3.
  EXPECT_NEAR(fk.x_base_tool().position().x(), -0.612 - 0.5723, 1e-9);
}

TEST_F(PlannerTlsTest, APlaintextClientIsRefused) {
  HealthCheckResponse health;
  const grpc::Status status = HealthCheck(planner_.Channel(), "", &health);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAVAILABLE) << status.error_message();
}

TEST_F(PlannerTlsTest, ATlsClientWithoutACertificateIsRefused) {
  const auto channel = planner_.Channel(runtime::ChannelFactory(TrustOnly(certs_->ca()), ""));
  HealthCheckResponse health;
  const grpc::Status status = HealthCheck(channel, "", &health);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAVAILABLE) << status.error_message();
  planner::v1::ComputeFkResponse fk;
  EXPECT_FALSE(ComputeFkAtZero(channel, &fk).ok());
}

TEST_F(PlannerTlsTest, AClientWithACertificateFromAnotherCaIsRefused) {
  // It trusts the planner's CA, so only its own certificate can be what is refused.
  runtime::TlsFiles files = other_certs_->Client("picking");
  files.ca_path = certs_->ca();
  const auto channel = planner_.Channel(runtime::ChannelFactory(files, ""));
  HealthCheckResponse health;
  const grpc::Status status = HealthCheck(channel, "", &health);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAVAILABLE) << status.error_message();
}

TEST_F(PlannerTlsTest, TheClientRefusesAServerItsCaDidNotSign) {
  // A valid client certificate, but the planner's certificate is checked against another CA.
  runtime::TlsFiles files = certs_->Client("picking");
  files.ca_path = other_certs_->ca();
  const auto channel = planner_.Channel(runtime::ChannelFactory(files, ""));
  HealthCheckResponse health;
  const grpc::Status status = HealthCheck(channel, "", &health);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAVAILABLE) << status.error_message();
}

TEST_F(PlannerTlsTest, TheServerNameOverrideIsCheckedAgainstTheCertificate) {
  // The planner's certificate names "planner" (and localhost, 127.0.0.1), not "robot".
  const auto as_planner =
      planner_.Channel(runtime::ChannelFactory(certs_->Client("picking"), "planner"));
  HealthCheckResponse health;
  grpc::Status status = HealthCheck(as_planner, "", &health);
  EXPECT_TRUE(status.ok()) << status.error_message();
  const auto as_robot =
      planner_.Channel(runtime::ChannelFactory(certs_->Client("picking"), "robot"));
  status = HealthCheck(as_robot, "", &health);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAVAILABLE) << status.error_message();
}

TEST_F(TlsTest, BadTlsSettingsStopTheServerWithStatus2AndOneLineNamingThem) {
  const std::string planner = ServerBinary("picking-planner");
  struct Case {
    std::vector<std::string> flags;
    std::string expected;
  };
  const std::vector<Case> cases = {
      {{"--tls.key=" + certs_->key("planner")}, "setting 'tls.key' needs setting 'tls.cert'"},
      {{"--tls.cert=" + certs_->cert("planner")}, "setting 'tls.cert' needs setting 'tls.key'"},
      {{"--tls.ca=" + certs_->ca()}, "setting 'tls.ca' needs setting 'tls.cert'"},
      {{"--tls.cert=/no/such/cert.pem", "--tls.key=" + certs_->key("planner")},
       "setting 'tls.cert': '/no/such/cert.pem' cannot be read"},
      {{"--tls.cert=" + certs_->key("planner"), "--tls.key=" + certs_->key("planner")},
       "holds no PEM certificate"},
      {{"--tls.cert=" + certs_->cert("planner"), "--tls.key=" + certs_->cert("planner")},
       "holds no PEM private key"},
      {{"--tls.cert=" + certs_->cert("planner"), "--tls.key=" + certs_->key("robot")},
       "setting 'tls.key': '" + certs_->key("robot") + "' is not the private key of"},
      {Concat({"--tls.cert=" + certs_->cert("planner"), "--tls.key=" + certs_->key("planner")},
              {"--tls.ca=" + certs_->key("planner")}),
       "setting 'tls.ca': '" + certs_->key("planner") + "' holds no PEM certificate"},
  };
  for (const Case& c : cases) {
    const ProgramResult result = RunProgram(planner, Concat({"--listen=127.0.0.1:0"}, c.flags));
    EXPECT_EQ(result.exit_status, 2) << c.flags[0] << ": " << result.output;
    // The log line aside, exactly one line for the operator, and it names the problem.
    const auto lines = LinesStartingWith(result.output, "picking-planner: ");
    ASSERT_EQ(lines.size(), 1u) << result.output;
    EXPECT_NE(lines[0].find(c.expected), std::string::npos) << c.flags[0] << ": " << lines[0];
  }
  const ProgramResult help = RunProgram(planner, {"--help"});
  EXPECT_EQ(help.exit_status, 0);
  for (const char* flag : {"--tls.cert=FILE", "--tls.key=FILE", "--tls.ca=FILE"}) {
    EXPECT_NE(help.output.find(flag), std::string::npos) << flag << " not in " << help.output;
  }
}

TEST_F(TlsTest, TheRobotCallsTheSimulatorOverMutualTls) {
  ServerProcess simulator(ServerBinary("picking-simulator"), certs_->ServerFlags("simulator"));
  const std::vector<std::string> sim_backend{"--backend=sim",
                                             "--sim.address=" + simulator.address()};
  ServerProcess robot(ServerBinary("picking-robot"),
                      Concat(certs_->ServerFlags("robot"), sim_backend));
  robot::v1::GetStateResponse state;
  const grpc::Status status =
      RobotState(robot.Channel(runtime::ChannelFactory(certs_->Client("picking"), "")), &state);
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(state.backend(), robot::v1::ROBOT_BACKEND_SIM);
  EXPECT_EQ(state.joints().positions_rad_size(), 6);

  // The same robot without certificates: the simulator refuses it, so its state is unknown.
  ServerProcess plaintext_robot(ServerBinary("picking-robot"), sim_backend);
  const grpc::Status refused = RobotState(plaintext_robot.Channel(), &state);
  EXPECT_EQ(refused.error_code(), grpc::StatusCode::UNAVAILABLE) << refused.error_message();

  EXPECT_EQ(plaintext_robot.Stop(), 0);
  EXPECT_EQ(robot.Stop(), 0);
  EXPECT_EQ(simulator.Stop(), 0);
}

TEST_F(TlsTest, TheCommandLineNeedsItsCertificateToReachTheOrchestrator) {
  const std::string tasks_dir = ::testing::TempDir() + "/tls_test_tasks";
  // Its peers on a port nothing listens on: `list` does not need them.
  ServerProcess orchestrator(
      ServerBinary("picking-orchestrator"),
      Concat(certs_->ServerFlags("orchestrator"),
             {"--tasks_dir=" + tasks_dir, "--scanner.address=127.0.0.1:1",
              "--detector.endpoints=127.0.0.1:1", "--planner.address=127.0.0.1:1",
              "--robot.address=127.0.0.1:1", "--gripper.address=127.0.0.1:1"}));
  const std::string cli = ServerBinary("picking");
  const std::vector<std::string> list{"list", "--address", orchestrator.address()};
  const std::vector<std::string> tls{"--tls-ca",   certs_->ca(),
                                     "--tls-cert", certs_->cert("picking"),
                                     "--tls-key",  certs_->key("picking")};

  ProgramResult result = RunProgram(cli, Concat(list, tls));
  EXPECT_EQ(result.exit_status, 0) << result.output;

  result = RunProgram(cli, list);
  EXPECT_EQ(result.exit_status, 3) << result.output;
  EXPECT_NE(result.output.find("was called over plaintext"), std::string::npos) << result.output;
  EXPECT_NE(result.output.find("--tls-ca"), std::string::npos) << result.output;

  result = RunProgram(cli, Concat(list, {"--tls-ca", certs_->ca()}));
  EXPECT_EQ(result.exit_status, 3) << result.output;
  EXPECT_NE(result.output.find("was called over TLS"), std::string::npos) << result.output;

  result = RunProgram(cli, Concat(list, {"--tls-key", certs_->key("picking")}));
  EXPECT_EQ(result.exit_status, 2) << result.output;
  EXPECT_NE(result.output.find("--tls-key needs --tls-cert"), std::string::npos) << result.output;

  EXPECT_EQ(orchestrator.Stop(), 0);
}

}  // namespace
}  // namespace picking::testing
