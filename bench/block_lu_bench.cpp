// The W-methods' linear algebra on the reference chain's shape (84 links, 21 x 21 blocks):
// CyclicBlockLU factorization and one solve, on a random diagonally dominant matrix of that
// structure (docs/integrators.md 12.2), with the two sweeps one after the other
// ("Sequential") and on two threads (tbb::parallel_invoke in a 2-thread arena; same bits).
#include <benchmark/benchmark.h>

#include <random>

#include <tbb/parallel_invoke.h>
#include <tbb/task_arena.h>

#include "engine/ode/block_cyclic.hpp"

namespace {

constexpr int kB = 21, kLinks = 84;
using LU = cvt::CyclicBlockLU<kB>;

// chain: the couplings of the reference chain's W (ModelOde's link order): link l reaches
// link l-1 through its rows 0-11, 15, 16 and link l-1's columns 0, 1, 5, 6, 10-19 (and the
// transposed pattern upwards); otherwise dense couplings.
void fill(LU& lu, bool chain) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-1, 1);
  const auto toward_prev = [](int i) { return i < 12 || i == 15 || i == 16; };
  const auto toward_next = [](int i) { return i == 0 || i == 1 || i == 5 || i == 6 || (i >= 10 && i < 20); };
  lu.resize(kLinks);
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

void BM_CyclicBlockLUFactor(benchmark::State& st) {
  LU lu, fresh;
  fill(fresh, st.range(1) != 0);
  in_arena(st, [&](const auto& both) {
    for (auto _ : st) {
      st.PauseTiming();
      lu = fresh;
      st.ResumeTiming();
      benchmark::DoNotOptimize(lu.factor(both));
    }
  });
  st.counters["fill_blocks"] = lu.fill_blocks();
}
void BM_CyclicBlockLUSolve(benchmark::State& st) {
  LU lu;
  fill(lu, st.range(1) != 0);
  lu.factor();
  std::vector<LU::Vec, Eigen::aligned_allocator<LU::Vec>> x(kLinks, LU::Vec::Ones());
  in_arena(st, [&](const auto& both) {
    for (auto _ : st) {
      lu.solve(x.data(), both);
      benchmark::DoNotOptimize(x.data());
    }
  });
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

}  // namespace

BENCHMARK(BM_PivotInverse)->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_CyclicBlockLUSolveColumns<2>)->ArgsProduct({{1, 2}, {1}})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_CyclicBlockLUSolveColumns<14>)->ArgsProduct({{1, 2}, {1}})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_CyclicBlockLUFactor)->ArgsProduct({{1, 2}, {0, 1}})->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_CyclicBlockLUSolve)->ArgsProduct({{1, 2}, {0, 1}})->Unit(benchmark::kMicrosecond);
BENCHMARK_MAIN();
