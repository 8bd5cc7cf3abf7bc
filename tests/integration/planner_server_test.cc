// Integration test of the picking-planner server binary through its generated client.
#include <grpcpp/client_context.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

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

class PlannerKinematicsTest : public ::testing::Test {
 protected:
  PlannerKinematicsTest()
      : server_(ServerBinary(kBinary)),
        stub_(planner::v1::PlannerService::NewStub(server_.Channel())) {}
  ~PlannerKinematicsTest() override { EXPECT_EQ(server_.Stop(), 0); }

  grpc::Status Fk(const std::vector<double>& q, planner::v1::ComputeFkResponse* out) {
    grpc::ClientContext ctx;
    planner::v1::ComputeFkRequest req;
    for (double v : q) req.mutable_joints()->add_positions_rad(v);
    return stub_->ComputeFk(&ctx, req, out);
  }

  ServerProcess server_;
  std::unique_ptr<planner::v1::PlannerService::Stub> stub_;
};

TEST_F(PlannerKinematicsTest, ForwardKinematicsAtZeroMatchesTheDhChain) {
  planner::v1::ComputeFkResponse fk;
  ASSERT_TRUE(Fk({0, 0, 0, 0, 0, 0}, &fk).ok());
  // UR10 factory DH chain at zero joints: x = a2 + a3, y = -(d4 + d6), z = d1 - d5.
  EXPECT_NEAR(fk.x_base_tool().position().x(), -0.612 - 0.5723, 1e-9);
  EXPECT_NEAR(fk.x_base_tool().position().y(), -(0.163941 + 0.0922), 1e-9);
  EXPECT_NEAR(fk.x_base_tool().position().z(), 0.1273 - 0.1157, 1e-9);
  EXPECT_EQ(fk.links_size(), 7);
}

TEST_F(PlannerKinematicsTest, InverseKinematicsReturnsTheGeneratingJoints) {
  std::mt19937 rng(42);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  for (int trial = 0; trial < 20; ++trial) {
    std::vector<double> q(6);
    for (double& v : q) v = u(rng);
    q[2] = std::clamp(q[2], -3.0, 3.0);
    planner::v1::ComputeFkResponse fk;
    ASSERT_TRUE(Fk(q, &fk).ok());
    grpc::ClientContext ctx;
    planner::v1::ComputeIkRequest req;
    *req.mutable_x_base_tcp() = fk.x_base_tcp();
    for (double v : q) req.mutable_seed()->add_positions_rad(v);
    planner::v1::ComputeIkResponse ik;
    ASSERT_TRUE(stub_->ComputeIk(&ctx, req, &ik).ok());
    ASSERT_GT(ik.solutions_size(), 0);
    // Sorted by distance to the seed: the first solution is the generating one.
    for (int j = 0; j < 6; ++j) {
      EXPECT_NEAR(ik.solutions(0).joints().positions_rad(j), q[j], 1e-6) << "trial " << trial;
    }
  }
}

TEST_F(PlannerKinematicsTest, UnreachablePoseGivesNoSolutionAndAReason) {
  grpc::ClientContext ctx;
  planner::v1::ComputeIkRequest req;
  req.mutable_x_base_tcp()->mutable_position()->set_x(5.0);
  req.mutable_x_base_tcp()->mutable_orientation()->set_w(1.0);
  planner::v1::ComputeIkResponse ik;
  ASSERT_TRUE(stub_->ComputeIk(&ctx, req, &ik).ok());
  EXPECT_EQ(ik.solutions_size(), 0);
  EXPECT_FALSE(ik.reason().empty());
}

TEST_F(PlannerKinematicsTest, BadInputIsRefusedWithInvalidArgument) {
  planner::v1::ComputeFkResponse fk;
  grpc::Status s = Fk({0, 0, 0, 0, 0}, &fk);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("6 joint positions"), std::string::npos) << s.error_message();
  s = Fk({0, std::numeric_limits<double>::quiet_NaN(), 0, 0, 0, 0}, &fk);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  s = Fk({0, 0, 4.0, 0, 0, 0}, &fk);  // Elbow beyond +-pi: the message names the joint.
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("elbow_joint at 4 rad"), std::string::npos) << s.error_message();

  grpc::ClientContext ctx;
  planner::v1::ComputeIkRequest req;
  req.mutable_x_base_tcp()->mutable_orientation()->set_w(0.5);  // Not a unit quaternion.
  planner::v1::ComputeIkResponse ik;
  s = stub_->ComputeIk(&ctx, req, &ik);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("X_base_tcp.orientation"), std::string::npos);
}

}  // namespace
}  // namespace picking::testing
