#include "services/detector/core/detection.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <fstream>
#include <functional>
#include <future>
#include <memory>
#include <stdexcept>
#include <string>
#include <thread>

namespace picking::detector {
namespace {

using TimePoint = std::chrono::steady_clock::time_point;
using std::chrono::milliseconds;

// A budget clock the test moves by hand, from an arbitrary start: a fake method "takes" the
// time it advances it by, and the machine's load has no say.
class ManualClock final {
 public:
  static constexpr TimePoint kStart = TimePoint(std::chrono::hours(1000));

  BudgetClock clock() const {
    return BudgetClock([this] { return kStart + std::chrono::nanoseconds(elapsed_ns_.load()); });
  }
  void Advance(std::chrono::nanoseconds d) { elapsed_ns_ += d.count(); }

 private:
  std::atomic<std::int64_t> elapsed_ns_{0};
};

// Returns fixed candidates (or throws) and counts its calls; `work` runs first (e.g. moves
// a ManualClock: a method with a long search).
class FakeEstimator final : public Estimator {
 public:
  FakeEstimator(Method method, std::vector<Detection> candidates, bool throws = false)
      : method_(method), candidates_(std::move(candidates)), throws_(throws) {}
  Method method() const override { return method_; }
  std::vector<Detection> Estimate(const EstimatorInput& input) override {
    ++calls;
    last_item = input.item;
    budget_end = input.budget_end;
    if (work) work();
    if (throws_) throw std::runtime_error("fake failure");
    return candidates_;
  }
  int calls = 0;
  std::string last_item;
  TimePoint budget_end;
  std::function<void()> work;

