#include "services/simulator/core/rgbd_sensor.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>

namespace picking::simulator {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr double kPi = 3.14159265358979323846;

// The infrared projector: a pinhole wide enough to light everything the depth camera sees
// from `baseline_m` beside it.
ScanPose SensorPose(const camera::PinholeCamera& camera, const Eigen::Isometry3d& X_BaseCamera,
                    double baseline_m) {
  const double f = camera.fx();
  const camera::PinholeCamera projector(2 * camera.width(), 2 * camera.height(), f, f,
                                        camera.width() - 0.5, camera.height() - 0.5);
  return {camera, X_BaseCamera, projector,
          X_BaseCamera * Eigen::Translation3d(baseline_m, 0.0, 0.0)};
}

// Angle between the surface normal and the reversed camera ray at pixel i, radians (pi/2
// without a surface).
double ViewAngle(const ScanGeometry& g, std::size_t i) {
  const Eigen::Vector3f& p = g.points_camera[i];
  const Eigen::Vector3f& n = g.normals_camera[i];
  if (!p.allFinite() || !n.allFinite()) return kPi / 2;
  const double c = -static_cast<double>(n.dot(p.normalized()));
  return std::acos(std::clamp(c, -1.0, 1.0));
}

// Whether the sensor measures pixel i, seen at `view_angle_rad`, at all: the pattern reaches
// it, comes back strongly enough, is seen at a usable angle and lies within the range.
bool Measurable(const ScanGeometry& g, std::size_t i, double view_angle_rad,
                const RgbdSensorOptions& options) {
  if (g.illumination[i] != Illumination::kLit) return false;  // shadowed, facing away, outside
  if (g.gain[i] < options.min_ir_signal) return false;        // dark, grazing or far
  const double z = g.depth_m[i];
  if (!(z >= options.min_depth_m && z <= options.max_depth_m)) return false;
  return view_angle_rad <= options.max_view_angle_deg * kPi / 180.0;
}

// Pixels within edge_width_px of a depth discontinuity of the scene (a neighbour farther
// than the jump, or no surface beside a surface): the matching window straddles two
// surfaces there.
std::vector<char> EdgeBand(const ScanGeometry& g, const RgbdSensorOptions& options) {
  const int w = g.width, h = g.height;
  std::vector<char> edge(g.size(), 0);
  auto jump = [&](float a, float b) {
    if (std::isnan(a) != std::isnan(b)) return true;
    if (std::isnan(a)) return false;
    const double z = std::min(a, b);
    return std::abs(a - b) > options.edge_jump_m + options.edge_jump_per_m * z;
  };
  // Both pixels of a jump, and those within edge_width_px - 1 of them.
  const int r = options.edge_width_px - 1;
  auto mark = [&](int u, int v) {
    for (int y = std::max(0, v - r); y <= std::min(h - 1, v + r); ++y) {
      for (int x = std::max(0, u - r); x <= std::min(w - 1, u + r); ++x) {
        edge[std::size_t(y) * w + x] = 1;
      }
    }
  };
  if (options.edge_width_px == 0) return edge;
  for (int v = 0; v < h; ++v) {
    for (int u = 0; u < w; ++u) {
      const float z = g.depth_m[std::size_t(v) * w + u];
      if (u + 1 < w && jump(z, g.depth_m[std::size_t(v) * w + u + 1])) {
        mark(u, v);
        mark(u + 1, v);
      }
      if (v + 1 < h && jump(z, g.depth_m[std::size_t(v + 1) * w + u])) {
        mark(u, v);
        mark(u, v + 1);
      }
    }
  }
  return edge;
}

// One noise stream per (seed, frame, row, channel): the frame does not depend on the order
// its rows are drawn in.
std::mt19937_64 RowStream(const RgbdSensorOptions& options, std::uint64_t frame, int row,
                          int channel) {
  std::seed_seq seq{
      static_cast<std::uint32_t>(options.seed), static_cast<std::uint32_t>(options.seed >> 32),
      static_cast<std::uint32_t>(frame),        static_cast<std::uint32_t>(frame >> 32),
      static_cast<std::uint32_t>(row),          static_cast<std::uint32_t>(channel)};
  return std::mt19937_64(seq);
}

// The measured depth of a true depth z seen at view angle theta: axial noise (Nguyen et al.),
// then the disparity f b / z rounded to the sensor's step.
float NoisyDepth(double z, double theta, double f_px, const RgbdSensorOptions& options,
                 std::mt19937_64& rng) {
  const double lateral = theta < kPi / 2 - 1e-3 ? 0.0001 / std::sqrt(z) * theta * theta /
                                                      ((kPi / 2 - theta) * (kPi / 2 - theta))
                                                : 0.0;
  const double sigma =
      options.noise_base_m + options.noise_quadratic_m * (z - 0.4) * (z - 0.4) + lateral;
  std::normal_distribution<double> normal(0.0, 1.0);
  double measured = z;
  if (options.noise_base_m > 0.0 || options.noise_quadratic_m > 0.0)
    measured += sigma * normal(rng);
  if (options.disparity_step_px > 0.0 && measured > 0.0) {
    const double fb = f_px * options.baseline_m;
    const double disparity = std::round(fb / measured / options.disparity_step_px);
    if (disparity <= 0.0) return kNaN;
    measured = fb / (disparity * options.disparity_step_px);
  }
  return static_cast<float>(measured);
}

// The colour camera's 8-bit value of reflectance `reflectance` lit by `irradiance`.
std::uint8_t ColourValue(double reflectance, double irradiance, const RgbdSensorOptions& options,
                         double noise_dn) {
  const double linear = std::clamp(options.colour_exposure * reflectance * irradiance, 0.0, 1.0);
  const double value = 255.0 * std::pow(linear, 1.0 / options.colour_gamma) + noise_dn;
  return static_cast<std::uint8_t>(std::clamp(std::round(value), 0.0, 255.0));
}

}  // namespace

