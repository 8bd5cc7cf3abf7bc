#pragma once

#include "libs/camera/pinhole_camera.h"
#include "libs/geometry/point_cloud.h"
#include "services/scanner/core/decoder.h"
#include "services/scanner/core/normals.h"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstddef>
#include <memory>
#include <string>
#include <vector>

namespace picking::scanner {

class BandPool;

struct TriangulationOptions {
  /// A point is kept only if the camera ray and the projector ray of its correspondence
  /// pass within this many projector pixels of each other (the width of one projector pixel
  /// at the point's distance from the projector). Integer correspondences give up to
  /// ~0.5 px; a misread bit gives far more.
  double max_residual_projector_px = 1.5;
  double min_depth_m = 0.05;  ///< Points with camera z outside [min, max] are dropped.
  double max_depth_m = 5.0;
  /// Drop points with fewer than `min_neighbors` of their 8 neighbours closer than
  /// `neighbor_depth_tolerance_m` in depth (isolated decoding errors, flying pixels).
  bool remove_isolated = true;
  int min_neighbors = 3;
  double neighbor_depth_tolerance_m = 0.01;
  std::string frame_id = "camera";  ///< frame_id of the output cloud.
  int num_threads = 0;              ///< Threads including the caller; 0 = all cores.
};

struct TriangulationResult {
  /// Organised cloud, one point per camera pixel (width x height, row-major), p_CameraPoint
  /// in metres; NaN where there is no point. Intensities (0-1) if an intensity image was
  /// given, else empty. No normals (see EstimateNormals).
  geometry::PointCloud cloud;
  std::size_t num_points = 0;             ///< Finite points in the cloud.
  std::size_t num_rejected_residual = 0;  ///< Valid correspondences failing the residual.
  std::size_t num_rejected_depth = 0;     ///< ... or the depth range.
  std::size_t num_removed_isolated = 0;   ///< ... or the neighbour test.
};

/// Triangulates camera-to-projector correspondences into an organised point cloud.
///
/// A projector column is a plane through the projector centre and a row another; their
/// intersection is the ray of projector pixel (column, row). The point of a camera pixel is
/// where its camera ray meets that projector ray in the least-squares sense (the point on
/// the camera ray closest to the projector ray), which is the least-squares intersection of
/// the camera ray with the column and row planes when those are perpendicular. With a
/// horizontal baseline the column carries the depth and the row mainly checks consistency:
/// the distance between the two rays is the residual.
///
/// Lens distortion is handled exactly: with projector distortion the mirrors of one column
/// do not lie on a plane, so instead of column and row planes the constructor precomputes
/// the undistorted ray of every projector pixel centre (as the camera's ray table does for
/// the camera), and Run() costs a few multiply-adds per pixel. Rows are computed by
/// vectorised kernels (ray intersection, isolated-point test, normals; AVX2 where the CPU has
/// it, chosen at load time). On Linux, fresh output buffers (a new cloud per call is ~37 MB
/// at 1280 x 1024) are advised for transparent huge pages and populated by the tasks that
/// write them, instead of taking a page fault per 4 KiB page.
class Triangulator final {
 public:
  /// @param camera the camera model (its size must match the correspondence maps).
  /// @param projector the projector model; its width x height are the columns x rows.
  /// @param X_CameraProjector pose of the projector frame in the camera frame.
  /// @throws std::invalid_argument for a negative residual, a depth range with
  ///   min_depth_m <= 0 or max_depth_m <= min_depth_m, min_neighbors outside [0, 8], a
  ///   negative depth tolerance or num_threads, or a non-rigid X_CameraProjector.
  Triangulator(const camera::PinholeCamera& camera, const camera::PinholeCamera& projector,
               const Eigen::Isometry3d& X_CameraProjector,
               const TriangulationOptions& options = {});
  ~Triangulator();
  Triangulator(const Triangulator&) = delete;
  Triangulator& operator=(const Triangulator&) = delete;

  const TriangulationOptions& options() const { return options_; }

  /// Triangulates `map`. `intensity` (optional) supplies the intensities, usually the
  /// all-white capture. If the map carries sub-pixel coordinates (map.has_subpixel(), see
  /// SubpixelRefiner) they are used: the projector ray of a non-integer projector pixel is
  /// interpolated bilinearly between the precomputed rays of the four nearest mirrors;
  /// otherwise the integer column and row are used.
  /// @throws std::invalid_argument if the map's size differs from the camera's or its
  ///   buffers (including present sub-pixel maps) are not width * height long, a valid
  ///   correspondence (integer or sub-pixel) lies outside the projector, or the intensity
  ///   image's size differs.
  TriangulationResult Run(const CorrespondenceMap& map, const ImageView* intensity = nullptr) const;

  /// As above, reusing the buffers of `result`.
  void Run(const CorrespondenceMap& map, const ImageView* intensity,
           TriangulationResult* result) const;

  /// As above, and the cloud's normals too: the result equals Run(map, intensity, result)
  /// followed by EstimateNormals(&result->cloud, normal_options) (normal_options.num_threads
  /// is ignored; this triangulator's threads are used), but each row is filtered and its
  /// normals computed while it is in cache rather than in two more passes over the cloud.
  /// Fills result->cloud.normals and, if not null, normal_result.
  /// @throws as Run, and std::invalid_argument for bad normal_options (see EstimateNormals)
  ///   or a camera with a single row. The result is untouched then.
  void Run(const CorrespondenceMap& map, const ImageView* intensity,
           const NormalOptions& normal_options, TriangulationResult* result,
           NormalResult* normal_result = nullptr) const;

 private:
  void RunImpl(const CorrespondenceMap& map, const ImageView* intensity,
               const NormalOptions* normal_options, TriangulationResult* result,
               NormalResult* normal_result) const;
  // Validation stage of RunImpl: throws unless the map and intensity image fit the camera.
  void CheckInputSizes(const CorrespondenceMap& map, const ImageView* intensity) const;
  // Validation stage of RunImpl: throws unless every valid correspondence is in the projector.
  void CheckCorrespondencesInside(const CorrespondenceMap& map) const;
  // Setup stage of RunImpl: sizes the cloud (intensities if any, normals if with_normals).
  void SizeOutputs(const ImageView* intensity, bool with_normals,
                   geometry::PointCloud* cloud_out) const;

  int camera_width_;
  int camera_height_;
  int projector_width_;
  int projector_height_;
  TriangulationOptions options_;
  float projector_focal_px_;
  Eigen::Vector3f p_CameraProjector_;
  std::vector<Eigen::Vector2f> rays_;  // Camera ray (x, y, 1) per pixel.
  // Per projector pixel (row-major): unit ray direction e in the camera frame and -e . o,
  // o the projector centre in the camera frame.
  std::vector<Eigen::Vector4f> projector_rays_;
  std::unique_ptr<BandPool> pool_;
};

}  // namespace picking::scanner
