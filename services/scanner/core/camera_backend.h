#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace picking::scanner {

/// An 8-bit monochrome image, row-major, `pixels.size() == width * height`.
struct GrayImage {
  std::uint32_t width = 0;
  std::uint32_t height = 0;
  std::vector<std::uint8_t> pixels;

  GrayImage() = default;
  /// A `width` x `height` image filled with `value`.
  GrayImage(std::uint32_t w, std::uint32_t h, std::uint8_t value = 0)
      : width(w), height(h), pixels(static_cast<std::size_t>(w) * h, value) {}

  bool empty() const { return pixels.empty(); }
  std::uint8_t at(std::uint32_t x, std::uint32_t y) const {
    return pixels[static_cast<std::size_t>(y) * width + x];
  }
  std::uint8_t& at(std::uint32_t x, std::uint32_t y) {
    return pixels[static_cast<std::size_t>(y) * width + x];
  }
};

/// One captured frame: the image and the identifiers the camera gave it.
struct Frame {
  GrayImage image;
  std::uint64_t frame_id = 0;  ///< Camera frame counter; consecutive frames differ by 1.
  double timestamp_s = 0.0;    ///< Camera timestamp in seconds (0 when unknown).
};

/// How a capture is started.
enum class TriggerMode {
  kFreeRun,   ///< The camera streams at its own frame rate.
  kSoftware,  ///< The host triggers each frame.
  kHardware,  ///< An external line (the projector's trigger out) starts each exposure.
};

/// Settings applied by `CameraBackend::Configure`.
struct CameraSettings {
  double exposure_us = 8000.0;  ///< Exposure time, microseconds, > 0.
  TriggerMode trigger_mode = TriggerMode::kHardware;
  std::string hardware_trigger_line = "Line0";  ///< GenICam TriggerSource for kHardware.
  double frame_timeout_s = 1.0;                 ///< Longest wait for one frame, seconds, > 0.
  /// kSoftware only: how many times a frame that arrives incomplete is triggered again
  /// before the capture fails (>= 0). A hardware-triggered frame cannot be taken again: the
  /// projector has moved on to the next pattern.
  int dropped_frame_retries = 2;
};

/// Any failure of a camera (not found, refused a setting, stream error).
class CameraError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// No frame arrived within `CameraSettings::frame_timeout_s`.
class CameraTimeoutError : public CameraError {
 public:
  using CameraError::CameraError;
};

/// The frame ids of a capture are not consecutive: at least one frame was lost.
class DroppedFrameError : public CameraError {
 public:
  using CameraError::CameraError;
};

/// A monochrome camera as the scanner uses it. Implementations: AravisCamera (GenICam),
/// ReplayCamera (a folder of images), and the simulator's camera.
class CameraBackend {
 public:
  virtual ~CameraBackend() = default;

  /// Applies `settings`. Throws std::invalid_argument for a non-positive exposure or
  /// timeout, CameraError when the device refuses a setting.
  virtual void Configure(const CameraSettings& settings) = 0;

  /// Arms the camera for the next `count` > 0 frames: when Arm returns, the camera waits
  /// for its trigger (the projector's trigger output with TriggerMode::kHardware), so a
  /// projector started afterwards loses no frame. The next Capture(count) collects the armed
  /// frames; Capture without Arm arms by itself. Arming again re-arms. Cameras whose frames
  /// cannot be missed (a replayed recording, a rendered camera) need not do anything, which
  /// is the default. Throws std::invalid_argument for count <= 0, CameraError when the
  /// device refuses to start.
  virtual void Arm(int count);

  /// Captures `count` > 0 frames, one per trigger in order, as 8-bit images. Throws
  /// CameraTimeoutError when a frame does not arrive in time, DroppedFrameError when the
  /// camera's frame ids show a lost frame or a frame arrived incomplete (and was not taken
  /// again), CameraError for any other device or stream failure. The backend checks the ids:
  /// a frame taken again after an incomplete one leaves a gap in the returned frames' ids.
  /// After a failure the camera is disarmed and can capture again.
  virtual std::vector<Frame> Capture(int count) = 0;

  /// Image size in pixels of the frames `Capture` returns.
  virtual std::uint32_t width() const = 0;
  virtual std::uint32_t height() const = 0;
};

/// Throws std::invalid_argument naming the field when `settings` is out of range.
void ValidateCameraSettings(const CameraSettings& settings);

/// Throws DroppedFrameError naming the first gap when the frame ids of `frames` are not
/// consecutive (each id is the previous one plus 1). A 16-bit counter that wraps from 65535
/// to 1 (GigE Vision 1.x block ids, which skip 0) counts as consecutive.
void CheckConsecutiveFrameIds(const std::vector<Frame>& frames);
/// The same check on frame ids received one after the other.
void CheckConsecutiveFrameIds(const std::vector<std::uint64_t>& frame_ids);

}  // namespace picking::scanner
