// TwoTasks (engine/wmethod/parallel.hpp) with TwoTaskPhases (engine/ode/block_cyclic.hpp),
// and ManyTasks with TaskPhases (engine/ode/segmented_lu.hpp), on two TBB threads: a phase
// that runs a parallel loop of its own does not hang the fork (each task is isolated), a
// phase that throws ends the fork with its exception instead of leaving the other tasks
// waiting for it, and the segmented block LU on more tasks than threads gives the one
// task's bits.
#include <gtest/gtest.h>

#include <atomic>
#include <stdexcept>

#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include "engine/ode/block_cyclic.hpp"
#include "engine/ode/segmented_lu.hpp"
#include "engine/wmethod/parallel.hpp"
#include "tests/engine/ode/cyclic_matrix.hpp"

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

TEST(TwoTasks, ManyTasksWithParallelLoopsInTheirPhasesFinish) {
  tbb::task_arena arena(2);
  std::atomic<long> work{0};
  arena.execute([&] {
    for (int rep = 0; rep < 5000; ++rep) {
      TaskPhases ph;
      const auto loop = [&](int) {
        tbb::parallel_for(
            tbb::blocked_range<int>(0, 8), [&](const tbb::blocked_range<int>& r) { work += r.size(); },
            tbb::static_partitioner());
      };
      ManyTasks{3}([&](int) {  // more tasks than threads
        ph.run(0, 4, loop);
        ph.run(1, 1, [&](int) { ++work; });
        ph.run(2, 5, [&](int) { ++work; });
      });
    }
  });
  EXPECT_EQ(work.load(), 5000L * (4 * 8 + 1 + 5));
}

TEST(TwoTasks, ManyTasksWithAPhaseThatThrowsEndTheFork) {
  tbb::task_arena arena(2);
  int caught = 0;
  arena.execute([&] {
    for (int rep = 0; rep < 200; ++rep) {
      TaskPhases ph;
      try {
        ManyTasks{3}([&](int) {
          ph.run(0, 4, [](int part) {
            if (part == 2) throw std::runtime_error("part 2");
          });
          ph.run(1, 1, [](int) {});
        });
      } catch (const std::runtime_error& e) {
        EXPECT_STREQ(e.what(), "part 2");
        ++caught;
      }
    }
  });
  EXPECT_EQ(caught, 200);
}

TEST(TwoTasks, TheSegmentedLUOnManyTasksGivesTheOneTasksBits) {
  constexpr int B = 5, n = 30;
  using LU = SegmentedBlockLU<B>;
  const Eigen::MatrixXd M = random_cyclic_matrix(n, B, 11u, 10.0, 0.1);
  const Eigen::VectorXd b = Eigen::VectorXd::Random(n * B);
  LU one;
  one.resize(n, 5);
  load_cyclic_blocks(M, n, B, one);
  LU fresh = one;
  ASSERT_TRUE(one.factor());
  std::vector<LU::Vec, Eigen::aligned_allocator<LU::Vec>> x0(n);
  for (int l = 0; l < n; ++l) x0[l] = b.segment(l * B, B);
  one.solve(x0.data());
  tbb::task_arena arena(2);
  arena.execute([&] {
    for (int tasks : {2, 3, 6}) {
      for (int rep = 0; rep < 20; ++rep) {
        LU lu = fresh;
        ASSERT_TRUE(lu.factor(ManyTasks{tasks}));
        std::vector<LU::Vec, Eigen::aligned_allocator<LU::Vec>> x(n);
        for (int l = 0; l < n; ++l) x[l] = b.segment(l * B, B);
        lu.solve(x.data(), ManyTasks{tasks});
        for (int l = 0; l < n; ++l) ASSERT_TRUE(x[l] == x0[l]) << tasks << " tasks, block " << l;
      }
    }
  });
}

}  // namespace
}  // namespace cvt
