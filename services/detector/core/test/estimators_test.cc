#include "services/detector/core/estimators.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <random>

#include "libs/errors/errors.h"
#include "services/detector/core/test/ppf_test_util.h"

namespace picking::detector {
namespace {

constexpr double kDeg = M_PI / 180.0;

TEST(FitOrganizedIntrinsicsTest, RecoversThePinholeOfAnOrganisedCloud) {
  const PinholeCamera truth(160, 120, 210.0, 205.0, 81.0, 58.5);
  std::mt19937 rng(11);
  const Eigen::Isometry3d X_BaseSensor = testing::RandomPose(&rng, 1.0);
  std::uniform_real_distribution<double> depth(0.4, 1.5);
  geometry::PointCloud cloud;
  cloud.width = truth.width();
  cloud.height = truth.height();
  for (int v = 0; v < truth.height(); ++v) {
    for (int u = 0; u < truth.width(); ++u) {
      if ((u + v) % 7 == 0) {  // Missing measurements.
        cloud.points.emplace_back(Eigen::Vector3f::Constant(NAN));
        continue;
      }
      const double z = depth(rng);
      const Eigen::Vector3d p_Sensor((u - truth.cx()) / truth.fx() * z,
                                     (v - truth.cy()) / truth.fy() * z, z);
      cloud.points.push_back((X_BaseSensor * p_Sensor).cast<float>());
    }
  }
  const auto fitted = FitOrganizedIntrinsics(cloud, X_BaseSensor);
  ASSERT_TRUE(fitted.has_value());
  EXPECT_EQ(fitted->width(), truth.width());
  EXPECT_EQ(fitted->height(), truth.height());
  EXPECT_NEAR(fitted->fx(), truth.fx(), 0.05);
  EXPECT_NEAR(fitted->fy(), truth.fy(), 0.05);
  EXPECT_NEAR(fitted->cx(), truth.cx(), 0.05);
  EXPECT_NEAR(fitted->cy(), truth.cy(), 0.05);
  // The wrong sensor pose does not fit a pinhole.
  EXPECT_FALSE(FitOrganizedIntrinsics(cloud, Eigen::Isometry3d::Identity()).has_value());
  // Unorganised clouds have no pixel grid.
  geometry::PointCloud flat = cloud;
  flat.width = static_cast<std::uint32_t>(flat.points.size());
  flat.height = 1;
  EXPECT_FALSE(FitOrganizedIntrinsics(flat, X_BaseSensor).has_value());
}

TEST(FitOrganizedIntrinsicsTest, RecoversALensWithDistortion) {
  // The simulated scanner camera of data/scanner/sim_sensor at a quarter of its size.
  Distortion k;
  k.k1 = -0.08;
  k.k2 = 0.05;
  k.p1 = 0.0005;
  k.p2 = -0.0003;
  const PinholeCamera truth(320, 256, 450.0, 450.0, 160.7, 127.4, k);
  std::mt19937 rng(5);
  const Eigen::Isometry3d X_BaseSensor = testing::RandomPose(&rng, 1.0);
  std::uniform_real_distribution<double> depth(0.4, 0.9);
  geometry::PointCloud cloud;
  cloud.width = truth.width();
  cloud.height = truth.height();
  for (int v = 0; v < truth.height(); ++v) {
    for (int u = 0; u < truth.width(); ++u) {
      const Eigen::Vector3d p_Sensor = truth.Unproject(Eigen::Vector2d(u, v)) * depth(rng);
      cloud.points.push_back((X_BaseSensor * p_Sensor).cast<float>());
    }
  }
  // A pinhole leaves pixels of residual at the image corners: the distortion model is fitted,
  // and projects like the true lens.
  const auto fitted = FitOrganizedIntrinsics(cloud, X_BaseSensor, 0.05);
  ASSERT_TRUE(fitted.has_value());
  EXPECT_FALSE(fitted->distortion().is_zero());
  EXPECT_NEAR(fitted->fx(), truth.fx(), 0.5);
  EXPECT_NEAR(fitted->cy(), truth.cy(), 0.5);
  for (const Eigen::Vector3d& p : {Eigen::Vector3d(0.0, 0.0, 1.0), Eigen::Vector3d(0.3, 0.25, 0.8),
                                   Eigen::Vector3d(-0.25, 0.2, 0.7)}) {
    EXPECT_LT((*fitted->Project(p) - *truth.Project(p)).norm(), 0.05) << p.transpose();
  }
}

// Two organised views of a floor (z = 0, normals up) stacked row-wise, as the scanner merges
// views without voxels: each view's intrinsics are fitted to its own block, its intensities
// compensated for its own sensor's shading, and where it grazes the floor left out.
TEST(MergeStackedViewsTest, SplitsTheViewsFitsEachCameraAndCompensatesEachShading) {
  const PinholeCamera camera(80, 60, 100.0, 100.0, 39.5, 29.5);
  // Looking straight down from 1 m, and from far to the side at a grazing angle.
  const Eigen::Isometry3d X_Down =
      Eigen::Translation3d(0.0, 0.0, 1.0) * Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX());
  const Eigen::Isometry3d X_Grazing =
      Eigen::Translation3d(-3.0, 0.0, 0.3) *
      Eigen::AngleAxisd(-0.5 * M_PI, Eigen::Vector3d::UnitZ()) *
      Eigen::AngleAxisd(-0.5 * M_PI - 0.1, Eigen::Vector3d::UnitX());
  geometry::PointCloud stacked;
  stacked.width = 80;
  stacked.height = 120;
  for (const Eigen::Isometry3d* X : {&X_Down, &X_Grazing}) {
    for (int v = 0; v < 60; ++v) {
      for (int u = 0; u < 80; ++u) {
        const Eigen::Vector3d ray = X->linear() * camera.Unproject(Eigen::Vector2d(u, v));
        const double t = -X->translation().z() / ray.z();
        if (!(t > 0.0)) {
          stacked.points.emplace_back(Eigen::Vector3f::Constant(NAN));
          stacked.normals.emplace_back(Eigen::Vector3f::Constant(NAN));
          stacked.intensities.push_back(NAN);
          continue;
        }
        stacked.points.push_back((X->translation() + t * ray).cast<float>());
        stacked.normals.push_back(Eigen::Vector3f::UnitZ());
        stacked.intensities.push_back(0.5f);
      }
    }
  }
  const PinholeCamera fallback(10, 10, 5.0, 5.0, 4.5, 4.5);
  const StackedViews views = MergeStackedViews(stacked, {X_Down, X_Grazing}, fallback);
  ASSERT_EQ(views.sensors.size(), 2u);
  EXPECT_NEAR(views.sensors[0].camera.fx(), 100.0, 0.1);
  EXPECT_NEAR(views.sensors[1].camera.fx(), 100.0, 0.1);
  EXPECT_TRUE(views.sensors[1].X_BaseSensor.isApprox(X_Grazing));
  EXPECT_EQ(views.cloud.height, 1u);
  std::size_t finite = 0;
  for (const auto& p : stacked.points) finite += p.allFinite() ? 1 : 0;
  ASSERT_EQ(views.cloud.size(), finite);
  ASSERT_EQ(views.cloud.intensities.size(), finite);
  // The first view's: the intensity with its own shading divided out.
  const AppearanceOptions appearance;
  EXPECT_FLOAT_EQ(
      views.cloud.intensities[0],
      ShadingCompensatedIntensity(0.5f, views.cloud.points[0], Eigen::Vector3f::UnitZ(),
                                  X_Down.translation().cast<float>(), appearance.min_cos));
  // The second view's: left out where it grazes the floor, compensated elsewhere.
  const std::size_t first_view = static_cast<std::size_t>(
      std::count_if(stacked.points.begin(), stacked.points.begin() + 80 * 60,
                    [](const Eigen::Vector3f& p) { return p.allFinite(); }));
  int grazed = 0, kept = 0;
  for (std::size_t i = first_view; i < views.cloud.size(); ++i) {
    const Eigen::Vector3f ray = X_Grazing.translation().cast<float>() - views.cloud.points[i];
    if (ray.normalized().z() < appearance.min_sample_cos) {
      EXPECT_TRUE(std::isnan(views.cloud.intensities[i])) << i;
      ++grazed;
    } else {
      EXPECT_FLOAT_EQ(
          views.cloud.intensities[i],
          ShadingCompensatedIntensity(0.5f, views.cloud.points[i], Eigen::Vector3f::UnitZ(),
                                      X_Grazing.translation().cast<float>(), appearance.min_cos));
      ++kept;
    }
  }
  EXPECT_GT(grazed, 100);
  EXPECT_GT(kept, 100);

