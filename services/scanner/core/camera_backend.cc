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

void CheckConsecutiveFrameIds(const std::vector<Frame>& frames) {
  for (std::size_t i = 1; i < frames.size(); ++i) {
    const std::uint64_t expected = frames[i - 1].frame_id + 1;
    const bool wrapped16 = frames[i - 1].frame_id == 0xFFFF && frames[i].frame_id == 1;
    if (frames[i].frame_id != expected && !wrapped16) {
      std::ostringstream message;
      message << "dropped frame: frame " << i << " of the capture has id " << frames[i].frame_id
              << ", expected " << expected << " (previous id " << frames[i - 1].frame_id << ")";
      throw DroppedFrameError(message.str());
    }
  }
}

}  // namespace picking::scanner
