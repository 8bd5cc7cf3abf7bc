#pragma once

#include <string>

#include "services/gripper/core/gripper_types.h"

namespace picking::gripper {

/// The hardware edge of the gripper: the serial micro controller or the simulator.
/// Implementations are thread safe (calls may come from several gRPC threads) and throw
/// the errors of libs/errors/errors.h: UnavailableError when the device or peer does not
/// answer, std::invalid_argument when it refuses an argument, PreconditionError when it
/// refuses in its present state.
class GripperBackend {
 public:
  virtual ~GripperBackend() = default;

  /// "serial" or "sim".
  virtual std::string name() const = 0;

  /// Switches the vacuum pump on or off. Returns without waiting for a seal.
  virtual void SetVacuum(bool on) = 0;

  /// Reads vacuum level, servo and accelerometer.
  virtual GripperReading Read() = 0;

  /// Sets the servo joint mode; `angle_rad` is the held angle for JointMode::kFixed
  /// (validated by the caller to be finite and within the servo's range) and ignored
  /// otherwise.
  virtual void SetJointMode(JointMode mode, double angle_rad) = 0;
};

}  // namespace picking::gripper
