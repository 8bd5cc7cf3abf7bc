#include "services/scanner/core/synthetic_capture.h"

#include "services/scanner/core/band_pool.h"

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>

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
  for (const SyntheticChessboard& board : scene.boards) {
    // In the board frame the board is the plane z = 0.
    const Eigen::Isometry3d X_BoardCamera = board.X_CameraBoard.inverse();
    const Eigen::Vector3d o = X_BoardCamera * origin;
    const Eigen::Vector3d d = X_BoardCamera.linear() * direction;
    if (std::abs(d.z()) < 1e-12) continue;
    const double t = -o.z() / d.z();
    if (!(t > t_min && t < best)) continue;
    const Eigen::Vector3d p = o + t * d;
    const double s = board.square_size_m;
    const double bx = p.x() / s, by = p.y() / s;
    const double m = board.margin_m / s;
    if (bx < -1.0 - m || by < -1.0 - m || bx > board.inner_corners_x + m ||
        by > board.inner_corners_y + m) {
      continue;
    }
    best = t;
    const Eigen::Vector3d n_Camera = board.X_CameraBoard.linear().col(2);
    if (normal) *normal = n_Camera.dot(direction) < 0 ? n_Camera : Eigen::Vector3d(-n_Camera);
    if (albedo) {
      *albedo = board.light_albedo;
      if (bx >= -1.0 && by >= -1.0 && bx <= board.inner_corners_x && by <= board.inner_corners_y) {
        const long ix = static_cast<long>(std::floor(bx)), iy = static_cast<long>(std::floor(by));
        if ((ix + iy) % 2 == 0) *albedo = board.dark_albedo;
      }
    }
  }
  for (const SyntheticBox& box : scene.boxes) {
    // Slab test in the box frame.
    const Eigen::Isometry3d X_BoxCamera = box.X_CameraBox.inverse();
    const Eigen::Vector3d o = X_BoxCamera * origin;
    const Eigen::Vector3d d = X_BoxCamera.linear() * direction;
    double t_near = -kNoHit, t_far = kNoHit;
    int near_axis = -1, far_axis = -1;
    bool miss = false;
    for (int a = 0; a < 3 && !miss; ++a) {
      const double h = box.half_size_m[a];
      if (std::abs(d[a]) < 1e-15) {
        if (o[a] < -h || o[a] > h) miss = true;
        continue;
      }
      double t0 = (-h - o[a]) / d[a], t1 = (h - o[a]) / d[a];
      if (t0 > t1) std::swap(t0, t1);
      if (t0 > t_near) t_near = t0, near_axis = a;
      if (t1 < t_far) t_far = t1, far_axis = a;
      if (t_near > t_far) miss = true;
    }
    if (miss) continue;
    double t = t_near;
    int axis = near_axis;
    if (!(t > t_min)) t = t_far, axis = far_axis;  // Starting inside the box.
    if (!(t > t_min && t < best) || axis < 0) continue;
    best = t;
    if (normal) {
      Eigen::Vector3d n_Box = Eigen::Vector3d::Zero();
      n_Box[axis] = d[axis] < 0 ? 1.0 : -1.0;
      *normal = box.X_CameraBox.linear() * n_Box;
    }
    if (albedo) *albedo = box.albedo;
  }
  return best;
}

// One camera ray traced into the scene.
struct RayHit {
  bool hit = false;  // Meets a surface.
  bool lit = false;  // ... that the projector lights.
  double depth_m = 0;
  double albedo = 0;
  double cosine = 0;  // Between the surface normal and the direction to the projector.
  Eigen::Vector2d uv = Eigen::Vector2d::Zero();  // Projector pixel coordinates.
  int column = -1;                               // Nearest mirror.
  int row = -1;
};

// Light of one projector mirror reaching one camera pixel when the mirror is on.
struct LitSample {
  std::int32_t column;
  std::int32_t row;
  float radiance;
};

// Per camera pixel: the ambient radiance, and the projector mirrors lighting it with the
// radiance each contributes when on (one entry per distinct mirror, kept per camera row so
// that rows are filled in parallel). Pixel u of row v owns
// row_samples[v][row_starts[v][u] .. row_starts[v][u + 1]).
struct LightTransport {
  std::vector<float> ambient;  // Row-major, grey levels.
  std::vector<std::vector<LitSample>> row_samples;
  std::vector<std::vector<std::uint32_t>> row_starts;
};

