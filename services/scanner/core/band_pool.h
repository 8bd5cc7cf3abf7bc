#pragma once

#include <functional>
#include <memory>

namespace picking::scanner {

/// A small fixed pool of worker threads that runs the bands of an image-sized job in
/// parallel: Run(n, fn) calls fn(0) ... fn(n - 1), each exactly once, spread over the
/// workers and the calling thread, and returns when all are done. Threads are created once
/// and sleep between jobs, so a job costs a wake-up, not a thread start.
///
/// Run may be called from one thread at a time (calls are serialised by a mutex).
class BandPool final {
 public:
  /// @param num_threads threads working on a job including the caller; 0 uses
  ///   std::thread::hardware_concurrency(). @throws std::invalid_argument if negative.
  explicit BandPool(int num_threads = 0);
  ~BandPool();
  BandPool(const BandPool&) = delete;
  BandPool& operator=(const BandPool&) = delete;

  int num_threads() const;

  /// Runs fn(i) for every i in [0, num_tasks). If a task throws, the remaining tasks still
  /// run and the first exception is rethrown here.
  void Run(int num_tasks, const std::function<void(int)>& fn);

 private:
  struct State;
  std::unique_ptr<State> state_;
};

}  // namespace picking::scanner
