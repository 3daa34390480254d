// A side job runs once, whoever claims it; wait() returns after it and reports its error; on
// a schedule that takes no side work it runs at start().
#include "graph/side_job.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <stdexcept>
#include <thread>

#include "tests/test_util.hpp"

namespace cvt {
namespace {

std::unique_ptr<Schedule> schedule_of(const Model& m, Workspace& ws, SchedulerKind kind, int threads) {
  ScheduleOptions o;
  o.kind = kind;
  o.threads = threads;
  return make_schedule(m, ws, o);
}

TEST(SideJobTest, SerialScheduleRunsTheJobAtStart) {
  const Model m = test::model("mini");
  Workspace ws(m);
  auto s = schedule_of(m, ws, SchedulerKind::serial, 1);
  SideJob job(*s);
  int runs = 0;
  job.start([&] { ++runs; });
  EXPECT_EQ(runs, 1);
  job.wait();
  EXPECT_FALSE(job.pending());
}

// On the flow graph with two threads each job runs exactly once, on whichever thread claims
// it, and its effects are visible after wait(), also when wait() comes at once (the master
// claims the job) or late (a worker took it).
TEST(SideJobTest, EachJobRunsOnceAndIsDoneAfterWait) {
  const Model m = test::model("mini");
  Workspace ws(m);
  auto s = schedule_of(m, ws, SchedulerKind::flowgraph, 2);
  SideJob job(*s);
  std::atomic<int> runs{0};
  long sum = 0;
  for (int i = 1; i <= 2000; ++i) {
    job.start([&, i] {
      sum += i;
      runs.fetch_add(1, std::memory_order_relaxed);
    });
    if (i % 3 == 0) std::this_thread::sleep_for(std::chrono::microseconds(50));  // let a worker take it
    if (i % 2 == 0) {
      job.wait();
      ASSERT_EQ(runs.load(), i);
      ASSERT_EQ(sum, static_cast<long>(i) * (i + 1) / 2);
    }
  }
  job.wait();
  EXPECT_EQ(runs.load(), 2000);
  EXPECT_EQ(sum, 2000L * 2001 / 2);
  // And the schedule's other thread does take jobs (on a loaded machine keep offering them
  // for up to 3 s, so that it gets a core).
  const std::thread::id master = std::this_thread::get_id();
  std::atomic<int> beside{0};
  const auto start = std::chrono::steady_clock::now();
  while (beside.load() == 0 && std::chrono::steady_clock::now() - start < std::chrono::seconds(3)) {
    job.start([&] {
      if (std::this_thread::get_id() != master) beside.fetch_add(1);
    });
    std::this_thread::sleep_for(std::chrono::microseconds(200));
    job.wait();
  }
  EXPECT_GT(beside.load(), 0);
}

TEST(SideJobTest, AnErrorReachesTheNextWaitOnce) {
  const Model m = test::model("mini");
  Workspace ws(m);
  for (int threads : {1, 2}) {
    auto s = schedule_of(m, ws, threads > 1 ? SchedulerKind::flowgraph : SchedulerKind::serial, threads);
    SideJob job(*s);
    job.start([] { throw std::runtime_error("disk full"); });
    EXPECT_THROW(job.wait(), std::runtime_error) << threads << " threads";
    EXPECT_NO_THROW(job.wait());
    int runs = 0;
    job.start([&] { ++runs; });
    job.wait();
    EXPECT_EQ(runs, 1);
  }
}

// A job still pending when the SideJob goes is finished first (its buffers may go next).
TEST(SideJobTest, DestructionFinishesThePendingJob) {
  const Model m = test::model("mini");
  Workspace ws(m);
  auto s = schedule_of(m, ws, SchedulerKind::flowgraph, 2);
  for (int k = 0; k < 200; ++k) {
    std::atomic<bool> done{false};
    {
      SideJob job(*s);
      job.start([&] {
        std::this_thread::sleep_for(std::chrono::microseconds(k % 4 * 20));
        done = true;
      });
    }
    ASSERT_TRUE(done.load()) << k;
  }
}

}  // namespace
}  // namespace cvt
