#include "services/detector/core/sift.h"

#include <gtest/gtest.h>

#include <Eigen/SVD>

#include <cmath>
#include <fstream>
#include <limits>
#include <sstream>
#include <string>

namespace picking::detector {
namespace {

const std::string kImages = std::string(PICKING_TEST_DATA_DIR) + "/images/";

// Reads the 3x3 matrix of an OpenCV XML file (the <data> block).
Eigen::Matrix3d ReadOpenCvMatrix(const std::string& path) {
  std::ifstream in(path);
  std::stringstream buffer;
  buffer << in.rdbuf();
  const std::string text = buffer.str();
  const auto begin = text.find("<data>");
  const auto end = text.find("</data>");
  EXPECT_NE(begin, std::string::npos);
  std::istringstream numbers(text.substr(begin + 6, end - begin - 6));
  Eigen::Matrix3d H;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) numbers >> H(r, c);
  return H;
}

Eigen::Vector2d Apply(const Eigen::Matrix3d& H, const Eigen::Vector2d& p) {
  return (H * p.homogeneous()).hnormalized();
}

TEST(SiftMatchTest, GraffitiInliersAgreeWithTrueHomography) {
  const GrayImage a = LoadGrayImage(kImages + "graf1.png");
  const GrayImage b = LoadGrayImage(kImages + "graf3.png");
  const Eigen::Matrix3d H_true = ReadOpenCvMatrix(kImages + "H1to3p.xml");
  const std::vector<FeatureMatch> matches = MatchSift(a, b);
  ASSERT_GT(matches.size(), 50u);
  // A tight RANSAC threshold: at 2 px and above the consensus can drift to a wrong
  // homography that a few hundred matches on the repetitive graffiti also support.
  const HomographyResult h = EstimateHomography(matches, 1.5);
  ASSERT_TRUE(h.found);
  ASSERT_GE(h.inliers.size(), 150u);
  int agree = 0;
  for (int i : h.inliers)
    if ((Apply(H_true, matches[i].p_a) - matches[i].p_b).norm() <= 3.0) ++agree;
  EXPECT_EQ(agree, static_cast<int>(h.inliers.size()))
      << agree << " of " << h.inliers.size() << " inliers within 3 px of the true homography";
  // The estimated homography maps the image corners close to the true one.
  for (const Eigen::Vector2d& corner :
       {Eigen::Vector2d(0, 0), Eigen::Vector2d(a.width - 1, 0), Eigen::Vector2d(0, a.height - 1),
        Eigen::Vector2d(a.width - 1, a.height - 1)})
    EXPECT_LT((Apply(H_true, corner) - Apply(h.H_ba, corner)).norm(), 10.0);
  // Brute-force matching finds the same geometry.
  SiftOptions bf;
  bf.use_flann = false;
  const auto bf_matches = MatchSift(a, b, bf);
  const HomographyResult h_bf = EstimateHomography(bf_matches, 1.5);
  ASSERT_TRUE(h_bf.found);
  EXPECT_LT((Apply(H_true, {400, 300}) - Apply(h_bf.H_ba, {400, 300})).norm(), 5.0);
}

TEST(SiftMatchTest, RejectsBadInput) {
  EXPECT_THROW(LoadGrayImage(kImages + "missing.png"), std::runtime_error);
  SiftOptions bad;
  bad.ratio = 0.0;
  const GrayImage a = LoadGrayImage(kImages + "box.png");
  EXPECT_THROW(MatchSift(a, a, bad), std::invalid_argument);
  EXPECT_THROW(MatchSift(GrayImage{}, a), std::invalid_argument);
}

// box.png lies flat in the item's xy plane at kMetresPerPixel; box_in_scene.png is the
// sensor's intensity image. The true pose comes from the image homography box -> scene
// and the camera intrinsics; every scene pixel gets the 3D point where its ray meets that
// plane, so the scene has real texture and known 3D.
class SiftPoseTest : public ::testing::Test {
 protected:
  static constexpr double kMetresPerPixel = 0.0005;

