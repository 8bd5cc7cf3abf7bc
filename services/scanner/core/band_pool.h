#pragma once

#include "libs/parallel/parallel_for.h"

namespace picking::scanner {

/// The scanner's pool for the bands of an image-sized job: a parallel::ThreadPool (threads
/// created once, sleeping between jobs) under the name the scanner's code knows it by.
/// Run(n, fn) is ParallelFor(n, fn): fn(band) or fn(band, thread) for every band in [0, n),
/// each exactly once, spread over the workers and the calling thread.
class BandPool final : public parallel::ThreadPool {
 public:
  using parallel::ThreadPool::ThreadPool;

  void Run(int num_tasks, parallel::TaskRef fn) { ParallelFor(num_tasks, fn); }
};

}  // namespace picking::scanner
