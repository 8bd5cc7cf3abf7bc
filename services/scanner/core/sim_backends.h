#pragma once

#include <Eigen/Geometry>

#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include "libs/camera/pinhole_camera.h"
#include "services/scanner/core/camera_backend.h"
#include "services/scanner/core/patterns.h"
#include "services/scanner/core/projector_backend.h"

namespace picking::scanner {

/// The true geometry of a simulated scanner: what the simulator renders with. Its
/// calibration (the values the scanner triangulates with) may differ, as a real sensor's
/// does from its nominal design.
struct SimSensorModel {
  camera::PinholeCamera camera;
  camera::PinholeCamera projector;                                      ///< Mirrors as pixels.
  Eigen::Isometry3d X_CameraProjector = Eigen::Isometry3d::Identity();  ///< Projector in camera.
  Eigen::Isometry3d X_ToolCamera = Eigen::Isometry3d::Identity();       ///< Camera in flange.
};

/// One rendering job: what the camera sees while the projector shows `patterns` in turn.
struct PatternRenderRequest {
  camera::PinholeCamera camera;
  Eigen::Isometry3d X_BaseCamera = Eigen::Isometry3d::Identity();
  camera::PinholeCamera projector;
  Eigen::Isometry3d X_BaseProjector = Eigen::Isometry3d::Identity();
  int column_bits = 10;  ///< Gray-code bits of the column patterns.
  int row_bits = 11;     ///< Gray-code bits of the row patterns.
  std::vector<PatternImage> patterns;
  double exposure = 1.0;   ///< Exposure relative to the nominal one (CameraSettings).
  std::uint64_t seed = 1;  ///< Noise seed of this capture.
};

/// Renders camera images of projected patterns (the simulator's RenderPatterns behind a
/// network client, or an analytic scene in tests).
class PatternRenderer {
 public:
  virtual ~PatternRenderer() = default;
  /// Returns one camera-sized image per pattern, in order. Throws picking::UnavailableError
  /// when the renderer cannot be reached, std::runtime_error for other failures.
  virtual std::vector<GrayImage> Render(const PatternRenderRequest& request) = 0;
};

/// State shared by a simulated projector and camera: the loaded pattern sequence, how far
/// it has been shown, and where the robot holds the sensor. Thread-safe.
class SimSensorLink final {
 public:
  /// @param tool_pose_source where the flange is when no pose was set for a capture (e.g.
  ///   the simulator's arm); may be empty, in which case a capture needs SetToolPose.
  explicit SimSensorLink(std::function<Eigen::Isometry3d()> tool_pose_source = {});

  /// Sets X_BaseTool for the following captures; nullopt returns to the pose source.
  /// @throws std::invalid_argument if the pose is not a finite rigid transform.
  void SetToolPose(const std::optional<Eigen::Isometry3d>& X_BaseTool);
  /// X_BaseTool now: the one set, else the source's. @throws picking::PreconditionError
  ///   when neither is available.
  Eigen::Isometry3d ToolPose() const;

  /// Projector side (see ProjectorBackend).
  void LoadSequence(const ProjectorSequenceSettings& settings);
  void Start();
  void Stop();

  /// Camera side: the next `count` patterns of the running sequence. Throws
  /// CameraTimeoutError when no sequence runs or fewer than `count` patterns are left (a
  /// triggered camera would wait in vain); nothing is consumed then.
  std::vector<PatternImage> TakePatterns(int count, ProjectorSequenceSettings* settings);

 private:
  std::function<Eigen::Isometry3d()> tool_pose_source_;
  mutable std::mutex mutex_;
  std::optional<Eigen::Isometry3d> X_BaseTool_;
  std::optional<ProjectorSequenceSettings> sequence_;
  bool running_ = false;
  int next_pattern_ = 0;
};

/// The simulated DLP projector: records the sequence in the link; the simulated camera
/// renders what it shows.
class SimProjector final : public ProjectorBackend {
 public:
  /// @throws std::invalid_argument for a null link or a non-positive size.
  SimProjector(std::shared_ptr<SimSensorLink> link, std::uint32_t width, std::uint32_t height);
  std::uint32_t width() const override { return width_; }
  std::uint32_t height() const override { return height_; }
  /// Throws std::invalid_argument for bad settings or codes that do not cover the mirrors.
  void LoadSequence(const ProjectorSequenceSettings& settings) override;
  void Start() override;
  void Stop() override;

 private:
  std::shared_ptr<SimSensorLink> link_;
  std::uint32_t width_;
  std::uint32_t height_;
};

/// The simulated camera: each Capture renders the next patterns of the running projector
/// sequence from the current sensor pose, X_BaseCamera = X_BaseTool * X_ToolCamera and
/// X_BaseProjector = X_BaseCamera * X_CameraProjector, with the model's true intrinsics.
class SimCamera final : public CameraBackend {
 public:
  /// Nominal exposure; CameraSettings::exposure_us is passed on relative to it.
  static constexpr double kNominalExposureUs = 8000.0;

  /// @throws std::invalid_argument for a null link or renderer.
  SimCamera(std::shared_ptr<SimSensorLink> link, std::shared_ptr<PatternRenderer> renderer,
            SimSensorModel model, std::uint64_t seed = 1);

  void Configure(const CameraSettings& settings) override;
  /// Throws CameraTimeoutError when the projector shows nothing (see
  /// SimSensorLink::TakePatterns), CameraError when the renderer returns the wrong number or
  /// size of images; a renderer's UnavailableError passes through.
  std::vector<Frame> Capture(int count) override;
  std::uint32_t width() const override { return model_.camera.width(); }
  std::uint32_t height() const override { return model_.camera.height(); }

 private:
  std::shared_ptr<SimSensorLink> link_;
  std::shared_ptr<PatternRenderer> renderer_;
  SimSensorModel model_;
  CameraSettings settings_;
  std::uint64_t seed_;
  std::uint64_t captures_ = 0;
  std::uint64_t next_frame_id_ = 0;
};

}  // namespace picking::scanner
