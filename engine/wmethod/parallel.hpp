// What the W-method's matrix code runs on the schedule's threads (engine/wmethod/*.cpp):
// the block LU's sweeps or segments, and loops over joint ranges or links.
#pragma once

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>
#include <tbb/partitioner.h>
#include <tbb/task_arena.h>

#include "graph/schedule.hpp"
#include "numa/hand_off.hpp"

namespace cvt {

// The block LU's two sweeps (CyclicBlockLU): concurrent on the schedule's threads (inside its
// arena), one after the other without; the same arithmetic, so the same bits, either way.
// Each task is isolated: a thread that waits inside one (a parallel loop within a phase of
// TwoTaskPhases) takes no other task of the fork, which could spin on a phase it holds.
struct TwoTasks {
  bool parallel;
  template <class F, class G>
  void operator()(const F& f, const G& g) const {
    if (parallel) {
      const auto first = [&] { tbb::this_task_arena::isolate(f); };
      const auto second = [&] { tbb::this_task_arena::isolate(g); };
      const numa::ScopedForkJoin fj;
      tbb::parallel_invoke(fj.task(first), fj.task(second));
    } else {
      f(), g();
    }
  }
};

// The segmented block LU's tasks (SegmentedBlockLU): `tasks` of them on the schedule's
// threads (inside its arena), each isolated as TwoTasks' are; one task runs every part.
struct ManyTasks {
  int tasks;
  template <class F>
  void operator()(const F& f) const {
    if (tasks <= 1) return f(0);
    const auto range = [&](const tbb::blocked_range<int>& r) {
      for (int t = r.begin(); t < r.end(); ++t) tbb::this_task_arena::isolate([&] { f(t); });
    };
    const numa::ScopedForkJoin fj;
    tbb::parallel_for(tbb::blocked_range<int>(0, tasks, 1), fj.task(range), tbb::static_partitioner());
  }
};

// f(begin, end) over the joints [0, links), on the schedule's threads (inside its arena: the
// drivers run in Schedule::within) or serially with one.
template <class F>
void for_joint_ranges(const Schedule& schedule, int links, const F& f) {
  if (schedule.threads() <= 1) return f(0, links);
  const auto range = [&](const tbb::blocked_range<int>& r) { f(r.begin(), r.end()); };
  const numa::ScopedForkJoin fj;
  tbb::parallel_for(tbb::blocked_range<int>(0, links), fj.task(range), tbb::static_partitioner());
}

// f(j) for every joint. Each joint's block is independent of the others: any split over
// threads gives the same bits.
template <class F>
void for_joints(const Schedule& schedule, int links, const F& f) {
  for_joint_ranges(schedule, links, [&](int b, int e) {
    for (int j = b; j < e; ++j) f(j);
  });
}

}  // namespace cvt
