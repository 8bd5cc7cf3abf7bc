#pragma once

#include <memory>
#include <string>
#include <vector>

#include "services/scanner/core/camera_backend.h"

namespace picking::scanner {

/// A GenICam camera (USB3 Vision or GigE Vision, e.g. the Point Grey Flea3) through Aravis
/// 0.8, delivering Mono8 frames.
class AravisCamera final : public CameraBackend {
 public:
  /// Opens the camera named `device_id` (as listed by arv-tool or ListAravisCameras);
  /// an empty id opens the first camera found. Sets the pixel format to Mono8.
  /// `buffer_count` stream buffers are queued (>= 2). Throws CameraError naming the device
  /// when it cannot be opened or does not support Mono8.
  explicit AravisCamera(const std::string& device_id, int buffer_count = 64);
  ~AravisCamera() override;
  AravisCamera(const AravisCamera&) = delete;
  AravisCamera& operator=(const AravisCamera&) = delete;

  /// Sets exposure time and trigger mode (kFreeRun: TriggerMode Off; kSoftware: trigger
  /// source "Software"; kHardware: the settings' hardware line).
  void Configure(const CameraSettings& settings) override;
  /// Starts the acquisition (stale frames are discarded first); with kHardware the camera
  /// then waits for the trigger line. Throws CameraError when Configure was not called or
  /// the camera refuses to start.
  void Arm(int count) override;
  /// Arms unless armed for `count` frames, takes `count` frames (sending a software trigger
  /// before each in kSoftware mode; each waits up to frame_timeout_s plus the exposure), and
  /// stops the acquisition again, also after a failure. A frame that arrives incomplete
  /// (packets still missing after resend requests) is triggered again in kSoftware mode, up to
  /// the settings' dropped_frame_retries times; otherwise, and with a hardware trigger, it is
  /// a DroppedFrameError.
  std::vector<Frame> Capture(int count) override;
  std::uint32_t width() const override;
  std::uint32_t height() const override;

  /// The device id of the opened camera.
  const std::string& device_id() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Makes Aravis's built-in fake camera (the "Fake" interface, no network needed) visible to
/// device discovery, for tests and demos without hardware, and returns its device id
/// (e.g. "Fake_1"). Throws CameraError when the fake camera does not appear.
std::string EnableAravisFakeCamera();

/// Ids of every camera Aravis can see.
std::vector<std::string> ListAravisCameras();

}  // namespace picking::scanner
