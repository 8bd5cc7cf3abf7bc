#include "services/scanner/core/synthetic_capture.h"

#include "services/scanner/core/band_pool.h"

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>

namespace picking::scanner {
namespace {

constexpr double kNoHit = std::numeric_limits<double>::infinity();

// Nearest intersection t > t_min of the ray origin + t * direction (direction unit) with the
// scene; writes the unit surface normal facing the ray origin and the albedo.
double Intersect(const SyntheticScene& scene, const Eigen::Vector3d& origin,
                 const Eigen::Vector3d& direction, double t_min, Eigen::Vector3d* normal,
                 double* albedo) {
  double best = kNoHit;
  for (const SyntheticPlane& plane : scene.planes) {
    const double denominator = plane.normal.dot(direction);
    if (std::abs(denominator) < 1e-12) continue;
    const double t = (plane.offset_m - plane.normal.dot(origin)) / denominator;
    if (t > t_min && t < best) {
      best = t;
      if (normal) *normal = denominator < 0 ? plane.normal : Eigen::Vector3d(-plane.normal);
      if (albedo) *albedo = plane.albedo;
    }
  }
  for (const SyntheticSphere& sphere : scene.spheres) {
    const Eigen::Vector3d oc = origin - sphere.center_m;
    const double b = oc.dot(direction);
    const double c = oc.squaredNorm() - sphere.radius_m * sphere.radius_m;
    const double discriminant = b * b - c;
    if (discriminant < 0) continue;
    const double root = std::sqrt(discriminant);
    double t = -b - root;
    if (t <= t_min) t = -b + root;
    if (t > t_min && t < best) {
      best = t;
      if (normal) *normal = (origin + t * direction - sphere.center_m).normalized();
      if (albedo) *albedo = sphere.albedo;
    }
  }
  return best;
}

}  // namespace

ScannerRig MakeExampleRig(int camera_width, int camera_height) {
  // Flea3 FL3-U3-13Y3 (4.8 um pixels) with an 8 mm lens: f = 1667 px at 1280 x 1024.
  const double scale = camera_width / 1280.0;
  camera::Distortion camera_distortion;
  camera_distortion.k1 = -0.08;
  camera_distortion.k2 = 0.05;
  camera_distortion.p1 = 0.0005;
  camera_distortion.p2 = -0.0003;
  camera::PinholeCamera camera(camera_width, camera_height, 1800.0 * scale, 1800.0 * scale,
                               (camera_width - 1) * 0.5 + 3.2 * scale,
                               (camera_height - 1) * 0.5 - 2.1 * scale, camera_distortion);
  camera::Distortion projector_distortion;
  projector_distortion.k1 = 0.03;
  projector_distortion.k2 = -0.01;
  camera::PinholeCamera projector(912, 1140, 1100.0, 1100.0, 455.5, 569.5, projector_distortion);
  // Projector 0.15 m to the right, toed in towards the camera axis at 1 m.
  Eigen::Isometry3d X_CameraProjector = Eigen::Isometry3d::Identity();
  X_CameraProjector.translation() = Eigen::Vector3d(0.15, 0.004, 0.01);
  X_CameraProjector.linear() =
      (Eigen::AngleAxisd(-std::atan2(0.15, 1.0), Eigen::Vector3d::UnitY()) *
       Eigen::AngleAxisd(0.005, Eigen::Vector3d::UnitX()))
          .toRotationMatrix();
  return ScannerRig{camera, projector, X_CameraProjector};
}

std::vector<ImageView> SyntheticCapture::views() const {
  std::vector<ImageView> result;
  result.reserve(images.size());
  for (const auto& image : images) result.push_back(MakeImageView(image.data(), width, height));
  return result;
}

SyntheticCapture RenderSyntheticCapture(const ScannerRig& rig, const PatternSequence& patterns,
                                        const SyntheticScene& scene,
                                        const SyntheticCaptureOptions& options) {
  if (!(options.blur_sigma_px >= 0.0)) {
    throw std::invalid_argument("RenderSyntheticCapture: options.blur_sigma_px must be >= 0");
  }
  if (!(options.noise_sigma >= 0.0)) {
    throw std::invalid_argument("RenderSyntheticCapture: options.noise_sigma must be >= 0");
  }
  if (!(options.gamma > 0.0)) {
    throw std::invalid_argument("RenderSyntheticCapture: options.gamma must be > 0");
  }
  const camera::PinholeCamera& cam = rig.camera;
  const int width = cam.width();
  const int height = cam.height();
  const std::size_t n = static_cast<std::size_t>(width) * height;
  SyntheticCapture capture;
  capture.width = width;
  capture.height = height;
  capture.column.assign(n, -1);
  capture.row.assign(n, -1);
  capture.depth_m.assign(n, std::numeric_limits<float>::quiet_NaN());
  // Per pixel: ambient radiance and the projector's contribution when lit.
  std::vector<float> ambient(n, 0.0f);
  std::vector<float> lit(n, 0.0f);
  const Eigen::Isometry3d X_ProjectorCamera = rig.X_CameraProjector.inverse();
  const Eigen::Vector3d p_CameraProjector = rig.X_CameraProjector.translation();
  const camera::RayTable rays = cam.ComputeRayTable();
  BandPool pool;
  pool.Run(height, [&](int v) {
    for (int u = 0; u < width; ++u) {
      const std::size_t i = static_cast<std::size_t>(v) * width + u;
      const Eigen::Vector3d ray = Eigen::Vector3d(rays.xy[i].x(), rays.xy[i].y(), 1.0).normalized();
      Eigen::Vector3d normal;
      double albedo = 0;
      const double t = Intersect(scene, Eigen::Vector3d::Zero(), ray, 1e-6, &normal, &albedo);
      if (t == kNoHit) continue;
      const Eigen::Vector3d p = t * ray;
      capture.depth_m[i] = static_cast<float>(p.z());
      ambient[i] = static_cast<float>(albedo * options.ambient_level);
      const Eigen::Vector3d to_projector = p_CameraProjector - p;
      const double distance = to_projector.norm();
      const double cosine = normal.dot(to_projector) / distance;
      if (cosine <= 0) continue;
      const double blocker =
          Intersect(scene, p_CameraProjector, -to_projector / distance, 1e-6, nullptr, nullptr);
      if (blocker < distance - 1e-7) continue;  // In shadow.
      const auto uv = rig.projector.Project(X_ProjectorCamera * p);
      if (!uv || !rig.projector.Contains(*uv)) continue;
      capture.column[i] =
          std::min(rig.projector.width() - 1, std::max(0, static_cast<int>(std::lround(uv->x()))));
      capture.row[i] =
          std::min(rig.projector.height() - 1, std::max(0, static_cast<int>(std::lround(uv->y()))));
      lit[i] = static_cast<float>(albedo * cosine * options.projector_level);
    }
  });

  const int num_images = patterns.num_images();
  capture.images.assign(num_images, std::vector<std::uint8_t>(n));
  pool.Run(num_images, [&](int k) {
    const PatternImage description = patterns.Describe(k);
    cv::Mat radiance(height, width, CV_32F);
    for (std::size_t i = 0; i < n; ++i) {
      bool on = false;
      if (capture.column[i] >= 0) {
        switch (description.kind) {
          case PatternImage::Kind::kWhite:
            on = true;
            break;
          case PatternImage::Kind::kBlack:
            on = false;
            break;
          case PatternImage::Kind::kColumnBit:
            on =
                ((GrayEncode(capture.column[i]) >> (patterns.column_bits() - 1 - description.bit)) &
                 1u) != description.inverse;
            break;
          case PatternImage::Kind::kRowBit:
            on = ((GrayEncode(capture.row[i]) >> (patterns.row_bits() - 1 - description.bit)) &
                  1u) != description.inverse;
            break;
        }
      }
      radiance.at<float>(static_cast<int>(i)) = ambient[i] + (on ? lit[i] : 0.0f);
    }
    if (options.blur_sigma_px > 0) {
      cv::GaussianBlur(radiance, radiance, cv::Size(0, 0), options.blur_sigma_px);
    }
    std::mt19937 rng(options.seed * 7919u + static_cast<std::uint32_t>(k));
    std::normal_distribution<float> noise(0.0f, static_cast<float>(options.noise_sigma));
    std::vector<std::uint8_t>& image = capture.images[k];
    for (std::size_t i = 0; i < n; ++i) {
      float value = radiance.at<float>(static_cast<int>(i));
      if (options.gamma != 1.0) {
        value =
            255.0f * std::pow(std::max(0.0f, value) / 255.0f, static_cast<float>(options.gamma));
      }
      if (options.noise_sigma > 0) value += noise(rng);
      image[i] = static_cast<std::uint8_t>(std::min(255.0f, std::max(0.0f, std::round(value))));
    }
  });
  return capture;
}

}  // namespace picking::scanner