void RgbdSensorOptions::Validate() const {
  auto fail = [](const std::string& field, const std::string& why) {
    throw std::invalid_argument("RgbdSensorOptions." + field + " " + why);
  };
  auto finite_at_least = [&](double value, double low, const char* field) {
    if (!(std::isfinite(value) && value >= low))
      fail(field, "must be finite and >= " + std::to_string(low));
  };
  if (!(std::isfinite(baseline_m) && baseline_m > 0.0)) fail("baseline_m", "must be > 0");
  finite_at_least(min_depth_m, 0.0, "min_depth_m");
  if (!(std::isfinite(max_depth_m) && max_depth_m > min_depth_m)) {
    fail("max_depth_m", "must be finite and > min_depth_m");
  }
  finite_at_least(min_ir_signal, 0.0, "min_ir_signal");
  if (!(std::isfinite(reference_distance_m) && reference_distance_m > 0.0)) {
    fail("reference_distance_m", "must be > 0");
  }
  if (!(max_view_angle_deg > 0.0 && max_view_angle_deg <= 90.0)) {
    fail("max_view_angle_deg", "must be in (0, 90]");
  }
  finite_at_least(edge_jump_m, 0.0, "edge_jump_m");
  finite_at_least(edge_jump_per_m, 0.0, "edge_jump_per_m");
  if (edge_width_px < 0 || edge_width_px > 8) fail("edge_width_px", "must be in [0, 8]");
  finite_at_least(noise_base_m, 0.0, "noise_base_m");
  finite_at_least(noise_quadratic_m, 0.0, "noise_quadratic_m");
  finite_at_least(disparity_step_px, 0.0, "disparity_step_px");
  finite_at_least(ambient_light, 0.0, "ambient_light");
  finite_at_least(ceiling_light, 0.0, "ceiling_light");
  finite_at_least(colour_exposure, 0.0, "colour_exposure");
  finite_at_least(colour_read_noise_dn, 0.0, "colour_read_noise_dn");
  if (!(std::isfinite(colour_gamma) && colour_gamma > 0.0)) fail("colour_gamma", "must be > 0");
  if (num_threads < 0) fail("num_threads", "must be >= 0");
}

