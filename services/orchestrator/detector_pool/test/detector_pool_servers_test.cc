// The detector pool over two real picking-detector servers (the test manifest
// tests/data/detector/models.json), on the real Kinect scene milk_cartoon_all_small_clorox.pcd
// in which the milk model's true pose is the identity. One server is killed (SIGKILL) as soon
// as the pool has streamed it the whole scan, while it detects: the detection still succeeds,
// on the other.
#include <gtest/gtest.h>
#include <signal.h>

#include <atomic>
#include <cmath>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "libs/geometry/point_cloud_io.h"
#include "libs/proto_convert/proto_convert.h"
#include "services/orchestrator/detector_pool/detector_pool.h"
#include "tests/harness/server_process.h"

namespace picking::orchestrator {
namespace {

namespace detpb = ::picking::detector::v1;
using picking::testing::ServerBinary;
using picking::testing::ServerProcess;

std::string TestData(const std::string& relative) {
  return std::string(PICKING_TEST_DATA_DIR) + "/" + relative;
}

// The scene in the base frame, captured by a sensor at the base origin.
SharedCloud MilkScene() {
  geometry::PointCloud cloud =
      geometry::ReadPointCloud(TestData("pointclouds/milk_cartoon_all_small_clorox.pcd"));
  cloud.frame_id = "base";
  auto chunks = proto_convert::CloudToChunks(cloud);
  *chunks.front().mutable_header()->mutable_x_frame_sensor() =
      proto_convert::PoseToProto(Eigen::Isometry3d::Identity());
  return std::make_shared<const std::vector<picking::common::v1::PointCloudChunk>>(
      std::move(chunks));
}

DetectCall FindMilk(const SharedCloud& scene) {
  DetectCall call;
  auto* query = call.params.add_queries();
  query->set_item("milk");
  query->set_method(detpb::METHOD_PPF);
  call.cloud = scene;
  return call;
}

// The milk found where it is: within 5 mm of the identity.
void ExpectMilkFound(const DetectOutcome& outcome) {
  ASSERT_TRUE(outcome.ok()) << outcome.status.error_message();
  ASSERT_EQ(outcome.response.results_size(), 1);
  const auto& milk = outcome.response.results(0);
  ASSERT_EQ(milk.status().code(), 0) << milk.status().message();
  ASSERT_EQ(milk.detections_size(), 1);
  const auto& p = milk.detections(0).x_frame_item().position();
  EXPECT_LT(std::sqrt(p.x() * p.x() + p.y() * p.y() + p.z() * p.z()), 0.005);
}

class DetectorPoolServersTest : public ::testing::Test {
 protected:
  void SetUp() override {
    for (int i = 0; i < 2; ++i) {
      const std::string cache = ::testing::TempDir() + "/detector_pool_cache_" + std::to_string(i);
      std::filesystem::remove_all(cache);
      caches_.push_back(cache);
      servers_.push_back(std::make_unique<ServerProcess>(
          ServerBinary("picking-detector"),
          std::vector<std::string>{"--models=" + TestData("detector/models.json"),
                                   "--cache_dir=" + cache}));
      by_address_[servers_.back()->address()] = servers_.back().get();
    }
  }
  void TearDown() override {
    for (auto& server : servers_) server->Stop();
    for (const auto& cache : caches_) std::filesystem::remove_all(cache);
  }

  DetectorPoolOptions Options() {
    DetectorPoolOptions options;
    for (const auto& server : servers_) options.endpoints.push_back(server->address());
    options.deadline_s = 240.0;  // The first call on a server builds the milk's PPF model.
    options.health_period_s = 0.0;
    options.health_timeout_s = 2.0;
    return options;
  }

  std::vector<std::string> caches_;
  std::vector<std::unique_ptr<ServerProcess>> servers_;
  std::map<std::string, ServerProcess*> by_address_;
};

TEST_F(DetectorPoolServersTest, DetectionSucceedsWhenAReplicaIsKilledMidway) {
  std::atomic<bool> killed{false};
  std::string victim;
  DetectorPoolOptions options = Options();
  options.on_event = [&](const PoolEvent& event) {
    if (event.kind != PoolEvent::Kind::kAttemptSent || killed.exchange(true)) return;
    victim = event.replica;
    ::kill(by_address_.at(event.replica)->pid(), SIGKILL);
  };
  DetectorPool pool(options);
  const SharedCloud scene = MilkScene();

  const DetectOutcome outcome = pool.Detect(FindMilk(scene));
  ExpectMilkFound(outcome);
  ASSERT_TRUE(killed);
  EXPECT_NE(outcome.replica, victim);
  ASSERT_EQ(outcome.attempts.size(), 2u);
  EXPECT_EQ(outcome.attempts[0].replica, victim);
  EXPECT_EQ(outcome.attempts[0].status.error_code(), grpc::StatusCode::UNAVAILABLE);

  // The health check agrees, and the jobs of the next scan all go to the survivor.
  pool.CheckHealthNow();
  const auto snapshot = pool.Snapshot();
  for (const auto& replica : snapshot) EXPECT_EQ(replica.healthy, replica.endpoint != victim);
  DetectCall bunny = FindMilk(scene);
  bunny.params.mutable_queries(0)->set_item("bunny");
  const auto outcomes = pool.DetectAll({FindMilk(scene), bunny});
  ExpectMilkFound(outcomes[0]);
  ASSERT_TRUE(outcomes[1].ok()) << outcomes[1].status.error_message();
  EXPECT_EQ(outcomes[1].response.results(0).detections_size(), 0) << "no bunny in the scene";
  for (const auto& o : outcomes) {
    EXPECT_EQ(o.replica, outcome.replica);
    EXPECT_EQ(o.attempts.size(), 1u);
  }
}

TEST_F(DetectorPoolServersTest, TwoViewsRunOnBothServersAtOnce) {
  DetectorPool pool(Options());
  const SharedCloud scene = MilkScene();
  const auto outcomes = pool.DetectAll({FindMilk(scene), FindMilk(scene)});
  for (const auto& outcome : outcomes) ExpectMilkFound(outcome);
  EXPECT_NE(outcomes[0].replica, outcomes[1].replica);
  for (const auto& replica : pool.Snapshot()) EXPECT_EQ(replica.calls_served, 1u);
}

// A dns:/// target: gRPC's round_robin with client-side health checking (the Watch of the
// server's grpc.health.v1 for picking.detector.v1.DetectorService) lets the calls through.
TEST_F(DetectorPoolServersTest, ADnsTargetReachesTheServersBehindIt) {
  DetectorPoolOptions options = Options();
  options.endpoints = {"dns:///localhost:" + std::to_string(servers_[0]->port())};
  DetectorPool pool(options);
  const DetectOutcome outcome = pool.Detect(FindMilk(MilkScene()));
  ExpectMilkFound(outcome);
  EXPECT_NE(outcome.peer.find(servers_[0]->address()), std::string::npos) << outcome.peer;
  pool.CheckHealthNow();
  EXPECT_TRUE(pool.Snapshot()[0].healthy);
}

}  // namespace
}  // namespace picking::orchestrator
