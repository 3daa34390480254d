// integrator.method = "ros2" through Simulation::step (docs/integrators.md 12): the same
// bits with every schedule and thread count, a resumed run repeats the uninterrupted one
// when resumed at a multiple of integrator.w_every, and the run stays close to RK4 at a
// step where RK4 itself is accurate.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>

#include "engine/simulation.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

Eigen::VectorXd run(const Model& m, const ScheduleOptions& so, int steps, double h) {
  Simulation sim(m, so);
  for (int k = 0; k < steps; ++k) sim.step(h);
  return sim.state();
}

bool same_bits(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), sizeof(double) * a.size()) == 0;
}

// Both W-methods; with threads the block LU's two sweeps run concurrently (CyclicBlockLU).
// The third case keeps the friction current between rebuilds for nearly every contact
// (integrator.w_fresh 1e-6, at most 4 contacts: the forced rebuilds too), so its run must
// differ from the same run without. The fourth takes the analytic stiffness (the Hessian
// per joint and per link over the threads), which must change the run too.
TEST(Ros2Run, SameBitsWithEveryScheduleAndThreadCount) {
  // method:w_fresh[:variant]: the analytic stiffness, or the block LU on four segments.
  for (const char* spec : {"ros2:5", "ros34pw2:5", "ros34pw2:1e-6", "ros34pw2:5:analytic", "ros34pw2:5:segments"}) {
    const std::string method(spec, std::strchr(spec, ':'));
    const char* rest = std::strchr(spec, ':') + 1;
    const char* third = std::strchr(rest, ':');
    const std::string w_fresh = third ? std::string(rest, third) : std::string(rest);
    const std::string variant = third ? third + 1 : "";
    const std::vector<std::string> keys = {"ramp.time=2e-5", "integrator.method=" + method, "integrator.w_every=3",
                                           "integrator.w_k_every=6", "integrator.startup_time=0",
                                           "integrator.w_fresh=" + w_fresh, "integrator.w_fresh_max=4"};
    std::vector<std::string> with = keys;
    if (variant == "analytic") with.push_back("integrator.w_analytic_stiffness=true");
    if (variant == "segments") with.push_back("integrator.w_segments=4");
    const Model m = test::model("mini", with);
    const Eigen::VectorXd ref = run(m, {}, 300, 1e-7);
    Simulation start(m);
    EXPECT_GT((ref - start.state()).norm(), 1e-6) << "the run must move";
    if (!variant.empty()) {
      const Eigen::VectorXd plain = run(test::model("mini", keys), {}, 300, 1e-7);
      EXPECT_FALSE(same_bits(plain, ref)) << "the " << variant << " must change the run's rounding";
      // The segments solve the same matrix: the same run but for rounding over 300 steps.
      if (variant == "segments") {
        EXPECT_LT((plain - ref).norm(), 1e-6 * (ref - start.state()).norm()) << variant;
      }
    }
    if (w_fresh != "5") {
      const Model plain = test::model("mini", {"ramp.time=2e-5", "integrator.method=" + method, "integrator.w_every=3",
                                               "integrator.w_k_every=6", "integrator.startup_time=0",
                                               "integrator.w_fresh=0"});
      EXPECT_FALSE(same_bits(run(plain, {}, 300, 1e-7), ref)) << "w_fresh must change the run";
    }
    for (int threads : {1, 2, 3}) {
      ScheduleOptions o;
      o.kind = SchedulerKind::flowgraph;
      o.threads = threads;
      EXPECT_TRUE(same_bits(run(m, o, 300, 1e-7), ref)) << method << ", flowgraph, " << threads << " threads";
      o.kind = SchedulerKind::paper_omp;
      EXPECT_TRUE(same_bits(run(m, o, 300, 1e-7), ref)) << method << ", paper-omp, " << threads << " threads";
    }
  }
}