// What camera rays are traced with: the scene, the rig (camera frame, metres), the camera's
// ray table and the area sampling of each pixel.
struct PixelTracer {
  const SyntheticScene& scene;
  const ScannerRig& rig;
  const camera::RayTable& rays;
  const SyntheticCaptureOptions& options;
  Eigen::Isometry3d X_ProjectorCamera;
  Eigen::Vector3d p_CameraProjector;
  int width;             // Camera pixels.
  int height;            // Camera pixels.
  int samples;           // Rays per pixel and axis (options.samples_per_axis).
  double sample_weight;  // 1 / samples^2: share of a pixel's light per ray.
};

// Rejects options and scene objects outside their documented ranges, before any work.
void CheckCaptureInputs(const SyntheticScene& scene, const SyntheticCaptureOptions& options) {
  if (!(options.blur_sigma_px >= 0.0)) {
    throw std::invalid_argument("RenderSyntheticCapture: options.blur_sigma_px must be >= 0");
  }
  if (!(options.noise_sigma >= 0.0)) {
    throw std::invalid_argument("RenderSyntheticCapture: options.noise_sigma must be >= 0");
  }
  if (!(options.gamma > 0.0)) {
    throw std::invalid_argument("RenderSyntheticCapture: options.gamma must be > 0");
  }
  if (options.samples_per_axis < 1 || options.samples_per_axis > 16) {
    throw std::invalid_argument(
        "RenderSyntheticCapture: options.samples_per_axis must be in [1, 16], got " +
        std::to_string(options.samples_per_axis));
  }
  for (const SyntheticBox& box : scene.boxes) {
    if (!(box.half_size_m.minCoeff() > 0.0)) {
      throw std::invalid_argument("RenderSyntheticCapture: a box's half_size_m must be > 0");
    }
  }
  for (const SyntheticChessboard& board : scene.boards) {
    if (board.inner_corners_x < 2 || board.inner_corners_y < 2 || !(board.square_size_m > 0.0) ||
        !(board.margin_m >= 0.0)) {
      throw std::invalid_argument(
          "RenderSyntheticCapture: a chessboard needs >= 2 x 2 inner corners, square_size_m > 0 "
          "and margin_m >= 0");
    }
  }
}

// A width x height capture with no ground truth yet (-1 / NaN everywhere) and no images.
SyntheticCapture MakeEmptyCapture(int width, int height) {
  const std::size_t n = static_cast<std::size_t>(width) * height;
  const float kNaN = std::numeric_limits<float>::quiet_NaN();
  SyntheticCapture capture;
  capture.width = width;
  capture.height = height;
  capture.column.assign(n, -1);
  capture.row.assign(n, -1);
  capture.column_exact.assign(n, kNaN);
  capture.row_exact.assign(n, kNaN);
  capture.depth_m.assign(n, kNaN);
  return capture;
}

// Traces the camera ray (x, y, 1) (normalised camera coordinates): the surface it meets and,
// if the projector lights that point (facing it, not shadowed, inside its image), where.
RayHit TraceCameraRay(const PixelTracer& tracer, const Eigen::Vector2d& xy) {
  const SyntheticScene& scene = tracer.scene;
  const ScannerRig& rig = tracer.rig;
  const Eigen::Vector3d& p_CameraProjector = tracer.p_CameraProjector;
  RayHit hit;
  const Eigen::Vector3d ray = Eigen::Vector3d(xy.x(), xy.y(), 1.0).normalized();
  Eigen::Vector3d normal;
  const double t = Intersect(scene, Eigen::Vector3d::Zero(), ray, 1e-6, &normal, &hit.albedo);
  if (t == kNoHit) return hit;
  hit.hit = true;
  const Eigen::Vector3d p = t * ray;
  hit.depth_m = p.z();
  const Eigen::Vector3d to_projector = p_CameraProjector - p;
  const double distance = to_projector.norm();
  const double cosine = normal.dot(to_projector) / distance;
  if (cosine <= 0) return hit;
  const double blocker =
      Intersect(scene, p_CameraProjector, -to_projector / distance, 1e-6, nullptr, nullptr);
  if (blocker < distance - 1e-7) return hit;  // In shadow.
  const auto uv = rig.projector.Project(tracer.X_ProjectorCamera * p);
  if (!uv || !rig.projector.Contains(*uv)) return hit;
  hit.lit = true;
  hit.uv = *uv;
  hit.column =
      std::min(rig.projector.width() - 1, std::max(0, static_cast<int>(std::lround(uv->x()))));
  hit.row =
      std::min(rig.projector.height() - 1, std::max(0, static_cast<int>(std::lround(uv->y()))));
  hit.cosine = cosine;
  return hit;
}