  // Kept inside a box: only those points, the cameras still fitted to the whole views.
  OrientedBox half;
  half.X_BaseBox.translation() = Eigen::Vector3d(-1.0, 0.0, 0.0);
  half.size_m = Eigen::Vector3d(2.0, 10.0, 1.0);  // x in [-2, 0]
  const StackedViews inside = MergeStackedViews(stacked, {X_Down, X_Grazing}, fallback, {}, &half);
  ASSERT_FALSE(inside.cloud.empty());
  EXPECT_LT(inside.cloud.size(), views.cloud.size());
  for (const Eigen::Vector3f& p : inside.cloud.points) EXPECT_LE(p.x(), 0.0f);
  EXPECT_EQ(inside.cloud.intensities.size(), inside.cloud.size());
  EXPECT_EQ(inside.fitted_cameras, 2);
  EXPECT_NEAR(inside.sensors[0].camera.fx(), 100.0, 0.1);

  // Bad input: no pose, a NaN pose, a height that is not a multiple of the views.
  EXPECT_THROW(MergeStackedViews(stacked, {}, fallback), std::invalid_argument);
  Eigen::Isometry3d nan_pose = X_Down;
  nan_pose.translation().x() = NAN;
  EXPECT_THROW(MergeStackedViews(stacked, {X_Down, nan_pose}, fallback), std::invalid_argument);
  EXPECT_THROW(MergeStackedViews(stacked, std::vector<Eigen::Isometry3d>(7, X_Down), fallback),
               std::invalid_argument);
}

TEST(IntensitiesFromColorsTest, UsesTheLuma) {
  geometry::PointCloud cloud;
  cloud.points.assign(2, Eigen::Vector3f::Zero());
  cloud.colors = {{255, 255, 255}, {255, 0, 0}};
  IntensitiesFromColors(&cloud);
  ASSERT_EQ(cloud.intensities.size(), 2u);
  EXPECT_NEAR(cloud.intensities[0], 1.0f, 1e-5f);
  EXPECT_NEAR(cloud.intensities[1], 0.299f, 1e-5f);
}

// Two blocks of points 5 cm apart and a lone point: two clusters, the larger first, with
// their extents; points near a block get its label, points far from both get -1.
TEST(SceneContextTest, ClusterLabelsNameTheNearestCluster) {
  geometry::PointCloud cloud;
  for (int i = 0; i < 20; ++i) {
    for (int j = 0; j < 20; ++j) {
      cloud.points.emplace_back(0.002f * i, 0.002f * j, 0.5f);  // 3.8 cm square
      if (i < 10) cloud.points.emplace_back(0.1f + 0.002f * i, 0.002f * j, 0.5f);
    }
  }
  cloud.points.emplace_back(0.3f, 0.3f, 0.5f);
  cloud.width = static_cast<std::uint32_t>(cloud.size());
  SceneContextOptions options;
  options.remove_dominant_plane = false;
  SceneContext context(cloud, Eigen::Isometry3d::Identity(), std::nullopt, options);
  const SceneContext::Clusters& clusters = context.SceneClusters();
  ASSERT_EQ(clusters.clusters.size(), 2u);
  EXPECT_EQ(clusters.clusters[0].size(), 400u);
  EXPECT_EQ(clusters.clusters[1].size(), 200u);
  ASSERT_EQ(clusters.extent_m.size(), 2u);
  EXPECT_NEAR(clusters.extent_m[0], std::sqrt(2.0) * 0.038, 1e-4);
  EXPECT_NEAR(clusters.extent_m[1], std::hypot(0.018, 0.038), 1e-4);
  const std::vector<std::int32_t> labels = context.ClusterLabels(
      {Eigen::Vector3f(0.01f, 0.01f, 0.503f), Eigen::Vector3f(0.11f, 0.02f, 0.5f),
       Eigen::Vector3f(0.3f, 0.3f, 0.5f), Eigen::Vector3f(0.06f, 0.0f, 0.5f)},
      0.005f);
  EXPECT_EQ(labels, (std::vector<std::int32_t>{0, 1, -1, -1}));
}

// The PCL milk scene: the milk model's true pose in the scene is the identity; the sensor is
// at the origin of the scene frame.
class MilkEstimatorTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scene_ = new geometry::PointCloud(
        testing::LoadPcd(testing::PointCloudPath("milk_cartoon_all_small_clorox.pcd")));
    cache_dir_ = new std::string(::testing::TempDir() + "/estimators_test_cache");
    std::filesystem::remove_all(*cache_dir_);
    ModelLibraryOptions options;
    options.cache_dir = *cache_dir_;
    library_ = new std::shared_ptr<const ModelLibrary>(std::make_shared<const ModelLibrary>(
        ModelManifest::LoadFile(std::string(PICKING_TEST_DATA_DIR) + "/detector/models.json",
                                PICKING_DATA_DIR),
        options));
  }
  static void TearDownTestSuite() {
    delete library_;
    delete scene_;
    std::filesystem::remove_all(*cache_dir_);
    delete cache_dir_;
  }

  static std::shared_ptr<SceneContext> Context() {
    return std::make_shared<SceneContext>(
        *scene_, Eigen::Isometry3d::Identity(),
        FitOrganizedIntrinsics(*scene_, Eigen::Isometry3d::Identity()));
  }
  // The budget clock stands still at kStart: a budget ending after it never runs out, and the
  // searches are those of a quiet machine whatever the load.
  static EstimatorInput Input(const std::string& item) {
    EstimatorInput input;
    input.item = item;
    input.scene = scene_;
    input.clock = BudgetClock::Frozen(kStart);
    return input;
  }

  static constexpr std::chrono::steady_clock::time_point kStart =
      std::chrono::steady_clock::time_point(std::chrono::hours(1000));

  static geometry::PointCloud* scene_;
  static std::string* cache_dir_;
  static std::shared_ptr<const ModelLibrary>* library_;
};
geometry::PointCloud* MilkEstimatorTest::scene_ = nullptr;
std::string* MilkEstimatorTest::cache_dir_ = nullptr;
std::shared_ptr<const ModelLibrary>* MilkEstimatorTest::library_ = nullptr;

