// Interleaved timing of whole RK4 steps of the reference model under each schedule: on a
// shared, noisy machine the schedules take turns in short batches, and the ratios are
// medians over the batches (flowgraph vs serial, flowgraph vs paper-omp).
// Usage: step_ratio_bench [threads=2] [batches=15] [steps per batch=200] [grain=4]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <vector>

#include "bench/bench_fixture.hpp"
#include "graph/schedule.hpp"

int main(int argc, char** argv) {
  using namespace cvt;
  const int threads = argc > 1 ? std::atoi(argv[1]) : 2;
  const int batches = argc > 2 ? std::atoi(argv[2]) : 15;
  const int steps = argc > 3 ? std::atoi(argv[3]) : 200;
  const int grain = argc > 4 ? std::atoi(argv[4]) : 4;
  auto& f = bench::reference();
  struct Candidate {
    const char* name;
    ScheduleOptions o;
    std::unique_ptr<Simulation> sim;
    std::vector<double> us;
  };
  std::vector<Candidate> c;
  for (auto [kind, t] : {std::pair{SchedulerKind::serial, 1}, {SchedulerKind::flowgraph, threads},
                         {SchedulerKind::paper_omp, threads}}) {
    ScheduleOptions o;
    o.kind = kind;
    o.threads = t;
    o.grain = grain;
    c.push_back({scheduler_name(kind), o, nullptr, {}});
  }
  for (auto& x : c) {
    x.sim = std::make_unique<Simulation>(f.m, x.o);
    x.sim->mutable_state() = f.y;
    x.sim->workspace().status = f.status;
    x.sim->set_clock(3e-4, 30000);
    for (int i = 0; i < 20; ++i) x.sim->step(f.m.cfg.integrator.step);  // warm up
  }
  for (int b = 0; b < batches; ++b)
    for (auto& x : c) {
      const auto t0 = std::chrono::steady_clock::now();
      for (int i = 0; i < steps; ++i) x.sim->step(f.m.cfg.integrator.step);
      x.us.push_back(std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count() / steps);
    }
  const auto median = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
  };
  std::printf("reference model, RK4 step, %d batches of %d steps, medians:\n", batches, steps);
  for (auto& x : c) std::printf("  %-10s threads %d  %8.1f us/step\n", x.name, x.sim->schedule().threads(), median(x.us));
  // Ratios batch by batch (same moment on the machine), then their median.
  std::vector<double> fs, fp;
  for (int b = 0; b < batches; ++b) {
    fs.push_back(c[0].us[b] / c[1].us[b]);
    fp.push_back(c[2].us[b] / c[1].us[b]);
  }
  std::printf("  speedup flowgraph vs serial     %.3f\n", median(fs));
  std::printf("  speedup flowgraph vs paper-omp  %.3f\n", median(fp));
  // Same bits: all three advanced the same number of steps from the same state.
  const bool same = c[0].sim->state() == c[1].sim->state() && c[0].sim->state() == c[2].sim->state();
  std::printf("  trajectories identical: %s\n", same ? "yes" : "NO");
  return same ? 0 : 1;
}
