// Adaptive W-steps (integrator.tolerance, docs/integrators.md 16): the chain's error norm
// sees the one pin that errs, a run from rest with the default matrix intervals follows RK4
// where fixed steps blow up, and the bits are the same on every schedule and thread count.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>

#include "engine/simulation.hpp"
#include "engine/wmethod/driver.hpp"
#include "engine/wmethod/model_ode.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

// The norm of ModelOdeOptions::error_tol: per joint, shaft and load the RMS of its positions
// and velocities in units of tol x (1 um, 1 mm/s; angles and slopes over a 0.05 m lever),
// maximized over the groups; the work integrals are left out.
TEST(AdaptiveRun, ChainNormIsThePinThatErrsMost) {
  const Model m = test::model("mini");
  Workspace ws(m);
  auto sched = make_schedule(m, ws, ScheduleOptions{});
  ModelOdeOptions o;
  o.error_tol = 2;
  ModelOde ode(m, ws, *sched, o);
  const OdeSystem& sys = ode.system();
  ASSERT_TRUE(static_cast<bool>(sys.error_norm));
  const int n = m.ndof, ns = m.nstate;
  Eigen::VectorXd e = Eigen::VectorXd::Zero(ns), y = Eigen::VectorXd::Zero(ns);
  auto norm = [&] { return sys.error_norm(e.data(), y.data(), y.data()); };
  const int j = 7, group = 2 * kJointSize;  // a joint's 21 positions and 21 velocities
  // 2 um on one coordinate of joint 7: one entry of 1 in its group of 42.
  e[m.joint(j)] = 2e-6;
  EXPECT_NEAR(norm(), std::sqrt(1.0 / group), 1e-12);
  // The same error at every joint: still the worst group's, not diluted by the others ...
  for (int k = 0; k < m.links; ++k) e[m.joint(k)] = 2e-6;
  EXPECT_NEAR(norm(), std::sqrt(1.0 / group), 1e-12);
  // ... where the RMS over the whole state would be sqrt(links / ns) of it.
  // A velocity error of 2 mm/s on top in joint 7's group doubles its sum of squares.
  e[n + m.joint(j) + 1] = 2e-3;
  EXPECT_NEAR(norm(), std::sqrt(2.0 / group), 1e-12);
  // A slope is a length over 0.05 m: 2 um / 0.05 m on joint 3's end slope s_x (entry 3).
  e.setZero();
  e[m.joint(3) + 3] = 2e-6 / 0.05;
  EXPECT_NEAR(norm(), std::sqrt(1.0 / group), 1e-12);
  // The shafts: 7 positions and 7 velocities per group; the work integrals do not count.
  e.setZero();
  e[m.shaft(1)] = 2e-6;
  EXPECT_NEAR(norm(), std::sqrt(1.0 / (2 * kShaftSize)), 1e-12);
  e.setZero();
  e[2 * n] = 1e3;  // 1 kJ of input work
  EXPECT_EQ(norm(), 0.0);
  EXPECT_THROW(
      {
        ModelOdeOptions bad;
        bad.error_tol = -1;
        ModelOde x(m, ws, *sched, bad);
      },
      std::invalid_argument);
}

double pins_off(const Simulation& a, const Simulation& b) {
  double dq = 0;
  for (int i = 0; i < kJointSize * a.model().links; ++i) dq = std::max(dq, std::abs(a.state()[i] - b.state()[i]));
  return dq;
}

