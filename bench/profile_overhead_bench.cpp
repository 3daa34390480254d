// Cost of the per-module timers: whole RK4 steps of the reference
// model with and without the profiler, for the serial schedule and the flow graph, in
// interleaved batches; the overhead is the median of the per-batch ratios. Also checks
// that profiling does not change the bits.
// Usage: profile_overhead_bench [threads=2] [batches=15] [steps per batch=200]
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
  auto& f = bench::reference();
  const double h = f.m.cfg.integrator.step;
  const auto median = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
  };
  int failures = 0;
  for (auto [kind, t] : {std::pair{SchedulerKind::serial, 1}, {SchedulerKind::flowgraph, threads},
                         {SchedulerKind::paper_omp, threads}}) {
    ScheduleOptions o;
    o.kind = kind;
    o.threads = t;
    Simulation off(f.m, o), on(f.m, o);
    on.enable_profiling();
    for (Simulation* s : {&off, &on}) {
      s->mutable_state() = f.y;
      s->workspace().status = f.status;
      s->set_clock(3e-4, 30000);
      for (int i = 0; i < 20; ++i) s->step(h);
    }
    std::vector<double> ratio, us_off, us_on;
    for (int b = 0; b < batches; ++b) {
      double us[2];
      // Alternate which goes first, so that neither always follows the other.
      for (int k = 0; k < 2; ++k) {
        const int which = (b + k) % 2;
        Simulation& s = which ? on : off;
        const auto t0 = std::chrono::steady_clock::now();
        for (int i = 0; i < steps; ++i) s.step(h);
        us[which] = std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count() / steps;
      }
      us_off.push_back(us[0]), us_on.push_back(us[1]);
      ratio.push_back(us[1] / us[0]);
    }
    const bool same = off.state() == on.state();
    failures += !same;
    std::printf("%-10s %d thread%s: without timers %7.1f us/step, with %7.1f; overhead (median of per-batch ratios) "
                "%+.2f %%; same bits: %s\n",
                scheduler_name(kind), t, t == 1 ? " " : "s", median(us_off), median(us_on),
                100.0 * (median(ratio) - 1.0), same ? "yes" : "NO");
  }
  return failures ? 1 : 0;
}
