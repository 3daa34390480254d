// TwoTasks (engine/wmethod/parallel.hpp) with TwoTaskPhases (engine/ode/block_cyclic.hpp) on
// two TBB threads: a phase that runs a parallel loop of its own does not hang the fork (each
// task is isolated), and a phase that throws ends the fork with its exception instead of
// leaving the other task waiting for it.
#include <gtest/gtest.h>

#include <atomic>
#include <stdexcept>

#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include "engine/ode/block_cyclic.hpp"
#include "engine/wmethod/parallel.hpp"

namespace cvt {
namespace {

TEST(TwoTasks, APhaseWithItsOwnParallelLoopFinishes) {
  tbb::task_arena arena(2);
  std::atomic<long> work{0};
  arena.execute([&] {
    for (int rep = 0; rep < 20000; ++rep) {
      TwoTaskPhases ph;
      const auto loop = [&] {
        tbb::parallel_for(
            tbb::blocked_range<int>(0, 8), [&](const tbb::blocked_range<int>& r) { work += r.size(); },
            tbb::static_partitioner());
      };
      const auto task = [&](int side) {
        ph.two(0, side, loop, [&] { ++work; });
        ph.one(2, [&] { ++work; });
      };
      TwoTasks{true}([&] { task(0); }, [&] { task(1); });
    }
  });
  EXPECT_EQ(work.load(), 20000L * 10);
}

TEST(TwoTasks, APhaseThatThrowsEndsTheFork) {
  tbb::task_arena arena(2);
  int caught = 0;
  arena.execute([&] {
    for (int rep = 0; rep < 200; ++rep) {
      TwoTaskPhases ph;
      const auto task = [&](int side) {
        ph.two(
            0, side, [] { throw std::runtime_error("phase 0"); }, [] {});
        ph.one(2, [] {});
      };
      try {
        TwoTasks{true}([&] { task(0); }, [&] { task(1); });
      } catch (const std::runtime_error& e) {
        EXPECT_STREQ(e.what(), "phase 0");
        ++caught;
      }
    }
  });
  EXPECT_EQ(caught, 200);
}

}  // namespace
}  // namespace cvt
