// The W-methods' linear algebra on the reference chain's shape (84 links, 21 x 21 blocks):
// CyclicBlockLU factorization and one solve, on a random diagonally dominant matrix of that
// structure (docs/integrators.md 12.6, 13), with the two sweeps one after the other
// ("Sequential") and on two threads (tbb::parallel_invoke in a 2-thread arena; same bits).
#include <benchmark/benchmark.h>

#include <random>

#include <tbb/parallel_invoke.h>
#include <tbb/task_arena.h>

#include "engine/block_cyclic.hpp"

namespace {

constexpr int kB = 21, kLinks = 84;
using LU = cvt::CyclicBlockLU<kB>;

void fill(LU& lu) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-1, 1);
  lu.resize(kLinks);
  for (int l = 0; l < kLinks; ++l) {
    for (int r = 0; r < kB; ++r)
      for (int c = 0; c < kB; ++c) {
        lu.diag(l)(r, c) = (r == c ? 3.0 * kB : 0.0) + u(rng);
        lu.sub(l)(r, c) = u(rng);
        lu.super(l)(r, c) = u(rng);
      }
  }
}

struct TwoThreads {
  template <class F, class G>
  void operator()(const F& f, const G& g) const {
    tbb::parallel_invoke(f, g);
  }
};

// st.range(0): 1 the sweeps one after the other, 2 on two threads.
template <class F>
void in_arena(benchmark::State& st, const F& f) {
  if (st.range(0) == 1) return f(LU::Sequential());
  tbb::task_arena arena(2);
  arena.execute([&] { f(TwoThreads()); });
}

void BM_CyclicBlockLUFactor(benchmark::State& st) {
  LU lu, fresh;
  fill(fresh);
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
  fill(lu);
  lu.factor();
  std::vector<LU::Vec, Eigen::aligned_allocator<LU::Vec>> x(kLinks, LU::Vec::Ones());
  in_arena(st, [&](const auto& both) {
    for (auto _ : st) {
      lu.solve(x.data(), both);
      benchmark::DoNotOptimize(x.data());
    }
  });
}

}  // namespace

BENCHMARK(BM_CyclicBlockLUFactor)->Arg(1)->Arg(2)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_CyclicBlockLUSolve)->Arg(1)->Arg(2)->Unit(benchmark::kMicrosecond);
BENCHMARK_MAIN();
