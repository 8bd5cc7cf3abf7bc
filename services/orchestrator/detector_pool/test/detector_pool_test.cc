// The detector pool against in-process fake detector servers (fake_detector.h) on free ports:
// which replica each call goes to, retries, health, concurrency, deadlines and hedging.
// Nothing sleeps to wait for something: fakes hang until released, meet at a rendezvous, and
// health changes are awaited through the pool's events.
#include "services/orchestrator/detector_pool/detector_pool.h"

#include <gtest/gtest.h>

#include <algorithm>

#include <chrono>
#include <condition_variable>
#include <deque>
#include <future>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <vector>

#include "libs/runtime/config.h"
#include "services/orchestrator/detector_pool/test/fake_detector.h"

namespace picking::orchestrator {
namespace {

using testing::FakeMode;
using testing::FakeReplica;
using testing::Rendezvous;
using Code = grpc::StatusCode;
using Clock = std::chrono::steady_clock;

double SecondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// A three-point cloud: the fakes only count points.
SharedCloud SmallCloud() {
  auto chunks = std::make_shared<std::vector<picking::common::v1::PointCloudChunk>>(1);
  auto& chunk = (*chunks)[0];
  chunk.mutable_header()->set_frame_id("base");
  chunk.mutable_header()->set_point_count(3);
  chunk.mutable_header()->set_width(3);
  chunk.mutable_header()->set_height(1);
  chunk.set_point_count(3);
  chunk.set_positions(std::string(3 * 3 * sizeof(float), '\0'));
  return chunks;
}

DetectCall Call(const std::string& item) {
  DetectCall call;
  call.params.add_queries()->set_item(item);
  call.cloud = SmallCloud();
  return call;
}

// Collects the pool's health events so a test can wait for one.
class HealthEvents final {
 public:
  void Add(const PoolEvent& event) {
    if (event.kind != PoolEvent::Kind::kHealthChanged) return;
    std::lock_guard<std::mutex> lock(mutex_);
    events_.push_back(event);
    cv_.notify_all();
  }
  // True when `replica` turned `healthy` within 30 s.
  bool WaitFor(const std::string& replica, bool healthy) {
    std::unique_lock<std::mutex> lock(mutex_);
    return cv_.wait_for(lock, std::chrono::seconds(30), [&] {
      for (const auto& e : events_) {
        if (e.replica == replica && e.healthy == healthy) return true;
      }
      return false;
    });
  }

 private:
  std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<PoolEvent> events_;
};

class DetectorPoolTest : public ::testing::Test {
 protected:
  void TearDown() override {
    for (FakeReplica* replica : {&a_, &b_}) {
      replica->detector().Release();
      replica->health().Release();
    }
  }

  // Two replicas, A first; no background health checks, no backoff waits (recorded instead).
  DetectorPoolOptions Options() {
    DetectorPoolOptions options;
    options.endpoints = {a_.address(), b_.address()};
    options.deadline_s = 10.0;
    options.max_attempts = 3;
    options.health_period_s = 0.0;
    options.health_timeout_s = 1.0;
    options.reconnect_backoff_max_s = 0.1;
    options.sleep_s = [this](double s) {
      std::lock_guard<std::mutex> lock(sleeps_mutex_);
      sleeps_.push_back(s);
    };
    return options;
  }

  std::vector<double> sleeps() {
    std::lock_guard<std::mutex> lock(sleeps_mutex_);
    return sleeps_;
  }

