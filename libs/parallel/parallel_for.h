#pragma once

#include <memory>
#include <type_traits>

namespace picking::parallel {

/// The number of threads for a request: `requested` when positive, else
/// std::thread::hardware_concurrency() (1 when that is unknown).
int ResolveThreads(int requested);

/// A non-owning reference to a task, callable as fn(int task, int thread) or fn(int task),
/// returning void or bool (false: see "leaving" below). The callable is called through a
/// function pointer, nothing is allocated or copied; it must outlive the TaskRef (a lambda
/// passed straight to ParallelFor does).
class TaskRef {
 public:
  template <class F, class = std::enable_if_t<!std::is_same_v<std::decay_t<F>, TaskRef>>>
  TaskRef(const F& fn) noexcept  // NOLINT(google-explicit-constructor): lambdas convert.
      : fn_(static_cast<const void*>(&fn)), call_(&Call<F>) {
    static_assert(!std::is_function_v<F>, "TaskRef: pass a lambda or a function pointer");
    static_assert(std::is_invocable_v<const F&, int, int> || std::is_invocable_v<const F&, int>,
                  "TaskRef: the task must be callable as fn(int task, int thread) or fn(int task)");
  }

  /// Runs the task; false when the thread is to leave the job.
  bool operator()(int task, int thread) const { return call_(fn_, task, thread); }

 private:
  template <class F>
  static bool Call(const void* fn, int task, int thread) {
    const F& f = *static_cast<const F*>(fn);
    if constexpr (std::is_invocable_v<const F&, int, int>) {
      return Result(f, task, thread);
    } else {
      return Result(f, task);
    }
  }

  template <class F, class... Args>
  static bool Result(const F& f, Args... args) {
    using R = std::invoke_result_t<const F&, Args...>;
    static_assert(std::is_void_v<R> || std::is_same_v<R, bool>,
                  "TaskRef: the task must return void or bool");
    if constexpr (std::is_void_v<R>) {
      f(args...);
      return true;
    } else {
      return f(args...);
    }
  }

  const void* fn_;
  bool (*call_)(const void*, int, int);
};

// The contract of both ParallelFor below:
//
// Calls fn(task, thread) (or fn(task)) for every task in [0, num_tasks), each exactly once
// (unless a thread leaves, below), and returns when all are done. The calling thread works
// too, as thread 0; the others are numbered 1, 2, ... and `thread` is always
// < min(threads, num_tasks), so per-thread scratch and results can live in a vector of that
// size indexed by `thread`, without locking: one thread index is one OS thread for the whole
// call. Tasks are handed out in increasing order from a shared counter (one atomic increment
// per task, nothing else), but which thread runs which task is up to the schedule: merge
// per-thread results in an order that does not depend on it. With one thread (or one task)
// the tasks run in order on the caller.
//
// Leaving: a task that returns false makes its thread take no more tasks of the job (for a
// deadline that thread has seen pass); the other threads go on, and tasks that no thread
// takes any more do not run. A task that returns void never leaves.
//
// If a task throws, tasks not yet started are skipped and, once the threads have stopped,
// the first exception is rethrown.

/// A fixed pool of worker threads for jobs of many tasks. The threads are created once and
/// sleep between jobs, so a job costs a wake-up, not a thread start: for a caller that runs
/// jobs again and again (the scanner's bands of rows).
///
/// ParallelFor may be called from one thread at a time (calls are serialised by a mutex) and
/// not from inside one of its own tasks.
class ThreadPool {
 public:
  /// @param num_threads threads working on a job including the caller; 0 uses
  ///   ResolveThreads(0). @throws std::invalid_argument if negative.
  explicit ThreadPool(int num_threads = 0);
  ~ThreadPool();
  ThreadPool(const ThreadPool&) = delete;
  ThreadPool& operator=(const ThreadPool&) = delete;

  int num_threads() const;

  /// Runs the job on min(num_threads(), num_tasks) threads (see the contract above).
  void ParallelFor(int num_tasks, TaskRef fn);

 private:
  struct State;
  std::unique_ptr<State> state_;
};

/// Runs the job on min(ResolveThreads(num_threads), num_tasks) threads (see the contract
/// above), starting those beyond the caller for this call and joining them before it
/// returns: for a caller without a pool of its own. If the system refuses a thread, the job
/// runs on those it has. @throws std::invalid_argument if num_threads is negative.
void ParallelFor(int num_tasks, int num_threads, TaskRef fn);

}  // namespace picking::parallel
