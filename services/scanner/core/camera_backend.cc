#include "services/scanner/core/camera_backend.h"

#include <sstream>

namespace picking::scanner {

void ValidateCameraSettings(const CameraSettings& settings) {
  if (!(settings.exposure_us > 0.0)) {
    throw std::invalid_argument("CameraSettings.exposure_us must be > 0, got " +
                                std::to_string(settings.exposure_us));
  }
  if (!(settings.frame_timeout_s > 0.0)) {
    throw std::invalid_argument("CameraSettings.frame_timeout_s must be > 0, got " +
                                std::to_string(settings.frame_timeout_s));
  }
  if (settings.dropped_frame_retries < 0) {
    throw std::invalid_argument("CameraSettings.dropped_frame_retries must be >= 0, got " +
                                std::to_string(settings.dropped_frame_retries));
  }
  if (settings.trigger_mode == TriggerMode::kHardware && settings.hardware_trigger_line.empty()) {
    throw std::invalid_argument(
        "CameraSettings.hardware_trigger_line must name a line for TriggerMode::kHardware");
  }
}

void CameraBackend::Arm(int count) {
  if (count <= 0) {
    throw std::invalid_argument("CameraBackend::Arm: count must be > 0, got " +
                                std::to_string(count));
  }
}

void CheckConsecutiveFrameIds(const std::vector<std::uint64_t>& ids) {
  for (std::size_t i = 1; i < ids.size(); ++i) {
    const std::uint64_t expected = ids[i - 1] + 1;
    const bool wrapped16 = ids[i - 1] == 0xFFFF && ids[i] == 1;
    if (ids[i] != expected && !wrapped16) {
      std::ostringstream message;
      message << "dropped frame: frame " << i << " of the capture has id " << ids[i]
              << ", expected " << expected << " (previous id " << ids[i - 1] << ")";
      throw DroppedFrameError(message.str());
    }
  }
}

void CheckConsecutiveFrameIds(const std::vector<Frame>& frames) {
  std::vector<std::uint64_t> ids;
  ids.reserve(frames.size());
  for (const Frame& frame : frames) ids.push_back(frame.frame_id);
  CheckConsecutiveFrameIds(ids);
}

}  // namespace picking::scanner
