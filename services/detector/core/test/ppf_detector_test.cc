#include "services/detector/core/ppf_detector.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "services/detector/core/test/ppf_test_util.h"

namespace picking::detector {
namespace {

using testing::LoadPcd;
using testing::PointCloudPath;

constexpr double kDeg = M_PI / 180.0;

class MilkSceneTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    milk_ = new geometry::PointCloud(LoadPcd(PointCloudPath("milk.pcd")));
    scene_ = new geometry::PointCloud(LoadPcd(PointCloudPath("milk_cartoon_all_small_clorox.pcd")));
  }
  static void TearDownTestSuite() {
    delete milk_;
    delete scene_;
  }
  static geometry::PointCloud* milk_;
  static geometry::PointCloud* scene_;
};
geometry::PointCloud* MilkSceneTest::milk_ = nullptr;
geometry::PointCloud* MilkSceneTest::scene_ = nullptr;

// The milk model moved by a seeded random transform X_MovedModel is found in the scene at
// X_SceneMoved = X_MovedModel^-1 (its true pose in the scene frame is the identity).
// Sampled with Drost et al.'s tau_d = 0.05 of the diameter (the default pipeline, 0.03, finds
// the milk in ObjectNotInSceneIsNotDetected).
TEST_F(MilkSceneTest, RecoversPoseOfMovedModel) {
  std::mt19937 rng(20160707);
  ObjectModelOptions options;
  options.sampling_distance_rel = 0.05f;
  for (int trial = 0; trial < 6; ++trial) {
    const Eigen::Isometry3d X_MovedModel = testing::RandomPose(&rng, 0.5);
    const ObjectModel model(testing::Transformed(*milk_, X_MovedModel), options);
    const PpfScene scene = PreparePpfScene(*scene_, model);
    const PpfDetectionResult result = DetectPpf(model, scene);
    ASSERT_FALSE(result.detections.empty()) << "trial " << trial;
    const Eigen::Isometry3d expected = X_MovedModel.inverse();
    const PpfDetection& best = result.detections.front();
    EXPECT_LT(testing::TranslationError(best.X_SceneModel, expected), 0.005) << "trial " << trial;
    EXPECT_LT(testing::RotationErrorRad(best.X_SceneModel, expected), 2.0 * kDeg)
        << "trial " << trial;
    EXPECT_GT(best.support, 0.8) << "trial " << trial;
  }
}

// A refine deadline that has passed (on the options' clock, standing still here) stops after
// the best-voted hypothesis, which alone still finds the milk at its true pose.
TEST_F(MilkSceneTest, RefineDeadlineKeepsOnlyTheBestVotedHypothesis) {
  const ObjectModel model(*milk_, ObjectModelOptions{});
  const PpfScene scene = PreparePpfScene(*scene_, model);
  const PpfDetectionResult all = DetectPpf(model, scene);
  EXPECT_EQ(all.refined_hypotheses, std::min<int>(PpfDetectorOptions{}.hypotheses_to_verify,
                                                  static_cast<int>(all.match.hypotheses.size())));
  PpfDetectorOptions options;
  const auto start = std::chrono::steady_clock::time_point(std::chrono::hours(1000));
  options.clock = BudgetClock::Frozen(start);
  options.refine_deadline = start - std::chrono::seconds(1);
  const PpfDetectionResult first = DetectPpf(model, scene, options);
  EXPECT_EQ(first.refined_hypotheses, 1);
  ASSERT_FALSE(first.detections.empty());
  EXPECT_LT(testing::TranslationError(first.detections.front().X_SceneModel,
                                      Eigen::Isometry3d::Identity()),
            0.005);
}