std::size_t RgbdFrame::valid() const {
  return static_cast<std::size_t>(
      std::count_if(depth_m.begin(), depth_m.end(), [](float z) { return !std::isnan(z); }));
}

camera::PinholeCamera XtionDepthCamera() {
  return camera::PinholeCamera(640, 480, 570.3, 570.3, 319.5, 239.5);
}

RgbdFrame RenderRgbd(const StructuredLightRenderer& renderer, const camera::PinholeCamera& camera,
                     const Eigen::Isometry3d& X_BaseCamera, const RgbdSensorOptions& options,
                     std::uint64_t frame_index) {
  options.Validate();  // (Prepare below refuses a pose that is not a finite rigid one.)
  GeometryOptions geometry_options;
  geometry_options.reference_distance_m = options.reference_distance_m;
  geometry_options.num_threads = options.num_threads;
  geometry_options.colour = true;
  const ScanGeometry g =
      renderer.Prepare(SensorPose(camera, X_BaseCamera, options.baseline_m), geometry_options);

  RgbdFrame frame{camera, X_BaseCamera, std::vector<float>(g.size(), kNaN),
                  std::vector<std::array<std::uint8_t, 3>>(g.size(), {0, 0, 0}), g.object_index};
  const std::vector<char> edge = EdgeBand(g, options);
  // The ceiling light's direction in the camera frame (from a surface toward the light).
  const Eigen::Vector3f up_Camera =
      (X_BaseCamera.linear().transpose() * Eigen::Vector3d::UnitZ()).cast<float>();
  std::normal_distribution<double> normal(0.0, 1.0);
  for (int row = 0; row < g.height; ++row) {
    std::mt19937_64 depth_rng = RowStream(options, frame_index, row, 0);
    std::mt19937_64 colour_rng = RowStream(options, frame_index, row, 1);
    for (int column = 0; column < g.width; ++column) {
      const std::size_t i = std::size_t(row) * g.width + column;
      if (!edge[i]) {
        const double view_angle_rad = ViewAngle(g, i);
        if (Measurable(g, i, view_angle_rad, options)) {
          frame.depth_m[i] =
              NoisyDepth(g.depth_m[i], view_angle_rad, camera.fx(), options, depth_rng);
        }
      }
      if (g.object_index[i] < 0) continue;  // nothing there: black
      const double lambert = std::max(0.0f, g.normals_camera[i].dot(up_Camera));
      const double irradiance = options.ambient_light + options.ceiling_light * lambert;
      for (int c = 0; c < 3; ++c) {
        frame.rgb[i][c] = ColourValue(g.colour[i][c], irradiance, options,
                                      options.colour_read_noise_dn * normal(colour_rng));
      }
    }
  }
  return frame;
}

geometry::PointCloud ToOrganisedCloud(const RgbdFrame& frame) {
  geometry::PointCloud cloud;
  cloud.width = static_cast<std::uint32_t>(frame.camera.width());
  cloud.height = static_cast<std::uint32_t>(frame.camera.height());
  cloud.frame_id = "camera";
  cloud.points.resize(frame.size());
  cloud.colors = frame.rgb;
  for (int row = 0; row < frame.camera.height(); ++row) {
    for (int column = 0; column < frame.camera.width(); ++column) {
      const std::size_t i = std::size_t(row) * frame.camera.width() + column;
      const float z = frame.depth_m[i];
      cloud.points[i] =
          std::isnan(z)
              ? Eigen::Vector3f::Constant(kNaN)
              : (z * frame.camera.Unproject(Eigen::Vector2d(column, row))).cast<float>().eval();
    }
  }
  return cloud;
}

}  // namespace picking::simulator
