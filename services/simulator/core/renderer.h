#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "libs/camera/pinhole_camera.h"
#include "libs/geometry/point_cloud.h"
#include "libs/world/mesh.h"

namespace picking::simulator {

/// An 8-bit single-channel image, row-major, `pixels.size() == width * height`.
struct GrayImage {
  int width = 0;
  int height = 0;
  std::vector<std::uint8_t> pixels;

  GrayImage() = default;
  /// Throws std::invalid_argument if a size is negative.
  GrayImage(int width, int height, std::uint8_t fill = 0);
  std::uint8_t at(int column, int row) const { return pixels[std::size_t(row) * width + column]; }
  std::uint8_t& at(int column, int row) { return pixels[std::size_t(row) * width + column]; }
};

/// One mesh placed in the scene. The renderer copies the mesh, so it need not outlive it.
struct SceneObject {
  const world::TriangleMesh* mesh = nullptr;
  Eigen::Isometry3d X_BaseObject = Eigen::Isometry3d::Identity();
};

/// How the projector light reaches a camera pixel (ScanGeometry::illumination).
enum class Illumination : std::uint8_t {
  kNoSurface = 0,         ///< The camera ray hits nothing.
  kLit = 1,               ///< The projector lights the surface point.
  kShadowed = 2,          ///< Something lies between the surface point and the projector.
  kOutsideProjector = 3,  ///< The point is outside the projector's image (or behind it).
  kFacingAway = 4,        ///< The surface seen by the camera faces away from the projector.
};

/// Sensor geometry of one scan pose (poses in the robot base frame, metres). Both models
/// follow camera::PinholeCamera's conventions (z forward, x right, y down; pixel centres at
/// integer coordinates); the projector is modelled as an inverse camera.
struct ScanPose {
  camera::PinholeCamera camera;
  Eigen::Isometry3d X_BaseCamera;
  camera::PinholeCamera projector;
  Eigen::Isometry3d X_BaseProjector;
};

/// Options of StructuredLightRenderer::Prepare (pattern independent).
struct GeometryOptions {
  /// Scale the projector irradiance by (reference_distance_m / r)^2, r the distance from the
  /// projector centre to the surface point. Default on.
  bool inverse_square_falloff = true;
  /// Distance at which the falloff factor is 1 (metres, > 0). Default 0.8 m, the scanner's
  /// working distance.
  double reference_distance_m = 0.8;
  /// Offset of shadow-ray origins along the normal, metres (>= 0). Default 0.1 mm.
  double shadow_epsilon_m = 1e-4;
  /// Worker threads; 0 = std::thread::hardware_concurrency(). Default 0.
  int num_threads = 0;
  /// Also fill ScanGeometry::colour (the meshes' vertex colours; grey at the albedo without
  /// them). Default off: the structured-light camera is monochrome.
  bool colour = false;
};

/// Per-camera-pixel result of the pattern-independent ray casting, row-major with
/// `width * height` entries each. Ground truth for tests and scoring, and the lookup table
/// for shading. Pixels without a surface hold NaN points / depth and object index -1.
struct ScanGeometry {
  int width = 0;             ///< Camera width, pixels.
  int height = 0;            ///< Camera height, pixels.
  int projector_width = 0;   ///< Projector width, pixels (size of the projected images).
  int projector_height = 0;  ///< Projector height, pixels.
  /// Depth: z of the surface point in the camera frame, metres (NaN: no surface).
  std::vector<float> depth_m;
  /// p_CameraPoint: surface point in the camera frame, metres (NaN: no surface).
  std::vector<Eigen::Vector3f> points_camera;
  /// Unit surface normal in the camera frame, turned toward the camera (NaN: no surface).
  std::vector<Eigen::Vector3f> normals_camera;
  /// Index of the hit object in the renderer's object list, -1 if none.
  std::vector<std::int32_t> object_index;
  /// Interpolated albedo of the surface in [0, 1] (0: no surface).
  std::vector<float> albedo;
  /// RGB reflectance of the surface in [0, 1] (0: no surface) with GeometryOptions::colour,
  /// else empty.
  std::vector<Eigen::Vector3f> colour;
  /// How the projector reaches the pixel's surface point.
  std::vector<Illumination> illumination;
  /// Distorted projector pixel coordinates of the surface point (NaN unless kLit).
  std::vector<Eigen::Vector2f> projector_uv;
  /// albedo * cos(angle between normal and direction to the projector) * falloff (0 unless
  /// kLit): camera signal per unit projector light.
  std::vector<float> gain;

