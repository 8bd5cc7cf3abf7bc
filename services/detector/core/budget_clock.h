#pragma once

#include <pthread.h>
#include <time.h>

#include <chrono>
#include <functional>
#include <stdexcept>
#include <utility>

namespace picking::detector {

/// The clock by which the detector judges its time budgets and search deadlines: whether an
/// item's fallback method is started (DetectionChain), when PPF voting, refinement,
/// verification and the box polish stop, when the range-template search stops. Every such
/// decision reads the time from here; by default that is the steady clock, as in production.
///
/// Time points are std::chrono::steady_clock's, so budgets and deadlines keep their type
/// whichever clock judges them. A test gives a clock of its own (Frozen: no budget ever runs
/// out, and a search is the same on a busy machine as on a quiet one; or one it advances
/// itself). The durations the detector reports (DetectionTimings, ChainAttempt::duration_s)
/// are measured on the steady clock regardless: they inform, they decide nothing. A call's
/// deadline (SceneContext::set_deadline) is the client's wall-clock deadline and stays on the
/// steady clock too.
///
/// Cheap to copy; copies share the time source.
class BudgetClock final {
 public:
  using time_point = std::chrono::steady_clock::time_point;
  using duration = std::chrono::steady_clock::duration;

  /// The steady clock.
  BudgetClock() = default;

  /// Reads the time from `now`, which must be safe to call from several threads at once (the
  /// searches read it on their worker threads) and must never go backwards. Throws
  /// std::invalid_argument when `now` is empty.
  explicit BudgetClock(std::function<time_point()> now) : now_(std::move(now)) {
    if (!now_) throw std::invalid_argument("BudgetClock: empty time source");
  }

  /// A clock standing still at `at`: a deadline after `at` never passes, one before it always
  /// has.
  static BudgetClock Frozen(time_point at = time_point()) {
    return BudgetClock([at] { return at; });
  }

  /// The CPU time of `thread`, read from any thread of the process (the searches' workers
  /// read the caller's): time passes only while that thread runs. The caller of a
  /// ParallelFor works as its thread 0, so on a quiet machine this keeps the steady clock's
  /// pace; on a busy one a budget is not spent while the thread waits for a core, and the
  /// search is the one a quiet machine makes, only slower. `thread` must outlive the clock's
  /// use. Throws std::runtime_error when the thread has no CPU clock.
  static BudgetClock ThreadCpu(pthread_t thread) {
    clockid_t id;
    if (pthread_getcpuclockid(thread, &id) != 0) {
      throw std::runtime_error("BudgetClock: the thread has no CPU-time clock");
    }
    return BudgetClock([id] {
      timespec ts{};
      clock_gettime(id, &ts);
      return time_point(std::chrono::duration_cast<duration>(std::chrono::seconds(ts.tv_sec) +
                                                             std::chrono::nanoseconds(ts.tv_nsec)));
    });
  }

  time_point Now() const { return now_ ? now_() : std::chrono::steady_clock::now(); }

 private:
  std::function<time_point()> now_;  // empty: std::chrono::steady_clock::now
};

}  // namespace picking::detector