  void SetUp() override {
    box_ = LoadGrayImage(kImages + "box.png");
    scene_image_ = LoadGrayImage(kImages + "box_in_scene.png");
    camera_ = PinholeCamera(scene_image_.width, scene_image_.height, 500.0, 500.0,
                            0.5 * (scene_image_.width - 1), 0.5 * (scene_image_.height - 1));

    const HomographyResult h = EstimateHomography(MatchSift(box_, scene_image_), 3.0);
    ASSERT_TRUE(h.found);
    ASSERT_GE(h.inliers.size(), 20u);
    // Item plane (x, y, 1) -> box pixel -> scene pixel.
    Eigen::Matrix3d A_inv;  // item plane -> box pixel
    A_inv << 1.0 / kMetresPerPixel, 0, 0.5 * (box_.width - 1), 0, 1.0 / kMetresPerPixel,
        0.5 * (box_.height - 1), 0, 0, 1;
    Eigen::Matrix3d K;
    K << camera_.fx(), 0, camera_.cx(), 0, camera_.fy(), camera_.cy(), 0, 0, 1;
    Eigen::Matrix3d M = K.inverse() * h.H_ba * A_inv;
    double lambda = 2.0 / (M.col(0).norm() + M.col(1).norm());
    if (M(2, 2) * lambda < 0.0) lambda = -lambda;
    Eigen::Matrix3d R;
    R << lambda * M.col(0), lambda * M.col(1), (lambda * M.col(0)).cross(lambda * M.col(1));
    Eigen::JacobiSVD<Eigen::Matrix3d> svd(R, Eigen::ComputeFullU | Eigen::ComputeFullV);
    R = svd.matrixU() * svd.matrixV().transpose();
    X_SensorItem_true_.setIdentity();
    X_SensorItem_true_.linear() = R;
    X_SensorItem_true_.translation() = lambda * M.col(2);

    X_BaseSensor_ = Eigen::Translation3d(0.3, -0.2, 1.1) *
                    Eigen::AngleAxisd(2.6, Eigen::Vector3d(0.2, 1.0, 0.1).normalized());
    scene_.width = camera_.width();
    scene_.height = camera_.height();
    const Eigen::Vector3d n = R.col(2);
    const Eigen::Vector3d t = X_SensorItem_true_.translation();
    for (int v = 0; v < camera_.height(); ++v) {
      for (int u = 0; u < camera_.width(); ++u) {
        const Eigen::Vector3d d((u - camera_.cx()) / camera_.fx(),
                                (v - camera_.cy()) / camera_.fy(), 1.0);
        const Eigen::Vector3d p_Sensor = d * (n.dot(t) / n.dot(d));
        scene_.points.push_back((X_BaseSensor_ * p_Sensor).cast<float>());
        scene_.intensities.push_back(
            scene_image_.pixels[static_cast<std::size_t>(v) * camera_.width() + u] / 255.0f);
      }
    }
    model_ = std::make_shared<SiftModel>(std::vector<SiftView>{
        PlanarView("front", box_, Eigen::Isometry3d::Identity(), kMetresPerPixel)});
  }

  void ExpectNearTruth(const Eigen::Isometry3d& X_BaseItem, double max_translation_m,
                       double max_angle_rad) const {
    const Eigen::Isometry3d X_true = X_BaseSensor_ * X_SensorItem_true_;
    EXPECT_LT((X_BaseItem.translation() - X_true.translation()).norm(), max_translation_m);
    const double angle =
        Eigen::AngleAxisd(X_BaseItem.linear().transpose() * X_true.linear()).angle();
    EXPECT_LT(angle, max_angle_rad);
  }

