#include "services/detector/core/sift.h"

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/core/eigen.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <optional>
#include <random>
#include <stdexcept>

namespace picking::detector {

struct SiftModel::Impl {
  struct View {
    std::vector<cv::KeyPoint> keypoints;
    std::vector<Eigen::Vector3d> p_ItemFeature;  // per keypoint
    cv::Mat descriptors;                         // CV_32F, one row per keypoint
  };
  std::vector<View> views;
};

namespace {

cv::Mat ToMat(const GrayImage& image) {
  if (image.empty() || image.width <= 0 || image.height <= 0 ||
      image.pixels.size() != static_cast<std::size_t>(image.width) * image.height)
    throw std::invalid_argument("GrayImage is empty or its size does not match its pixels");
  return cv::Mat(image.height, image.width, CV_8UC1,
                 const_cast<std::uint8_t*>(image.pixels.data()));
}

// SIFT keypoints (in image coordinates) and descriptors of `image`, or of its `roi` only.
void Detect(const GrayImage& image, int max_features, std::vector<cv::KeyPoint>* keypoints,
            cv::Mat* descriptors, const std::optional<cv::Rect>& roi = std::nullopt) {
  auto sift = cv::SIFT::create(max_features);
  const cv::Mat full = ToMat(image);
  sift->detectAndCompute(roi ? full(*roi) : full, cv::noArray(), *keypoints, *descriptors);
  if (!roi) return;
  for (cv::KeyPoint& k : *keypoints) {
    k.pt.x += static_cast<float>(roi->x);
    k.pt.y += static_cast<float>(roi->y);
  }
}

// Ratio-test matches from `query` rows to `train` rows: (query index, train index, distance).
std::vector<cv::DMatch> RatioMatches(const cv::Mat& query, const cv::Mat& train, double ratio,
                                     bool use_flann) {
  std::vector<cv::DMatch> good;
  if (query.rows == 0 || train.rows < 2) return good;
  std::vector<std::vector<cv::DMatch>> knn;
  if (use_flann) {
    // Deterministic: FLANN's randomised trees are seeded by cv::theRNG.
    cv::theRNG().state = 0x12345678;
    cv::FlannBasedMatcher matcher(cv::makePtr<cv::flann::KDTreeIndexParams>(4),
                                  cv::makePtr<cv::flann::SearchParams>(64));
    matcher.knnMatch(query, train, knn, 2);
  } else {
    cv::BFMatcher matcher(cv::NORM_L2);
    matcher.knnMatch(query, train, knn, 2);
  }
  for (const auto& pair : knn)
    if (pair.size() == 2 && pair[0].distance < ratio * pair[1].distance) good.push_back(pair[0]);
  return good;
}

// Least-squares rigid transform with dst ~ R * src + t (Kabsch / Umeyama without scale).
bool Kabsch(const std::vector<Eigen::Vector3d>& src, const std::vector<Eigen::Vector3d>& dst,
            Eigen::Isometry3d* X) {
  if (src.size() < 3) return false;
  Eigen::Matrix3Xd a(3, src.size()), b(3, dst.size());
  for (std::size_t i = 0; i < src.size(); ++i) {
    a.col(i) = src[i];
    b.col(i) = dst[i];
  }
  const Eigen::Matrix4d T = Eigen::umeyama(a, b, false);
  if (!T.allFinite()) return false;
  X->matrix() = T;
  return true;
}

}  // namespace

GrayImage LoadGrayImage(const std::string& path) {
  const cv::Mat image = cv::imread(path, cv::IMREAD_GRAYSCALE);
  if (image.empty()) throw std::runtime_error(path + ": cannot read image");
  GrayImage out;
  out.width = image.cols;
  out.height = image.rows;
  out.pixels.resize(static_cast<std::size_t>(image.cols) * image.rows);
  for (int v = 0; v < image.rows; ++v)
    std::copy(image.ptr<std::uint8_t>(v), image.ptr<std::uint8_t>(v) + image.cols,
              out.pixels.begin() + static_cast<std::ptrdiff_t>(v) * image.cols);
  return out;
}

GrayImage IntensityImage(const geometry::PointCloud& cloud) {
  if (!cloud.is_organized() || static_cast<std::size_t>(cloud.width) * cloud.height != cloud.size())
    throw std::invalid_argument("IntensityImage: the cloud is not organised");
  if (cloud.intensities.size() != cloud.size())
    throw std::invalid_argument("IntensityImage: the cloud has no intensity per point");
  GrayImage out;
  out.width = static_cast<int>(cloud.width);
  out.height = static_cast<int>(cloud.height);
  out.pixels.resize(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const float v = cloud.intensities[i];
    out.pixels[i] = std::isfinite(v)
                        ? static_cast<std::uint8_t>(std::lround(255.0f * std::clamp(v, 0.0f, 1.0f)))
                        : 0;
  }
  return out;
}

std::vector<FeatureMatch> MatchSift(const GrayImage& a, const GrayImage& b,
                                    const SiftOptions& options) {
  if (!(options.ratio > 0.0 && options.ratio <= 1.0))
    throw std::invalid_argument("SiftOptions.ratio must be in (0, 1]");
  std::vector<cv::KeyPoint> ka, kb;
  cv::Mat da, db;
  Detect(a, options.max_features, &ka, &da);
  Detect(b, options.max_features, &kb, &db);
  std::vector<FeatureMatch> out;
  for (const cv::DMatch& m : RatioMatches(da, db, options.ratio, options.use_flann)) {
    FeatureMatch f;
    f.p_a = Eigen::Vector2d(ka[m.queryIdx].pt.x, ka[m.queryIdx].pt.y);
    f.p_b = Eigen::Vector2d(kb[m.trainIdx].pt.x, kb[m.trainIdx].pt.y);
    f.distance = m.distance;
    out.push_back(f);
  }
  return out;
}

HomographyResult EstimateHomography(const std::vector<FeatureMatch>& matches,
                                    double reprojection_threshold_px) {
  HomographyResult result;
  if (matches.size() < 4) return result;
  std::vector<cv::Point2f> a, b;
  for (const auto& m : matches) {
    a.emplace_back(static_cast<float>(m.p_a.x()), static_cast<float>(m.p_a.y()));
    b.emplace_back(static_cast<float>(m.p_b.x()), static_cast<float>(m.p_b.y()));
  }
  cv::theRNG().state = 0x12345678;
  std::vector<unsigned char> mask;
  const cv::Mat H =
      cv::findHomography(a, b, cv::RANSAC, reprojection_threshold_px, mask, 5000, 0.999);
  if (H.empty()) return result;
  cv::cv2eigen(H, result.H_ba);
  for (std::size_t i = 0; i < mask.size(); ++i)
    if (mask[i]) result.inliers.push_back(static_cast<int>(i));
  result.found = true;
  return result;
}

SiftView PlanarView(std::string name, GrayImage image, const Eigen::Isometry3d& X_ItemFace,
                    double metres_per_pixel) {
  ToMat(image);  // validates
  if (!(metres_per_pixel > 0.0))
    throw std::invalid_argument("PlanarView: metres_per_pixel must be > 0");
  SiftView view;
  view.name = std::move(name);
  view.p_ItemPixel.resize(image.pixels.size());
  const double cu = 0.5 * (image.width - 1), cv_ = 0.5 * (image.height - 1);
  for (int v = 0; v < image.height; ++v)
    for (int u = 0; u < image.width; ++u)
      view.p_ItemPixel[static_cast<std::size_t>(v) * image.width + u] =
          (X_ItemFace *
           Eigen::Vector3d((u - cu) * metres_per_pixel, (v - cv_) * metres_per_pixel, 0.0))
              .cast<float>();
  view.image = std::move(image);
  return view;
}

SiftModel::SiftModel(std::vector<SiftView> views, const SiftOptions& options)
    : options_(options), impl_(std::make_unique<Impl>()) {
  for (std::size_t k = 0; k < views.size(); ++k) {
    const SiftView& view = views[k];
    if (view.p_ItemPixel.size() != view.image.pixels.size())
      throw std::invalid_argument("SiftModel: view " + std::to_string(k) + " ('" + view.name +
                                  "') has " + std::to_string(view.p_ItemPixel.size()) +
                                  " 3D points for " + std::to_string(view.image.pixels.size()) +
                                  " pixels");
    std::vector<cv::KeyPoint> keypoints;
    cv::Mat descriptors;
    Detect(view.image, options.max_features, &keypoints, &descriptors);
    Impl::View out;
    for (std::size_t i = 0; i < keypoints.size(); ++i) {
      const int u = static_cast<int>(std::lround(keypoints[i].pt.x));
      const int v = static_cast<int>(std::lround(keypoints[i].pt.y));
      if (u < 0 || v < 0 || u >= view.image.width || v >= view.image.height) continue;
      const Eigen::Vector3f& p =
          view.p_ItemPixel[static_cast<std::size_t>(v) * view.image.width + u];
      if (!p.allFinite()) continue;
      out.keypoints.push_back(keypoints[i]);
      out.p_ItemFeature.push_back(p.cast<double>());
      out.descriptors.push_back(descriptors.row(static_cast<int>(i)));
    }
    impl_->views.push_back(std::move(out));
  }
  if (num_features() == 0)
    throw std::invalid_argument("SiftModel: no view has a feature with a 3D model point");
}

SiftModel::~SiftModel() = default;
SiftModel::SiftModel(SiftModel&&) noexcept = default;
SiftModel& SiftModel::operator=(SiftModel&&) noexcept = default;

std::size_t SiftModel::num_views() const { return impl_->views.size(); }

std::size_t SiftModel::num_features() const {
  std::size_t n = 0;
  for (const auto& v : impl_->views) n += v.keypoints.size();
  return n;
}

namespace {

// ---- Stages of EstimateSiftPose ------------------------------------------------------------

// The scene's SIFT features (keypoints in full-image pixel coordinates) and the image size.
struct SceneFeatures {
  int width = 0;   // px
  int height = 0;  // px
  std::vector<cv::KeyPoint> keypoints;
  cv::Mat descriptors;  // CV_32F, one row per keypoint
};

// Where scene features are sought: around the scan's finite points only (the whole image when
// it has none: the pose then comes from EPnP). A scene cropped to a bin keeps its organisation
// with NaN elsewhere, and the rest of the image would cost most of the detection time.
cv::Rect FinitePointsRoi(const geometry::PointCloud& scene, const GrayImage& image) {
  int u0 = image.width, v0 = image.height, u1 = -1, v1 = -1;
  for (int v = 0; v < image.height; ++v) {
    for (int u = 0; u < image.width; ++u) {
      if (!scene.points[static_cast<std::size_t>(v) * image.width + u].allFinite()) continue;
      u0 = std::min(u0, u);
      u1 = std::max(u1, u);
      v0 = std::min(v0, v);
      v1 = std::max(v1, v);
    }
  }
  if (u1 < u0 || v1 < v0) {
    u0 = v0 = 0;
    u1 = image.width - 1;
    v1 = image.height - 1;
  }
  constexpr int kPad = 16;  // Room for the descriptor windows of features on the edge.
  return cv::Rect(std::max(0, u0 - kPad), std::max(0, v0 - kPad),
                  std::min(image.width, u1 + kPad + 1) - std::max(0, u0 - kPad),
                  std::min(image.height, v1 + kPad + 1) - std::max(0, v0 - kPad));
}

// SIFT features of the scene's intensity `image`, within FinitePointsRoi.
SceneFeatures DetectSceneFeatures(const geometry::PointCloud& scene, const GrayImage& image,
                                  int max_features) {
  SceneFeatures features;
  features.width = image.width;
  features.height = image.height;
  const cv::Rect roi = FinitePointsRoi(scene, image);
  Detect(image, max_features, &features.keypoints, &features.descriptors, roi);
  return features;
}

// Scene-to-view matches as parallel point lists. Every match gives a model point (item frame,
// metres) and a scene keypoint (pixels); those whose scene pixel has a measured point are also
// in the *_3d lists, with that point (base frame, metres).
struct Correspondences {
  std::vector<Eigen::Vector3d> p_ItemModel;
  std::vector<Eigen::Vector2d> px_Scene;
  std::vector<Eigen::Vector3d> p_ItemModel_3d;
  std::vector<Eigen::Vector3d> p_BaseScene_3d;
  std::vector<Eigen::Vector2d> px_Scene_3d;
};

// Splits the matches into those with a measured scene point and 2D-only ones.
Correspondences SplitMatches(const std::vector<cv::DMatch>& matches, const SceneFeatures& features,
                             const SiftModel::Impl::View& view, const geometry::PointCloud& scene) {
  Correspondences corr;
  for (const cv::DMatch& m : matches) {
    const cv::Point2f& pt = features.keypoints[m.queryIdx].pt;
    const int u = static_cast<int>(std::lround(pt.x)), v = static_cast<int>(std::lround(pt.y));
    const Eigen::Vector3d& p_ItemFeature = view.p_ItemFeature[m.trainIdx];
    corr.p_ItemModel.push_back(p_ItemFeature);
    corr.px_Scene.emplace_back(pt.x, pt.y);
    if (u < 0 || v < 0 || u >= features.width || v >= features.height) continue;
    const Eigen::Vector3f& p_BasePoint =
        scene.points[static_cast<std::size_t>(v) * features.width + u];
    if (!p_BasePoint.allFinite()) continue;
    corr.p_ItemModel_3d.push_back(p_ItemFeature);
    corr.p_BaseScene_3d.push_back(p_BasePoint.cast<double>());
    corr.px_Scene_3d.emplace_back(pt.x, pt.y);
  }
  return corr;
}

// A rigid pose hypothesis and the matches it explains (indices into the *_3d lists).
struct RigidFit {
  Eigen::Isometry3d X_BaseItem = Eigen::Isometry3d::Identity();
  std::vector<int> inliers;
};

// Indices of the 3D matches whose model point X_BaseItem maps within sqrt(threshold_sq_m2)
// of their scene point.
std::vector<int> InliersOf(const Eigen::Isometry3d& X_BaseItem, const Correspondences& corr,
                           double threshold_sq_m2) {
  std::vector<int> in;
  for (std::size_t i = 0; i < corr.p_ItemModel_3d.size(); ++i)
    if ((X_BaseItem * corr.p_ItemModel_3d[i] - corr.p_BaseScene_3d[i]).squaredNorm() <=
        threshold_sq_m2)
      in.push_back(static_cast<int>(i));
  return in;
}

// RANSAC over 3-point Kabsch hypotheses (seeded by options.seed): the hypothesis with the most
// inliers. Needs at least 3 3D matches.
RigidFit SampleRigidFit(const Correspondences& corr, const SiftPoseOptions& options,
                        double threshold_sq_m2) {
  const std::vector<Eigen::Vector3d>& p_Item = corr.p_ItemModel_3d;
  const std::vector<Eigen::Vector3d>& p_Base = corr.p_BaseScene_3d;
  // Whether the model and scene distances between 3D matches i and j agree.
  const auto consistent = [&](std::size_t i, std::size_t j) {
    return std::abs((p_Item[i] - p_Item[j]).norm() - (p_Base[i] - p_Base[j]).norm()) <
           2.0 * options.inlier_threshold_m;
  };
  RigidFit best;
  std::mt19937 rng(options.seed);
  std::uniform_int_distribution<std::size_t> pick(0, p_Item.size() - 1);
  for (int it = 0; it < options.ransac_iterations; ++it) {
    const std::size_t a = pick(rng), b = pick(rng), c = pick(rng);
    if (a == b || b == c || a == c) continue;
    // Reject degenerate samples and ones whose model and scene distances disagree.
    if (!consistent(a, b) || !consistent(b, c) || !consistent(a, c)) continue;
    if ((p_Item[b] - p_Item[a]).cross(p_Item[c] - p_Item[a]).norm() < 1e-8) continue;
    Eigen::Isometry3d X;
    if (!Kabsch({p_Item[a], p_Item[b], p_Item[c]}, {p_Base[a], p_Base[b], p_Base[c]}, &X)) continue;
    std::vector<int> in = InliersOf(X, corr, threshold_sq_m2);
    if (in.size() > best.inliers.size()) {
      best.inliers = std::move(in);
      best.X_BaseItem = X;
    }
  }
  return best;
}

// Least-squares refit on the inliers until the set is stable (at most 5 rounds; stops early
// when a refit would lose inliers).
void RefineRigidFit(const Correspondences& corr, double threshold_sq_m2, RigidFit* fit) {
  for (int refit = 0; refit < 5 && fit->inliers.size() >= 3; ++refit) {
    std::vector<Eigen::Vector3d> p_Item, p_Base;
    for (int i : fit->inliers) {
      p_Item.push_back(corr.p_ItemModel_3d[i]);
      p_Base.push_back(corr.p_BaseScene_3d[i]);
    }
    Eigen::Isometry3d X;
    if (!Kabsch(p_Item, p_Base, &X)) break;
    std::vector<int> in = InliersOf(X, corr, threshold_sq_m2);
    if (in.size() < fit->inliers.size()) break;
    const bool same = in == fit->inliers;
    fit->inliers = std::move(in);
    fit->X_BaseItem = X;
    if (same) break;
  }
}

// 3D-3D RANSAC then refit. No inliers (identity pose) with fewer than 3 3D matches.
RigidFit FitRigid3d(const Correspondences& corr, const SiftPoseOptions& options) {
  const double threshold_sq_m2 = options.inlier_threshold_m * options.inlier_threshold_m;
  if (corr.p_ItemModel_3d.size() < 3) return RigidFit{};
  RigidFit fit = SampleRigidFit(corr, options, threshold_sq_m2);
  RefineRigidFit(corr, threshold_sq_m2, &fit);
  return fit;
}

// Fills `result` with the 3D-3D pose: its 3D inliers and their RMSE.
void SetRigidPose(const RigidFit& fit, const Correspondences& corr, SiftPoseResult* result) {
  result->found = true;
  result->X_BaseItem = fit.X_BaseItem;
  double sum_sq_m2 = 0.0;
  for (int i : fit.inliers) {
    sum_sq_m2 += (fit.X_BaseItem * corr.p_ItemModel_3d[i] - corr.p_BaseScene_3d[i]).squaredNorm();
    result->inlier_pixels.push_back(corr.px_Scene_3d[i]);
    result->inlier_model_points.push_back(corr.p_ItemModel_3d[i]);
  }
  result->inlier_rmse_m = std::sqrt(sum_sq_m2 / fit.inliers.size());
  result->num_inliers = fit.inliers.size();
}

// Adds to `result` the 2D-only matches whose model point, at pose X_BaseItem, reprojects within
// threshold_px of their keypoint.
void AddReprojectedMatches(const Correspondences& corr, const Eigen::Isometry3d& X_BaseItem,
                           const Eigen::Isometry3d& X_BaseSensor, const PinholeCamera& camera,
                           double threshold_px, SiftPoseResult* result) {
  const Eigen::Isometry3d X_SensorItem = X_BaseSensor.inverse() * X_BaseItem;
  for (std::size_t i = 0; i < corr.p_ItemModel.size(); ++i) {
    const Eigen::Vector3d p_SensorModel = X_SensorItem * corr.p_ItemModel[i];
    if (p_SensorModel.z() <= 0.0) continue;
    const Eigen::Vector2d px_Projected = *camera.Project(p_SensorModel);
    const bool has_3d = std::find(corr.px_Scene_3d.begin(), corr.px_Scene_3d.end(),
                                  corr.px_Scene[i]) != corr.px_Scene_3d.end();
    if (!has_3d && (px_Projected - corr.px_Scene[i]).norm() <= threshold_px) {
      ++result->num_inliers;
      result->inlier_pixels.push_back(corr.px_Scene[i]);
      result->inlier_model_points.push_back(corr.p_ItemModel[i]);
    }
  }
}

// An OpenCV rotation vector and translation as a pose.
Eigen::Isometry3d ToIsometry(const cv::Mat& rvec, const cv::Mat& tvec) {
  cv::Mat R;
  cv::Rodrigues(rvec, R);
  Eigen::Matrix3d R_e;
  Eigen::Vector3d t_e;
  cv::cv2eigen(R, R_e);
  cv::cv2eigen(tvec, t_e);
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = R_e;
  X.translation() = t_e;
  return X;
}

// For too few measured points: EPnP RANSAC on every 2D-3D match, polished with
// Levenberg-Marquardt on its inliers. Fills `result` when at least min_inliers agree.
void SolveEpnpPose(const Correspondences& corr, const PinholeCamera& camera,
                   const Eigen::Isometry3d& X_BaseSensor, const SiftPoseOptions& options,
                   SiftPoseResult* result) {
  std::vector<cv::Point3f> object_points;
  std::vector<cv::Point2f> image_points;
  for (std::size_t i = 0; i < corr.p_ItemModel.size(); ++i) {
    object_points.emplace_back(corr.p_ItemModel[i].x(), corr.p_ItemModel[i].y(),
                               corr.p_ItemModel[i].z());
    image_points.emplace_back(corr.px_Scene[i].x(), corr.px_Scene[i].y());
  }
  const cv::Matx33d K(camera.fx(), 0, camera.cx(), 0, camera.fy(), camera.cy(), 0, 0, 1);
  const Distortion& k = camera.distortion();
  const cv::Mat distortion = (cv::Mat_<double>(1, 5) << k.k1, k.k2, k.p1, k.p2, k.k3);
  cv::Mat rvec, tvec;
  std::vector<int> inliers;
  cv::theRNG().state = options.seed;
  const bool ok = cv::solvePnPRansac(
      object_points, image_points, K, distortion, rvec, tvec, false, options.ransac_iterations,
      static_cast<float>(options.reprojection_threshold_px), 0.999, inliers, cv::SOLVEPNP_EPNP);
  if (!ok || static_cast<int>(inliers.size()) < options.min_inliers) return;
  // Polish on the inliers with Levenberg-Marquardt.
  std::vector<cv::Point3f> in_obj;
  std::vector<cv::Point2f> in_img;
  for (int i : inliers) {
    in_obj.push_back(object_points[i]);
    in_img.push_back(image_points[i]);
  }
  cv::solvePnPRefineLM(in_obj, in_img, K, distortion, rvec, tvec);
  const Eigen::Isometry3d X_SensorItem = ToIsometry(rvec, tvec);
  result->found = true;
  result->used_epnp = true;
  result->X_BaseItem = X_BaseSensor * X_SensorItem;
  result->num_inliers = inliers.size();
  for (int i : inliers) {
    result->inlier_pixels.push_back(corr.px_Scene[i]);
    result->inlier_model_points.push_back(corr.p_ItemModel[i]);
  }
}

// The pose from one view: ratio-test matches to the scene, then the 3D-3D fit, or EPnP when
// that has too few inliers and there is a camera and at least 4 matches.
SiftPoseResult EstimateViewPose(const SiftModel& model, std::size_t view_index,
                                const SceneFeatures& features, const geometry::PointCloud& scene,
                                const Eigen::Isometry3d& X_BaseSensor,
                                const std::optional<PinholeCamera>& camera,
                                const SiftPoseOptions& options) {
  const SiftModel::Impl::View& view = model.impl().views[view_index];
  const auto matches = RatioMatches(features.descriptors, view.descriptors, options.ratio,
                                    model.options().use_flann);
  const Correspondences corr = SplitMatches(matches, features, view, scene);
  SiftPoseResult result;
  result.view_index = static_cast<int>(view_index);
  result.num_matches = matches.size();
  result.num_with_3d = corr.p_ItemModel_3d.size();
  const RigidFit fit = FitRigid3d(corr, options);
  if (static_cast<int>(fit.inliers.size()) >= options.min_inliers) {
    SetRigidPose(fit, corr, &result);
    // 2D-only matches are kept when they reproject onto their keypoint.
    if (camera)
      AddReprojectedMatches(corr, fit.X_BaseItem, X_BaseSensor, *camera,
                            options.reprojection_threshold_px, &result);
  } else if (camera && corr.p_ItemModel.size() >= 4) {
    // Too few measured points: EPnP on every 2D-3D match.
    SolveEpnpPose(corr, *camera, X_BaseSensor, options, &result);
  }
  return result;
}

// Whether a view's `result` beats the `best` so far: a found pose with more inliers or, while
// nothing is found, more matches.
bool Replaces(const SiftPoseResult& result, const SiftPoseResult& best) {
  if (result.found && (!best.found || result.num_inliers > best.num_inliers)) return true;
  return !best.found && result.num_matches > best.num_matches;
}

}  // namespace

SiftPoseResult EstimateSiftPose(const SiftModel& model, const geometry::PointCloud& scene,
                                const Eigen::Isometry3d& X_BaseSensor,
                                const std::optional<PinholeCamera>& camera,
                                const SiftPoseOptions& options) {
  const GrayImage image = IntensityImage(scene);
  if (options.min_inliers < 3 || options.ransac_iterations < 1 ||
      !(options.inlier_threshold_m > 0.0) || !(options.reprojection_threshold_px > 0.0))
    throw std::invalid_argument("SiftPoseOptions: a count or threshold is out of range");
  const SceneFeatures features = DetectSceneFeatures(scene, image, model.options().max_features);
  SiftPoseResult best;
  for (std::size_t k = 0; k < model.impl().views.size(); ++k) {
    SiftPoseResult result =
        EstimateViewPose(model, k, features, scene, X_BaseSensor, camera, options);
    if (Replaces(result, best)) best = std::move(result);
  }
  return best;
}

SiftEstimator::SiftEstimator(std::map<std::string, std::shared_ptr<const SiftModel>> models,
                             SiftPoseOptions options)
    : models_(std::move(models)), options_(options) {
  for (const auto& [item, m] : models_)
    if (!m) throw std::invalid_argument("SiftEstimator: null model for item '" + item + "'");
}

std::vector<Detection> SiftEstimator::Estimate(const EstimatorInput& input) {
  if (input.scene == nullptr) throw std::invalid_argument("SiftEstimator: null scene");
  const auto it = models_.find(input.item);
  if (it == models_.end()) return {};
  const auto start = std::chrono::steady_clock::now();
  const SiftPoseResult r =
      EstimateSiftPose(*it->second, *input.scene, input.X_BaseSensor, input.camera, options_);
  if (!r.found) return {};
  Detection d;
  d.item = input.item;
  d.X_BaseItem = r.X_BaseItem;
  d.method = ToString(Method::kSift);
  d.fitness = r.num_matches == 0 ? 0.0 : static_cast<double>(r.num_inliers) / r.num_matches;
  d.score = d.fitness;
  d.inlier_rmse_m = r.inlier_rmse_m;
  d.timings.estimate_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  d.timings.total_s = d.timings.estimate_s;
  return {d};
}

}  // namespace picking::detector