TEST_F(MilkEstimatorTest, TheKinectSceneHasKinectIntrinsics) {
  const auto camera = FitOrganizedIntrinsics(*scene_, Eigen::Isometry3d::Identity());
  ASSERT_TRUE(camera.has_value());
  EXPECT_EQ(camera->width(), 640);
  EXPECT_EQ(camera->height(), 480);
  EXPECT_GT(camera->fx(), 450.0);
  EXPECT_LT(camera->fx(), 600.0);
}

TEST_F(MilkEstimatorTest, PpfFindsTheMilkAndVerifiesIt) {
  auto context = Context();
  PpfEstimator ppf(*library_, context);
  const std::vector<Detection> found = ppf.Estimate(Input("milk"));
  ASSERT_FALSE(found.empty());
  const Detection& best = found.front();
  EXPECT_EQ(best.item, "milk");
  EXPECT_EQ(best.method, "ppf");
  EXPECT_LT(testing::TranslationError(best.X_BaseItem, Eigen::Isometry3d::Identity()), 0.005);
  EXPECT_LT(testing::RotationErrorRad(best.X_BaseItem, Eigen::Isometry3d::Identity()), 2 * kDeg);
  EXPECT_GT(best.score, 0.7);
  EXPECT_GT(best.fitness, 0.5);
  EXPECT_LT(best.inlier_rmse_m, 0.005);
  for (std::size_t i = 1; i < found.size(); ++i) EXPECT_LE(found[i].score, found[i - 1].score);
}

