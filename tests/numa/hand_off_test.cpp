// Tests of numa/hand_off.hpp: a wrapped task is the same call as the callable it wraps (the
// same object for a named one, its arguments and result passed through), and what the
// tasks of a fork write is what the caller reads after the join. Under ThreadSanitizer
// (tools/checking_builds.sh tsan) the last two also check the annotations: without them
// the sanitizer reports the caller's and the tasks' accesses as races.
#include <gtest/gtest.h>
#include <oneapi/tbb/blocked_range.h>
#include <oneapi/tbb/parallel_for.h>
#include <oneapi/tbb/parallel_invoke.h>
#include <oneapi/tbb/task_arena.h>

#include <atomic>
#include <memory>
#include <thread>
#include <vector>

#include "numa/hand_off.hpp"

namespace cvt::numa {
namespace {

struct Counting {
  int* calls;
  int operator()(int a, int b) const { return ++*calls, a * 10 + b; }
};

TEST(HandOffTest, ATaskIsTheSameCallWithItsArgumentsAndResult) {
  int calls = 0;
  const Counting named{&calls};
  const ForkJoin fj;
  const auto by_reference = fj.task(named);
  EXPECT_EQ(by_reference(4, 2), 42);
  EXPECT_EQ(calls, 1);
  auto owned = std::make_unique<int>(7);
  const auto by_value = fj.task([p = std::move(owned)](int a) { return *p + a; });
  EXPECT_EQ(owned, nullptr) << "a temporary is moved into the task";
  EXPECT_EQ(by_value(1), 8);
}

TEST(HandOffTest, WhatTheTasksOfAForkWroteIsReadAfterTheJoin) {
  tbb::task_arena arena(2);
  std::vector<double> out(4096, 0.0);
  std::vector<double> in(out.size());
  for (std::size_t i = 0; i < in.size(); ++i) in[i] = static_cast<double>(i);
  arena.execute([&] {
    for (int round = 1; round <= 20; ++round) {
      const auto scale = [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i != r.end(); ++i) out[i] = in[i] * round;
      };
      const ScopedForkJoin fj;
      tbb::parallel_for(tbb::blocked_range<std::size_t>(0, out.size(), 64), fj.task(scale));
    }
  });
  for (std::size_t i = 0; i < out.size(); ++i) ASSERT_EQ(out[i], 20.0 * static_cast<double>(i)) << i;

  int a = 0, b = 0;
  const auto left = [&] { a = 1; };
  const auto right = [&] { b = 2; };
  {
    const ScopedForkJoin fj;
    tbb::parallel_invoke(fj.task(left), fj.task(right));
  }
  EXPECT_EQ(a + b, 3);
}

TEST(HandOffTest, AnEnqueuedJobRunsWithItsContextAfterWhatItsCallerWrote) {
  tbb::task_arena arena(2);
  struct Job {
    int input = 0, output = 0;
    std::atomic<bool> done{false};
  } job;
  job.input = 21;  // written before the enqueue, read by the task
  arena.enqueue(enqueued(
      [](void* ctx) {
        Job& j = *static_cast<Job*>(ctx);
        j.output = 2 * j.input;
        j.done.store(true, std::memory_order_release);
      },
      &job));
  while (!job.done.load(std::memory_order_acquire)) std::this_thread::yield();
  EXPECT_EQ(job.output, 42);
}

}  // namespace
}  // namespace cvt::numa
