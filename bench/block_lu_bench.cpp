// The W-methods' linear algebra on the reference chain's shape (84 links, 21 x 21 blocks):
// CyclicBlockLU factorization and one solve, on a random diagonally dominant matrix of that
// structure (docs/integrators.md 12.2), with the two sweeps one after the other
// ("Sequential") and on two threads (tbb::parallel_invoke in a 2-thread arena; same bits).
#include <benchmark/benchmark.h>

#include <random>

#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>
#include <tbb/task_arena.h>

#include "engine/ode/block_cyclic.hpp"
#include "engine/ode/segmented_lu.hpp"

namespace {

constexpr int kB = 21, kLinks = 84;
using LU = cvt::CyclicBlockLU<kB>;

// chain: the couplings of the reference chain's W (ModelOde's link order): link l reaches
// link l-1 through its rows 0-11, 15, 16 and link l-1's columns 0, 1, 5, 6, 10-19 (and the
// transposed pattern upwards); otherwise dense couplings.
template <class L>
void fill_matrix(L& lu, bool chain) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-1, 1);
  const auto toward_prev = [](int i) { return i < 12 || i == 15 || i == 16; };
  const auto toward_next = [](int i) { return i == 0 || i == 1 || i == 5 || i == 6 || (i >= 10 && i < 20); };
  for (int l = 0; l < kLinks; ++l) {
    for (int r = 0; r < kB; ++r)
      for (int c = 0; c < kB; ++c) {
        lu.diag(l)(r, c) = (r == c ? 3.0 * kB : 0.0) + u(rng);
        const bool s = !chain || (toward_prev(r) && toward_next(c)), p = !chain || (toward_next(r) && toward_prev(c));
        lu.sub(l)(r, c) = s ? u(rng) : 0.0;
        lu.super(l)(r, c) = p ? u(rng) : 0.0;
      }
  }
}

void fill(LU& lu, bool chain) {
  lu.resize(kLinks);
  fill_matrix(lu, chain);
}

struct TwoThreads {
  template <class F, class G>
  void operator()(const F& f, const G& g) const {
    tbb::parallel_invoke(f, g);
  }
};

// st.range(0): 1 the sweeps one after the other, 2 on two threads; st.range(1): 1 the
// chain's sparse couplings, 0 dense ones.
template <class F>
void in_arena(benchmark::State& st, const F& f) {
  if (st.range(0) == 1) return f(LU::Sequential());
  tbb::task_arena arena(2);
  arena.execute([&] { f(TwoThreads()); });
}

// The factorization of a copy of `fresh` per iteration (the copy untimed), and a solve with
// its factors, each on the tasks that run(st, f) hands f.
template <class L, class Run>
void time_factor(benchmark::State& st, const L& fresh, const Run& run) {
  L lu;
  run(st, [&](const auto& tasks) {
    for (auto _ : st) {
      st.PauseTiming();
      lu = fresh;
      st.ResumeTiming();
      benchmark::DoNotOptimize(lu.factor(tasks));
    }
  });
  st.counters["fill_blocks"] = lu.fill_blocks();
}
template <class L, class Run>
void time_solve(benchmark::State& st, L& lu, const Run& run) {
  lu.factor();
  std::vector<typename L::Vec, Eigen::aligned_allocator<typename L::Vec>> x(kLinks, L::Vec::Ones());
  run(st, [&](const auto& tasks) {
    for (auto _ : st) {
      lu.solve(x.data(), tasks);
      benchmark::DoNotOptimize(x.data());
    }
  });
}
const auto two_tasks = [](benchmark::State& st, const auto& f) { in_arena(st, f); };

void BM_CyclicBlockLUFactor(benchmark::State& st) {
  LU fresh;
  fill(fresh, st.range(1) != 0);
  time_factor(st, fresh, two_tasks);
}
void BM_CyclicBlockLUSolve(benchmark::State& st) {
  LU lu;
  fill(lu, st.range(1) != 0);
  time_solve(st, lu, two_tasks);
}
// C right sides at once (solve_columns), against C single solves in BM_CyclicBlockLUSolve:
// the fresh-friction columns (C = 2 per contact) and the shafts' (C = 14).
template <int C>
void BM_CyclicBlockLUSolveColumns(benchmark::State& st) {
  LU lu;
  fill(lu, st.range(1) != 0);
  lu.factor();
  using Cols = Eigen::Matrix<double, kB, C>;
  std::vector<Cols, Eigen::aligned_allocator<Cols>> x(kLinks, Cols::Ones());
  in_arena(st, [&](const auto& both) {
    for (auto _ : st) {
      lu.solve_columns(x.data(), both);
      benchmark::DoNotOptimize(x.data());
    }
  });
}

