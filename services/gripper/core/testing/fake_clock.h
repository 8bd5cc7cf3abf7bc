#pragma once

#include <mutex>

#include "services/gripper/core/clock.h"

namespace picking::gripper::testing {

/// A clock that only moves when someone sleeps on it: waits in tests take no time.
class FakeClock final : public Clock {
 public:
  time_point Now() override {
    std::lock_guard<std::mutex> lock(mutex_);
    return now_;
  }
  void SleepFor(duration d) override {
    std::lock_guard<std::mutex> lock(mutex_);
    if (d > duration::zero()) now_ += d;
    ++sleeps_;
  }
  /// Seconds since the clock was made.
  double elapsed_s() {
    std::lock_guard<std::mutex> lock(mutex_);
    return std::chrono::duration<double>(now_ - time_point()).count();
  }
  int sleeps() {
    std::lock_guard<std::mutex> lock(mutex_);
    return sleeps_;
  }

 private:
  std::mutex mutex_;
  time_point now_{};
  int sleeps_ = 0;
};

}  // namespace picking::gripper::testing