// Undistorted normalised coordinates of camera pixel position (u, v) inside the image,
// interpolated bilinearly between the ray table's pixel centres (extrapolated half a pixel
// at the border).
Eigen::Vector2d NormalizedAt(const PixelTracer& tracer, double u, double v) {
  const int width = tracer.width;
  const int height = tracer.height;
  const camera::RayTable& rays = tracer.rays;
  if (width < 2 || height < 2) return tracer.rig.camera.PixelToNormalized(Eigen::Vector2d(u, v));
  const int u0 = std::min(width - 2, std::max(0, static_cast<int>(std::floor(u))));
  const int v0 = std::min(height - 2, std::max(0, static_cast<int>(std::floor(v))));
  const double a = u - u0;
  const double b = v - v0;
  const std::size_t i = static_cast<std::size_t>(v0) * width + u0;
  const Eigen::Vector2d top =
      (1 - a) * rays.xy[i].cast<double>() + a * rays.xy[i + 1].cast<double>();
  const Eigen::Vector2d bottom =
      (1 - a) * rays.xy[i + width].cast<double>() + a * rays.xy[i + width + 1].cast<double>();
  return (1 - b) * top + b * bottom;
}

// Writes the ground truth of the ray through the centre of pixel i: depth where it meets a
// surface, and the projector mirror (nearest and exact) where that surface is lit.
void RecordGroundTruth(const RayHit& centre, std::size_t i, SyntheticCapture* capture) {
  if (centre.hit) capture->depth_m[i] = static_cast<float>(centre.depth_m);
  if (centre.lit) {
    capture->column[i] = centre.column;
    capture->row[i] = centre.row;
    capture->column_exact[i] = static_cast<float>(centre.uv.x());
    capture->row_exact[i] = static_cast<float>(centre.uv.y());
  }
}

// Area sampling of camera pixel (u, v): traces samples x samples rays spread over the pixel,
// merges the light of each mirror into the pixel's entries of *out_samples (those from
// pixel_start on) and returns the pixel's ambient radiance.
double SamplePixelArea(const PixelTracer& tracer, int u, int v, std::uint32_t pixel_start,
                       std::vector<LitSample>* out_samples) {
  const SyntheticCaptureOptions& options = tracer.options;
  const int samples = tracer.samples;
  const double sample_weight = tracer.sample_weight;
  std::vector<LitSample>& out = *out_samples;
  double ambient_sum = 0;
  for (int sy = 0; sy < samples; ++sy) {
    for (int sx = 0; sx < samples; ++sx) {
      const double du = (sx + 0.5) / samples - 0.5;
      const double dv = (sy + 0.5) / samples - 0.5;
      const RayHit hit = TraceCameraRay(tracer, NormalizedAt(tracer, u + du, v + dv));
      if (!hit.hit) continue;
      ambient_sum += hit.albedo * options.ambient_level * sample_weight;
      if (!hit.lit) continue;
      const float radiance =
          static_cast<float>(hit.albedo * hit.cosine * options.projector_level * sample_weight);
      bool merged = false;
      for (std::size_t k = pixel_start; k < out.size() && !merged; ++k) {
        if (out[k].column == hit.column && out[k].row == hit.row) {
          out[k].radiance += radiance;
          merged = true;
        }
      }
      if (!merged) out.push_back({hit.column, hit.row, radiance});
    }
  }
  return ambient_sum;
}

// Traces camera row v: the ground truth at each pixel centre into `capture`, and each
// pixel's ambient radiance and lighting mirrors into row v of `transport`. Rows are
// independent (safe to run in parallel).
void TraceCameraRow(const PixelTracer& tracer, int v, SyntheticCapture* capture,
                    LightTransport* transport) {
  const SyntheticCaptureOptions& options = tracer.options;
  const int width = tracer.width;
  std::vector<float>& ambient = transport->ambient;
  std::vector<LitSample>& out = transport->row_samples[v];
  std::vector<std::uint32_t>& starts = transport->row_starts[v];
  starts.assign(width + 1, 0);
  for (int u = 0; u < width; ++u) {
    const std::size_t i = static_cast<std::size_t>(v) * width + u;
    starts[u] = static_cast<std::uint32_t>(out.size());
    const RayHit centre = TraceCameraRay(tracer, tracer.rays.xy[i].cast<double>());
    RecordGroundTruth(centre, i, capture);
    if (tracer.samples == 1) {
      if (centre.hit) ambient[i] = static_cast<float>(centre.albedo * options.ambient_level);
      if (centre.lit) {
        out.push_back(
            {centre.column, centre.row,
             static_cast<float>(centre.albedo * centre.cosine * options.projector_level)});
      }
      continue;
    }
    ambient[i] = static_cast<float>(SamplePixelArea(tracer, u, v, starts[u], &out));
  }
  starts[width] = static_cast<std::uint32_t>(out.size());
}