// Hypotheses are refined in parallel; without a deadline the result is that of one thread.
TEST_F(MilkSceneTest, RefiningOnManyThreadsGivesTheResultOfOne) {
  const ObjectModel model(*milk_, ObjectModelOptions{});
  const PpfScene scene = PreparePpfScene(*scene_, model);
  PpfDetectorOptions one;
  one.match.num_threads = 1;
  PpfDetectorOptions three = one;
  three.match.num_threads = 3;
  const PpfDetectionResult a = DetectPpf(model, scene, one);
  const PpfDetectionResult b = DetectPpf(model, scene, three);
  EXPECT_EQ(a.refined_hypotheses, b.refined_hypotheses);
  ASSERT_EQ(a.detections.size(), b.detections.size());
  for (std::size_t i = 0; i < a.detections.size(); ++i) {
    EXPECT_TRUE(a.detections[i].X_SceneModel.isApprox(b.detections[i].X_SceneModel, 1e-12));
    EXPECT_EQ(a.detections[i].support, b.detections[i].support);
    EXPECT_EQ(a.detections[i].votes, b.detections[i].votes);
  }
}

TEST_F(MilkSceneTest, ObjectNotInSceneIsNotDetected) {
  const geometry::PointCloud bunny = LoadPcd(PointCloudPath("bun0.pcd"));
  // bun0 has 397 points: normals need a wider neighbourhood than the default.
  ObjectModelOptions bunny_options;
  bunny_options.normal_radius_rel = 0.1f;
  const ObjectModel model(bunny, bunny_options);
  ASSERT_GT(model.icp_cloud().size(), 200u);
  const PpfScene scene = PreparePpfScene(*scene_, model);
  const PpfDetectionResult result = DetectPpf(model, scene);
  EXPECT_TRUE(result.detections.empty())
      << "support " << result.detections.front().support << ", conflicts "
      << result.detections.front().conflict_fraction;
  EXPECT_LT(result.best.support, 0.6);
  // The milk model, prepared the same way, is detected: the verification is not just strict.
  const ObjectModel milk(*milk_, ObjectModelOptions{});
  const PpfDetectionResult milk_result = DetectPpf(milk, PreparePpfScene(*scene_, milk));
  ASSERT_FALSE(milk_result.detections.empty());
  EXPECT_GT(milk_result.detections.front().support, result.best.support + 0.3);
  EXPECT_LT(milk_result.detections.front().conflict_fraction, 0.02);
}

// A model whose ICP cloud has a handful of points (the 397-point bunny with the default
// normal radius keeps 16) cannot be verified: no detection however well the points fit.
TEST_F(MilkSceneTest, TooFewVisiblePointsAreNotADetection) {
  const ObjectModel model(LoadPcd(PointCloudPath("bun0.pcd")), ObjectModelOptions{});
  ASSERT_LT(model.icp_cloud().size(), 30u);
  const PpfDetectionResult result = DetectPpf(model, PreparePpfScene(*scene_, model));
  EXPECT_TRUE(result.detections.empty());
  PpfDetectorOptions options;
  options.min_visible_fraction = -0.1f;
  EXPECT_THROW(DetectPpf(model, PreparePpfScene(*scene_, model), options), std::invalid_argument);
  PpfDetectorOptions no_stride;
  no_stride.coarse_icp_stride = 0;
  EXPECT_THROW(DetectPpf(model, PreparePpfScene(*scene_, model), no_stride), std::invalid_argument);
}

// A pose that puts the model in front of the measured surface (in space the sensor saw
// through) is in conflict; the true pose is not.
TEST_F(MilkSceneTest, FreeSpaceConflicts) {
  const ObjectModel milk(*milk_, ObjectModelOptions{});
  const PpfScene scene = PreparePpfScene(*scene_, milk);
  ASSERT_FALSE(scene.view_ranges.empty());
  const float step = milk.sampling_distance_m();
  const SceneAgreement truth =
      MeasureAgreement(milk, scene, Eigen::Isometry3d::Identity(), 0.5f * step, 0.5f, 2.0f * step);
  EXPECT_GT(truth.support, 0.9);
  EXPECT_LT(truth.conflict_fraction, 0.02);
  // Pulled 10 cm toward the sensor (the scene's viewpoint is its origin).
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& p : milk.icp_cloud().points) centroid += p.cast<double>();
  centroid /= static_cast<double>(milk.icp_cloud().size());
  Eigen::Isometry3d X_front = Eigen::Isometry3d::Identity();
  X_front.translation() = -0.1 * centroid.normalized();
  const SceneAgreement front =
      MeasureAgreement(milk, scene, X_front, 0.5f * step, 0.5f, 2.0f * step);
  EXPECT_LT(front.support, 0.2);
  EXPECT_GT(front.conflict_fraction, 0.5);
}