TEST(Ros2Run, ResumedAtAMultipleOfWKEveryRepeatsTheBits) {
  const Model m = test::model("mini", {"ramp.time=2e-5", "integrator.method=ros2", "integrator.w_every=4",
                                       "integrator.w_k_every=16", "integrator.startup_time=0"});
  const Eigen::VectorXd ref = run(m, {}, 240, 1e-7);
  for (int at : {128, 121}) {
    Simulation first(m);
    for (int k = 0; k < at; ++k) first.step(1e-7);
    const Checkpoint c = first.checkpoint();
    Simulation second(m);
    second.restore(c);
    for (int k = at; k < 240; ++k) second.step(1e-7);
    if (at % 16 == 0)
      EXPECT_TRUE(same_bits(second.state(), ref)) << "resumed at step " << at;
    else {
      // The stale matrix of the uninterrupted run is not in the checkpoint: close, not equal
      // (in the pins' positions; their end slopes, the stiffest and least damped unknowns,
      // follow W more closely: 2.8e-6 rad measured).
      double dq = 0;
      for (int j = 0; j < m.links; ++j)
        for (int h = 0; h < 2; ++h)
          for (int e = 0; e < 2; ++e)
            for (int c : {half::kX, half::kY, half::kZ}) {
              const int i = m.joint(j) + h * half::kSize + e * half::kEnd + c;
              dq = std::max(dq, std::abs(second.state()[i] - ref[i]));
            }
      std::printf("[ros2] resumed at step %d (not a multiple of w_k_every): max |dx| of the pin ends %.3e m\n", at, dq);
      EXPECT_LT(dq, 1e-7) << "resumed at step " << at;
    }
  }
}

// 20 us of the mini model in its load ramp: the state after 5000 RK4 steps of 1e-8 (the
// start), and RK4 at 1e-8 over the next 20 us (the reference).
struct RampWindow {
  const Model rk = test::model("mini", {"ramp.time=1e-4"});  // (a Simulation keeps a reference to its Model)
  Checkpoint start;
  Eigen::VectorXd ref;
  RampWindow() {
    Simulation warm(rk);
    for (int k = 0; k < 5000; ++k) warm.step(rk.cfg.integrator.step);
    start = warm.checkpoint();
    Simulation r(rk);
    r.restore(start);
    for (int k = 0; k < 2000; ++k) r.step(1e-8);
    ref = r.state();
  }
  // Max |dq| of the pins [m] after the 20 us taken by model m at step h from the start.
  double pins_off(const Model& m, double h) const {
    Simulation s(m);
    s.restore(start);
    const int n = static_cast<int>(std::lround(2e-5 / h));
    for (int k = 0; k < n; ++k) s.step(h);
    double dq = 0;
    for (int i = 0; i < kJointSize * m.links; ++i) dq = std::max(dq, std::abs(s.state()[i] - ref[i]));
    return dq;
  }
};

// Against RK4 at the production step over 20 us of the mini model in its load ramp (restored
// from an RK4 run at 1e-8, continued at 1e-7: the clock is re-anchored): ROS2 at 1e-7 s keeps
// the pins within a micrometre, with a fresh matrix every step as close as RK4 at 1e-7 (the
// mini model's friction is 3x less stiff than the reference's, where ROS2 gains). In this
// transient a stale matrix costs accuracy (printed), unlike at the reference's full load.
TEST(Ros2Run, CloseToRk4AtTheProductionStep) {
  const RampWindow win;
  const double dq_rk = win.pins_off(win.rk, 1e-7);
  double dq_w[2][3];
  const int every[3] = {1, 4, 16};
  for (int secant = 0; secant < 2; ++secant)
    for (int i = 0; i < 3; ++i)
      dq_w[secant][i] = win.pins_off(test::model("mini", {"ramp.time=1e-4", "integrator.method=ros2",
                                                      "integrator.startup_time=0",
                                                      "integrator.w_every=" + std::to_string(every[i]),
                                                      std::string("integrator.w_secant=") + (secant ? "true" : "false")}),
                                 1e-7);
  for (int secant = 0; secant < 2; ++secant)
    std::printf("[ros2] 20 us of the mini model in its load ramp vs RK4 h = 1e-8, max |dq| of the pins: ros2 h = 1e-7 "
                "(%s slope) with the matrix every 1 / 4 / 16 steps %.3e / %.3e / %.3e m; rk4 h = 1e-7 %.3e m\n",
                secant ? "secant" : "exact", dq_w[secant][0], dq_w[secant][1], dq_w[secant][2], dq_rk);
  // With the exact slope and a fresh matrix, as close as RK4 at the same step; the secant
  // (the default, robust against a stale matrix at full load) overdamps the sliding
  // contacts of this transient in W and costs accuracy, within a micrometre still.
  EXPECT_LT(dq_w[0][0], 2 * dq_rk);
  for (const auto& row : dq_w)
    for (double d : row) EXPECT_LT(d, 1e-6);
}