 private:
  Method method_;
  std::vector<Detection> candidates_;
  bool throws_;
};

Detection MakeDetection(double score, double x, double rmse = 0.001) {
  Detection d;
  d.score = score;
  d.fitness = score;
  d.inlier_rmse_m = rmse;
  d.X_BaseItem.translation() = Eigen::Vector3d(x, 0, 0);
  return d;
}

ObjectConfig Config(Method preferred, std::vector<Method> fallbacks, double min_score) {
  ObjectConfig c;
  c.preferred = preferred;
  c.fallbacks = std::move(fallbacks);
  c.thresholds.min_score = min_score;
  return c;
}

TEST(MethodTest, StringRoundTrip) {
  for (Method m : {Method::kPpf, Method::kSift, Method::kRangeTemplates})
    EXPECT_EQ(MethodFromString(ToString(m)), m);
  EXPECT_THROW(MethodFromString("linemod"), std::invalid_argument);
}

TEST(DetectionChainTest, PreferredMethodAcceptedStopsTheChain) {
  auto ppf = std::make_shared<FakeEstimator>(Method::kPpf,
                                             std::vector<Detection>{MakeDetection(0.9, 1.0)});
  auto sift = std::make_shared<FakeEstimator>(Method::kSift,
                                              std::vector<Detection>{MakeDetection(0.95, 2.0)});
  DetectionChain chain(DetectorConfig(Config(Method::kPpf, {Method::kSift}, 0.5)), {ppf, sift});
  geometry::PointCloud scene;
  EstimatorInput input{"duck", &scene, Eigen::Isometry3d::Identity(), std::nullopt};
  const ChainResult r = chain.Run(input);
  ASSERT_TRUE(r.detection.has_value());
  EXPECT_DOUBLE_EQ(r.detection->X_BaseItem.translation().x(), 1.0);
  EXPECT_EQ(r.detection->method, "ppf");
  EXPECT_EQ(r.detection->item, "duck");
  EXPECT_EQ(ppf->calls, 1);
  EXPECT_EQ(sift->calls, 0);
  ASSERT_EQ(r.attempts.size(), 1u);
  EXPECT_TRUE(r.attempts[0].accepted);
}

TEST(DetectionChainTest, FallsBackWhenBelowThresholdThrowingOrMissing) {
  auto ppf = std::make_shared<FakeEstimator>(Method::kPpf,
                                             std::vector<Detection>{MakeDetection(0.3, 1.0)});
  auto sift = std::make_shared<FakeEstimator>(Method::kSift, std::vector<Detection>{}, true);
  auto templates = std::make_shared<FakeEstimator>(
      Method::kRangeTemplates,
      std::vector<Detection>{MakeDetection(0.9, 5.0, /*rmse=*/0.5), MakeDetection(0.8, 4.0),
                             MakeDetection(0.55, 3.0)});
  ObjectConfig c = Config(Method::kPpf, {Method::kSift, Method::kRangeTemplates}, 0.5);
  DetectionChain chain(DetectorConfig(c), {ppf, sift, templates});
  geometry::PointCloud scene;
  const ChainResult r = chain.Run({"duck", &scene, Eigen::Isometry3d::Identity(), std::nullopt});
  ASSERT_TRUE(r.detection.has_value());
  // The 0.9 candidate fails max_inlier_rmse_m; the next one, 0.8, is accepted.
  EXPECT_DOUBLE_EQ(r.detection->X_BaseItem.translation().x(), 4.0);
  EXPECT_EQ(r.detection->method, "range_templates");
  ASSERT_EQ(r.attempts.size(), 3u);
  EXPECT_FALSE(r.attempts[0].accepted);
  ASSERT_TRUE(r.attempts[0].best.has_value());
  EXPECT_DOUBLE_EQ(r.attempts[0].best->score, 0.3);
  EXPECT_EQ(r.attempts[1].error, "fake failure");
  EXPECT_TRUE(r.attempts[2].accepted);
}

TEST(DetectionChainTest, TakesTheEstimatorsRankingNotTheBareScore) {
  // An estimator ranks by score and appearance: its first candidate (a pose whose printing
  // matches) comes before a higher-scoring one (a neighbour of the same shape).
  auto ppf = std::make_shared<FakeEstimator>(
      Method::kPpf, std::vector<Detection>{MakeDetection(0.7, 1.0), MakeDetection(0.8, 2.0)});
  DetectionChain chain(DetectorConfig(Config(Method::kPpf, {}, 0.5)), {ppf});
  geometry::PointCloud scene;
  const ChainResult r = chain.Run({"duck", &scene, Eigen::Isometry3d::Identity(), std::nullopt});
  ASSERT_TRUE(r.detection.has_value());
  EXPECT_DOUBLE_EQ(r.detection->X_BaseItem.translation().x(), 1.0);
  EXPECT_DOUBLE_EQ(r.detection->score, 0.7);
}

TEST(DetectionChainTest, NothingAcceptedAndUnavailableMethodRecorded) {
  auto ppf = std::make_shared<FakeEstimator>(Method::kPpf,
                                             std::vector<Detection>{MakeDetection(0.3, 1.0)});
  DetectionChain chain(DetectorConfig(Config(Method::kPpf, {Method::kSift}, 0.5)), {ppf});
  geometry::PointCloud scene;
  const ChainResult r = chain.Run({"duck", &scene, Eigen::Isometry3d::Identity(), std::nullopt});
  EXPECT_FALSE(r.detection.has_value());
  ASSERT_EQ(r.attempts.size(), 2u);
  EXPECT_FALSE(r.attempts[1].available);
}

TEST(DetectionChainTest, PerMethodThresholdOverride) {
  auto sift = std::make_shared<FakeEstimator>(Method::kSift,
                                              std::vector<Detection>{MakeDetection(0.4, 1.0)});
  ObjectConfig c = Config(Method::kSift, {}, 0.5);
  c.method_thresholds[Method::kSift].min_score = 0.35;
  DetectionChain chain(DetectorConfig(c), {sift});
  geometry::PointCloud scene;
  EXPECT_TRUE(chain.Run({"duck", &scene, {}, std::nullopt}).detection.has_value());
}

// Throws the exception it is given, as an estimator does that cannot run or finds nothing.
class RaisingEstimator final : public Estimator {
 public:
  RaisingEstimator(Method method, std::exception_ptr error) : method_(method), error_(error) {}
  Method method() const override { return method_; }
  std::vector<Detection> Estimate(const EstimatorInput&) override {
    std::rethrow_exception(error_);
  }