// Whether the projector mirror lighting `sample` is on in the pattern image `description`.
bool IsMirrorOn(const PatternSequence& patterns, const PatternImage& description,
                const LitSample& sample) {
  switch (description.kind) {
    case PatternImage::Kind::kWhite:
      return true;
    case PatternImage::Kind::kBlack:
      return false;
    case PatternImage::Kind::kColumnBit:
      return ((GrayEncode(sample.column) >> (patterns.column_bits() - 1 - description.bit)) & 1u) !=
             static_cast<std::uint32_t>(description.inverse);
    case PatternImage::Kind::kRowBit:
      return ((GrayEncode(sample.row) >> (patterns.row_bits() - 1 - description.bit)) & 1u) !=
             static_cast<std::uint32_t>(description.inverse);
  }
  return false;
}

// Scene radiance (grey levels, before blur and response) at every camera pixel while the
// projector shows `description`: ambient plus the light of the mirrors that are on.
cv::Mat PatternRadiance(const LightTransport& transport, const PatternSequence& patterns,
                        const PatternImage& description, int width, int height) {
  cv::Mat radiance(height, width, CV_32F);
  for (int v = 0; v < height; ++v) {
    const std::vector<LitSample>& samples_v = transport.row_samples[v];
    const std::vector<std::uint32_t>& starts = transport.row_starts[v];
    float* dst = radiance.ptr<float>(v);
    const float* ambient_v = transport.ambient.data() + static_cast<std::size_t>(v) * width;
    for (int u = 0; u < width; ++u) {
      float lit = 0.0f;
      for (std::uint32_t s = starts[u]; s < starts[u + 1]; ++s) {
        if (IsMirrorOn(patterns, description, samples_v[s])) lit += samples_v[s].radiance;
      }
      dst[u] = ambient_v[u] + lit;
    }
  }
  return radiance;
}

// Image formation of image k from its radiance: optical blur, gamma response, sensor noise
// (seeded by options.seed and k, so independent of the thread schedule), 8-bit rounding.
void ExposeImage(const SyntheticCaptureOptions& options, int k, cv::Mat* radiance_image,
                 std::vector<std::uint8_t>* image_out) {
  cv::Mat& radiance = *radiance_image;
  if (options.blur_sigma_px > 0) {
    cv::GaussianBlur(radiance, radiance, cv::Size(0, 0), options.blur_sigma_px);
  }
  std::mt19937 rng(options.seed * 7919u + static_cast<std::uint32_t>(k));
  std::normal_distribution<float> noise(0.0f, static_cast<float>(options.noise_sigma));
  std::vector<std::uint8_t>& image = *image_out;
  const std::size_t n = image.size();
  for (std::size_t i = 0; i < n; ++i) {
    float value = radiance.at<float>(static_cast<int>(i));
    if (options.gamma != 1.0) {
      value = 255.0f * std::pow(std::max(0.0f, value) / 255.0f, static_cast<float>(options.gamma));
    }
    if (options.noise_sigma > 0) value += noise(rng);
    image[i] = static_cast<std::uint8_t>(std::min(255.0f, std::max(0.0f, std::round(value))));
  }
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
  CheckCaptureInputs(scene, options);
  const camera::PinholeCamera& cam = rig.camera;
  const int width = cam.width();
  const int height = cam.height();
  const std::size_t n = static_cast<std::size_t>(width) * height;
  SyntheticCapture capture = MakeEmptyCapture(width, height);
  LightTransport transport;
  transport.ambient.assign(n, 0.0f);
  transport.row_samples.resize(height);
  transport.row_starts.resize(height);
  const Eigen::Isometry3d X_ProjectorCamera = rig.X_CameraProjector.inverse();
  const Eigen::Vector3d p_CameraProjector = rig.X_CameraProjector.translation();
  const camera::RayTable rays = cam.ComputeRayTable();
  const int samples = options.samples_per_axis;
  const PixelTracer tracer{scene,
                           rig,
                           rays,
                           options,
                           X_ProjectorCamera,
                           p_CameraProjector,
                           width,
                           height,
                           samples,
                           1.0 / (samples * samples)};

  BandPool pool;
  pool.Run(height, [&](int v) { TraceCameraRow(tracer, v, &capture, &transport); });

  const int num_images = patterns.num_images();
  capture.images.assign(num_images, std::vector<std::uint8_t>(n));
  pool.Run(num_images, [&](int k) {
    const PatternImage description = patterns.Describe(k);
    cv::Mat radiance = PatternRadiance(transport, patterns, description, width, height);
    ExposeImage(options, k, &radiance, &capture.images[k]);
  });
  return capture;
}

}  // namespace picking::scanner
