#include "services/gripper/core/gripper.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>

#include "libs/errors/errors.h"

namespace picking::gripper {
namespace {

std::string Format(const char* fmt, double value) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), fmt, value);
  return buf;
}

}  // namespace

Gripper::Gripper(std::unique_ptr<GripperBackend> backend, const GripperOptions& options,
                 std::shared_ptr<Clock> clock)
    : backend_(std::move(backend)),
      options_(options),
      clock_(std::move(clock)),
      seal_(options.seal) {
  if (!backend_) throw std::invalid_argument("Gripper: null backend");
  if (!clock_) throw std::invalid_argument("Gripper: null clock");
  if (!(options.poll_interval_s > 0.0) || !std::isfinite(options.poll_interval_s)) {
    throw std::invalid_argument("gripper poll_interval_s must be > 0, got " +
                                std::to_string(options.poll_interval_s));
  }
  if (!(options.max_joint_angle_rad > 0.0) || !std::isfinite(options.max_joint_angle_rad)) {
    throw std::invalid_argument("gripper max_joint_angle_rad must be > 0");
  }
  if (!(options.max_wait_for_seal_s >= 0.0) || !std::isfinite(options.max_wait_for_seal_s)) {
    throw std::invalid_argument("gripper max_wait_for_seal_s must be >= 0");
  }
}

GripperState Gripper::StateLocked() {
  GripperState state;
  state.kind = options_.kind;
  state.backend = backend_->name();
  state.reading = backend_->Read();
  if (options_.kind == GripperKind::kShelf) {
    // The shelf gripper has no joint: whatever the controller reports about a servo is
    // not part of this gripper.
    state.reading.joint_mode = JointMode::kUnactuated;
    state.reading.joint_angle_rad = 0.0;
  }
  state.item_attached = seal_.Update(state.reading.vacuum_on, state.reading.vacuum_kpa);
  return state;
}

GripperState Gripper::State() {
  std::lock_guard<std::mutex> lock(mutex_);
  return StateLocked();
}

GripperState Gripper::SetVacuum(bool on, double wait_for_seal_s, const CancelFn& cancelled) {
  if (!std::isfinite(wait_for_seal_s) || wait_for_seal_s < 0.0 ||
      wait_for_seal_s > options_.max_wait_for_seal_s) {
    throw std::invalid_argument("wait_for_seal_s must be in [0, " +
                                Format("%g", options_.max_wait_for_seal_s) + "] s, got " +
                                Format("%g", wait_for_seal_s));
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    backend_->SetVacuum(on);
    if (!on) seal_.Reset();
  }
  if (on && wait_for_seal_s > 0.0) return WaitForSeal(wait_for_seal_s, cancelled);
  return State();
}

GripperState Gripper::WaitForSeal(double timeout_s, const CancelFn& cancelled) {
  if (!std::isfinite(timeout_s) || timeout_s < 0.0) {
    throw std::invalid_argument("seal timeout must be finite and >= 0 s");
  }
  const Clock::time_point deadline = clock_->Now() + std::chrono::duration_cast<Clock::duration>(
                                                         std::chrono::duration<double>(timeout_s));
  const auto poll = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double>(options_.poll_interval_s));
  while (true) {
    const GripperState state = State();
    if (state.item_attached) return state;
    const Clock::time_point now = clock_->Now();
    if (now >= deadline) {
      throw TimeoutError("the vacuum did not reach the seal threshold of " +
                         Format("%.1f", options_.seal.attach_kpa) + " kPa within " +
                         Format("%g", timeout_s) + " s (last reading " +
                         Format("%.1f", state.reading.vacuum_kpa) + " kPa, pump " +
                         (state.reading.vacuum_on ? "on" : "off") + ")");
    }
    if (cancelled && cancelled()) {
      throw UnavailableError("the wait for a seal was cancelled (last reading " +
                             Format("%.1f", state.reading.vacuum_kpa) + " kPa)");
    }
    clock_->SleepFor(std::min(poll, deadline - now));
  }
}

GripperState Gripper::SetJointMode(JointMode mode, double angle_rad) {
  if (options_.kind == GripperKind::kShelf) {
    throw PreconditionError("the shelf gripper has no servo joint (setting kind=shelf)");
  }
  if (!std::isfinite(angle_rad)) {
    throw std::invalid_argument("angle_rad must be finite, got " + Format("%g", angle_rad));
  }
  if (mode == JointMode::kFixed && std::abs(angle_rad) > options_.max_joint_angle_rad) {
    throw std::invalid_argument("angle_rad " + Format("%.4f", angle_rad) +
                                " is outside the servo range [-" +
                                Format("%.4f", options_.max_joint_angle_rad) + ", " +
                                Format("%.4f", options_.max_joint_angle_rad) + "]");
  }
  std::lock_guard<std::mutex> lock(mutex_);
  backend_->SetJointMode(mode, mode == JointMode::kFixed ? angle_rad : 0.0);
  return StateLocked();
}

}  // namespace picking::gripper
