// The production W-step of the reference model, serial against the flow graph on N threads,
// interleaved in short batches on a shared, noisy machine: ROS34PW2 at the fixed step
// (integrator.step) and with adaptive steps (integrator.tolerance), each batch 0.5 ms of
// model time from the same running state (the fixture's, 0.3 ms after rest, past the
// start-up, inside the settling phase: the fixed step's sub-steps count as one step).
// Prints per batch and as medians: us per step, the 2-thread speed-up, and model minutes
// per model second; the ratios are what counts (docs/performance.md).
// Usage: w_step_bench [threads=2] [batches=7] [tolerance=3]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

#include "bench/bench_fixture.hpp"
#include "graph/schedule.hpp"

namespace {

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  using namespace cvt;
  std::vector<std::string> args;  // positional (make bench passes Google Benchmark's flags: skipped)
  for (int i = 1; i < argc; ++i)
    if (argv[i][0] != '-') args.push_back(argv[i]);
  const int threads = args.size() > 0 ? std::max(1, std::atoi(args[0].c_str())) : 2;
  const int batches = args.size() > 1 ? std::max(1, std::atoi(args[1].c_str())) : 7;
  const std::string tol = args.size() > 2 ? args[2] : "3";
  const double t_batch = 5e-4;
  auto& f = bench::reference();
  const std::string path = std::string(CVT_SOURCE_DIR) + "/configs/reference.toml";
  const Model fixed = build_model(load_config(path, {}));
  const Model adaptive = build_model(load_config(path, {"integrator.tolerance=" + tol}));
  struct Candidate {
    std::string name;
    const Model* m;
    ScheduleOptions o;
    std::vector<double> us, wall;  // per batch: us per step, wall s
    long steps = 0;
  };
  std::vector<Candidate> c;
  for (const Model* m : {&fixed, &adaptive})
    for (auto [kind, t] : {std::pair{SchedulerKind::serial, 1}, {SchedulerKind::flowgraph, threads}}) {
      ScheduleOptions o;
      o.kind = kind, o.threads = t;
      char step[64];
      std::snprintf(step, sizeof step, "ros34pw2 h = %.3g", m->cfg.integrator.step);
      const std::string method = m == &fixed ? std::string(step) : "ros34pw2 tolerance " + tol;
      c.push_back({method + (t == 1 ? ", serial" : ", flow graph " + std::to_string(t) + " threads"), m, o, {}, {}});
    }
  const double t0 = 3e-4;
  for (int b = 0; b < batches; ++b)
    for (Candidate& k : c) {
      // Each batch from the same state: a fresh simulation (its matrix built at the first step).
      Simulation sim(*k.m, k.o);
      sim.mutable_state() = f.y;
      sim.workspace().status = f.status;
      const double h = grid_step(k.m->cfg);
      sim.set_clock(t0, 0);
      const long n = std::lround(t_batch / h);
      const auto w0 = std::chrono::steady_clock::now();
      for (long i = 0; i < n; ++i) sim.step(h);
      const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count();
      k.steps = sim.steps_taken();
      k.us.push_back(1e6 * wall / static_cast<double>(k.steps));
      k.wall.push_back(wall);
    }
  std::printf("reference model, %g s of model time per batch from t = %g s, %d batches (medians):\n", t_batch, t0,
              batches);
  for (const Candidate& k : c) {
    const double wall = median(k.wall);
    std::printf("  %-46s %6ld steps  %8.1f us per step  %6.2f model min per model second\n", k.name.c_str(), k.steps,
                median(k.us), wall / t_batch / 60.0);
  }
  for (size_t i = 0; i + 1 < c.size(); i += 2) {
    std::vector<double> r;
    for (int b = 0; b < batches; ++b) r.push_back(c[i].wall[b] / c[i + 1].wall[b]);
    std::printf("  %s: %d-thread speed-up over serial %.2fx (median of the batches' ratios)\n",
                c[i].name.substr(0, c[i].name.find(',')).c_str(), threads, median(r));
  }
  return 0;
}