TEST_F(MilkEstimatorTest, BadSearchOptionsThrow) {
  auto context = Context();
  const auto make = [&](const PpfSearchOptions& search) {
    return PpfEstimator(*library_, context, PpfDetectorOptions{}, RefineVerifyOptions{}, search);
  };
  PpfSearchOptions no_room;
  no_room.verify_budget_fraction = 0.6f;  // with voting's 0.5, nothing is left to refine
  EXPECT_THROW(make(no_room), std::invalid_argument);
  PpfSearchOptions no_patches;
  no_patches.box.max_patches = 0;
  EXPECT_THROW(make(no_patches), std::invalid_argument);
  PpfSearchOptions few_points;
  few_points.box_screen_points = 10;
  EXPECT_THROW(make(few_points), std::invalid_argument);
  PpfSearchOptions no_time;
  no_time.box_budget_fraction = 0.0f;
  EXPECT_THROW(make(no_time), std::invalid_argument);
  PpfSearchOptions negative_tolerance;
  negative_tolerance.box_near_square_tolerance = -0.1;
  EXPECT_THROW(make(negative_tolerance), std::invalid_argument);
  PpfSearchOptions no_step;
  no_step.box_polish_step_m = 0.0;
  EXPECT_THROW(make(no_step), std::invalid_argument);
  PpfSearchOptions negative_levels;
  negative_levels.box_polish_levels = -1;
  EXPECT_THROW(make(negative_levels), std::invalid_argument);
  EXPECT_NO_THROW(make(PpfSearchOptions{}));
}