// ROS34PW2 (third order for any matrix, stiffly accurate) against ROS2 at the same steps,
// over the 20 us of CloseToRk4AtTheProductionStep: closer to RK4 at 1e-8 at every step
// (measured: 0.5x, 0.13x, 0.6x ROS2's error at 4e-7, 2e-7, 1e-7).
TEST(Ros2Run, Ros34pw2CloserToRk4ThanRos2) {
  const RampWindow win;
  auto pins_off = [&](const char* method, double h) {
    const Model m = test::model("mini", {"ramp.time=1e-4", std::string("integrator.method=") + method,
                                         "integrator.startup_time=0", "integrator.w_every=4",
                                         "integrator.w_k_every=16"});
    return win.pins_off(m, h);
  };
  double e2[3], e34[3];
  const double hs[3] = {4e-7, 2e-7, 1e-7};
  for (int i = 0; i < 3; ++i) e2[i] = pins_off("ros2", hs[i]), e34[i] = pins_off("ros34pw2", hs[i]);
  std::printf("[ros34pw2] 20 us of the mini model in its load ramp vs RK4 h = 1e-8, max |dq| of the pins at h = 4e-7 / "
              "2e-7 / 1e-7: ros2 %.3e / %.3e / %.3e m, ros34pw2 %.3e / %.3e / %.3e m\n",
              e2[0], e2[1], e2[2], e34[0], e34[1], e34[2]);
  for (int i = 0; i < 3; ++i) EXPECT_LT(e34[i], e2[i]) << "h = " << hs[i];
}

// The start-up phase (integrator.startup_time, startup_step): from rest, each step is
// taken as sub-steps, on the same grid of steps and the same clock, closer to RK4 than whole
// steps; past it the run goes on with whole steps; the bits are the same on any schedule.
TEST(Ros2Run, StartupSubStepsFollowRk4FromRestOnTheSameGrid) {
  const double h = 1e-7;
  const int n = 400;  // 40 us; the start-up covers the first 20
  const Model rk = test::model("mini", {"ramp.time=2e-5"});  // (a Simulation keeps a reference to its Model)
  Simulation ref(rk);
  for (int k = 0; k < n * 10; ++k) ref.step(1e-8);
  ASSERT_TRUE(ref.state().allFinite());
  auto pins_off = [&](const Simulation& s) {  // max |dq| of the pins [m]
    double dq = 0;
    for (int i = 0; i < kJointSize * s.model().links; ++i) dq = std::max(dq, std::abs(s.state()[i] - ref.state()[i]));
    return dq;
  };
  const std::vector<std::string> base = {"ramp.time=2e-5", "integrator.method=ros2", "integrator.w_every=4",
                                         "integrator.w_k_every=16"};
  auto with = [&](const std::string& a, const std::string& b) {
    std::vector<std::string> o = base;
    o.push_back(a), o.push_back(b);
    return test::model("mini", o);
  };
  const Model plain = with("integrator.startup_time=0", "integrator.startup_step=2.5e-8");
  const Model startup = with("integrator.startup_time=2e-5", "integrator.startup_step=2.5e-8");  // 4 per step
  Simulation a(plain), b(startup);
  for (int k = 0; k < n; ++k) a.step(h), b.step(h);
  EXPECT_EQ(b.steps(), n);
  EXPECT_EQ(b.time(), a.time());
  ASSERT_TRUE(a.state().allFinite() && b.state().allFinite());
  const double da = pins_off(a), db = pins_off(b);
  std::printf("[ros2] 40 us from rest, h = 1e-7, vs RK4 at 1e-8: max |dq| of the pins %.3e m whole steps, %.3e m "
              "with the first 20 us in 4 sub-steps\n", da, db);
  EXPECT_GT(da, 0.0);
  EXPECT_LT(db, da);
  ScheduleOptions o;
  o.kind = SchedulerKind::flowgraph;
  o.threads = 2;
  Simulation c(startup, o);
  for (int k = 0; k < n; ++k) c.step(h);
  EXPECT_TRUE(same_bits(c.state(), b.state()));
}

