// Per-module cost of one right-hand-side evaluation of the reference model (serial), one
// RHS and one RK4 step: the first performance record (README "Performance").
#include <benchmark/benchmark.h>

#include "engine/model/config.hpp"
#include "engine/model/model.hpp"
#include "engine/rhs/rhs.hpp"
#include "engine/simulation.hpp"
#include "modules/chain_forces.hpp"
#include "modules/inertia.hpp"
#include "modules/other_forces.hpp"
#include "modules/pulley_contact.hpp"
#include "bench/bench_fixture.hpp"
#include "engine/ode/w_stages.hpp"
#include "engine/wmethod/chain_stiffness.hpp"
#include "engine/wmethod/parallel.hpp"

namespace {

using namespace cvt;
using bench::reference;
using bench::prepared;
using bench::Fixture;

void BM_ChainForces(benchmark::State& st) {
  auto& f = reference();
  Workspace ws = prepared(f);
  for (auto _ : st) chain_forces(f.m, ws, 0, f.m.links);
  benchmark::DoNotOptimize(ws.chain_slots.data());
}
void BM_PulleyContact(benchmark::State& st) {
  auto& f = reference();
  Workspace ws = prepared(f);
  for (auto _ : st) pulley_contact(f.m, ws, 0, f.m.links);
  benchmark::DoNotOptimize(ws.pulley_slots.data());
}
void BM_OtherForces(benchmark::State& st) {
  auto& f = reference();
  Workspace ws = prepared(f);
  for (auto _ : st) other_forces(f.m, ws);
  benchmark::DoNotOptimize(ws.other.f.data());
}
void BM_InertiaDecomposition(benchmark::State& st) {
  auto& f = reference();
  Workspace ws = prepared(f);
  for (auto _ : st) {
    link_kinematics(f.m, ws, 0, f.m.links);
    inertia_decomposition(f.m, ws, 0, f.m.links);
  }
  benchmark::DoNotOptimize(ws.capacitance_inv.data());
}
void BM_GatherAccelerationsStageUpdate(benchmark::State& st) {
  auto& f = reference();
  Workspace ws = prepared(f);
  chain_forces(f.m, ws, 0, f.m.links);
  pulley_contact(f.m, ws, 0, f.m.links);
  other_forces(f.m, ws);
  inertia_decomposition(f.m, ws, 0, f.m.links);
  // The passes after the modules as every schedule runs them: the ordered gather with
  // A0^-1, the shafts, then the Woodbury correction, dy and the RK4 stage update.
  Eigen::VectorXd dy(f.m.nstate), next(f.m.nstate), acc(f.m.nstate);
  StageOp op;
  op.base = f.y.data();
  op.next = next.data();
  op.acc = acc.data();
  op.a = 0.5e-8;
  op.w = 2.0;
  for (auto _ : st) {
    gather_joints(f.m, ws, 0, f.m.links);
    gather_shafts(f.m, ws);
    finish_joints(f.m, ws, dy.data(), &op, 0, f.m.links);
    finish_shafts(f.m, ws, dy.data(), &op);
  }
  benchmark::DoNotOptimize(next.data());
}
void BM_Rhs(benchmark::State& st) {
  auto& f = reference();
  Workspace ws(f.m);
  ws.status = f.status;
  Eigen::VectorXd dy(f.m.nstate);
  for (auto _ : st) rhs_serial(f.m, ws, 3e-4, f.y.data(), dy.data());
  benchmark::DoNotOptimize(dy.data());
}
void BM_ContactStatus(benchmark::State& st) {
  auto& f = reference();
  Workspace ws(f.m);
  for (auto _ : st) update_contact_status(f.m, ws, 3e-4, f.y.data());
  benchmark::DoNotOptimize(ws.status.pulley.data());
}
void BM_Rk4Step(benchmark::State& st) {
  auto& f = reference();
  Simulation sim(f.m);
  sim.mutable_state() = f.y;
  sim.workspace().status = f.status;
  sim.set_clock(3e-4, 30000);
  for (auto _ : st) sim.step(f.m.cfg.integrator.step);
  st.counters["model_s_per_hour"] = benchmark::Counter(f.m.cfg.integrator.step * 3600.0 * st.iterations(),
                                                       benchmark::Counter::kIsRate);
}

// One take of the W matrix's chain stiffness on the serial schedule: the 63 differences of
// the forces (arg 0) or the analytic stiffness (arg 1: the Hessian of the elastic energy
// and the friction parts);
// docs/integrators.md 12.2, "The analytic stiffness".
void BM_ChainStiffness(benchmark::State& st) {
  auto& f = reference();
  Workspace ws = prepared(f);
  const auto schedule = make_schedule(f.m, ws, {});
  ChainStiffness k(f.m, ws, *schedule, st.range(0) == 1);
  for (auto _ : st) k.take(3e-4, f.y.data());
  benchmark::DoNotOptimize(k.diag(0).data());
  st.SetLabel(st.range(0) == 1 ? "analytic" : "differences");
}

// The vector work of one ROS34PW2 step on the reference model's state (the stage sums, the
// new state and the error estimate: w4_stages (ROS34PW2) with its evaluations and solves left
// out), against one fork and join over the joints on the flow graph's threads (arg: the
// threads) with nothing inside: what moving those sums onto the threads would have to beat
// (docs/performance.md 3.2).
void BM_Ros34pw2StageSums(benchmark::State& st) {
  auto& f = reference();
  const int n = f.m.nstate;
  Eigen::VectorXd y = f.y, f0 = Eigen::VectorXd::Constant(n, 1e-3);
  WStageVectors w;
  w.resize(n);
  const auto eval = [](double, const Eigen::VectorXd& yy, Eigen::VectorXd& dy) { dy = 1e-3 * yy; };
  const auto none = [](double, const Eigen::VectorXd&, Eigen::VectorXd&) {};
  const auto solve = [](Eigen::VectorXd&) {};
  const bool with_eval = st.range(0) == 1;
  for (auto _ : st) {
    if (with_eval)
      w4_stages(kRos34pw2, 3e-4, 2.5e-6, y, f0, nullptr, w, true, eval, solve);
    else
      w4_stages(kRos34pw2, 3e-4, 2.5e-6, y, f0, nullptr, w, true, none, solve);
    benchmark::DoNotOptimize(w.y_new.data());
  }
  st.SetLabel(with_eval ? "with a vector copy per evaluation" : "the sums alone");
}
void BM_ForkJoinOverJoints(benchmark::State& st) {
  auto& f = reference();
  Workspace ws = prepared(f);
  ScheduleOptions o;
  o.kind = SchedulerKind::flowgraph;
  o.threads = static_cast<int>(st.range(0));
  const auto schedule = make_schedule(f.m, ws, o);
  schedule->within([&] {
    for (auto _ : st) for_joint_ranges(*schedule, f.m.links, [](int b, int e) { benchmark::DoNotOptimize(b + e); });
  });
}

BENCHMARK(BM_Ros34pw2StageSums)->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_ForkJoinOverJoints)->Arg(1)->Arg(2)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_ChainStiffness)->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_ChainForces)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_PulleyContact)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_OtherForces)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_InertiaDecomposition)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_GatherAccelerationsStageUpdate)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_Rhs)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_ContactStatus)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_Rk4Step)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