// Seed poses are a fallback: not asked for while a voted hypothesis finds the milk, and
// refined into a detection when none is good enough.
TEST_F(MilkSceneTest, SeedPosesAreRefinedOnlyWhenVotingFindsNothing) {
  const ObjectModel model(*milk_, ObjectModelOptions{});
  const PpfScene scene = PreparePpfScene(*scene_, model);
  std::mt19937 rng(11);
  const Eigen::Isometry3d seed = testing::Perturbation(&rng, 2.0 * kDeg, 0.003);
  int calls = 0;
  PpfDetectorOptions options;
  options.seed_source = [&]() {
    ++calls;
    return std::vector<Eigen::Isometry3d>{seed};
  };
  const PpfDetectionResult voted = DetectPpf(model, scene, options);
  EXPECT_EQ(calls, 0);
  ASSERT_FALSE(voted.detections.empty());
  EXPECT_FALSE(voted.detections.front().seed);

  options.seed_fallback_support = 1.01f;  // no voted hypothesis is good enough
  const PpfDetectionResult seeded = DetectPpf(model, scene, options);
  EXPECT_EQ(calls, 1);
  EXPECT_EQ(seeded.refined_hypotheses, voted.refined_hypotheses + 1);
  // The seed converges on the milk, where the best-voted hypothesis is too (one object, one
  // detection).
  ASSERT_FALSE(seeded.detections.empty());
  EXPECT_LT(testing::TranslationError(seeded.detections.front().X_SceneModel,
                                      Eigen::Isometry3d::Identity()),
            0.005);

  options.seed_source = []() {
    Eigen::Isometry3d bad = Eigen::Isometry3d::Identity();
    bad.translation().x() = std::numeric_limits<double>::quiet_NaN();
    return std::vector<Eigen::Isometry3d>{bad};
  };
  EXPECT_THROW(DetectPpf(model, scene, options), std::invalid_argument);
  options.seed_refine_fraction = 1.0f;
  EXPECT_THROW(DetectPpf(model, scene, options), std::invalid_argument);
  options.seed_refine_fraction = 0.25f;
  options.seed_source = [&]() { return std::vector<Eigen::Isometry3d>{seed}; };
  EXPECT_NO_THROW(DetectPpf(model, scene, options));
  options.seed_keep_margin = -0.01f;
  EXPECT_THROW(DetectPpf(model, scene, options), std::invalid_argument);
}

TEST_F(MilkSceneTest, BadScenesThrow) {
  const ObjectModel model(*milk_, ObjectModelOptions{});
  EXPECT_THROW(PreparePpfScene(geometry::PointCloud{}, model), std::invalid_argument);
  geometry::PointCloud nan_scene;
  nan_scene.points.assign(100, Eigen::Vector3f::Constant(std::numeric_limits<float>::quiet_NaN()));
  EXPECT_THROW(PreparePpfScene(nan_scene, model), std::invalid_argument);
  geometry::PointCloud mismatched = *milk_;
  mismatched.normals.resize(3, Eigen::Vector3f::UnitZ());
  EXPECT_THROW(PreparePpfScene(mismatched, model), std::invalid_argument);
  geometry::PointCloud huge;  // a scene spanning kilometres at millimetre voxels
  huge.points = {Eigen::Vector3f::Zero(), Eigen::Vector3f(1.0e4f, 0.0f, 0.0f)};
  EXPECT_THROW(PreparePpfScene(huge, model), std::invalid_argument);
}

}  // namespace
}  // namespace picking::detector
