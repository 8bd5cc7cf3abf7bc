#pragma once

#include <chrono>

namespace picking::gripper {

/// Time source for waits, injectable so tests advance time without sleeping.
class Clock {
 public:
  using time_point = std::chrono::steady_clock::time_point;
  using duration = std::chrono::steady_clock::duration;

  virtual ~Clock() = default;
  virtual time_point Now() = 0;
  /// Lets `d` pass (a real clock sleeps; a test clock advances).
  virtual void SleepFor(duration d) = 0;
};

/// std::chrono::steady_clock and std::this_thread::sleep_for.
class SteadyClock final : public Clock {
 public:
  time_point Now() override;
  void SleepFor(duration d) override;
};

}  // namespace picking::gripper
