#pragma once

#include "libs/camera/pinhole_camera.h"
#include "services/scanner/core/decoder.h"
#include "services/scanner/core/patterns.h"

#include <Eigen/Geometry>

#include <cstdint>
#include <vector>

namespace picking::scanner {

/// A camera and a projector with their relative pose: the scanner's geometry.
struct ScannerRig {
  camera::PinholeCamera camera;
  camera::PinholeCamera projector;  ///< Pixels are mirror (column, row).
  Eigen::Isometry3d X_CameraProjector = Eigen::Isometry3d::Identity();
};

/// A rig like the paper's scanner: a 1280 x 1024 camera with an 8 mm lens (scaled to the
/// requested camera size) and a 912 x 1140 projector, 0.15 m to the camera's right and
/// turned towards it so that both views overlap at about 1 m. Mild lens distortion on both.
ScannerRig MakeExampleRig(int camera_width = 1280, int camera_height = 1024);

/// Analytic scene for synthetic captures, in the camera frame, metres.
struct SyntheticPlane {
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  ///< Unit normal (either orientation).
  double offset_m = 1.0;  ///< The plane is { p : normal . p == offset_m }.
  double albedo = 0.8;
};
struct SyntheticSphere {
  Eigen::Vector3d center_m = Eigen::Vector3d(0, 0, 1);
  double radius_m = 0.1;
  double albedo = 0.6;
};
/// A printed chessboard: a flat rectangle in the plane z = 0 of its board frame (the frame of
/// ChessboardSpec: origin at the first inner corner, x along a row of inner corners, y along a
/// column). The (inner_corners_x + 1) x (inner_corners_y + 1) squares are surrounded by a
/// light margin; the square diagonally outside the first inner corner is dark.
struct SyntheticChessboard {
  Eigen::Isometry3d X_CameraBoard = Eigen::Isometry3d::Identity();  ///< Board pose, metres.
  int inner_corners_x = 9;
  int inner_corners_y = 6;
  double square_size_m = 0.03;
  double margin_m = 0.03;  ///< Light border around the squares, metres.
  double dark_albedo = 0.2;
  double light_albedo = 0.9;
};
/// A box (e.g. a shelf), in its own frame spanning [-half_size, +half_size] on each axis.
struct SyntheticBox {
  Eigen::Isometry3d X_CameraBox = Eigen::Isometry3d::Identity();  ///< Pose of the box centre.
  Eigen::Vector3d half_size_m = Eigen::Vector3d::Constant(0.1);   ///< Half edge lengths, > 0.
  double albedo = 0.7;
};
struct SyntheticScene {
  std::vector<SyntheticPlane> planes;
  std::vector<SyntheticSphere> spheres;
  std::vector<SyntheticChessboard> boards;
  std::vector<SyntheticBox> boxes;
};

/// Image formation of the synthetic capture, in 8-bit grey levels.
struct SyntheticCaptureOptions {
  double projector_level = 220.0;  ///< Radiance of a lit, albedo-1 surface facing the projector.
  double ambient_level = 12.0;     ///< Radiance of albedo 1 from ambient light alone.
  double blur_sigma_px = 0.0;      ///< Gaussian optical blur, camera pixels (0 = none).
  double noise_sigma = 0.0;        ///< Gaussian sensor noise, grey levels (0 = none).
  double gamma = 1.0;              ///< Response: out = 255 * (in / 255)^gamma.
  std::uint32_t seed = 1;          ///< Seed of the noise generator.
  /// Area sampling: each pixel integrates a regular grid of n x n rays over its square (the
  /// way a sensor pixel integrates light), so that a pixel straddling a projector stripe edge
  /// gets a mixed grey level. 1 samples the pixel centre only; in [1, 16].
  int samples_per_axis = 1;
};

/// Rendered captures with the ground truth they were rendered from.
struct SyntheticCapture {
  int width = 0;
  int height = 0;
  std::vector<std::vector<std::uint8_t>> images;  ///< In PatternSequence order.
  /// Projector column / row (nearest mirror) whose light reaches each camera pixel, -1 where
  /// none does (no surface, outside the projector, facing away or in shadow).
  std::vector<std::int32_t> column;
  std::vector<std::int32_t> row;
  /// Continuous projector coordinates (column = u, row = v, pixel centres at integers) of the
  /// surface point at each camera pixel centre; NaN where `column` is -1.
  std::vector<float> column_exact;
  std::vector<float> row_exact;
  /// Depth z (metres, camera frame) of the surface each pixel sees, NaN where none.
  std::vector<float> depth_m;

  std::vector<ImageView> views() const;
};

/// Renders the pattern sequence as the rig's camera sees it on `scene` by ray casting each
/// camera pixel centre (or samples_per_axis^2 points spread over each pixel), with shadows
/// cast from the projector, Lambertian shading, ambient light, then blur, gamma and noise.
/// Each ray is lit by the projector mirror nearest to where it meets the projector image.
/// Deterministic for a given seed.
/// @throws std::invalid_argument for a negative blur or noise, a gamma <= 0, or
///   samples_per_axis outside [1, 16].
SyntheticCapture RenderSyntheticCapture(const ScannerRig& rig, const PatternSequence& patterns,
                                        const SyntheticScene& scene,
                                        const SyntheticCaptureOptions& options);

}  // namespace picking::scanner