  std::size_t size() const { return std::size_t(width) * height; }
};

/// Ground-truth depth image of one camera pose: z of the first surface along each pixel
/// centre's ray, in the camera frame (metres), row-major with `width * height` entries; NaN
/// where the ray hits nothing.
struct DepthImage {
  int width = 0;   ///< Camera width, pixels.
  int height = 0;  ///< Camera height, pixels.
  std::vector<float> depth_m;

  std::size_t size() const { return std::size_t(width) * height; }
  float at(int column, int row) const { return depth_m[std::size_t(row) * width + column]; }
};

/// How a projector image value is sampled at a sub-pixel projector coordinate.
enum class ProjectorSampling : std::uint8_t { kNearest, kBilinear };

/// Options of RenderImage / RenderSequence (per pattern). The camera signal in digital
/// numbers (DN, 0-255 full scale) of a pixel with albedo a, gain g and projector light L in
/// [0, 1] is  s = 255 * exposure * (ambient * a + projector_brightness * g * L),  with
/// L = (value / 255)^projector_gamma sampled at the pixel's projector coordinates. Gaussian
/// noise of variance read_noise_dn^2 + s / electrons_per_dn (read and shot noise) is added
/// to s, drawn from a seeded stream per (seed, frame, camera row) so the result does not
/// depend on the thread count; then the camera response 255 * (s / 255)^(1 / camera_gamma)
/// is rounded and clamped to 8 bits.
struct RenderOptions {
  double ambient = 0.03;              ///< Ambient irradiance, relative to full projector (>= 0).
  double projector_brightness = 1.0;  ///< Projector white irradiance at the reference distance.
  double exposure = 0.85;             ///< Camera exposure scale (>= 0).
  double projector_gamma = 1.0;       ///< Projector response exponent (> 0); 1 = linear.
  double camera_gamma = 1.0;          ///< Camera response gamma (> 0); 1 = linear.
  double read_noise_dn = 1.0;         ///< Read-noise sigma, DN (>= 0).
  double electrons_per_dn = 40.0;     ///< Conversion gain for shot noise (> 0); 0 = no shot noise.
  /// Gaussian blur of the projected image (projector defocus / pixel footprint), sigma in
  /// projector pixels (>= 0); 0 = off.
  double projector_blur_sigma_px = 0.0;
  ProjectorSampling sampling = ProjectorSampling::kBilinear;
  std::uint64_t seed = 1;  ///< Noise seed; the same seed and frame give the same image.
  int num_threads = 0;     ///< Worker threads; 0 = hardware_concurrency.

  /// Throws std::invalid_argument naming the field if a value is out of range.
  void Validate() const;
};

/// Renders what the structured-light scanner's camera sees while its projector shows a given
/// image, by ray casting (Embree 3) a scene of triangle meshes.
///
/// Usage: build with the scene, call Prepare() once per scan pose (camera rays, hit points,
/// normals, albedo, shadow rays to the projector, projector coordinates), then RenderImage()
/// or RenderSequence() for each projected pattern, which only looks up the projector image.
/// Prepare() is thread safe with itself; SetObjects / SetObjectPose must not run
/// concurrently with anything else on the same renderer.
class StructuredLightRenderer final {
 public:
  /// Builds the scene (the meshes are copied; X_BaseObject places each in the robot base
  /// frame). Throws std::invalid_argument naming the object index and field if a mesh is
  /// null, has a vertex index out of range, a non-finite vertex, an albedo outside [0, 1],
  /// a vertex_albedo of the wrong size, or a pose that is not a finite rigid transform;
  /// std::runtime_error if Embree fails.
  explicit StructuredLightRenderer(const std::vector<SceneObject>& objects);
  ~StructuredLightRenderer();
  StructuredLightRenderer(const StructuredLightRenderer&) = delete;
  StructuredLightRenderer& operator=(const StructuredLightRenderer&) = delete;

