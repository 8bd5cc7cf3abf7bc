#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <cstdint>
#include <vector>

#include "libs/camera/pinhole_camera.h"
#include "libs/geometry/point_cloud.h"
#include "services/simulator/core/renderer.h"

namespace picking::simulator {

/// A commodity RGB-D camera of the Kinect v1 / Asus Xtion kind: an infrared projector casts a
/// dot pattern that an infrared camera beside it, `baseline_m` away along the camera's +x,
/// matches block by block, and a colour camera registered to the depth image sees the scene
/// under the room's light. What such a sensor gets wrong, and this model reproduces:
///   - holes where the projector's pattern does not reach what the camera sees (the shadow
///     beside every near edge, surfaces facing away), where too little of it comes back
///     (dark surfaces, grazing angles, far away), outside its range, and along depth
///     discontinuities, where the matching window straddles two surfaces;
///   - axial noise growing with the square of the distance and with the incidence angle
///     (Nguyen, Izadi and Lovell, 3DIMPVT 2012, for the Kinect v1), on disparities quantised
///     to 1/8 pixel as the sensor reports them;
///   - a colour image lit by ambient light and a ceiling light (Lambert), with read noise and
///     the sRGB-like gamma of a consumer camera, no projector pattern in it.
/// Shiny surfaces are not modelled (the meshes carry no specularity).
struct RgbdSensorOptions {
  /// The infrared projector's offset from the depth camera along its +x axis, metres (> 0).
  double baseline_m = 0.075;
  /// Depth range, metres: nearer or farther pixels are holes.
  double min_depth_m = 0.4;
  double max_depth_m = 4.0;
  /// Smallest returned infrared signal, albedo * cos(incidence at the projector) *
  /// (reference_distance_m / r)^2; below it the pattern is lost (dark, grazing or far).
  double min_ir_signal = 0.03;
  double reference_distance_m = 1.0;
  /// Largest angle between the surface normal and the camera ray with a depth, degrees.
  double max_view_angle_deg = 78.0;
  /// A pixel next to a neighbour whose depth differs by more than
  /// edge_jump_m + edge_jump_per_m * depth is a hole, `edge_width_px` pixels each way.
  double edge_jump_m = 0.01;
  double edge_jump_per_m = 0.02;
  int edge_width_px = 1;
  /// Axial noise sigma = noise_base_m + noise_quadratic_m * (z - 0.4)^2 + an incidence term
  /// (Nguyen et al.); 0 for both turns the noise off.
  double noise_base_m = 0.0012;
  double noise_quadratic_m = 0.0019;
  /// Disparity steps, pixels (the Kinect v1 reports 1/8 pixel); 0 = no quantisation.
  double disparity_step_px = 0.125;
  /// Colour: ambient irradiance and a light from straight above (base +z), relative.
  double ambient_light = 0.35;
  double ceiling_light = 0.65;
  double colour_exposure = 0.9;
  double colour_read_noise_dn = 2.0;
  double colour_gamma = 2.2;
  std::uint64_t seed = 1;
  int num_threads = 0;  ///< For the ray casting; 0 = hardware_concurrency.

  /// Throws std::invalid_argument naming the field.
  void Validate() const;
};

/// One registered RGB-D frame, row-major `camera.width() * camera.height()` entries each.
struct RgbdFrame {
  camera::PinholeCamera camera;  ///< The depth camera (the colour image is registered to it).
  Eigen::Isometry3d X_BaseCamera = Eigen::Isometry3d::Identity();
  std::vector<float> depth_m;                    ///< z in the camera frame; NaN: a hole.
  std::vector<std::array<std::uint8_t, 3>> rgb;  ///< The colour image.
  std::vector<std::int32_t> object_index;        ///< Ground truth: what each pixel sees, -1.

  std::size_t size() const { return depth_m.size(); }
  /// Pixels with a depth.
  std::size_t valid() const;
};

/// The Xtion's depth camera: 640 x 480, focal length 570.3 pixels, no distortion.
camera::PinholeCamera XtionDepthCamera();

/// Renders one frame of the sensor at X_BaseCamera (base frame, metres; the camera looks along
/// its +z). `frame_index` selects the noise realisation (with options.seed). Throws
/// std::invalid_argument for a bad option or pose.
RgbdFrame RenderRgbd(const StructuredLightRenderer& renderer, const camera::PinholeCamera& camera,
                     const Eigen::Isometry3d& X_BaseCamera, const RgbdSensorOptions& options,
                     std::uint64_t frame_index = 0);

/// The frame as the sensor's driver gives it: an organised cloud in the camera frame
/// (frame_id "camera"), NaN at the holes, with the colours.
geometry::PointCloud ToOrganisedCloud(const RgbdFrame& frame);

}  // namespace picking::simulator
