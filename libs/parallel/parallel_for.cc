#include "libs/parallel/parallel_for.h"

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <mutex>
#include <stdexcept>
#include <string>
#include <system_error>
#include <thread>
#include <vector>

namespace picking::parallel {
namespace {

// One call's tasks, shared by the threads working on it.
struct Job {
  Job(TaskRef task_fn, int tasks) : fn(task_fn), num_tasks(tasks) {}

  const TaskRef fn;
  const int num_tasks;
  // The next task to hand out; 64 bits so that the increments past num_tasks (one per
  // thread, and the jump of a failure) cannot wrap.
  std::atomic<std::int64_t> next{0};
  std::mutex error_mutex;
  std::exception_ptr error;  // The first exception of a task.
};

// Takes tasks of `job` as thread `thread` until there are none left or a task says to leave.
void Work(Job& job, int thread) {
  for (std::int64_t task = job.next.fetch_add(1, std::memory_order_relaxed); task < job.num_tasks;
       task = job.next.fetch_add(1, std::memory_order_relaxed)) {
    try {
      if (!job.fn(static_cast<int>(task), thread)) return;
    } catch (...) {
      std::lock_guard<std::mutex> lock(job.error_mutex);
      if (!job.error) job.error = std::current_exception();
      job.next.store(job.num_tasks, std::memory_order_relaxed);  // Skip the tasks not started.
    }
  }
}

void RunSerially(int num_tasks, TaskRef fn) {
  for (int task = 0; task < num_tasks; ++task) {
    if (!fn(task, 0)) return;
  }
}

}  // namespace

int ResolveThreads(int requested) {
  if (requested > 0) return requested;
  const unsigned hw = std::thread::hardware_concurrency();
  return hw == 0 ? 1 : static_cast<int>(hw);
}

struct ThreadPool::State {
  int num_threads = 1;
  std::vector<std::thread> workers;  // workers[i] is thread i + 1.

  std::mutex run_mutex;  // Serialises ParallelFor callers.

  std::mutex mutex;
  std::condition_variable wake;
  std::condition_variable done;
  std::uint64_t generation = 0;
  bool stop = false;
  // The current job and the threads on it (caller included): workers 1 ... active - 1.
  Job* job = nullptr;
  int active = 0;
  int busy_workers = 0;

  // Wakes the workers to return and joins them.
  void StopWorkers() {
    {
      std::lock_guard<std::mutex> lock(mutex);
      stop = true;
    }
    wake.notify_all();
    for (std::thread& worker : workers) worker.join();
  }

  void WorkerLoop(int thread) {
    std::uint64_t seen = 0;
    for (;;) {
      Job* current = nullptr;
      {
        std::unique_lock<std::mutex> lock(mutex);
        wake.wait(lock, [&] { return stop || generation != seen; });
        if (stop) return;
        seen = generation;
        if (thread >= active) continue;  // A job of fewer tasks than threads.
        current = job;
      }
      Work(*current, thread);
      {
        std::lock_guard<std::mutex> lock(mutex);
        if (--busy_workers == 0) done.notify_one();
      }
    }
  }
};

ThreadPool::ThreadPool(int num_threads) : state_(std::make_unique<State>()) {
  if (num_threads < 0) {
    throw std::invalid_argument("ThreadPool: num_threads must not be negative, got " +
                                std::to_string(num_threads));
  }
  num_threads = ResolveThreads(num_threads);
  state_->num_threads = num_threads;
  state_->workers.reserve(num_threads - 1);
  try {
    for (int t = 1; t < num_threads; ++t) {
      state_->workers.emplace_back([s = state_.get(), t] { s->WorkerLoop(t); });
    }
  } catch (...) {
    state_->StopWorkers();  // The ones started, before they are destroyed.
    throw;
  }
}

ThreadPool::~ThreadPool() { state_->StopWorkers(); }

int ThreadPool::num_threads() const { return state_->num_threads; }

void ThreadPool::ParallelFor(int num_tasks, TaskRef fn) {
  if (num_tasks <= 0) return;
  State& s = *state_;
  std::lock_guard<std::mutex> run_lock(s.run_mutex);
  const int threads = std::min(s.num_threads, num_tasks);
  if (threads <= 1) {
    RunSerially(num_tasks, fn);
    return;
  }
  Job job(fn, num_tasks);
  {
    std::lock_guard<std::mutex> lock(s.mutex);
    s.job = &job;
    s.active = threads;
    s.busy_workers = threads - 1;
    ++s.generation;
  }
  s.wake.notify_all();
  Work(job, 0);
  {
    std::unique_lock<std::mutex> lock(s.mutex);
    s.done.wait(lock, [&] { return s.busy_workers == 0; });
    s.job = nullptr;
  }
  if (job.error) std::rethrow_exception(job.error);
}

void ParallelFor(int num_tasks, int num_threads, TaskRef fn) {
  if (num_threads < 0) {
    throw std::invalid_argument("ParallelFor: num_threads must not be negative, got " +
                                std::to_string(num_threads));
  }
  if (num_tasks <= 0) return;
  const int threads = std::min(ResolveThreads(num_threads), num_tasks);
  if (threads <= 1) {
    RunSerially(num_tasks, fn);
    return;
  }
  Job job(fn, num_tasks);
  std::vector<std::thread> workers;
  workers.reserve(threads - 1);
  for (int t = 1; t < threads; ++t) {
    try {
      workers.emplace_back([&job, t] { Work(job, t); });
    } catch (const std::system_error&) {
      break;  // No more threads: the ones started and the caller do the job.
    }
  }
  Work(job, 0);
  for (std::thread& worker : workers) worker.join();
  if (job.error) std::rethrow_exception(job.error);
}

}  // namespace picking::parallel
