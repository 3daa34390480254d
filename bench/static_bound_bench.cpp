// A bound for any 2-thread schedule of one RHS on this machine: a hand-written static
// schedule with no task scheduler (two threads, each owning half the pins in every pass,
// spin barriers between the passes, the second thread spinning while a batch runs),
// measured in the same process as the serial RHS and the flow graph, batches taking turns.
// If the flow graph is about as fast as this, what is left is the machine, not TBB.
// Usage: static_bound_bench [batches=20] [rhs per batch=200]
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <thread>
#include <vector>

#include "engine/base/timing.hpp"
#include "bench/bench_fixture.hpp"
#include "graph/schedule.hpp"
#include "modules/chain_forces.hpp"
#include "modules/other_forces.hpp"
#include "modules/pulley_contact.hpp"

namespace {

double now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

// Sense-reversing spin barrier for two threads.
struct Barrier {
  std::atomic<int> count{0}, generation{0};
  void wait() {
    const int g = generation.load();
    if (count.fetch_add(1) == 1) {
      count = 0;
      generation.fetch_add(1);
    } else {
      while (generation.load() == g) {
      }
    }
  }
};

}  // namespace

int main(int argc, char** argv) {
  using namespace cvt;
  const int batches = argc > 1 ? std::atoi(argv[1]) : 20, per = argc > 2 ? std::atoi(argv[2]) : 200;
  auto& f = bench::reference();
  const Model& m = f.m;
  const int N = m.links;
  Workspace ws(m), wf(m);
  ws.status = wf.status = f.status;
  Eigen::VectorXd dy(m.nstate), next(m.nstate), acc(m.nstate);
  StageOp op;
  op.base = f.y.data(), op.next = next.data(), op.acc = acc.data(), op.a = 1e-9, op.w = 2.0;

  Barrier barrier;
  std::atomic<int> go{0};
  std::atomic<bool> active{false}, stop{false};
  auto half_stage = [&](int t) {
    const int b = t == 0 ? 0 : N / 2, e = t == 0 ? N / 2 : N;
    link_kinematics(m, ws, b, e);
    barrier.wait();
    chain_forces(m, ws, b, e);
    pulley_contact(m, ws, b, e);
    inertia_decomposition(m, ws, b, e);
    if (t == 1) other_forces(m, ws);
    barrier.wait();
    gather_joints(m, ws, b, e);
    if (t == 0) gather_shafts(m, ws);
    barrier.wait();
    finish_joints(m, ws, dy.data(), &op, b, e);
    if (t == 0) finish_shafts(m, ws, dy.data(), &op);
    barrier.wait();
  };
  std::thread worker([&] {
    int seen = 0;
    while (!stop) {
      if (!active) {
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
        continue;
      }
      if (go.load() > seen) ++seen, half_stage(1);
    }
  });

  ScheduleOptions o;
  o.kind = SchedulerKind::flowgraph;
  o.threads = 2;
  auto flowgraph = make_schedule(m, wf, o);
  std::vector<double> serial_us, static_us, flow_us;
  for (int b = 0; b < batches; ++b) {
    for (int i = 0; i < per; ++i) {
      const double t0 = now();
      rhs_serial(m, ws, 3e-4, f.y.data(), dy.data(), &op);
      serial_us.push_back(1e6 * (now() - t0));
    }
    active = true;
    std::this_thread::sleep_for(std::chrono::milliseconds(3));
    for (int i = 0; i < per; ++i) {
      const double t0 = now();
      set_stage_input(m, ws, 3e-4, f.y.data());
      go.fetch_add(1);
      half_stage(0);
      static_us.push_back(1e6 * (now() - t0));
    }
    active = false;
    std::this_thread::sleep_for(std::chrono::milliseconds(3));
    flowgraph->within([&] {
      for (int i = 0; i < per; ++i) {
        const double t0 = now();
        flowgraph->rhs(3e-4, f.y.data(), dy.data(), &op);
        flow_us.push_back(1e6 * (now() - t0));
      }
    });
  }
  stop = true;
  worker.join();
  const double s = cvt::median(serial_us), st = cvt::median(static_us), fg = cvt::median(flow_us);
  std::printf("reference model, one RHS, medians of %d x %d:\n", batches, per);
  std::printf("  serial                         %6.1f us\n", s);
  std::printf("  ideal static, 2 threads        %6.1f us  (x%.2f)\n", st, s / st);
  std::printf("  flowgraph, 2 threads           %6.1f us  (x%.2f)\n", fg, s / fg);
  return 0;
}
