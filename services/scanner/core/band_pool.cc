#include "services/scanner/core/band_pool.h"

#include <atomic>
#include <condition_variable>
#include <exception>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace picking::scanner {

struct BandPool::State {
  int num_threads = 1;
  std::vector<std::thread> workers;

  std::mutex run_mutex;  // Serialises Run() callers.

  std::mutex mutex;
  std::condition_variable wake;
  std::condition_variable done;
  std::uint64_t generation = 0;
  bool stop = false;
  int busy_workers = 0;

  // The current job.
  const std::function<void(int)>* fn = nullptr;
  int num_tasks = 0;
  std::atomic<int> next_task{0};
  std::exception_ptr error;

  void Work() {
    for (;;) {
      const int task = next_task.fetch_add(1, std::memory_order_relaxed);
      if (task >= num_tasks) return;
      try {
        (*fn)(task);
      } catch (...) {
        std::lock_guard<std::mutex> lock(mutex);
        if (!error) error = std::current_exception();
      }
    }
  }

  void WorkerLoop() {
    std::uint64_t seen = 0;
    for (;;) {
      {
        std::unique_lock<std::mutex> lock(mutex);
        wake.wait(lock, [&] { return stop || generation != seen; });
        if (stop) return;
        seen = generation;
      }
      Work();
      {
        std::lock_guard<std::mutex> lock(mutex);
        if (--busy_workers == 0) done.notify_one();
      }
    }
  }
};

BandPool::BandPool(int num_threads) : state_(std::make_unique<State>()) {
  if (num_threads < 0) {
    throw std::invalid_argument("BandPool: num_threads must not be negative, got " +
                                std::to_string(num_threads));
  }
  if (num_threads == 0) {
    num_threads = static_cast<int>(std::thread::hardware_concurrency());
    if (num_threads <= 0) num_threads = 1;
  }
  state_->num_threads = num_threads;
  for (int i = 1; i < num_threads; ++i) {
    state_->workers.emplace_back([s = state_.get()] { s->WorkerLoop(); });
  }
}

BandPool::~BandPool() {
  {
    std::lock_guard<std::mutex> lock(state_->mutex);
    state_->stop = true;
  }
  state_->wake.notify_all();
  for (std::thread& worker : state_->workers) worker.join();
}

int BandPool::num_threads() const { return state_->num_threads; }

void BandPool::Run(int num_tasks, const std::function<void(int)>& fn) {
  if (num_tasks <= 0) return;
  State& s = *state_;
  std::lock_guard<std::mutex> run_lock(s.run_mutex);
  if (s.workers.empty() || num_tasks == 1) {
    for (int i = 0; i < num_tasks; ++i) fn(i);
    return;
  }
  {
    std::lock_guard<std::mutex> lock(s.mutex);
    s.fn = &fn;
    s.num_tasks = num_tasks;
    s.next_task.store(0, std::memory_order_relaxed);
    s.error = nullptr;
    s.busy_workers = static_cast<int>(s.workers.size());
    ++s.generation;
  }
  s.wake.notify_all();
  s.Work();
  std::exception_ptr error;
  {
    std::unique_lock<std::mutex> lock(s.mutex);
    s.done.wait(lock, [&] { return s.busy_workers == 0; });
    s.fn = nullptr;
    error = s.error;
  }
  if (error) std::rethrow_exception(error);
}

}  // namespace picking::scanner
