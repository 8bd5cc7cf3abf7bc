#include "services/gripper/core/seal_detector.h"

#include <cmath>
#include <stdexcept>
#include <string>

namespace picking::gripper {

SealDetector::SealDetector(const SealOptions& options) : options_(options) {
  if (!std::isfinite(options.attach_kpa) || !std::isfinite(options.release_kpa) ||
      options.release_kpa < 0.0 || options.release_kpa >= options.attach_kpa) {
    throw std::invalid_argument(
        "seal thresholds: need 0 <= release_kpa < attach_kpa, got release " +
        std::to_string(options.release_kpa) + " kPa, attach " + std::to_string(options.attach_kpa) +
        " kPa");
  }
}

bool SealDetector::Update(bool vacuum_on, double vacuum_kpa) {
  if (!vacuum_on || !std::isfinite(vacuum_kpa)) {
    attached_ = false;
  } else if (attached_) {
    attached_ = vacuum_kpa >= options_.release_kpa;
  } else {
    attached_ = vacuum_kpa >= options_.attach_kpa;
  }
  return attached_;
}

}  // namespace picking::gripper
