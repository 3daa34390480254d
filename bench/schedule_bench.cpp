// The schedules side by side on the reference model: one RHS and one RK4 step
// for serial, flowgraph and paper-omp at 1..max threads, the flow graph's own overhead
// with empty node bodies, and the serial gap the master thread spends between graph runs.
// Compare ratios within one run; `--benchmark_repetitions=5` gives medians.
#include <benchmark/benchmark.h>

#include <thread>

#include "bench/bench_fixture.hpp"
#include "graph/schedule.hpp"

namespace {

using namespace cvt;
using bench::reference;

ScheduleOptions options(SchedulerKind kind, int threads, int grain = 4) {
  ScheduleOptions o;
  o.kind = kind;
  o.threads = threads;
  o.grain = grain;
  return o;
}

void BM_Rhs(benchmark::State& st, SchedulerKind kind) {
  auto& f = reference();
  Workspace ws(f.m);
  ws.status = f.status;
  auto schedule = make_schedule(f.m, ws, options(kind, static_cast<int>(st.range(0)), static_cast<int>(st.range(1))));
  Eigen::VectorXd dy(f.m.nstate);
  for (auto _ : st) schedule->rhs(3e-4, f.y.data(), dy.data(), nullptr);
  benchmark::DoNotOptimize(dy.data());
}

void BM_Rk4Step(benchmark::State& st, SchedulerKind kind) {
  auto& f = reference();
  Simulation sim(f.m, options(kind, static_cast<int>(st.range(0)), static_cast<int>(st.range(1))));
  sim.mutable_state() = f.y;
  sim.workspace().status = f.status;
  sim.set_clock(3e-4, 30000);
  for (auto _ : st) sim.step(f.m.cfg.integrator.step);
  st.counters["model_s_per_hour"] =
      benchmark::Counter(f.m.cfg.integrator.step * 3600.0 * st.iterations(), benchmark::Counter::kIsRate);
}

// The flow graph of one stage with every node body empty: what the graph itself costs.
void BM_FlowGraphEmptyStage(benchmark::State& st) {
  auto& f = reference();
  Workspace ws(f.m);
  ScheduleOptions o = options(SchedulerKind::flowgraph, static_cast<int>(st.range(0)));
  o.empty_kernels = true;
  auto schedule = make_schedule(f.m, ws, o);
  Eigen::VectorXd dy(f.m.nstate);
  for (auto _ : st) schedule->rhs(3e-4, f.y.data(), dy.data(), nullptr);
}

// What the master does between two graph runs: the stage input and the link kinematics.
void BM_SerialGapBetweenStages(benchmark::State& st) {
  auto& f = reference();
  Workspace ws(f.m);
  for (auto _ : st) {
    set_stage_input(f.m, ws, 3e-4, f.y.data());
    link_kinematics(f.m, ws, 0, f.m.links);
  }
  benchmark::DoNotOptimize(ws.kin.psi_dot.data());
}

void thread_args(benchmark::internal::Benchmark* b) {
  const int hw = std::max(1u, std::thread::hardware_concurrency());
  for (int t = 1; t <= hw; t *= 2) b->Args({t, 4});
  if (hw >= 2)
    for (int g : {1, 2, 8, 16, 42}) b->Args({2, g});
  if ((hw & (hw - 1)) != 0) b->Args({hw, 4});
}

const int registered = [] {
  for (auto [kind, name] : {std::pair{SchedulerKind::serial, "serial"}, {SchedulerKind::flowgraph, "flowgraph"},
                            {SchedulerKind::paper_omp, "paper-omp"}}) {
    auto* r = benchmark::RegisterBenchmark((std::string("BM_Rhs/") + name).c_str(), BM_Rhs, kind);
    auto* s = benchmark::RegisterBenchmark((std::string("BM_Rk4Step/") + name).c_str(), BM_Rk4Step, kind);
    for (auto* b : {r, s}) {
      b->Unit(benchmark::kMicrosecond)->ArgNames({"threads", "grain"})->UseRealTime();
      if (kind == SchedulerKind::serial) b->Args({1, 4});
      else thread_args(b);
    }
  }
  benchmark::RegisterBenchmark("BM_FlowGraphEmptyStage", BM_FlowGraphEmptyStage)
      ->Unit(benchmark::kMicrosecond)
      ->ArgName("threads")
      ->UseRealTime()
      ->Apply([](benchmark::internal::Benchmark* b) {
        const int hw = std::max(1u, std::thread::hardware_concurrency());
        for (int t = 1; t <= hw; t *= 2) b->Arg(t);
      });
  benchmark::RegisterBenchmark("BM_SerialGapBetweenStages", BM_SerialGapBetweenStages)->Unit(benchmark::kMicrosecond);
  return 0;
}();

}  // namespace

BENCHMARK_MAIN();