  /// Replaces the whole scene (same checks as the constructor; on error nothing changes).
  void SetObjects(const std::vector<SceneObject>& objects);

  /// Moves object `index` to X_BaseObject (its mesh is unchanged). Throws std::out_of_range
  /// for a bad index and std::invalid_argument for a non-finite pose.
  void SetObjectPose(std::size_t index, const Eigen::Isometry3d& X_BaseObject);

  std::size_t num_objects() const;
  std::size_t num_triangles() const;

  /// Pattern-independent ray casting for one sensor pose: one ray per camera pixel centre
  /// (through the lens distortion), a shadow ray from each hit toward the projector centre.
  /// The camera's per-pixel rays are cached for the last few camera models. Throws
  /// std::invalid_argument if a pose is not a finite rigid transform or an option is
  /// out of range.
  ScanGeometry Prepare(const ScanPose& pose, const GeometryOptions& options = {}) const;

  /// Prepare() into an existing ScanGeometry, reusing its buffers (no allocation when the
  /// camera size is unchanged). On a thrown error `*geometry` is unchanged.
  void Prepare(const ScanPose& pose, const GeometryOptions& options, ScanGeometry* geometry) const;

  /// Ground-truth depth of what `camera` sees from X_BaseCamera (base frame, metres): the
  /// same camera rays as Prepare() (pixel centres through the lens distortion, same ray
  /// cache), without any projector, so the result equals Prepare()'s ScanGeometry::depth_m
  /// bit for bit. `num_threads` 0 = hardware_concurrency. Throws std::invalid_argument if
  /// the pose is not a finite rigid transform or num_threads is negative.
  DepthImage RenderDepth(const camera::PinholeCamera& camera, const Eigen::Isometry3d& X_BaseCamera,
                         int num_threads = 0) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Camera image (camera width x height) when the projector shows `projector_image`, which
/// must have the projector model's size. `frame_index` selects the noise realisation.
/// Throws std::invalid_argument if the sizes disagree or an option is invalid.
GrayImage RenderImage(const ScanGeometry& geometry, const GrayImage& projector_image,
                      const RenderOptions& options, std::uint64_t frame_index = 0);

/// RenderImage for each image of a sequence (frame_index = position in the sequence), all
/// images sharing one pool of threads working on row blocks.
std::vector<GrayImage> RenderSequence(const ScanGeometry& geometry,
                                      const std::vector<GrayImage>& projector_images,
                                      const RenderOptions& options);

/// RenderSequence into `camera_images`, resized to the sequence length, reusing the buffers
/// of images that already have the camera's size (a scan loop then allocates nothing).
/// Image k is frame first_frame + k (its noise realisation), so a long sequence rendered in
/// parts with first_frame = the part's offset equals the sequence rendered at once.
void RenderSequence(const ScanGeometry& geometry, const std::vector<GrayImage>& projector_images,
                    const RenderOptions& options, std::vector<GrayImage>* camera_images,
                    std::uint64_t first_frame = 0);

/// The ground truth as an organised point cloud in the camera frame (frame_id "camera"):
/// points, normals and albedo as intensity; NaN where the camera sees nothing.
geometry::PointCloud GroundTruthCloud(const ScanGeometry& geometry);

}  // namespace picking::simulator