  FakeReplica a_;
  FakeReplica b_;
  std::mutex sleeps_mutex_;
  std::vector<double> sleeps_;
};

TEST_F(DetectorPoolTest, AnswersFromTheFirstReplicaAndReportsIt) {
  std::mutex mutex;
  std::vector<PoolEvent::Kind> kinds;
  DetectorPoolOptions options = Options();
  options.on_event = [&](const PoolEvent& e) {
    std::lock_guard<std::mutex> lock(mutex);
    kinds.push_back(e.kind);
  };
  DetectorPool pool(options);
  const DetectOutcome outcome = pool.Detect(Call("milk"));
  ASSERT_TRUE(outcome.ok()) << outcome.status.error_message();
  ASSERT_EQ(outcome.response.results_size(), 1);
  EXPECT_EQ(outcome.response.results(0).item(), "milk");
  EXPECT_EQ(outcome.response.points_received(), 3u);
  EXPECT_EQ(outcome.replica, a_.address());
  EXPECT_NE(outcome.peer.find(std::to_string(a_.port())), std::string::npos) << outcome.peer;
  ASSERT_EQ(outcome.attempts.size(), 1u);
  EXPECT_TRUE(outcome.failed_attempts().empty());
  EXPECT_EQ(a_.detector().calls(), std::vector<std::string>{"milk"});
  EXPECT_TRUE(b_.detector().calls().empty());
  EXPECT_EQ(kinds, (std::vector<PoolEvent::Kind>{PoolEvent::Kind::kAttemptStarted,
                                                 PoolEvent::Kind::kAttemptSent,
                                                 PoolEvent::Kind::kAttemptFinished}));
}

TEST_F(DetectorPoolTest, RetriesOnAnotherReplicaWhenOneIsUnavailable) {
  a_.detector().SetMode(FakeMode::kUnavailable);
  DetectorPool pool(Options());
  const DetectOutcome outcome = pool.Detect(Call("milk"));
  ASSERT_TRUE(outcome.ok()) << outcome.status.error_message();
  EXPECT_EQ(outcome.replica, b_.address());
  ASSERT_EQ(outcome.attempts.size(), 2u);
  EXPECT_EQ(outcome.attempts[0].replica, a_.address());
  EXPECT_EQ(outcome.attempts[0].status.error_code(), Code::UNAVAILABLE);
  EXPECT_EQ(outcome.attempts[1].replica, b_.address());
  ASSERT_EQ(outcome.failed_attempts().size(), 1u);
  EXPECT_TRUE(sleeps().empty()) << "no backoff before a fresh replica";
  EXPECT_EQ(a_.detector().calls().size(), 1u);
  EXPECT_EQ(b_.detector().calls().size(), 1u);

  // UNAVAILABLE took A out: the next call goes straight to B.
  const auto snapshot = pool.Snapshot();
  EXPECT_FALSE(snapshot[0].healthy);
  EXPECT_EQ(snapshot[0].failures, 1u);
  EXPECT_EQ(snapshot[0].last_error, "fake: going away");
  EXPECT_TRUE(snapshot[1].healthy);
  EXPECT_EQ(snapshot[1].calls_served, 1u);
  EXPECT_EQ(pool.Detect(Call("clorox")).attempts.size(), 1u);
  EXPECT_EQ(b_.detector().calls().size(), 2u);
}

TEST_F(DetectorPoolTest, ATaskDoesNotFailWhenAReplicaDies) {
  DetectorPool pool(Options());
  ASSERT_TRUE(pool.Detect(Call("milk")).ok());  // A answers and the channel is connected.
  a_.Shutdown();
  // Round robin would now pick B; make A the least loaded choice again by using both at once.
  const auto outcomes = pool.DetectAll({Call("one"), Call("two")});
  std::size_t failed = 0;
  for (const auto& outcome : outcomes) {
    EXPECT_TRUE(outcome.ok()) << outcome.status.error_message();
    EXPECT_EQ(outcome.replica, b_.address());
    for (const auto& attempt : outcome.failed_attempts()) {
      EXPECT_EQ(attempt.replica, a_.address());
      EXPECT_EQ(attempt.status.error_code(), Code::UNAVAILABLE);
      ++failed;
    }
  }
  EXPECT_EQ(failed, 1u) << "one job was sent to the dead A, then to B";
  EXPECT_FALSE(pool.Snapshot()[0].healthy);
  EXPECT_EQ(pool.Detect(Call("three")).replica, b_.address());
}

TEST_F(DetectorPoolTest, InvalidArgumentAndNotFoundAreNotRetried) {
  DetectorPool pool(Options());
  a_.detector().SetMode(FakeMode::kInvalidArgument, 1);
  const DetectOutcome bad = pool.Detect(Call("milk"));
  EXPECT_EQ(bad.status.error_code(), Code::INVALID_ARGUMENT);
  EXPECT_EQ(bad.status.error_message(), "fake: bad cloud");
  EXPECT_EQ(bad.replica, a_.address());
  EXPECT_EQ(bad.attempts.size(), 1u);

  b_.detector().SetMode(FakeMode::kNotFound, 1);  // Round robin: B is next.
  const DetectOutcome unknown = pool.Detect(Call("nothing"));
  EXPECT_EQ(unknown.status.error_code(), Code::NOT_FOUND);
  EXPECT_EQ(unknown.replica, b_.address());
  EXPECT_EQ(unknown.attempts.size(), 1u);

  EXPECT_EQ(a_.detector().calls().size(), 1u);
  EXPECT_EQ(b_.detector().calls().size(), 1u);
  for (const auto& replica : pool.Snapshot()) {
    EXPECT_TRUE(replica.healthy) << "the request's fault, not the replica's";
    EXPECT_EQ(replica.failures, 0u);
  }
}

TEST_F(DetectorPoolTest, AMissedDeadlineIsRetriedElsewhere) {
  a_.detector().SetMode(FakeMode::kHang);
  DetectorPoolOptions options = Options();
  options.deadline_s = 0.3;
  DetectorPool pool(options);
  const DetectOutcome outcome = pool.Detect(Call("milk"));
  ASSERT_TRUE(outcome.ok()) << outcome.status.error_message();
  EXPECT_EQ(outcome.replica, b_.address());
  ASSERT_EQ(outcome.attempts.size(), 2u);
  EXPECT_EQ(outcome.attempts[0].status.error_code(), Code::DEADLINE_EXCEEDED);
  EXPECT_GE(outcome.attempts[0].duration_s, 0.25);
  EXPECT_LT(outcome.attempts[0].duration_s, 3.0);
  // Slow is not dead: the health check decides about A.
  EXPECT_TRUE(pool.Snapshot()[0].healthy);
  EXPECT_EQ(pool.Snapshot()[0].failures, 1u);
}

TEST_F(DetectorPoolTest, EveryAttemptMissingItsDeadlineFailsTheCallInTime) {
  a_.detector().SetMode(FakeMode::kHang);
  b_.detector().SetMode(FakeMode::kHang);
  DetectorPoolOptions options = Options();
  options.deadline_s = 0.2;
  DetectorPool pool(options);
  DetectCall call = Call("milk");
  call.deadline_s = 0.25;  // The call's own deadline wins over the pool's.
  const auto start = Clock::now();
  const DetectOutcome outcome = pool.Detect(call);
  const double elapsed_s = SecondsSince(start);
  EXPECT_EQ(outcome.status.error_code(), Code::DEADLINE_EXCEEDED);
  ASSERT_EQ(outcome.attempts.size(), 3u);
  // Never the same replica twice in a row while another is there.
  EXPECT_EQ(outcome.attempts[0].replica, a_.address());
  EXPECT_EQ(outcome.attempts[1].replica, b_.address());
  EXPECT_EQ(outcome.attempts[2].replica, a_.address());
  for (const auto& attempt : outcome.attempts) {
    EXPECT_EQ(attempt.status.error_code(), Code::DEADLINE_EXCEEDED);
    EXPECT_GE(attempt.duration_s, 0.2);
  }
  EXPECT_GE(elapsed_s, 0.7);
  EXPECT_LT(elapsed_s, 5.0);
  EXPECT_EQ(outcome.failed_attempts().size(), 3u);
  // The third attempt went back to A, which the call had tried: after a backoff.
  EXPECT_EQ(sleeps().size(), 1u);
}

TEST_F(DetectorPoolTest, TheCallsBudgetBoundsItsRetries) {
  a_.detector().SetMode(FakeMode::kHang);
  b_.detector().SetMode(FakeMode::kHang);
  DetectorPoolOptions options = Options();
  options.deadline_s = 0.3;
  options.max_attempts = 10;
  DetectorPool pool(options);
  DetectCall call = Call("milk");
  call.budget_s = 0.4;  // Room for one full attempt and a third of a second.
  const auto start = Clock::now();
  const DetectOutcome outcome = pool.Detect(call);
  const double elapsed_s = SecondsSince(start);
  EXPECT_EQ(outcome.status.error_code(), Code::DEADLINE_EXCEEDED);
  ASSERT_EQ(outcome.attempts.size(), 2u);
  EXPECT_GE(outcome.attempts[0].duration_s, 0.25);
  EXPECT_LT(outcome.attempts[1].duration_s, 0.25) << "cut short by the budget";
  EXPECT_GE(elapsed_s, 0.35);
  EXPECT_LT(elapsed_s, 3.0);
  for (const auto& replica : pool.Snapshot()) EXPECT_EQ(replica.in_flight, 0);
}

TEST_F(DetectorPoolTest, BacksOffBeforeRetryingTheSameReplica) {
  b_.Shutdown();
  a_.detector().SetMode(FakeMode::kUnavailable, 2);
  DetectorPoolOptions options = Options();
  options.endpoints = {a_.address()};
  options.backoff_initial_s = 0.1;
  options.backoff_multiplier = 3.0;
  options.backoff_max_s = 0.25;
  DetectorPool pool(options);
  const DetectOutcome outcome = pool.Detect(Call("milk"));
  ASSERT_TRUE(outcome.ok()) << outcome.status.error_message();
  EXPECT_EQ(outcome.attempts.size(), 3u);
  ASSERT_EQ(sleeps().size(), 2u);
  EXPECT_DOUBLE_EQ(sleeps()[0], 0.1);
  EXPECT_DOUBLE_EQ(sleeps()[1], 0.25);  // 0.3, capped.
}

TEST_F(DetectorPoolTest, HealthChecksTakeADeadReplicaOutAndBringItBack) {
  DetectorPoolOptions options = Options();
  options.health_timeout_s = 0.5;
  DetectorPool pool(options);
  pool.CheckHealthNow();
  EXPECT_TRUE(pool.Snapshot()[0].healthy);
  EXPECT_TRUE(pool.Snapshot()[1].healthy);

  a_.Shutdown();
  pool.CheckHealthNow();
  auto snapshot = pool.Snapshot();
  EXPECT_FALSE(snapshot[0].healthy);
  EXPECT_NE(snapshot[0].last_error.find("health check"), std::string::npos);
  EXPECT_TRUE(snapshot[1].healthy);
  for (int i = 0; i < 3; ++i) {
    const DetectOutcome outcome = pool.Detect(Call("milk"));
    EXPECT_EQ(outcome.replica, b_.address());
    EXPECT_EQ(outcome.attempts.size(), 1u) << "a replica taken out gets no calls";
  }
  EXPECT_EQ(pool.ConcurrencyLimit(), 1);

  a_.Restart();
  pool.CheckHealthNow();
  EXPECT_TRUE(pool.Snapshot()[0].healthy);
  EXPECT_EQ(pool.ConcurrencyLimit(), 2);
  // Round robin among the two idle replicas: A's turn after B.
  EXPECT_EQ(pool.Detect(Call("milk")).replica, a_.address());
  EXPECT_EQ(a_.detector().calls().size(), 1u);
}

TEST_F(DetectorPoolTest, AReplicaNotServingIsTakenOutUntilItServesAgain) {
  DetectorPool pool(Options());
  b_.SetServing(false);
  pool.CheckHealthNow();
  EXPECT_FALSE(pool.Snapshot()[1].healthy);
  EXPECT_NE(pool.Snapshot()[1].last_error.find("NOT_SERVING"), std::string::npos);
  b_.SetServing(true);
  pool.CheckHealthNow();
  EXPECT_TRUE(pool.Snapshot()[1].healthy);
}

TEST_F(DetectorPoolTest, TheHealthThreadNoticesBothChanges) {
  HealthEvents events;
  DetectorPoolOptions options = Options();
  options.health_period_s = 0.02;
  options.health_timeout_s = 0.5;
  options.on_event = [&events](const PoolEvent& e) { events.Add(e); };
  DetectorPool pool(options);
  a_.Shutdown();
  EXPECT_TRUE(events.WaitFor(a_.address(), false));
  a_.Restart();
  EXPECT_TRUE(events.WaitFor(a_.address(), true));
}

TEST_F(DetectorPoolTest, DestructionStopsTheHealthThreadAtOnce) {
  DetectorPoolOptions options = Options();
  options.health_period_s = 3600.0;
  auto pool = std::make_unique<DetectorPool>(options);
  const auto start = Clock::now();
  pool.reset();
  EXPECT_LT(SecondsSince(start), 1.0);
}

TEST_F(DetectorPoolTest, DestructionCancelsAHealthCheckInFlight) {
  a_.health().HoldChecks();  // A's check would take the whole minute.
  DetectorPoolOptions options = Options();
  options.health_period_s = 0.01;
  options.health_timeout_s = 60.0;
  auto pool = std::make_unique<DetectorPool>(options);
  ASSERT_TRUE(a_.health().WaitForHeldCheck());
  const auto start = Clock::now();
  pool.reset();
  EXPECT_LT(SecondsSince(start), 5.0);
}

TEST_F(DetectorPoolTest, DetectAllRunsIndependentJobsOnDifferentReplicasAtOnce) {
  // Each fake holds its call until the other has one too: run one after the other, the jobs
  // would not meet and the fakes would answer ABORTED.
  auto rendezvous = std::make_shared<Rendezvous>(2);
  a_.detector().SetRendezvous(rendezvous);
  b_.detector().SetRendezvous(rendezvous);
  DetectorPool pool(Options());
  const auto outcomes = pool.DetectAll({Call("view_0"), Call("view_1")});
  ASSERT_EQ(outcomes.size(), 2u);
  for (int i = 0; i < 2; ++i) {
    ASSERT_TRUE(outcomes[i].ok()) << outcomes[i].status.error_message();
    ASSERT_EQ(outcomes[i].response.results_size(), 1);
    EXPECT_EQ(outcomes[i].response.results(0).item(), "view_" + std::to_string(i));
  }
  EXPECT_NE(outcomes[0].replica, outcomes[1].replica);
  EXPECT_EQ(a_.detector().calls().size(), 1u);
  EXPECT_EQ(b_.detector().calls().size(), 1u);
}

TEST_F(DetectorPoolTest, DetectSpreadSplitsTheItemsOverTheReplicasAndJoinsThemInOrder) {
  // The two jobs must run at once: each fake holds its call until the other has one too.
  auto rendezvous = std::make_shared<Rendezvous>(2);
  a_.detector().SetRendezvous(rendezvous);
  b_.detector().SetRendezvous(rendezvous);
  DetectorPool pool(Options());
  DetectCall call = Call("target");
  for (const char* other : {"other_1", "other_2", "other_3", "other_4"}) {
    call.params.add_queries()->set_item(other);
  }
  const DetectOutcome outcome = pool.DetectSpread(call);
  ASSERT_TRUE(outcome.ok()) << outcome.status.error_message();
  ASSERT_EQ(outcome.response.results_size(), 5);
  for (int i = 0; i < 5; ++i) {
    EXPECT_EQ(outcome.response.results(i).item(), call.params.queries(i).item());
  }
  EXPECT_EQ(outcome.response.points_received(), 3u);
  EXPECT_EQ(outcome.attempts.size(), 2u);
  // The target leads one job, the second item the other.
  std::vector<std::string> firsts = a_.detector().calls();
  const std::vector<std::string> b_calls = b_.detector().calls();
  firsts.insert(firsts.end(), b_calls.begin(), b_calls.end());
  std::sort(firsts.begin(), firsts.end());
  EXPECT_EQ(firsts, (std::vector<std::string>{"other_1", "target"}));
  EXPECT_NE(outcome.replica.find(a_.address()), std::string::npos) << outcome.replica;
  EXPECT_NE(outcome.replica.find(b_.address()), std::string::npos) << outcome.replica;
}

TEST_F(DetectorPoolTest, DetectSpreadWithOneQueryIsOneCall) {
  DetectorPool pool(Options());
  const DetectOutcome outcome = pool.DetectSpread(Call("milk"));
  ASSERT_TRUE(outcome.ok()) << outcome.status.error_message();
  EXPECT_EQ(outcome.replica, a_.address());
  EXPECT_EQ(a_.detector().calls().size() + b_.detector().calls().size(), 1u);
  DetectCall no_cloud = Call("milk");
  no_cloud.cloud = nullptr;
  EXPECT_THROW(pool.DetectSpread(no_cloud), std::invalid_argument);
}

TEST_F(DetectorPoolTest, DetectSpreadReportsAFailedJob) {
  a_.detector().SetMode(FakeMode::kInvalidArgument);
  b_.detector().SetMode(FakeMode::kInvalidArgument);
  DetectorPool pool(Options());
  DetectCall call = Call("target");
  call.params.add_queries()->set_item("other");
  const DetectOutcome outcome = pool.DetectSpread(call);
  EXPECT_EQ(outcome.status.error_code(), Code::INVALID_ARGUMENT);
  EXPECT_EQ(outcome.response.results_size(), 0);
}

TEST_F(DetectorPoolTest, DetectAsyncRunsBesideAnotherCall) {
  auto rendezvous = std::make_shared<Rendezvous>(2);
  a_.detector().SetRendezvous(rendezvous);
  b_.detector().SetRendezvous(rendezvous);
  DetectorPool pool(Options());
  std::future<DetectOutcome> next_target = pool.DetectAsync(Call("next_target"));
  const DetectOutcome now = pool.Detect(Call("this_target"));
  const DetectOutcome later = next_target.get();
  ASSERT_TRUE(now.ok()) << now.status.error_message();
  ASSERT_TRUE(later.ok()) << later.status.error_message();
  EXPECT_EQ(later.response.results(0).item(), "next_target");
  EXPECT_NE(now.replica, later.replica);
}

TEST_F(DetectorPoolTest, DetectAllKeepsToTheConcurrencyPerReplica) {
  DetectorPool pool(Options());
  std::vector<DetectCall> calls;
  for (int i = 0; i < 8; ++i) calls.push_back(Call("item_" + std::to_string(i)));
  const auto outcomes = pool.DetectAll(calls);
  for (std::size_t i = 0; i < calls.size(); ++i) {
    ASSERT_TRUE(outcomes[i].ok());
    EXPECT_EQ(outcomes[i].response.results(0).item(), "item_" + std::to_string(i));
  }
  EXPECT_EQ(a_.detector().calls().size() + b_.detector().calls().size(), 8u);
  EXPECT_EQ(a_.detector().max_concurrent(), 1);
  EXPECT_EQ(b_.detector().max_concurrent(), 1);
}

TEST_F(DetectorPoolTest, AHedgeOnAnIdleReplicaAnswersForASlowOne) {
  a_.detector().SetMode(FakeMode::kHang);
  DetectorPoolOptions options = Options();
  options.deadline_s = 20.0;
  options.hedge_delay_s = 0.05;
  DetectorPool pool(options);
  const auto start = Clock::now();
  const DetectOutcome outcome = pool.Detect(Call("milk"));
  ASSERT_TRUE(outcome.ok()) << outcome.status.error_message();
  EXPECT_LT(SecondsSince(start), 10.0);
  EXPECT_EQ(outcome.replica, b_.address());
  ASSERT_EQ(outcome.attempts.size(), 2u);
  EXPECT_EQ(outcome.attempts[0].replica, a_.address());
  EXPECT_FALSE(outcome.attempts[0].hedge);
  EXPECT_EQ(outcome.attempts[0].status.error_code(), Code::CANCELLED);
  EXPECT_TRUE(outcome.attempts[1].hedge);
  EXPECT_TRUE(outcome.failed_attempts().empty());
  const auto snapshot = pool.Snapshot();
  EXPECT_TRUE(snapshot[0].healthy);
  EXPECT_EQ(snapshot[0].failures, 0u) << "a cancelled loser is no failure";
  EXPECT_EQ(snapshot[0].in_flight, 0);
}

TEST_F(DetectorPoolTest, NoHedgeWithoutAnIdleReplica) {
  b_.Shutdown();
  DetectorPoolOptions options = Options();
  options.endpoints = {a_.address()};
  options.hedge_delay_s = 0.01;
  DetectorPool pool(options);
  const DetectOutcome outcome = pool.Detect(Call("milk"));
  ASSERT_TRUE(outcome.ok());
  EXPECT_EQ(outcome.attempts.size(), 1u);
}

TEST_F(DetectorPoolTest, VerifyRetriesLikeDetect) {
  a_.detector().SetMode(FakeMode::kUnavailable, 1);
  DetectorPool pool(Options());
  VerifyCall call;
  call.params.set_item("milk");
  call.cloud = SmallCloud();
  const VerifyOutcome outcome = pool.Verify(call);
  ASSERT_TRUE(outcome.ok()) << outcome.status.error_message();
  EXPECT_DOUBLE_EQ(outcome.response.score(), 0.75);
  EXPECT_EQ(outcome.replica, b_.address());
  EXPECT_EQ(outcome.attempts.size(), 2u);
  const auto all = pool.VerifyAll({call, call});
  EXPECT_TRUE(all[0].ok() && all[1].ok());
}

TEST_F(DetectorPoolTest, ADnsTargetIsOneRoundRobinReplica) {
  DetectorPoolOptions options = Options();
  options.endpoints = {"dns:///localhost:" + std::to_string(a_.port())};
  DetectorPool pool(options);
  const DetectOutcome outcome = pool.Detect(Call("milk"));
  ASSERT_TRUE(outcome.ok()) << outcome.status.error_message();
  EXPECT_EQ(outcome.replica, options.endpoints[0]);
  EXPECT_NE(outcome.peer.find("127.0.0.1:" + std::to_string(a_.port())), std::string::npos)
      << outcome.peer;
  pool.CheckHealthNow();
  ASSERT_EQ(pool.Snapshot().size(), 1u);
  EXPECT_TRUE(pool.Snapshot()[0].healthy);
}

// gRPC's client-side health checking (the dns:/// channel's healthCheckConfig) keeps calls off
// an address whose health service does not say SERVING.
TEST_F(DetectorPoolTest, ADnsTargetSendsNothingToAnAddressNotServing) {
  a_.SetServing(false);
  DetectorPoolOptions options = Options();
  options.endpoints = {"dns:///localhost:" + std::to_string(a_.port())};
  options.max_attempts = 1;
  options.health_timeout_s = 0.5;
  DetectorPool pool(options);
  // The call waits for the first health answer, NOT_SERVING, and fails without being sent.
  const DetectOutcome refused = pool.Detect(Call("milk"));
  EXPECT_EQ(refused.status.error_code(), Code::UNAVAILABLE) << refused.status.error_message();
  EXPECT_TRUE(a_.detector().calls().empty());
  pool.CheckHealthNow();
  EXPECT_FALSE(pool.Snapshot()[0].healthy);

  a_.SetServing(true);
  // The check goes through once the channel has the address back (it waits for that).
  pool.CheckHealthNow();
  EXPECT_TRUE(pool.Snapshot()[0].healthy);
  const DetectOutcome served = pool.Detect(Call("milk"));
  EXPECT_TRUE(served.ok()) << served.status.error_message();
  EXPECT_EQ(a_.detector().calls().size(), 1u);
}

TEST_F(DetectorPoolTest, ACallWithoutACloudIsRefused) {
  DetectorPool pool(Options());
  DetectCall call = Call("milk");
  call.cloud = nullptr;
  EXPECT_THROW(pool.Detect(call), std::invalid_argument);
  EXPECT_THROW(pool.DetectAll({Call("milk"), call}), std::invalid_argument);
  EXPECT_TRUE(a_.detector().calls().empty()) << "nothing sent before the check";
}

// --- Options -------------------------------------------------------------------------------

void ExpectRefused(const DetectorPoolOptions& options, const std::string& key) {
  try {
    options.Validate();
    ADD_FAILURE() << "accepted; expected an error about " << key;
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find(key), std::string::npos) << e.what();
  }
}

TEST(DetectorPoolOptionsTest, RefusesBadSettingsNamingThem) {
  DetectorPoolOptions good;
  good.endpoints = {"detector-0:50051", "[::1]:50052", "dns:///detector.picking.svc:50051"};
  EXPECT_NO_THROW(good.Validate());

  auto with = [&good](auto change) {
    DetectorPoolOptions o = good;
    change(o);
    return o;
  };
  ExpectRefused(with([](auto& o) { o.endpoints.clear(); }), "detector.endpoints");
  ExpectRefused(with([](auto& o) { o.endpoints = {"detector-0"}; }), "detector.endpoints");
  ExpectRefused(with([](auto& o) { o.endpoints = {"detector-0:http"}; }), "detector.endpoints");
  ExpectRefused(with([](auto& o) { o.endpoints = {"detector-0:70000"}; }), "detector.endpoints");
  ExpectRefused(with([](auto& o) { o.endpoints = {"http://a:1"}; }), "detector.endpoints");
  ExpectRefused(with([](auto& o) { o.endpoints = {"dns:detector:1"}; }), "detector.endpoints");
  ExpectRefused(with([](auto& o) { o.endpoints = {"a:1", "a:1"}; }), "listed twice");
  ExpectRefused(with([](auto& o) { o.deadline_s = 0; }), "detector.deadline_s");
  ExpectRefused(with([](auto& o) { o.max_attempts = 0; }), "detector.max_attempts");
  ExpectRefused(with([](auto& o) { o.backoff_multiplier = 0.5; }), "detector.backoff_multiplier");
  ExpectRefused(with([](auto& o) { o.backoff_max_s = 0.01; }), "detector.backoff_max_s");
  ExpectRefused(with([](auto& o) { o.health_period_s = -1; }), "detector.health_period_s");
  ExpectRefused(with([](auto& o) { o.health_timeout_s = 0; }), "detector.health_timeout_s");
  ExpectRefused(with([](auto& o) { o.hedge_delay_s = 30; }), "detector.hedge_delay_s");
  ExpectRefused(with([](auto& o) { o.max_in_flight_per_replica = 0; }),
                "detector.max_in_flight_per_replica");
  ExpectRefused(with([](auto& o) { o.max_in_flight = -1; }), "detector.max_in_flight");
  ExpectRefused(with([](auto& o) { o.reconnect_backoff_max_s = 0; }),
                "detector.reconnect_backoff_max_s");
  ExpectRefused(with([](auto& o) { o.max_message_mb = 0; }), "detector.max_message_mb");
  EXPECT_THROW(DetectorPool(with([](auto& o) { o.max_attempts = 0; })), std::invalid_argument);
}

TEST(DetectorPoolOptionsTest, FromConfigReadsTheDetectorSettings) {
  const runtime::Config config = runtime::Config::FromYamlText(
      "detector:\n"
      "  endpoints: [detector-0:50051, 'detector-1:50051']\n"
      "  deadline_s: 12.5\n"
      "  max_attempts: 4\n"
      "  backoff_initial_s: 0.2\n"
      "  backoff_multiplier: 1.5\n"
      "  backoff_max_s: 1\n"
      "  health_period_s: 2\n"
      "  health_timeout_s: 0.5\n"
      "  hedge_delay_s: 3\n"
      "  max_in_flight_per_replica: 2\n"
      "  max_in_flight: 5\n"
      "  reconnect_backoff_max_s: 4\n"
      "  max_message_mb: 32\n",
      "orchestrator.yaml");
  const DetectorPoolOptions o = FromConfig(config);
  EXPECT_EQ(o.endpoints, (std::vector<std::string>{"detector-0:50051", "detector-1:50051"}));
  EXPECT_DOUBLE_EQ(o.deadline_s, 12.5);
  EXPECT_EQ(o.max_attempts, 4);
  EXPECT_DOUBLE_EQ(o.backoff_initial_s, 0.2);
  EXPECT_DOUBLE_EQ(o.backoff_multiplier, 1.5);
  EXPECT_DOUBLE_EQ(o.backoff_max_s, 1.0);
  EXPECT_DOUBLE_EQ(o.health_period_s, 2.0);
  EXPECT_DOUBLE_EQ(o.health_timeout_s, 0.5);
  EXPECT_DOUBLE_EQ(o.hedge_delay_s, 3.0);
  EXPECT_EQ(o.max_in_flight_per_replica, 2);
  EXPECT_EQ(o.max_in_flight, 5);
  EXPECT_DOUBLE_EQ(o.reconnect_backoff_max_s, 4.0);
  EXPECT_EQ(o.max_message_mb, 32);
  EXPECT_TRUE(config.UnusedKeys().empty());
}

TEST(DetectorPoolOptionsTest, FromConfigDefaultsToTheDetectorNameAndTakesDefaults) {
  runtime::Config config;
  EXPECT_EQ(FromConfig(config).endpoints, std::vector<std::string>{kDefaultEndpoints});
  config.Set("detector.endpoints", "dns:///detector.picking.svc.cluster.local:50051");
  const DetectorPoolOptions o = FromConfig(config);
  EXPECT_EQ(o.endpoints.size(), 1u);
  EXPECT_DOUBLE_EQ(o.deadline_s, DetectorPoolOptions().deadline_s);
  EXPECT_EQ(o.max_attempts, DetectorPoolOptions().max_attempts);
  config.Set("detector.endpoints", "a:1,,b:2");
  EXPECT_THROW(FromConfig(config), std::invalid_argument);
  config.Set("detector.endpoints", "a:1");
  config.Set("detector.hedge_delay_s", "40");
  try {
    FromConfig(config);
    ADD_FAILURE() << "hedge delay above the deadline accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("detector.hedge_delay_s"), std::string::npos);
  }
}

}  // namespace
}  // namespace picking::orchestrator