  GrayImage box_, scene_image_;
  PinholeCamera camera_{1, 1, 1.0, 1.0, 0.0, 0.0};  // Set in SetUp.
  Eigen::Isometry3d X_SensorItem_true_, X_BaseSensor_;
  geometry::PointCloud scene_;
  std::shared_ptr<SiftModel> model_;
};

TEST_F(SiftPoseTest, RecoversPoseFromMeasured3dPoints) {
  ASSERT_GT(X_SensorItem_true_.translation().z(), 0.2);
  const SiftPoseResult r = EstimateSiftPose(*model_, scene_, X_BaseSensor_, camera_);
  ASSERT_TRUE(r.found);
  EXPECT_FALSE(r.used_epnp);
  EXPECT_GE(r.num_inliers, 20u);
  EXPECT_LT(r.inlier_rmse_m, 0.005);
  ExpectNearTruth(r.X_BaseItem, 0.005, 2.0 * M_PI / 180.0);
  // Every accepted match is consistent with the true pose.
  const Eigen::Isometry3d X_true = X_BaseSensor_ * X_SensorItem_true_;
  for (std::size_t i = 0; i < r.inlier_pixels.size(); ++i) {
    const Eigen::Vector3d p = X_BaseSensor_.inverse() * X_true * r.inlier_model_points[i];
    const Eigen::Vector2d px(camera_.fx() * p.x() / p.z() + camera_.cx(),
                             camera_.fy() * p.y() / p.z() + camera_.cy());
    EXPECT_LT((px - r.inlier_pixels[i]).norm(), 6.0);
  }
}

TEST_F(SiftPoseTest, FallsBackToEpnpWhen3dPointsAreMissing) {
  for (auto& p : scene_.points) p.setConstant(std::numeric_limits<float>::quiet_NaN());
  const SiftPoseResult r = EstimateSiftPose(*model_, scene_, X_BaseSensor_, camera_);
  ASSERT_TRUE(r.found);
  EXPECT_TRUE(r.used_epnp);
  EXPECT_GE(r.num_inliers, 20u);
  // EPnP on a single plane is less certain about the tilt than the 3D path.
  ExpectNearTruth(r.X_BaseItem, 0.02, 6.0 * M_PI / 180.0);
  // Without intrinsics there is nothing to fall back on.
  EXPECT_FALSE(EstimateSiftPose(*model_, scene_, X_BaseSensor_, std::nullopt).found);
}

TEST_F(SiftPoseTest, MixedMissingPointsStillUse3d) {
  // Every second row unmeasured.
  for (int v = 0; v < camera_.height(); v += 2)
    for (int u = 0; u < camera_.width(); ++u)
      scene_.points[static_cast<std::size_t>(v) * camera_.width() + u].setConstant(
          std::numeric_limits<float>::quiet_NaN());
  const SiftPoseResult r = EstimateSiftPose(*model_, scene_, X_BaseSensor_, camera_);
  ASSERT_TRUE(r.found);
  EXPECT_FALSE(r.used_epnp);
  EXPECT_GT(r.num_inliers, r.num_with_3d / 2);
  ExpectNearTruth(r.X_BaseItem, 0.005, 2.0 * M_PI / 180.0);
}

TEST_F(SiftPoseTest, AbsentItemIsNotFound) {
  const GrayImage other = LoadGrayImage(kImages + "graf1.png");
  geometry::PointCloud scene = scene_;
  for (int v = 0; v < camera_.height(); ++v)
    for (int u = 0; u < camera_.width(); ++u)
      scene.intensities[static_cast<std::size_t>(v) * camera_.width() + u] =
          other.pixels[static_cast<std::size_t>(v) * other.width + u] / 255.0f;
  EXPECT_FALSE(EstimateSiftPose(*model_, scene, X_BaseSensor_, camera_).found);
}

TEST_F(SiftPoseTest, EstimatorAdapter) {
  SiftEstimator estimator({{"box", model_}});
  EstimatorInput input{"box", &scene_, X_BaseSensor_, camera_};
  const auto detections = estimator.Estimate(input);
  ASSERT_EQ(detections.size(), 1u);
  EXPECT_EQ(detections[0].method, "sift");
  EXPECT_GT(detections[0].score, 0.3);
  ExpectNearTruth(detections[0].X_BaseItem, 0.005, 2.0 * M_PI / 180.0);
  input.item = "unknown";
  EXPECT_TRUE(estimator.Estimate(input).empty());
  geometry::PointCloud unorganised = scene_;
  unorganised.height = 1;
  unorganised.width = static_cast<std::uint32_t>(unorganised.size());
  EXPECT_THROW(EstimateSiftPose(*model_, unorganised, X_BaseSensor_, camera_),
               std::invalid_argument);
}

}  // namespace
}  // namespace picking::detector