TEST_F(MilkEstimatorTest, AbsentObjectGetsNoAcceptableCandidate) {
  auto context = Context();
  PpfEstimator ppf(*library_, context);
  const std::vector<Detection> found = ppf.Estimate(Input("bunny"));
  const Thresholds thresholds = (*library_)->ConfigFor("bunny").thresholds;
  for (const Detection& d : found) EXPECT_FALSE(thresholds.Accepts(d)) << "score " << d.score;
}

TEST_F(MilkEstimatorTest, RefinementPullsANearbyPoseInAndVerificationRejectsAShiftedOne) {
  auto context = Context();
  const auto milk = (*library_)->Get("milk");
  const Detection truth =
      RefineAndVerify(*milk, *context, Method::kPpf, Eigen::Isometry3d::Identity(), false);
  EXPECT_GT(truth.score, 0.7);
  EXPECT_GT(truth.fitness, 0.8);

  Eigen::Isometry3d shifted = Eigen::Isometry3d::Identity();
  shifted.translation() = Eigen::Vector3d(0.03, 0.0, 0.0);
  const Detection wrong = RefineAndVerify(*milk, *context, Method::kPpf, shifted, false);
  EXPECT_LT(wrong.score, 0.3);

  std::mt19937 rng(5);
  const Eigen::Isometry3d near = testing::Perturbation(&rng, 2 * kDeg, 0.003);
  const Detection refined = RefineAndVerify(*milk, *context, Method::kSift, near, true);
  EXPECT_EQ(refined.method, "sift");
  EXPECT_LT(testing::TranslationError(refined.X_BaseItem, Eigen::Isometry3d::Identity()), 0.002);
  EXPECT_LT(testing::RotationErrorRad(refined.X_BaseItem, Eigen::Isometry3d::Identity()), kDeg);
  EXPECT_GT(refined.score, 0.7);
}

