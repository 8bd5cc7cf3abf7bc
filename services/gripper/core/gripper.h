#pragma once

#include <functional>
#include <memory>
#include <mutex>

#include "services/gripper/core/clock.h"
#include "services/gripper/core/gripper_backend.h"
#include "services/gripper/core/gripper_types.h"
#include "services/gripper/core/seal_detector.h"

namespace picking::gripper {

/// Settings of a Gripper.
struct GripperOptions {
  GripperKind kind = GripperKind::kTote;
  SealOptions seal;
  /// Interval between vacuum readings while waiting for a seal, seconds (> 0).
  double poll_interval_s = 0.02;
  /// Servo joint range, radians: fixed angles must lie in [-max, +max].
  double max_joint_angle_rad = 1.5707963267948966;
  /// Longest accepted wait for a seal, seconds.
  double max_wait_for_seal_s = 10.0;
};

/// One gripper: validates requests, turns backend readings into a state with the seal
/// decision, and waits for a seal. Thread safe; backend calls are serialised.
class Gripper final {
 public:
  /// Throws std::invalid_argument for a null backend or clock or bad options.
  Gripper(std::unique_ptr<GripperBackend> backend, const GripperOptions& options,
          std::shared_ptr<Clock> clock = std::make_shared<SteadyClock>());

  /// Asked between readings while waiting; true ends the wait (the caller went away or the
  /// server is stopping).
  using CancelFn = std::function<bool()>;

  /// Switches the vacuum. With `on` and `wait_for_seal_s` > 0, waits until the vacuum shows
  /// a seal. Throws std::invalid_argument for a wait that is NaN or outside
  /// [0, max_wait_for_seal_s]; TimeoutError (the pump stays on) when no seal comes in time;
  /// UnavailableError when `cancelled` ends the wait.
  GripperState SetVacuum(bool on, double wait_for_seal_s = 0.0, const CancelFn& cancelled = {});

  /// Reads the backend and decides whether an item is attached.
  GripperState State();

  /// Polls State() until an item is attached or `timeout_s` passes (TimeoutError naming the
  /// last vacuum level and the threshold), or `cancelled` returns true (UnavailableError).
  GripperState WaitForSeal(double timeout_s, const CancelFn& cancelled = {});

  /// Sets the servo joint mode. Throws PreconditionError on the shelf gripper (no joint),
  /// std::invalid_argument for a NaN angle or a fixed angle outside the servo range.
  GripperState SetJointMode(JointMode mode, double angle_rad = 0.0);

  const GripperOptions& options() const { return options_; }

 private:
  GripperState StateLocked();

  std::unique_ptr<GripperBackend> backend_;
  const GripperOptions options_;
  std::shared_ptr<Clock> clock_;
  std::mutex mutex_;
  SealDetector seal_;
};

}  // namespace picking::gripper
