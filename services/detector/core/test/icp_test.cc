#include "services/detector/core/icp.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "services/detector/core/model.h"
#include "services/detector/core/ppf_detector.h"
#include "services/detector/core/test/ppf_test_util.h"

namespace picking::detector {
namespace {

constexpr double kDeg = M_PI / 180.0;

class IcpMilkTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    const geometry::PointCloud milk = testing::LoadPcd(testing::PointCloudPath("milk.pcd"));
    model_ = new ObjectModel(milk, ObjectModelOptions{});
    scene_ = new PpfScene(PreparePpfScene(
        testing::LoadPcd(testing::PointCloudPath("milk_cartoon_all_small_clorox.pcd")), *model_));
  }
  static void TearDownTestSuite() {
    delete model_;
    delete scene_;
  }
  static ObjectModel* model_;
  static PpfScene* scene_;
};
ObjectModel* IcpMilkTest::model_ = nullptr;
PpfScene* IcpMilkTest::scene_ = nullptr;

// The milk model's true pose in the scene is the identity.
TEST_F(IcpMilkTest, ConvergesFromSmallPerturbations) {
  std::mt19937 rng(42);
  for (IcpLoss loss : {IcpLoss::kLeastSquares, IcpLoss::kHuber, IcpLoss::kTukey}) {
    for (int trial = 0; trial < 3; ++trial) {
      // Rotation about the carton's centroid (it stands about 0.8 m from the camera).
      Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
      for (const auto& p : model_->icp_cloud().points) centroid += p.cast<double>();
      centroid /= static_cast<double>(model_->icp_cloud().size());
      const Eigen::Isometry3d start = Eigen::Translation3d(centroid) *
                                      testing::Perturbation(&rng, 4.0 * kDeg, 0.006) *
                                      Eigen::Translation3d(-centroid);
      IcpOptions options;
      options.loss = loss;
      options.max_correspondence_distance_m = 0.02f;
      options.loss_scale_m = 0.005f;
      options.max_iterations = 60;
      const IcpResult r =
          RunIcp(model_->icp_cloud(), scene_->fine, scene_->fine_tree, start, options);
      const Eigen::Isometry3d identity = Eigen::Isometry3d::Identity();
      EXPECT_LT(testing::TranslationError(r.X_TargetSource, identity), 0.002)
          << "loss " << static_cast<int>(loss) << " trial " << trial;
      EXPECT_LT(testing::RotationErrorRad(r.X_TargetSource, identity), 1.0 * kDeg);
      EXPECT_TRUE(r.converged);
      EXPECT_GT(r.fitness, 0.9);
      EXPECT_LT(r.inlier_rmse_m, 0.003);
      EXPECT_NEAR(r.X_TargetSource.linear().determinant(), 1.0, 1e-9);
    }
  }
}

// The scene's sensor is at its origin: matching only the model points that face it gives the
// same pose, and the figures still count every model point.
TEST_F(IcpMilkTest, MatchingOnlyTheSideFacingTheSensorConvergesAlike) {
  std::mt19937 rng(7);
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& p : model_->icp_cloud().points) centroid += p.cast<double>();
  centroid /= static_cast<double>(model_->icp_cloud().size());
  for (int trial = 0; trial < 3; ++trial) {
    const Eigen::Isometry3d start = Eigen::Translation3d(centroid) *
                                    testing::Perturbation(&rng, 4.0 * kDeg, 0.006) *
                                    Eigen::Translation3d(-centroid);
    IcpOptions options;
    options.max_correspondence_distance_m = 0.02f;
    options.loss_scale_m = 0.005f;
    options.max_iterations = 60;
    const IcpResult all =
        RunIcp(model_->icp_cloud(), scene_->fine, scene_->fine_tree, start, options);
    options.viewpoint = Eigen::Vector3f::Zero();
    options.max_view_angle_rad = static_cast<float>(M_PI / 2.0);
    const IcpResult facing =
        RunIcp(model_->icp_cloud(), scene_->fine, scene_->fine_tree, start, options);
    const Eigen::Isometry3d identity = Eigen::Isometry3d::Identity();
    EXPECT_LT(testing::TranslationError(facing.X_TargetSource, identity), 0.002) << trial;
    EXPECT_LT(testing::RotationErrorRad(facing.X_TargetSource, identity), 1.0 * kDeg) << trial;
    EXPECT_NEAR(facing.fitness, all.fitness, 0.02) << trial;
  }
  // Seen from behind the model, no point faces the sensor: nothing is matched, the pose stays.
  IcpOptions behind;
  behind.viewpoint = Eigen::Vector3f(0.0f, 0.0f, 3.0f);
  behind.max_view_angle_rad = static_cast<float>(M_PI / 2.0);
  const Eigen::Isometry3d start =
      Eigen::Translation3d(0.003, 0.0, 0.0) * Eigen::Isometry3d::Identity();
  const IcpResult none =
      RunIcp(model_->icp_cloud(), scene_->fine, scene_->fine_tree, start, behind);
  EXPECT_EQ(none.iterations, 0);
  EXPECT_TRUE(none.X_TargetSource.isApprox(start));
}