// ROS34PW2 from rest on the reference model: its small gamma (0.44) does not damp what the
// matrix taken at the start misses while the pins settle and the rocker faces load up, and it
// blows up within microseconds; the start-up phase, in ROS2 sub-steps of at most
// integrator.startup_step, carries it through (docs/integrators.md 12.3).
TEST(Ros2Run, Ros34pw2FromRestNeedsTheRos2StartUp) {
  const double h = 1.5625e-7;
  const Model bare = test::model("reference", {"integrator.method=ros34pw2", "integrator.startup_time=0"});
  Simulation a(bare);
  for (int k = 0; k < 40 && a.state().allFinite(); ++k) a.step(h);
  // Its steps fail by 6.25 us: the run blows up, or goes on only by retaking them.
  EXPECT_TRUE(!a.state().allFinite() || a.steps_rejected() > 0)
      << "expected the bare ROS34PW2 run from rest to fail its steps by 6.25 us";
  const Model started = test::model("reference", {"integrator.method=ros34pw2"});  // start-up: 3 ROS2 sub-steps
  Simulation b(started);
  for (int k = 0; k < 320; ++k) b.step(h);  // 50 us
  ASSERT_TRUE(b.state().allFinite());
  const Sample s = b.sample();
  std::printf("[ros34pw2] reference model from rest, h = 1.5625e-7: bare run %s after %ld steps (%ld retaken); with "
              "the ROS2 start-up 50 us, energy residual %.3g J (kinetic energy %.4g J)\n",
              a.state().allFinite() ? "finite" : "not finite", a.steps(), a.steps_rejected(), s.energy_residual,
              s.energy_kinetic);
  EXPECT_LT(std::abs(s.energy_residual), 0.05);
}

// The step tuned to the running chain (the default, the shafts' rows in W) from rest: the
// start-up's ROS2 sub-steps, counted one by one in the matrix's rebuild schedule, carry it
// to 0.1 ms; with fixed steps (integrator.fixed_steps) and without the settling phase's
// sub-steps of at most integrator.settle_step the contacts that load up next go wrong (the
// energy balance off by more than 0.2 J by 0.4 ms, or the run blows up), with them the energy
// balance holds; by default the steps whose estimate is gross are retaken in pieces, which
// holds it without the settling phase too (docs/integrators.md 12.3).
TEST(Ros2Run, TheLongStepSettlesInSubSteps) {
  const double h = Config::Integrator{}.step, t_end = 4e-4;
  char step[64];
  std::snprintf(step, sizeof step, "integrator.step=%.17g", h);
  double residual[3] = {0, 0, 0};
  long rejected[3] = {0, 0, 0};
  for (int run = 0; run < 3; ++run) {
    const bool settle = run == 1, fixed = run < 2;
    const Model m = test::model("reference", {"integrator.method=ros34pw2", step, "integrator.w_shafts=true",
                                              settle ? "integrator.settle_time=1e-3" : "integrator.settle_time=0",
                                              fixed ? "integrator.fixed_steps=true" : "integrator.fixed_steps=false"});
    Simulation sim(m);
    const long n = std::lround(t_end / h);
    for (long k = 0; k < n; ++k) sim.step(h);
    rejected[run] = sim.steps_rejected();
    if (!sim.state().allFinite()) {
      ASSERT_EQ(run, 0) << "run " << run << " blew up";
      residual[run] = std::numeric_limits<double>::infinity();
      continue;
    }
    const Sample s = sim.sample();
    residual[run] = std::abs(s.energy_residual);
  }
  std::printf("[ros34pw2] reference model from rest, h = %g, 0.4 ms: energy residual %.3g J with fixed steps and "
              "without the settling sub-steps, %.3g J with them; %.3g J by default without them (%ld steps "
              "retaken)\n", h, residual[0], residual[1], residual[2], rejected[2]);
  EXPECT_GT(residual[0], 0.2);
  EXPECT_GT(residual[0], 20 * residual[1]);
  EXPECT_LT(residual[1], 0.05);
  EXPECT_LT(residual[2], 0.05);
  EXPECT_GT(rejected[2], 0) << "no step was retaken: the case no longer exercises the error test";
}

