// Convergence of RK4 (docs/model.md 7).
//
// 1. The integrator is 4th order on a smooth system (halving h divides the error by 16).
// 2. It is 4th order on the CVT model with the smooth friction law, measured on positions
//    over a short window (statuses frozen) of a running, clamped mini chain. Why positions
//    and a short window: the stiffest modes (omega ~ 1e8 rad/s) turn the rounding of
//    positions (an ulp of 0.05 m is 7e-18 m) into velocity noise of ~1e-9 m/s, which hides
//    RK4's truncation error in any velocity norm once h < 2e-9; positions keep a rounding
//    floor near 2e-15 m, two decades under the errors measured here. Over longer windows
//    contacts open and close, and the Hertz law (C1 at zero penetration) and the contact
//    damping (a jump) bring the order down to 1-2: that is the model, not the integrator.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "engine/ode/rk4.hpp"
#include "engine/simulation.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

TEST(ConvergenceTest, Rk4IsFourthOrderOnASmoothSystem) {
  // Nonlinear pendulum-like oscillator x'' = -sin(x), with a known-smooth solution.
  auto f = [](double, const double* y, double* dy) {
    dy[0] = y[1];
    dy[1] = -std::sin(y[0]);
  };
  auto solve = [&](int n) {
    Rk4 rk(2);
    Eigen::VectorXd y(2);
    y << 1.0, 0.0;
    const double h = 2.0 / n;
    for (int i = 0; i < n; ++i) rk.step(f, i * h, h, y);
    return y;
  };
  const Eigen::VectorXd ref = solve(20000);
  double prev = 0;
  for (int n : {20, 40, 80, 160}) {
    const double err = (solve(n) - ref).norm();
    if (prev > 0) {
      std::printf("n = %d: error %.3g, observed order %.3f\n", n, err, std::log2(prev / err));
      EXPECT_NEAR(std::log2(prev / err), 4.0, 0.15);
    }
    prev = err;
  }
}

TEST(ConvergenceTest, Rk4IsFourthOrderOnTheModelWithSmoothFriction) {
  const Model m = test::model("mini", {"friction.law=\"smooth\"", "ramp.time=0"});
  // A running chain under full clamping after 0.2 ms, velocities kicked by up to 1 cm/s.
  Simulation settle(m);
  for (int i = 0; i < 20000; ++i) settle.step(1e-8);
  Eigen::VectorXd y0 = settle.state();
  const Eigen::VectorXd kick = test::perturbed_state(m, 3, 0, 0, 0.01) - m.y0;
  y0.segment(m.ndof, m.ndof) += kick.segment(m.ndof, m.ndof);
  const ContactStatus status = settle.workspace().status;
  const double T = 1e-7;
  auto solve = [&](int n) {
    Simulation s(m);
    s.mutable_state() = y0;
    s.workspace().status = status;
    s.set_clock(settle.time(), 0);
    for (int i = 0; i < n; ++i) s.step(T / n, false);
    return Eigen::VectorXd(s.state().head(m.ndof));
  };
  const Eigen::VectorXd ref = solve(3200);
  const double e25 = (solve(25) - ref).norm(), e50 = (solve(50) - ref).norm(), floor = (solve(400) - ref).norm();
  const double order = std::log2(e25 / e50);
  std::printf("position error h = 4e-9: %.3g m, h = 2e-9: %.3g m, observed order %.2f (rounding floor %.2g m)\n", e25,
              e50, order, floor);
  EXPECT_GT(e50, 4.0 * floor) << "errors too close to rounding to measure an order";
  EXPECT_NEAR(order, 4.0, 0.4);
}

}  // namespace
}  // namespace cvt
