#include "libs/parallel/parallel_for.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <thread>
#include <vector>

namespace picking::parallel {
namespace {

// What one job saw: how often each task ran, the largest thread index, and whether every
// thread index stayed on one OS thread.
struct Record {
  explicit Record(int num_tasks, int max_threads)
      : runs(std::make_unique<std::atomic<int>[]>(std::max(1, num_tasks))),
        thread_ids(std::max(1, max_threads)) {
    for (int i = 0; i < num_tasks; ++i) runs[i] = 0;
  }

  void Saw(int task, int thread) {
    runs[task].fetch_add(1);
    std::lock_guard<std::mutex> lock(mutex);
    max_thread = std::max(max_thread, thread);
    min_thread = std::min(min_thread, thread);
    if (thread < 0 || thread >= static_cast<int>(thread_ids.size())) return;  // Checked below.
    if (thread_ids[thread] == std::thread::id()) thread_ids[thread] = std::this_thread::get_id();
    if (thread_ids[thread] != std::this_thread::get_id()) shared_index = true;
  }

  std::unique_ptr<std::atomic<int>[]> runs;
  std::mutex mutex;
  std::vector<std::thread::id> thread_ids;
  int max_thread = -1;
  int min_thread = 1 << 30;
  bool shared_index = false;
};

void ExpectEachTaskOnceAndThreadsInRange(Record& r, int num_tasks, int threads) {
  for (int i = 0; i < num_tasks; ++i) EXPECT_EQ(r.runs[i].load(), 1) << "task " << i;
  if (num_tasks > 0) {
    EXPECT_GE(r.min_thread, 0);
    EXPECT_LT(r.max_thread, std::min(threads, num_tasks));
  }
  EXPECT_FALSE(r.shared_index) << "a thread index was used by two OS threads";
}

TEST(ParallelForTest, RunsEveryTaskOnceWithThreadIndicesInRange) {
  for (int threads : {1, 2, 3, 8}) {
    for (int num_tasks : {0, 1, 2, 7, 100, 5000}) {
      SCOPED_TRACE(testing::Message() << threads << " threads, " << num_tasks << " tasks");
      Record r(num_tasks, threads);
      ParallelFor(num_tasks, threads, [&](int task, int thread) { r.Saw(task, thread); });
      ExpectEachTaskOnceAndThreadsInRange(r, num_tasks, threads);
    }
  }
}

TEST(ParallelForTest, AcceptsTasksWithoutThreadIndex) {
  std::vector<int> out(1000, 0);
  ParallelFor(static_cast<int>(out.size()), 4, [&](int task) { out[task] = task * 2; });
  for (int i = 0; i < static_cast<int>(out.size()); ++i) EXPECT_EQ(out[i], i * 2);
}

TEST(ParallelForTest, PerThreadScratchNeedsNoLocking) {
  constexpr int kThreads = 4;
  constexpr int kTasks = 10000;
  std::vector<std::int64_t> sums(kThreads, 0);  // Plain per-thread sums.
  ParallelFor(kTasks, kThreads, [&](int task, int thread) { sums[thread] += task; });
  std::int64_t total = 0;
  for (std::int64_t s : sums) total += s;
  EXPECT_EQ(total, std::int64_t{kTasks} * (kTasks - 1) / 2);
}

TEST(ParallelForTest, OneThreadRunsTasksInOrderOnTheCaller) {
  std::vector<int> order;
  const std::thread::id caller = std::this_thread::get_id();
  ParallelFor(50, 1, [&](int task, int thread) {
    EXPECT_EQ(thread, 0);
    EXPECT_EQ(std::this_thread::get_id(), caller);
    order.push_back(task);
  });
  ASSERT_EQ(order.size(), 50u);
  for (int i = 0; i < 50; ++i) EXPECT_EQ(order[i], i);
}

// Each thread's tasks in the order it ran them, and the task after which it left (-1: none).
struct Leaving {
  explicit Leaving(int threads) : tasks(threads), left_after(threads, -1) {}
  std::vector<std::vector<int>> tasks;
  std::vector<int> left_after;
};

void ExpectLeftThreadsRanNothingMore(const Leaving& l, int num_tasks) {
  std::vector<int> runs(num_tasks, 0);
  for (std::size_t t = 0; t < l.tasks.size(); ++t) {
    for (int task : l.tasks[t]) ++runs[task];
    if (l.left_after[t] >= 0) {
      ASSERT_FALSE(l.tasks[t].empty());
      EXPECT_EQ(l.tasks[t].back(), l.left_after[t]) << "thread " << t << " went on";
    }
  }
  for (int i = 0; i < num_tasks; ++i) EXPECT_LE(runs[i], 1) << "task " << i;
}

TEST(ParallelForTest, AThreadThatLeavesTakesNoMoreTasks) {
  constexpr int kThreads = 4;
  constexpr int kTasks = 400;
  Leaving l(kThreads);
  // Every thread leaves after its third task: the others go on until they leave too.
  ParallelFor(kTasks, kThreads, [&](int task, int thread) {
    l.tasks[thread].push_back(task);
    if (l.tasks[thread].size() < 3) return true;
    l.left_after[thread] = task;
    return false;
  });
  ExpectLeftThreadsRanNothingMore(l, kTasks);
  std::size_t ran = 0;
  for (const auto& t : l.tasks) ran += t.size();
  EXPECT_LE(ran, 3u * kThreads);

  // One thread: the tasks after the one that left do not run.
  std::vector<int> order;
  ParallelFor(10, 1, [&](int task) {
    order.push_back(task);
    return task < 4;
  });
  EXPECT_EQ(order, (std::vector<int>{0, 1, 2, 3, 4}));
}

TEST(ThreadPoolTest, AThreadThatLeavesTakesNoMoreTasksAndThePoolGoesOn) {
  constexpr int kThreads = 3;
  ThreadPool pool(kThreads);
  for (int repeat = 0; repeat < 10; ++repeat) {
    Leaving l(kThreads);
    pool.ParallelFor(300, [&](int task, int thread) {
      l.tasks[thread].push_back(task);
      if (thread != 0 || l.tasks[thread].size() < 2) return true;
      l.left_after[thread] = task;  // The caller leaves after two tasks, the workers stay.
      return false;
    });
    ExpectLeftThreadsRanNothingMore(l, 300);
  }
  Record r(100, kThreads);
  pool.ParallelFor(100, [&](int task, int thread) { r.Saw(task, thread); });
  ExpectEachTaskOnceAndThreadsInRange(r, 100, kThreads);
}

TEST(ParallelForTest, RethrowsTheFirstExceptionAfterAllThreadsStopped) {
  std::atomic<int> ran{0};
  EXPECT_THROW(ParallelFor(1000, 4,
                           [&](int task) {
                             ++ran;
                             if (task == 10) throw std::runtime_error("task 10");
                           }),
               std::runtime_error);
  EXPECT_GE(ran.load(), 11);
  EXPECT_LE(ran.load(), 1000);
}

TEST(ParallelForTest, RejectsNegativeThreads) {
  EXPECT_THROW(ParallelFor(10, -1, [](int) {}), std::invalid_argument);
  EXPECT_THROW({ ThreadPool pool(-1); }, std::invalid_argument);
}

TEST(ParallelForTest, ZeroThreadsUsesTheHardware) {
  EXPECT_GE(ResolveThreads(0), 1);
  EXPECT_EQ(ResolveThreads(3), 3);
  Record r(64, ResolveThreads(0));
  ParallelFor(64, 0, [&](int task, int thread) { r.Saw(task, thread); });
  ExpectEachTaskOnceAndThreadsInRange(r, 64, ResolveThreads(0));
}

TEST(ThreadPoolTest, RunsEveryTaskOnceWithThreadIndicesInRangeJobAfterJob) {
  for (int threads : {1, 2, 3, 8}) {
    ThreadPool pool(threads);
    EXPECT_EQ(pool.num_threads(), threads);
    // The same workers again and again, with jobs of more and of fewer tasks than threads.
    for (int repeat = 0; repeat < 20; ++repeat) {
      for (int num_tasks : {0, 1, 2, 5, 100, 3000}) {
        SCOPED_TRACE(testing::Message()
                     << threads << " threads, " << num_tasks << " tasks, repeat " << repeat);
        Record r(num_tasks, threads);
        pool.ParallelFor(num_tasks, [&](int task, int thread) { r.Saw(task, thread); });
        ExpectEachTaskOnceAndThreadsInRange(r, num_tasks, threads);
      }
    }
  }
}

TEST(ThreadPoolTest, StaysUsableAfterATaskThrew) {
  ThreadPool pool(4);
  EXPECT_THROW(pool.ParallelFor(100,
                                [](int task) {
                                  if (task % 7 == 3) throw std::runtime_error("task");
                                }),
               std::runtime_error);
  Record r(200, 4);
  pool.ParallelFor(200, [&](int task, int thread) { r.Saw(task, thread); });
  ExpectEachTaskOnceAndThreadsInRange(r, 200, 4);
}

}  // namespace
}  // namespace picking::parallel