// A sample ahead of a W-method's step (Simulation::sample(h), as a run takes them) reads that
// step's first evaluation, taken now; the step then starts from it. The samples and the
// states are those of samples with a diagnostic evaluation of their own, to the bit, and the
// steps evaluate once less per sample: the profiled evaluations (the diagnostic one is not
// profiled) are as many as without the samples ahead. From rest through the start-up's ROS2
// sub-steps and the settling sub-steps, then the method's own steps; fixed and adaptive.
TEST(Ros2Run, ASampleAheadIsTheNextStepsFirstEvaluation) {
  for (const char* tol : {"0", "3"}) {
    const Model m = test::model("mini", {"integrator.method=ros34pw2", "integrator.startup_time=2e-5",
                                         "ramp.time=5e-5", "integrator.tolerance=" + std::string(tol)});
    const bool fixed = std::string(tol) == "0";
    const double h = fixed ? m.cfg.integrator.step : m.cfg.run.sample_interval;
    const int steps = fixed ? 96 : 8, every = fixed ? 4 : 1;
    std::vector<Sample> s[2];
    long evaluations[2] = {0, 0};
    Eigen::VectorXd y[2];
    for (int ahead = 0; ahead < 2; ++ahead) {
      ScheduleOptions so;
      so.kind = SchedulerKind::flowgraph;
      so.threads = 2;
      Simulation sim(m, so);
      Profiler& prof = sim.enable_profiling();
      for (int k = 0; k <= steps; ++k) {
        if (k % every == 0) s[ahead].push_back(ahead ? sim.sample(h) : sim.sample());
        if (k < steps) sim.step(h);
      }
      for (const Profiler::Row& r : prof.report(1.0, 1.0, 1, "").rows)
        if (r.name == "chain forces") evaluations[ahead] = r.calls;
      y[ahead] = sim.state();
    }
    EXPECT_TRUE(same_bits(y[0], y[1])) << "tolerance " << tol;
    ASSERT_EQ(s[0].size(), s[1].size());
    for (std::size_t i = 0; i < s[0].size(); ++i) {
      const Sample &a = s[0][i], &b = s[1][i];
      for (const auto& [x, z] : {std::pair{a.input_torque, b.input_torque}, {a.output_torque, b.output_torque},
                                 {a.geometric_ratio, b.geometric_ratio}, {a.power_dissipated, b.power_dissipated},
                                 {a.rocker_force, b.rocker_force}, {a.pin_end_friction[0], b.pin_end_friction[0]},
                                 {a.pin_end_normal[2], b.pin_end_normal[2]}, {a.link_tension, b.link_tension},
                                 {a.energy_residual, b.energy_residual}, {a.chain_torsion_angle, b.chain_torsion_angle}})
        EXPECT_EQ(std::memcmp(&x, &z, sizeof x), 0) << "tolerance " << tol << ", sample " << i;
    }
    // Fixed steps: the last sample's evaluation ahead has no step to serve. Adaptive steps:
    // the samples in the start-up serve its fixed sub-steps; after it they are diagnostic
    // evaluations (the generic solver's step evaluates for itself), and so is the last.
    EXPECT_EQ(evaluations[1], evaluations[0] + (fixed ? 1 : 0)) << "tolerance " << tol;
  }
}


// The start-up's ROS2 sub-steps take the stiffness afresh at every rebuild of their matrix:
// at 100 rad/s a stiffness kept for 32 sub-steps (2 us at 6.25e-8) let a mode grow 2.3x per
// 0.125 us from rest until its next rebuild, putting 0.38 J into the energy balance by 2 us
// (docs/integrators.md 12.3); RK4 at 1e-8 keeps it below 1e-4 J.
TEST(Ros2Run, TheStartUpHoldsTheEnergyBalanceAtLowSpeed) {
  const Model m = test::model("reference", {"integrator.method=ros34pw2", "integrator.step=2.5e-6", "drive.speed=100"});
  const double h = m.cfg.integrator.step;
  Simulation sim(m);
  for (int k = 0; k < 2; ++k) sim.step(h);  // 5 us: 80 start-up sub-steps
  ASSERT_TRUE(sim.state().allFinite());
  const Sample s = sim.sample();
  std::printf("[ros2 start-up] reference model at 100 rad/s from rest, 5 us: energy residual %.3g J\n",
              s.energy_residual);
  EXPECT_LT(std::abs(s.energy_residual), 0.01);
}

}  // namespace
}  // namespace cvt
