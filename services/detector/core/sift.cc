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

SiftPoseResult EstimateSiftPose(const SiftModel& model, const geometry::PointCloud& scene,
                                const Eigen::Isometry3d& X_BaseSensor,
                                const std::optional<PinholeCamera>& camera,
                                const SiftPoseOptions& options) {
  const GrayImage image = IntensityImage(scene);
  if (options.min_inliers < 3 || options.ransac_iterations < 1 ||
      !(options.inlier_threshold_m > 0.0) || !(options.reprojection_threshold_px > 0.0))
    throw std::invalid_argument("SiftPoseOptions: a count or threshold is out of range");
  // Features are sought only around the scan's finite points (the whole image when it has
  // none: the pose then comes from EPnP): a scene cropped to a bin keeps its organisation
  // with NaN elsewhere, and the rest of the image would cost most of the detection time.
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
  const cv::Rect roi(std::max(0, u0 - kPad), std::max(0, v0 - kPad),
                     std::min(image.width, u1 + kPad + 1) - std::max(0, u0 - kPad),
                     std::min(image.height, v1 + kPad + 1) - std::max(0, v0 - kPad));
  std::vector<cv::KeyPoint> scene_keypoints;
  cv::Mat scene_descriptors;
  Detect(image, model.options().max_features, &scene_keypoints, &scene_descriptors, roi);

  SiftPoseResult best;
  const auto& views = model.impl().views;
  for (std::size_t k = 0; k < views.size(); ++k) {
    const auto& view = views[k];
    const auto matches =
        RatioMatches(scene_descriptors, view.descriptors, options.ratio, model.options().use_flann);
    // Split into matches with a measured scene point and 2D-only ones.
    std::vector<Eigen::Vector3d> model_3d, scene_3d, model_all;
    std::vector<Eigen::Vector2d> pixels_3d, pixels_all;
    for (const cv::DMatch& m : matches) {
      const cv::Point2f& pt = scene_keypoints[m.queryIdx].pt;
      const int u = static_cast<int>(std::lround(pt.x)), v = static_cast<int>(std::lround(pt.y));
      const Eigen::Vector3d& p_model = view.p_ItemFeature[m.trainIdx];
      model_all.push_back(p_model);
      pixels_all.emplace_back(pt.x, pt.y);
      if (u < 0 || v < 0 || u >= image.width || v >= image.height) continue;
      const Eigen::Vector3f& s = scene.points[static_cast<std::size_t>(v) * image.width + u];
      if (!s.allFinite()) continue;
      model_3d.push_back(p_model);
      scene_3d.push_back(s.cast<double>());
      pixels_3d.emplace_back(pt.x, pt.y);
    }
    SiftPoseResult result;
    result.view_index = static_cast<int>(k);
    result.num_matches = matches.size();
    result.num_with_3d = model_3d.size();

    // 3D-3D RANSAC.
    const double threshold_sq = options.inlier_threshold_m * options.inlier_threshold_m;
    const auto inliers_of = [&](const Eigen::Isometry3d& X) {
      std::vector<int> in;
      for (std::size_t i = 0; i < model_3d.size(); ++i)
        if ((X * model_3d[i] - scene_3d[i]).squaredNorm() <= threshold_sq)
          in.push_back(static_cast<int>(i));
      return in;
    };
    std::vector<int> best_inliers;
    Eigen::Isometry3d best_X = Eigen::Isometry3d::Identity();
    if (model_3d.size() >= 3) {
      std::mt19937 rng(options.seed);
      std::uniform_int_distribution<std::size_t> pick(0, model_3d.size() - 1);
      for (int it = 0; it < options.ransac_iterations; ++it) {
        const std::size_t a = pick(rng), b = pick(rng), c = pick(rng);
        if (a == b || b == c || a == c) continue;
        // Reject degenerate samples and ones whose model and scene distances disagree.
        const auto consistent = [&](std::size_t i, std::size_t j) {
          return std::abs((model_3d[i] - model_3d[j]).norm() - (scene_3d[i] - scene_3d[j]).norm()) <
                 2.0 * options.inlier_threshold_m;
        };
        if (!consistent(a, b) || !consistent(b, c) || !consistent(a, c)) continue;
        if ((model_3d[b] - model_3d[a]).cross(model_3d[c] - model_3d[a]).norm() < 1e-8) continue;
        Eigen::Isometry3d X;
        if (!Kabsch({model_3d[a], model_3d[b], model_3d[c]},
                    {scene_3d[a], scene_3d[b], scene_3d[c]}, &X))
          continue;
        std::vector<int> in = inliers_of(X);
        if (in.size() > best_inliers.size()) {
          best_inliers = std::move(in);
          best_X = X;
        }
      }
      // Least-squares refit on the inliers until the set is stable.
      for (int refit = 0; refit < 5 && best_inliers.size() >= 3; ++refit) {
        std::vector<Eigen::Vector3d> src, dst;
        for (int i : best_inliers) {
          src.push_back(model_3d[i]);
          dst.push_back(scene_3d[i]);
        }
        Eigen::Isometry3d X;
        if (!Kabsch(src, dst, &X)) break;
        std::vector<int> in = inliers_of(X);
        if (in.size() < best_inliers.size()) break;
        const bool same = in == best_inliers;
        best_inliers = std::move(in);
        best_X = X;
        if (same) break;
      }
    }
    if (static_cast<int>(best_inliers.size()) >= options.min_inliers) {
      result.found = true;
      result.X_BaseItem = best_X;
      double sum_sq = 0.0;
      for (int i : best_inliers) {
        sum_sq += (best_X * model_3d[i] - scene_3d[i]).squaredNorm();
        result.inlier_pixels.push_back(pixels_3d[i]);
        result.inlier_model_points.push_back(model_3d[i]);
      }
      result.inlier_rmse_m = std::sqrt(sum_sq / best_inliers.size());
      result.num_inliers = best_inliers.size();
      // 2D-only matches are kept when they reproject onto their keypoint.
      if (camera) {
        const Eigen::Isometry3d X_SensorItem = X_BaseSensor.inverse() * best_X;
        for (std::size_t i = 0; i < model_all.size(); ++i) {
          const Eigen::Vector3d p = X_SensorItem * model_all[i];
          if (p.z() <= 0.0) continue;
          const Eigen::Vector2d px = *camera->Project(p);
          const bool has_3d =
              std::find(pixels_3d.begin(), pixels_3d.end(), pixels_all[i]) != pixels_3d.end();
          if (!has_3d && (px - pixels_all[i]).norm() <= options.reprojection_threshold_px) {
            ++result.num_inliers;
            result.inlier_pixels.push_back(pixels_all[i]);
            result.inlier_model_points.push_back(model_all[i]);
          }
        }
      }
    } else if (camera && model_all.size() >= 4) {
      // Too few measured points: EPnP on every 2D-3D match.
      std::vector<cv::Point3f> object_points;
      std::vector<cv::Point2f> image_points;
      for (std::size_t i = 0; i < model_all.size(); ++i) {
        object_points.emplace_back(model_all[i].x(), model_all[i].y(), model_all[i].z());
        image_points.emplace_back(pixels_all[i].x(), pixels_all[i].y());
      }
      const cv::Matx33d K(camera->fx(), 0, camera->cx(), 0, camera->fy(), camera->cy(), 0, 0, 1);
      const Distortion& k = camera->distortion();
      const cv::Mat distortion = (cv::Mat_<double>(1, 5) << k.k1, k.k2, k.p1, k.p2, k.k3);
      cv::Mat rvec, tvec;
      std::vector<int> inliers;
      cv::theRNG().state = options.seed;
      const bool ok = cv::solvePnPRansac(
          object_points, image_points, K, distortion, rvec, tvec, false, options.ransac_iterations,
          static_cast<float>(options.reprojection_threshold_px), 0.999, inliers, cv::SOLVEPNP_EPNP);
      if (ok && static_cast<int>(inliers.size()) >= options.min_inliers) {
        // Polish on the inliers with Levenberg-Marquardt.
        std::vector<cv::Point3f> in_obj;
        std::vector<cv::Point2f> in_img;
        for (int i : inliers) {
          in_obj.push_back(object_points[i]);
          in_img.push_back(image_points[i]);
        }
        cv::solvePnPRefineLM(in_obj, in_img, K, distortion, rvec, tvec);
        cv::Mat R;
        cv::Rodrigues(rvec, R);
        Eigen::Matrix3d R_e;
        Eigen::Vector3d t_e;
        cv::cv2eigen(R, R_e);
        cv::cv2eigen(tvec, t_e);
        Eigen::Isometry3d X_SensorItem = Eigen::Isometry3d::Identity();
        X_SensorItem.linear() = R_e;
        X_SensorItem.translation() = t_e;
        result.found = true;
        result.used_epnp = true;
        result.X_BaseItem = X_BaseSensor * X_SensorItem;
        result.num_inliers = inliers.size();
        for (int i : inliers) {
          result.inlier_pixels.push_back(pixels_all[i]);
          result.inlier_model_points.push_back(model_all[i]);
        }
      }
    }
    if (result.found && (!best.found || result.num_inliers > best.num_inliers)) {
      best = std::move(result);
    } else if (!best.found && result.num_matches > best.num_matches) {
      best = std::move(result);
    }
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
