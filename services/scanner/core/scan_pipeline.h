#pragma once

#include <Eigen/Geometry>

#include <cstddef>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "libs/camera/pinhole_camera.h"
#include "libs/geometry/point_cloud.h"
#include "services/scanner/core/camera_backend.h"
#include "services/scanner/core/decoder.h"
#include "services/scanner/core/merge.h"
#include "services/scanner/core/normals.h"
#include "services/scanner/core/patterns.h"
#include "services/scanner/core/projector_backend.h"
#include "services/scanner/core/triangulation.h"

namespace picking::scanner {

/// The calibration a scan is computed with.
struct ScanCalibration {
  camera::PinholeCamera camera;
  camera::PinholeCamera projector;  ///< Mirrors as pixels; columns x rows.
  Eigen::Isometry3d X_CameraProjector = Eigen::Isometry3d::Identity();
  /// Hand-eye calibration; needed for clouds in the base frame.
  std::optional<Eigen::Isometry3d> X_ToolCamera;
};

/// The frame of a scan's cloud.
enum class ScanFrame {
  kBase,    ///< Robot base ("base"): needs X_ToolCamera and each view's X_BaseTool.
  kCamera,  ///< Camera optical frame ("camera"): single view only.
};

/// One viewpoint.
struct ScanViewSpec {
  /// Flange pose at capture time (the robot is already there). Required for kBase.
  std::optional<Eigen::Isometry3d> X_BaseTool;
};

/// Options of ScanPipeline::Run. Defaults are the service's.
struct ScanOptions {
  DecoderOptions decode;
  /// Refine the integer correspondences to sub-pixel projector coordinates before
  /// triangulating (SubpixelRefiner): the depth error drops from the projector column step
  /// (~1.5 mm at 1 m) to a fraction of a millimetre, for 6-7 ms more per view with the
  /// default `refinement` (columns only; 14-17 ms with rows too; 2 threads, 1280 x 1024,
  /// quiet machine).
  bool subpixel = true;
  /// Pixels the refiner cannot refine (a camera coarser than the projector sees codes jump
  /// by more than one column between neighbours) keep their integer correspondence rather
  /// than being dropped, so refinement never costs coverage. Only the projector columns are
  /// refined (refine_rows = false): the rows add ~0.005 mm of median depth accuracy on the
  /// benchmark scene (0.150 -> 0.145 mm) for twice the refinement time.
  RefinementOptions refinement = [] {
    RefinementOptions r;
    r.reject_unrefined = false;
    r.refine_rows = false;
    return r;
  }();
  TriangulationOptions triangulation;  ///< frame_id is set by the pipeline.
  NormalOptions normals;
  bool with_normals = true;
  bool with_intensities = true;
  ScanFrame frame = ScanFrame::kBase;
  MergeOptions merge;
  /// Axis-aligned crop box in the output frame (min, max), metres; unset keeps all.
  std::optional<std::pair<Eigen::Vector3d, Eigen::Vector3d>> crop;
};

/// Per view figures.
struct ScanViewResult {
  double valid_fraction = 0.0;  ///< Camera pixels with a decoded correspondence.
  std::size_t num_points = 0;   ///< Triangulated points of the view (before merge / crop).
  Eigen::Isometry3d X_FrameCamera = Eigen::Isometry3d::Identity();  ///< Camera in output frame.
  double capture_time_s = 0.0;
  double processing_time_s = 0.0;
};

struct ScanResult {
  geometry::PointCloud cloud;  ///< Merged (and cropped) cloud in the output frame.
  std::size_t num_points = 0;  ///< Finite points in `cloud`.
  std::vector<ScanViewResult> views;
  double capture_time_s = 0.0;     ///< Projector set-up and frame capture, all views.
  double processing_time_s = 0.0;  ///< Decode, triangulate, normals, transform, merge, crop.
};

/// Stages reported to the progress callback.
enum class ScanStage { kCapture, kDecode, kTriangulate, kMerge };
/// "capture", "decode", "triangulate", "merge".
const char* ScanStageName(ScanStage stage);
using ScanProgress = std::function<void(int view_index, int view_count, ScanStage stage)>;

/// The sensor devices a scan drives.
struct ScanDevices {
  CameraBackend* camera = nullptr;        ///< Required.
  ProjectorBackend* projector = nullptr;  ///< Null: the camera's frames arrive by themselves
                                          ///< (a replayed recording, an external sequencer).
  /// Called before each view's capture with the view's X_BaseTool (e.g. to place a
  /// simulated sensor); may be empty.
  std::function<void(const std::optional<Eigen::Isometry3d>&)> before_capture;
};

/// The structured-light scan: for each view, project and capture the Gray-code sequence,
/// decode it, triangulate an organised cloud in the camera frame, estimate normals, move it
/// to the output frame with X_BaseTool * X_ToolCamera, then merge the views and crop.
///
/// Thread-safe: concurrent Run calls are serialised (there is one sensor).
class ScanPipeline final {
 public:
  /// @param patterns the projected sequence (its projector size must match the
  ///   calibration's projector).
  /// @throws std::invalid_argument when the projector sizes differ.
  ScanPipeline(ScanCalibration calibration, PatternSequence patterns,
               ProjectorSequenceSettings projector_settings = {});
  ~ScanPipeline();

  const ScanCalibration& calibration() const { return calibration_; }
  const PatternSequence& patterns() const { return patterns_; }

  /// Captures and processes `views` (empty: one view with no pose).
  /// @throws std::invalid_argument for bad options or several views with kCamera;
  ///   picking::PreconditionError when kBase lacks X_ToolCamera or a view's X_BaseTool, or
  ///   the camera's image size differs from the calibration's; picking::TimeoutError,
  ///   picking::DataLossError, picking::UnavailableError for camera / projector failures
  ///   (timeout, dropped frame, any other device error).
  ScanResult Run(const ScanDevices& devices, const std::vector<ScanViewSpec>& views,
                 const ScanOptions& options, const ScanProgress& progress = {});

  /// Captures one view's raw sequence (projector driven when present).
  /// @throws as Run for device failures.
  std::vector<GrayImage> Capture(const ScanDevices& devices,
                                 const std::optional<Eigen::Isometry3d>& X_BaseTool);

  /// Processes one view's captured images into a cloud in the camera frame (decode,
  /// triangulate, normals). Intensities are kept if options.with_intensities.
  /// @throws std::invalid_argument for a wrong image count or sizes.
  geometry::PointCloud ProcessView(const std::vector<GrayImage>& images, const ScanOptions& options,
                                   double* valid_fraction = nullptr);

 private:
  struct Cache;
  geometry::PointCloud ProcessViewLocked(const std::vector<GrayImage>& images,
                                         const ScanOptions& options, double* valid_fraction);
  ScanCalibration calibration_;
  PatternSequence patterns_;
  ProjectorSequenceSettings projector_settings_;
  std::mutex mutex_;
  std::unique_ptr<Cache> cache_;
};

}  // namespace picking::scanner