// One pivot block's inverse, as the factorization takes it (CyclicBlockLU::invert: in-place
// Gauss-Jordan with partial pivoting) against Eigen's PartialPivLU(D).inverse(), on the
// 84 diagonal blocks of the chain-shaped matrix.
void BM_PivotInverse(benchmark::State& st) {
  LU lu;
  fill(lu, true);
  std::vector<LU::Mat, Eigen::aligned_allocator<LU::Mat>> inv(kLinks);
  for (auto _ : st) {
    for (int l = 0; l < kLinks; ++l) {
      if (st.range(0) == 0) {
        const Eigen::PartialPivLU<LU::Mat> p(lu.diag(l));
        inv[l] = p.inverse();
      } else {
        benchmark::DoNotOptimize(LU::invert(lu.diag(l), inv[l]));
      }
    }
    benchmark::DoNotOptimize(inv.data());
  }
}

// The same on S segments (SegmentedBlockLU, docs/performance.md 3): st.range(0) threads (a
// task each), st.range(1) = S; the chain's sparse couplings, the W-method's drop tolerance
// (1e-12) here and in BM_CyclicBlockLUDrop, its two-sweep counterpart.
using SegLU = cvt::SegmentedBlockLU<kB>;
struct ArenaTasks {
  int tasks;
  template <class F>
  void operator()(const F& f) const {
    if (tasks == 1) return f(0);
    tbb::parallel_for(0, tasks, [&](int t) { tbb::this_task_arena::isolate([&] { f(t); }); });
  }
};
template <class F>
void in_segment_arena(benchmark::State& st, const F& f) {
  const int t = static_cast<int>(st.range(0));
  if (t == 1) return f(ArenaTasks{1});
  tbb::task_arena arena(t);
  arena.execute([&] { f(ArenaTasks{t}); });
}
void seg_fill(SegLU& lu, int segments) {
  lu.resize(kLinks, segments);
  lu.set_drop_tolerance(1e-12);
  fill_matrix(lu, true);
}
const auto segment_tasks = [](benchmark::State& st, const auto& f) { in_segment_arena(st, f); };
void BM_SegmentedBlockLUFactor(benchmark::State& st) {
  SegLU fresh;
  seg_fill(fresh, static_cast<int>(st.range(1)));
  time_factor(st, fresh, segment_tasks);
}
void BM_SegmentedBlockLUSolve(benchmark::State& st) {
  SegLU lu;
  seg_fill(lu, static_cast<int>(st.range(1)));
  time_solve(st, lu, segment_tasks);
}
// The two sweeps with the W-method's drop tolerance (1e-12), the segments' counterpart:
// st.range(1) 0 the factorization, 1 a solve.
void BM_CyclicBlockLUDrop(benchmark::State& st) {
  LU lu;
  fill(lu, true);
  lu.set_drop_tolerance(1e-12);
  if (st.range(1) == 0)
    time_factor(st, lu, two_tasks);
  else
    time_solve(st, lu, two_tasks);
}

}  // namespace

BENCHMARK(BM_PivotInverse)->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_CyclicBlockLUSolveColumns<2>)->ArgsProduct({{1, 2}, {1}})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_CyclicBlockLUSolveColumns<14>)->ArgsProduct({{1, 2}, {1}})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_CyclicBlockLUFactor)->ArgsProduct({{1, 2}, {0, 1}})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_CyclicBlockLUSolve)->ArgsProduct({{1, 2}, {0, 1}})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_CyclicBlockLUDrop)->ArgsProduct({{1, 2}, {0, 1}})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_SegmentedBlockLUFactor)->ArgsProduct({{1, 2}, {4, 8, 12}})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_SegmentedBlockLUSolve)->ArgsProduct({{1, 2}, {4, 8, 12}})->Unit(benchmark::kMicrosecond);
BENCHMARK_MAIN();