// The mini model from rest with the stiffness every 64 steps: with error-controlled steps
// (tolerance 1) ROS34PW2 runs on the sample grid, with steps that grow past the start-up's,
// its pins within a few percent of their motion from RK4 at 1e-8 (the fixed steps of the
// shipped config printed for scale); the same bits on the flow graph with two threads.
TEST(AdaptiveRun, FromRestWithTheDefaultIntervalsFollowsRk4) {
  const double t_end = 4e-4, grid = 1e-5;
  const std::vector<std::string> base = {"integrator.method=ros34pw2", "integrator.step=8.333333333333333e-7",
                                         "integrator.w_k_every=64", "integrator.w_every=8"};
  auto with = [&](const std::string& extra) {
    std::vector<std::string> o = base;
    o.push_back(extra);
    return test::model("mini", o);
  };
  const Model adaptive = with("integrator.tolerance=1");
  EXPECT_DOUBLE_EQ(grid_step(adaptive.cfg), adaptive.cfg.run.sample_interval);
  Simulation a(adaptive);
  const long n = std::lround(t_end / grid);
  for (long k = 0; k < n; ++k) a.step(grid);
  ASSERT_TRUE(a.state().allFinite());
  EXPECT_EQ(a.steps(), n);
  EXPECT_DOUBLE_EQ(a.time(), t_end);
  const Model rk = test::model("mini", {"integrator.method=rk4"});
  Simulation r(rk);
  for (long k = 0; k < std::lround(t_end / 1e-8); ++k) r.step(1e-8);
  const double dq = pins_off(a, r);
  double moved = 0;  // the pins' largest motion since rest (RK4)
  for (int i = 0; i < kJointSize * rk.links; ++i) moved = std::max(moved, std::abs(r.state()[i] - rk.y0[i]));
  // The shipped mini configuration's own fixed steps (its stiffness every 16 steps) for scale.
  const Model shipped = test::model("mini", {"integrator.method=ros34pw2", "integrator.step=8.333333333333333e-7",
                                             "integrator.w_k_every=16"});
  Simulation g(shipped);
  for (long k = 0; k < std::lround(t_end / shipped.cfg.integrator.step); ++k) g.step(shipped.cfg.integrator.step);
  const double dq_fixed = pins_off(g, r);
  const long startup = std::lround(adaptive.cfg.integrator.startup_time / adaptive.cfg.integrator.startup_step);
  const double mean_after = (t_end - adaptive.cfg.integrator.startup_time) / static_cast<double>(a.steps_taken() - startup);
  const Sample s = a.sample();
  std::printf("[adaptive] mini from rest to %.2g s, tolerance 1: %ld steps (%ld start-up sub-steps, %ld rejected), "
              "mean step after the start-up %.3g s; max |dq| of the pins against RK4 at 1e-8 %.3g m of a motion of "
              "%.3g m (fixed steps of 8.33e-7 with the stiffness every 16 steps: %.3g m); energy residual %.3g of %.3g J "
              "turned over\n",
              t_end, a.steps_taken(), startup, a.steps_rejected(), mean_after, dq, moved, dq_fixed, s.energy_residual,
              std::abs(s.work_input) + std::abs(s.work_output) + std::abs(s.work_dissipated) + std::abs(s.work_clamping));
  EXPECT_GT(mean_after, 4 * adaptive.cfg.integrator.startup_step);
  // Within 5 % of the motion (both differ from RK4 in phase).
  EXPECT_LT(dq, 0.05 * moved);
  EXPECT_LT(std::abs(s.energy_residual), 0.01 * (std::abs(s.work_input) + std::abs(s.work_clamping)));

  ScheduleOptions o;
  o.kind = SchedulerKind::flowgraph;
  o.threads = 2;
  Simulation b(adaptive, o);
  for (long k = 0; k < n; ++k) b.step(grid);
  EXPECT_EQ(std::memcmp(a.state().data(), b.state().data(), sizeof(double) * a.state().size()), 0);
  EXPECT_EQ(a.steps_taken(), b.steps_taken());
}

// The mini model at a light load (6 N m) for 20 ms from rest, its shipped matrix intervals:
// fixed steps of 8.33e-7 (the start-up's sub-steps counted one by one in the matrix schedule)
// and adaptive steps at tolerance 3 both run to the end with a small energy residual
// (docs/integrators.md 12.3, 16.1).
TEST(AdaptiveRun, SlowLightLoadRunsWithFixedAndAdaptiveSteps) {
  auto mini = [](const std::string& tol) {
    return test::model("mini", {"integrator.method=ros34pw2", "integrator.step=8.333333333333333e-7",
                                "run.t_end=2e-2", "load.torque=6", "integrator.tolerance=" + tol});
  };
  auto run = [](const Model& m, double* t_bad) {
    Simulation s(m);
    const double h = grid_step(m.cfg);
    const long n = std::lround(m.cfg.run.t_end / h);
    for (long k = 0; k < n; ++k) {
      s.step(h);
      if (!s.state().allFinite()) {
        *t_bad = s.time();
        return s.sample();
      }
    }
    *t_bad = -1;
    return s.sample();
  };
  const auto turnover = [](const Sample& s) {
    return std::abs(s.work_input) + std::abs(s.work_output) + std::abs(s.work_dissipated) + std::abs(s.work_clamping) +
           std::abs(s.work_contact_switching);
  };
  double bad[2] = {0, 0};
  const Sample f = run(mini("0"), &bad[0]), a = run(mini("3"), &bad[1]);
  std::printf("[adaptive] mini at 6 N m, 20 ms: fixed steps %s, energy residual %.3g of %.3g J turned over; "
              "tolerance 3 %s, %.3g of %.3g J\n", bad[0] < 0 ? "ran to the end" : "blew up", f.energy_residual,
              turnover(f), bad[1] < 0 ? "ran to the end" : "blew up", a.energy_residual, turnover(a));
  EXPECT_LT(bad[0], 0.0);
  EXPECT_LT(bad[1], 0.0);
  EXPECT_LT(std::abs(f.energy_residual), 0.01 * turnover(f));
  EXPECT_LT(std::abs(a.energy_residual), 0.01 * turnover(a));
}

// A piece that ends a few ulps past the longest step the factorized matrix allows (1.25
// times the step it was made for): the driver takes it as two equal steps, not as that step
// and then a sliver of a few ulps, which no step can take (the solver would stop with "step
// size underflow").
TEST(AdaptiveRun, NoSliverBeforeThePiecesEnd) {
  const double h0 = 1e-8;
  const Model m = test::model("mini", {"integrator.method=ros34pw2", "integrator.tolerance=1e6",
                                       "integrator.step=1e-8", "integrator.w_every=8"});
  Simulation s(m);
  OdeDriver drv(s.model(), s.workspace(), s.schedule(), w_run_options(m.cfg, h0, false));
  s.advance(drv, s.time() + h0);  // the matrix made for h0; the next step proposed at 2 h0
  const double t = s.time(), t1 = t + 1.25 * h0 * (1 + 8e-16);
  ASSERT_GT(t1 - (t + 1.25 * h0), 0.0);
  EXPECT_NO_THROW(s.advance(drv, t1));
  EXPECT_EQ(s.time(), t1);
  EXPECT_TRUE(s.state().allFinite());
}

}  // namespace
}  // namespace cvt
