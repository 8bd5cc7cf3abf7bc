#pragma once

#include <Eigen/Geometry>

#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "libs/geometry/point_cloud.h"
#include "services/detector/core/detection.h"

namespace picking::detector {

/// An 8-bit grey image, row-major.
struct GrayImage {
  int width = 0;
  int height = 0;
  std::vector<std::uint8_t> pixels;

  bool empty() const { return pixels.empty(); }
};

/// Reads an image file as grey levels. Throws std::runtime_error naming the file.
GrayImage LoadGrayImage(const std::string& path);

/// The intensity channel of an organised cloud as an image (intensity 0-1 -> 0-255).
/// Throws std::invalid_argument when the cloud is not organised or has no intensities.
GrayImage IntensityImage(const geometry::PointCloud& cloud);

struct SiftOptions {
  int max_features = 0;   ///< 0: all keypoints cv::SIFT finds.
  double ratio = 0.75;    ///< Lowe's ratio test: best / second best distance below this.
  bool use_flann = true;  ///< FLANN k-d trees; false: brute force L2.
};

/// A keypoint correspondence between image a and image b, pixel coordinates.
struct FeatureMatch {
  Eigen::Vector2d p_a = Eigen::Vector2d::Zero();
  Eigen::Vector2d p_b = Eigen::Vector2d::Zero();
  float distance = 0.0f;  ///< Descriptor distance.
};

/// SIFT keypoints of both images matched with the ratio test. Throws std::invalid_argument
/// on an empty image or ratio outside (0, 1].
std::vector<FeatureMatch> MatchSift(const GrayImage& a, const GrayImage& b,
                                    const SiftOptions& options = {});

struct HomographyResult {
  bool found = false;
  Eigen::Matrix3d H_ba = Eigen::Matrix3d::Identity();  ///< p_b ~ H_ba * p_a.
  std::vector<int> inliers;                            ///< Indices into the matches.
};

/// RANSAC homography (cv::findHomography) of at least four matches.
HomographyResult EstimateHomography(const std::vector<FeatureMatch>& matches,
                                    double reprojection_threshold_px = 3.0);

/// A textured view of an item: an image and, per pixel, the 3D model point it shows
/// (item frame, metres; NaN where the pixel does not show the item).
struct SiftView {
  std::string name;
  GrayImage image;
  std::vector<Eigen::Vector3f> p_ItemPixel;  ///< width * height, row-major.
};

/// A view of a flat textured face: pixel (u, v) shows the point
/// X_ItemFace * ((u - (width-1)/2) * metres_per_pixel, (v - (height-1)/2) * metres_per_pixel, 0).
/// Throws std::invalid_argument on an empty image or metres_per_pixel <= 0.
SiftView PlanarView(std::string name, GrayImage image, const Eigen::Isometry3d& X_ItemFace,
                    double metres_per_pixel);

/// The SIFT features of an item's views that have a known 3D model point.
class SiftModel final {
 public:
  /// Throws std::invalid_argument when a view's sizes are inconsistent or no view has a
  /// feature with a 3D point.
  explicit SiftModel(std::vector<SiftView> views, const SiftOptions& options = {});
  ~SiftModel();
  SiftModel(SiftModel&&) noexcept;
  SiftModel& operator=(SiftModel&&) noexcept;

  std::size_t num_views() const;
  std::size_t num_features() const;  ///< Over all views.
  const SiftOptions& options() const { return options_; }

  struct Impl;
  const Impl& impl() const { return *impl_; }

 private:
  SiftOptions options_;
  std::unique_ptr<Impl> impl_;
};

struct SiftPoseOptions {
  double ratio = 0.75;                ///< Lowe's ratio for scene-to-view matches.
  double inlier_threshold_m = 0.005;  ///< 3D RANSAC inlier distance.
  int ransac_iterations = 2000;
  int min_inliers = 8;                     ///< Fewer inliers: no detection.
  double reprojection_threshold_px = 4.0;  ///< EPnP RANSAC / 2D checks.
  std::uint32_t seed = 7;
};

struct SiftPoseResult {
  bool found = false;
  Eigen::Isometry3d X_BaseItem = Eigen::Isometry3d::Identity();
  int view_index = -1;
  std::size_t num_matches = 0;  ///< Ratio-test matches to the best view.
  std::size_t num_with_3d = 0;  ///< Of which the scene pixel has a measured point.
  std::size_t num_inliers = 0;  ///< Matches consistent with the pose (3D or 2D).
  double inlier_rmse_m = 0.0;   ///< Of the 3D inliers (0 for a pure EPnP pose).
  bool used_epnp = false;       ///< Pose from EPnP because too few 3D points matched.
  /// Scene pixel and model point of each inlier.
  std::vector<Eigen::Vector2d> inlier_pixels;
  std::vector<Eigen::Vector3d> inlier_model_points;
};

/// Pose of the item in an organised scene with intensities (points in the base frame).
/// Scene SIFT features are matched to each view; where the scene pixel has a measured point,
/// the pose comes from 3D-3D RANSAC (3-point Kabsch hypotheses, least-squares refit on the
/// inliers) and matches inconsistent with it are rejected; if too few such points exist and
/// `camera` is given, from EPnP RANSAC on the 2D-3D matches. The best view (most inliers)
/// wins. Throws std::invalid_argument when the scene is not organised or has no intensities.
SiftPoseResult EstimateSiftPose(const SiftModel& model, const geometry::PointCloud& scene,
                                const Eigen::Isometry3d& X_BaseSensor,
                                const std::optional<PinholeCamera>& camera,
                                const SiftPoseOptions& options = {});

/// Estimator adapter: Detection.score = inlier fraction of the best view's matches.
class SiftEstimator final : public Estimator {
 public:
  /// Throws std::invalid_argument on a null model.
  SiftEstimator(std::map<std::string, std::shared_ptr<const SiftModel>> models,
                SiftPoseOptions options = {});
  Method method() const override { return Method::kSift; }
  /// Empty when the item has no SIFT model or nothing was found.
  std::vector<Detection> Estimate(const EstimatorInput& input) override;

 private:
  std::map<std::string, std::shared_ptr<const SiftModel>> models_;
  SiftPoseOptions options_;
};

}  // namespace picking::detector