 private:
  Method method_;
  std::exception_ptr error_;
};

// Every method of the chain says how it ended and why it gave no accepted pose.
TEST(DetectionChainTest, EveryMethodSaysWhyItGaveNothing) {
  auto ppf = std::make_shared<FakeEstimator>(Method::kPpf,
                                             std::vector<Detection>{MakeDetection(0.3, 1.0)});
  auto sift = std::make_shared<RaisingEstimator>(
      Method::kSift,
      std::make_exception_ptr(MethodNotApplicableError("the model has no SIFT views")));
  auto templates = std::make_shared<RaisingEstimator>(
      Method::kRangeTemplates, std::make_exception_ptr(NoCandidateError("no cluster")));
  ObjectConfig c = Config(Method::kPpf, {Method::kSift, Method::kRangeTemplates}, 0.5);
  geometry::PointCloud scene;
  const ChainResult r = DetectionChain(DetectorConfig(c), {ppf, sift, templates})
                            .Run({"duck", &scene, Eigen::Isometry3d::Identity(), std::nullopt});
  EXPECT_FALSE(r.detection.has_value());
  ASSERT_EQ(r.attempts.size(), 3u);
  EXPECT_EQ(r.attempts[0].outcome, AttemptOutcome::kBelowThresholds);
  EXPECT_NE(r.attempts[0].reason.find("score 0.3 < 0.5"), std::string::npos)
      << r.attempts[0].reason;
  EXPECT_EQ(r.attempts[1].outcome, AttemptOutcome::kCannotRun);
  EXPECT_EQ(r.attempts[1].reason, "the model has no SIFT views");
  EXPECT_TRUE(r.attempts[1].error.empty());  // not a failure
  EXPECT_EQ(r.attempts[2].outcome, AttemptOutcome::kNoCandidate);
  EXPECT_EQ(r.attempts[2].reason, "no cluster");

  // A failure, a method this detector lacks, an estimator that finds nothing silently.
  auto failing = std::make_shared<FakeEstimator>(Method::kPpf, std::vector<Detection>{}, true);
  auto silent = std::make_shared<FakeEstimator>(Method::kSift, std::vector<Detection>{});
  const ChainResult f = DetectionChain(DetectorConfig(c), {failing, silent})
                            .Run({"duck", &scene, Eigen::Isometry3d::Identity(), std::nullopt});
  ASSERT_EQ(f.attempts.size(), 3u);
  EXPECT_EQ(f.attempts[0].outcome, AttemptOutcome::kFailed);
  EXPECT_EQ(f.attempts[0].reason, "fake failure");
  EXPECT_EQ(f.attempts[1].outcome, AttemptOutcome::kNoCandidate);
  EXPECT_EQ(f.attempts[1].reason, "no candidate pose");
  EXPECT_EQ(f.attempts[2].outcome, AttemptOutcome::kUnavailable);
  EXPECT_FALSE(f.attempts[2].reason.empty());

  // Accepted: no reason.
  auto good = std::make_shared<FakeEstimator>(Method::kPpf,
                                              std::vector<Detection>{MakeDetection(0.9, 1.0)});
  const ChainResult a = DetectionChain(DetectorConfig(c), {good})
                            .Run({"duck", &scene, Eigen::Isometry3d::Identity(), std::nullopt});
  ASSERT_EQ(a.attempts.size(), 1u);
  EXPECT_EQ(a.attempts[0].outcome, AttemptOutcome::kAccepted);
  EXPECT_TRUE(a.attempts[0].reason.empty());
  EXPECT_STREQ(ToString(AttemptOutcome::kNotStarted), "not started");
}

// The budget is judged on the input's clock: a preferred method that takes longer than the
// budget leaves no time for the fallback, one that takes less does, whatever the wall time
// (no sleeping, no spinning on the steady clock).
TEST(DetectionChainTest, NoFallbackIsStartedOnceTheTimeBudgetIsSpent) {
  ManualClock time;
  auto ppf = std::make_shared<FakeEstimator>(Method::kPpf, std::vector<Detection>{});
  auto templates = std::make_shared<FakeEstimator>(Method::kRangeTemplates,
                                                   std::vector<Detection>{MakeDetection(0.9, 1.0)});
  ObjectConfig c = Config(Method::kPpf, {Method::kRangeTemplates}, 0.5);
  c.time_budget_s = 0.01;
  const DetectionChain chain(DetectorConfig(c), {ppf, templates});
  geometry::PointCloud scene;
  EstimatorInput input{"duck", &scene, Eigen::Isometry3d::Identity(), std::nullopt};
  input.clock = time.clock();

  ppf->work = [&time] { time.Advance(milliseconds(20)); };
  const ChainResult spent = chain.Run(input);
  EXPECT_FALSE(spent.detection.has_value());
  EXPECT_EQ(ppf->calls, 1);        // the preferred method always runs ...
  EXPECT_EQ(templates->calls, 0);  // ... the fallback is not started, and says so
  ASSERT_EQ(spent.attempts.size(), 2u);
  EXPECT_EQ(spent.attempts[1].outcome, AttemptOutcome::kNotStarted);
  EXPECT_NE(spent.attempts[1].reason.find("time budget"), std::string::npos);
  // Counted from the start of Run on the input's clock.
  EXPECT_EQ(ppf->budget_end, ManualClock::kStart + milliseconds(10));

  ppf->work = [&time] { time.Advance(milliseconds(5)); };
  const TimePoint run_start = input.clock.Now();
  const ChainResult in_time = chain.Run(input);
  ASSERT_TRUE(in_time.detection.has_value());
  EXPECT_EQ(templates->calls, 1);
  EXPECT_EQ(templates->budget_end, run_start + milliseconds(10));
}

// The budget counts from the caller's start (its pre-processing counts) when it gives one;
// an earlier end the caller gives is kept; no budget is no end.
TEST(DetectionChainTest, TheBudgetCountsFromTheCallersStart) {
  const BudgetClock frozen = BudgetClock::Frozen(ManualClock::kStart);
  auto ppf = std::make_shared<FakeEstimator>(Method::kPpf, std::vector<Detection>{});
  auto templates = std::make_shared<FakeEstimator>(Method::kRangeTemplates,
                                                   std::vector<Detection>{MakeDetection(0.9, 1.0)});
  ObjectConfig c = Config(Method::kPpf, {Method::kRangeTemplates}, 0.5);
  c.time_budget_s = 0.01;
  geometry::PointCloud scene;
  EstimatorInput late{"duck", &scene, Eigen::Isometry3d::Identity(), std::nullopt};
  late.clock = frozen;
  const TimePoint started = ManualClock::kStart - std::chrono::seconds(1);
  late.budget_start = started;
  const ChainResult spent = DetectionChain(DetectorConfig(c), {ppf, templates}).Run(late);
  EXPECT_FALSE(spent.detection.has_value());
  EXPECT_EQ(templates->calls, 0);
  EXPECT_EQ(ppf->budget_end, started + milliseconds(10));

  c.time_budget_s = 0.0;  // no budget: the whole chain
  const ChainResult whole = DetectionChain(DetectorConfig(c), {ppf, templates}).Run(late);
  ASSERT_TRUE(whole.detection.has_value());
  EXPECT_EQ(templates->calls, 1);
  EXPECT_EQ(ppf->budget_end, TimePoint::max());

  c.time_budget_s = 10.0;
  EstimatorInput early{"duck", &scene, Eigen::Isometry3d::Identity(), std::nullopt};
  early.clock = frozen;
  early.budget_end = ManualClock::kStart + milliseconds(5);
  DetectionChain(DetectorConfig(c), {ppf, templates}).Run(early);
  EXPECT_EQ(ppf->budget_end, early.budget_end);
}

TEST(BudgetClockTest, SteadyByDefaultFrozenOrTheCallersOwn) {
  const TimePoint before = std::chrono::steady_clock::now();
  EXPECT_GE(BudgetClock().Now(), before);
  const BudgetClock frozen = BudgetClock::Frozen(ManualClock::kStart);
  EXPECT_EQ(frozen.Now(), ManualClock::kStart);
  EXPECT_EQ(frozen.Now(), ManualClock::kStart);
  ManualClock time;
  const BudgetClock manual = time.clock();
  const BudgetClock copy = manual;  // copies share the time source
  time.Advance(milliseconds(3));
  EXPECT_EQ(copy.Now(), ManualClock::kStart + milliseconds(3));
  EXPECT_THROW(BudgetClock(std::function<TimePoint()>()), std::invalid_argument);
}

TEST(BudgetClockTest, AThreadsCpuClockStandsStillWhileTheThreadWaits) {
  // A thread that waits (as a call's thread does while other work holds the cores) spends
  // none of a budget judged by its CPU clock, read here from another thread.
  std::promise<void> go;
  std::promise<pthread_t> started;
  std::thread waiter([&] {
    started.set_value(pthread_self());
    go.get_future().wait();
  });
  const BudgetClock waiting = BudgetClock::ThreadCpu(started.get_future().get());
  const BudgetClock mine = BudgetClock::ThreadCpu(pthread_self());
  const TimePoint waiting_at = waiting.Now();
  const TimePoint mine_at = mine.Now();
  volatile double sink = 0.0;
  while (mine.Now() - mine_at < milliseconds(30)) {
    for (int k = 0; k < 10000; ++k) sink = sink + 1e-9 * k;  // busy on this thread only
  }
  EXPECT_LT(waiting.Now() - waiting_at, milliseconds(5));
  EXPECT_GE(mine.Now() - mine_at, milliseconds(30));
  go.set_value();
  waiter.join();
}

TEST(DetectionChainTest, RejectsBadConstruction) {
  auto a = std::make_shared<FakeEstimator>(Method::kPpf, std::vector<Detection>{});
  auto b = std::make_shared<FakeEstimator>(Method::kPpf, std::vector<Detection>{});
  EXPECT_THROW(DetectionChain(DetectorConfig(), {a, b}), std::invalid_argument);
  EXPECT_THROW(DetectionChain(DetectorConfig(), {nullptr}), std::invalid_argument);
  DetectionChain chain(DetectorConfig(), {a});
  EXPECT_THROW(chain.Run({"duck", nullptr, {}, std::nullopt}), std::invalid_argument);
}

TEST(DetectorConfigTest, ParsesDefaultsObjectsAndOverrides) {
  const std::string text = R"({
    "default": {"preferred": "ppf", "fallbacks": ["range_templates"],
                "thresholds": {"min_score": 0.6, "max_inlier_rmse_m": 0.004}},
    "objects": {
      "expo_dry_erase_board_eraser": {"preferred": "sift", "fallbacks": ["ppf"],
                                      "method_thresholds": {"sift": {"min_score": 0.3}}},
      "dove_beauty_bar": {"thresholds": {"min_fitness": 0.2}, "time_budget_s": 2.5}
    }})";
  const DetectorConfig config = DetectorConfig::Parse(text);
  const ObjectConfig eraser = config.ForItem("expo_dry_erase_board_eraser");
  EXPECT_EQ(eraser.Order(), (std::vector<Method>{Method::kSift, Method::kPpf}));
  EXPECT_DOUBLE_EQ(eraser.thresholds.min_score, 0.6);  // inherited
  EXPECT_DOUBLE_EQ(eraser.ThresholdsFor(Method::kSift).min_score, 0.3);
  EXPECT_DOUBLE_EQ(eraser.ThresholdsFor(Method::kSift).max_inlier_rmse_m, 0.004);
  EXPECT_DOUBLE_EQ(eraser.ThresholdsFor(Method::kPpf).min_score, 0.6);
  const ObjectConfig dove = config.ForItem("dove_beauty_bar");
  EXPECT_EQ(dove.Order(), (std::vector<Method>{Method::kPpf, Method::kRangeTemplates}));
  EXPECT_DOUBLE_EQ(dove.thresholds.min_fitness, 0.2);
  EXPECT_DOUBLE_EQ(dove.thresholds.min_score, 0.6);
  EXPECT_DOUBLE_EQ(dove.time_budget_s, 2.5);
  EXPECT_DOUBLE_EQ(eraser.time_budget_s, ObjectConfig().time_budget_s);  // the default
  const ObjectConfig other = config.ForItem("unknown_item");
  EXPECT_EQ(other.item, "unknown_item");
  EXPECT_EQ(other.preferred, Method::kPpf);
}