TEST_F(IcpMilkTest, TrimmingAndRejectionLimitCorrespondences) {
  IcpOptions options;
  options.trim_fraction = 1.0f;
  options.max_iterations = 1;
  const IcpResult all = RunIcp(model_->icp_cloud(), scene_->fine, scene_->fine_tree,
                               Eigen::Isometry3d::Identity(), options);
  // Far away start: nothing within the correspondence distance.
  Eigen::Isometry3d far = Eigen::Isometry3d::Identity();
  far.translation() = Eigen::Vector3d(0, 0, 5.0);
  const IcpResult none = RunIcp(model_->icp_cloud(), scene_->fine, scene_->fine_tree, far, options);
  EXPECT_GT(all.fitness, 0.95);
  EXPECT_EQ(none.correspondences, 0);
  EXPECT_EQ(none.fitness, 0.0);
  EXPECT_FALSE(none.converged);
  EXPECT_TRUE(none.X_TargetSource.isApprox(far));
}

// A flat box seen from the front and above: its top and front faces, and none of its ends.
// Nothing holds the box along its length, so the pose keeps its start there, while the
// held directions converge; solving for every direction lets the noise of the scan's normals
// push the box along.
TEST(IcpDegenerateTest, AnUnconstrainedDirectionKeepsItsStart) {
  const double hx = 0.103, hy = 0.068, hz = 0.0165, step = 0.004;
  const auto faces = [&](double x_end) {
    geometry::PointCloud c;
    for (double x = -x_end; x <= x_end; x += step) {
      for (double y = -hy; y <= hy; y += step) {
        c.points.emplace_back(x, y, hz);
        c.normals.emplace_back(0, 0, 1);
      }
      for (double z = -hz; z <= hz; z += step) {
        c.points.emplace_back(x, -hy, z);
        c.normals.emplace_back(0, -1, 0);
      }
    }
    c.width = static_cast<std::uint32_t>(c.points.size());
    c.height = 1;
    return c;
  };
  const geometry::PointCloud model = faces(hx);
  // The scan loses a few millimetres at each end, and its normals are noisy.
  geometry::PointCloud scan = faces(hx - 0.007);
  std::mt19937 rng(7);
  std::normal_distribution<float> noise(0.0f, 0.003f);
  for (auto& n : scan.normals) n = (n + Eigen::Vector3f(noise(rng), noise(rng), 0.0f)).normalized();
  const KdTree tree(scan.points);
  Eigen::Isometry3d start = Eigen::Isometry3d::Identity();
  start.translation() = Eigen::Vector3d(0.004, 0.003, 0.003);
  IcpOptions options;
  options.max_correspondence_distance_m = 0.01f;
  const IcpResult held = RunIcp(model, scan, tree, start, options);
  EXPECT_NEAR(held.X_TargetSource.translation().x(), 0.004, 2e-4);
  EXPECT_NEAR(held.X_TargetSource.translation().y(), 0.0, 5e-4);
  EXPECT_NEAR(held.X_TargetSource.translation().z(), 0.0, 5e-4);
  EXPECT_LT(Eigen::AngleAxisd(held.X_TargetSource.linear()).angle(), 0.2 * kDeg);
  options.min_constraint_ratio = 0.0;
  const IcpResult free = RunIcp(model, scan, tree, start, options);
  EXPECT_GT(std::abs(free.X_TargetSource.translation().x() - 0.004), 5e-4);
}

TEST_F(IcpMilkTest, RejectsBadInput) {
  const KdTree& tree = scene_->fine_tree;
  EXPECT_THROW(RunIcp(geometry::PointCloud{}, scene_->fine, tree, Eigen::Isometry3d::Identity()),
               std::invalid_argument);
  geometry::PointCloud no_normals = scene_->fine;
  no_normals.normals.clear();
  EXPECT_THROW(RunIcp(model_->icp_cloud(), no_normals, tree, Eigen::Isometry3d::Identity()),
               std::invalid_argument);
  // Each option out of its range on its own.
  std::vector<IcpOptions> bad(4);
  bad[0].trim_fraction = 0.0f;
  bad[1].max_view_angle_rad = 0.0f;
  bad[2].viewpoint = Eigen::Vector3f::Constant(std::nanf(""));
  bad[3].min_constraint_ratio = 1.0;
  for (std::size_t k = 0; k < bad.size(); ++k) {
    EXPECT_THROW(
        RunIcp(model_->icp_cloud(), scene_->fine, tree, Eigen::Isometry3d::Identity(), bad[k]),
        std::invalid_argument)
        << k;
  }
  const KdTree other(model_->icp_cloud().points);
  EXPECT_THROW(RunIcp(model_->icp_cloud(), scene_->fine, other, Eigen::Isometry3d::Identity()),
               std::invalid_argument);
}

}  // namespace
}  // namespace picking::detector
