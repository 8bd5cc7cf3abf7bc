#include "services/gripper/core/clock.h"

#include <thread>

namespace picking::gripper {

SteadyClock::time_point SteadyClock::Now() { return std::chrono::steady_clock::now(); }

void SteadyClock::SleepFor(duration d) {
  if (d > duration::zero()) std::this_thread::sleep_for(d);
}

}  // namespace picking::gripper