void ExpectParseError(const std::string& text, const std::string& fragment) {
  try {
    DetectorConfig::Parse(text, "detector.json");
    FAIL() << "no error for " << text;
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("detector.json"), std::string::npos) << e.what();
  }
}

TEST(DetectorConfigTest, ValidationErrorsNameTheField) {
  ExpectParseError(R"({"objects": {"a": {"preferred": "linemod"}}})", "objects.a.preferred");
  ExpectParseError(R"({"objects": {"a": {"colour": "red"}}})", "objects.a.colour");
  ExpectParseError(R"({"default": {"thresholds": {"min_score": 1.5}}})", "default.thresholds");
  ExpectParseError(R"({"objects": {"a": {"preferred": "sift", "fallbacks": ["sift"]}}})",
                   "more than once");
  ExpectParseError(R"({"objects": {"a": {"fallbacks": ["ppf", 3]}}})", "objects.a.fallbacks[1]");
  ExpectParseError("{\n\"default\": {\n  \"preferred\": }\n}", "detector.json:3");
  ExpectParseError(R"({"objects": {"a": {"time_budget_s": -1}}})", "objects.a");
  ExpectParseError(R"({"objects": {"a": {"time_budget_s": "1 s"}}})", "objects.a.time_budget_s");
}

TEST(DetectorConfigTest, LoadsFileAndReportsMissingFile) {
  const std::string path = ::testing::TempDir() + "/detector_config_test.json";
  {
    std::ofstream out(path);
    out << R"({"default": {"preferred": "range_templates"}})";
  }
  EXPECT_EQ(DetectorConfig::LoadFile(path).ForItem("x").preferred, Method::kRangeTemplates);
  std::remove(path.c_str());
  EXPECT_THROW(DetectorConfig::LoadFile(path), std::runtime_error);
}

}  // namespace
}  // namespace picking::detector