TEST_F(MilkEstimatorTest, ChainRunsThePreferredMethodAndAcceptsTheMilk) {
  auto context = Context();
  const DetectionChain chain((*library_)->manifest().config(), MakeEstimators(*library_, context));
  const ChainResult result = chain.Run(Input("milk"));
  ASSERT_TRUE(result.detection.has_value());
  EXPECT_EQ(result.detection->method, "ppf");
  ASSERT_EQ(result.attempts.size(), 1u);  // The test manifest has no fallbacks.
  EXPECT_TRUE(result.attempts[0].accepted);
}

// A budget spent before the estimators start (by the call's pre-processing) ends their
// searches at once: PPF verifies at most its best hypothesis, range templates match nothing.
// One left on the budget's clock, however short next to the search's wall time, leaves the
// search whole.
TEST_F(MilkEstimatorTest, ASpentBudgetStopsTheSearches) {
  auto context = Context();
  PpfEstimator ppf(*library_, context);
  const std::vector<Detection> all = ppf.Estimate(Input("milk"));
  ASSERT_GT(all.size(), 1u);
  EstimatorInput left = Input("milk");
  left.budget_end = kStart + std::chrono::milliseconds(1);
  const std::vector<Detection> whole = ppf.Estimate(left);
  ASSERT_EQ(whole.size(), all.size());
  EXPECT_TRUE(whole.front().X_BaseItem.isApprox(all.front().X_BaseItem, 1e-12));
  EstimatorInput spent = Input("milk");
  spent.budget_end = kStart - std::chrono::milliseconds(1);
  EXPECT_LE(ppf.Estimate(spent).size(), 1u);
  // The milk has no range templates: the estimator says it cannot run (the spent budget's
  // own answer is covered where templates exist).
  RangeTemplateEstimator templates(*library_, context);
  EXPECT_THROW(templates.Estimate(spent), MethodNotApplicableError);
}

TEST_F(MilkEstimatorTest, DeadlineAndForeignScenesStopTheEstimators) {
  auto context = Context();
  context->set_deadline(std::chrono::steady_clock::now() - std::chrono::seconds(1));
  PpfEstimator ppf(*library_, context);
  EXPECT_THROW(ppf.Estimate(Input("milk")), TimeoutError);

  auto fresh = Context();
  PpfEstimator other(*library_, fresh);
  geometry::PointCloud copy = *scene_;
  EstimatorInput input = Input("milk");
  input.scene = &copy;
  EXPECT_THROW(other.Estimate(input), std::invalid_argument);
  EXPECT_THROW(other.Estimate(Input("no_such_item")), NotFoundError);
}

TEST_F(MilkEstimatorTest, AMethodWithoutItsModelSaysWhy) {
  // The milk model has no colours, so no SIFT views, and no templates were asked for: each
  // estimator says it cannot run and why, rather than answering "nothing found".
  auto context = Context();
  SiftPoseEstimator sift(*library_, context);
  try {
    sift.Estimate(Input("milk"));
    ADD_FAILURE() << "SIFT without views ran";
  } catch (const MethodNotApplicableError& e) {
    EXPECT_NE(std::string(e.what()).find("no SIFT views"), std::string::npos) << e.what();
  }
  RangeTemplateEstimator templates(*library_, context);
  try {
    templates.Estimate(Input("milk"));
    ADD_FAILURE() << "templates without templates ran";
  } catch (const MethodNotApplicableError& e) {
    EXPECT_NE(std::string(e.what()).find("no range templates"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace picking::detector
