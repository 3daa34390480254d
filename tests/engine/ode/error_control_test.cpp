// The error control of the adaptive implicit and W-methods: does an accepted step's error
// estimate hold? Every accepted step from (t_n, y_n) is taken again from the same y_n by
// ESDIRK3 at tol 1e-12 (the "true" solution), and the difference is measured in the norm
// of the error test, where 1 is the tolerance (docs/integrators.md 12.5).
#include <algorithm>
#include <cmath>
#include <cstdio>

#include <gtest/gtest.h>

#include "engine/ode/ode.hpp"
#include "tests/engine/ode/ode_problems.hpp"

namespace cvt {
namespace {

using namespace ode_test;

struct LocalErrors {
  int steps = 0, above_tolerance = 0;
  double worst_true = 0, est_at_worst = 0, growth_at_worst = 0, t_at_worst = 0;
  double mescd = 0;
};

LocalErrors local_errors(const TestSetProblem& p, OdeMethod m, double tol, bool linearization_test = true) {
  OdeOptions o;
  o.rtol = o.atol = tol;
  o.w_linearization_test = linearization_test;
  OdeSolver solver(p.sys, m, o);
  const int n = p.sys.size;
  Eigen::VectorXd y = p.y0, y_prev = p.y0;
  double t_prev = 0, h_prev = 0;
  LocalErrors r;
  const OdeObserver observer = [&](double t, const Eigen::VectorXd& y_new) {
    if (t == 0) return;
    Eigen::VectorXd exact = y_prev;
    OdeOptions tight;
    tight.rtol = 1e-12, tight.atol = 1e-16;
    integrate(p.sys, OdeMethod::Esdirk3, t_prev, t, exact, tight);
    double sum = 0;
    for (int i = 0; i < n; ++i) {
      const double e = (y_new[i] - exact[i]) / (tol + tol * std::max(std::abs(y_prev[i]), std::abs(y_new[i])));
      sum += e * e;
    }
    const double err = std::sqrt(sum / n), h = solver.stats().h_last;
    ++r.steps;
    if (err > 1) ++r.above_tolerance;
    if (err > r.worst_true)
      r.worst_true = err, r.est_at_worst = solver.stats().err_last, r.growth_at_worst = h_prev > 0 ? h / h_prev : 0,
      r.t_at_worst = t_prev;
    y_prev = y_new, t_prev = t, h_prev = h;
  };
  solver.integrate(0, p.t_end, y, observer);
  r.mescd = mescd(y, p.ref, tol, tol);
  std::printf("[ode] local errors %-12s %-9s tol %.0e%s: %4d steps, %2d above the tolerance, worst true %.3g (estimate "
              "%.3g, step grown %.2fx, at t = %.4g), mescd %.2f\n",
              p.name, to_string(m), tol, linearization_test ? "" : " (estimate alone)", r.steps, r.above_tolerance,
              r.worst_true, r.est_at_worst, r.growth_at_worst, r.t_at_worst, r.mescd);
  return r;
}

// HIRES at tol 1e-4. With steps growing 10x (W-methods) or 5x (implicit) per step and the
// embedded estimate alone, ROS34PW2 accepted a step of 212 (grown 2.8x) estimated at 0.55
// with a true error of 57; the growth bound of 2 alone still leaves one at 0.80 against 52.
// Now every accepted step of every method stays within the tolerance.
TEST(OdeErrorControl, HiresAcceptedStepsAreWithinTolerance) {
  const TestSetProblem p = hires();
  for (OdeMethod m : {OdeMethod::Ros2, OdeMethod::Ros34pw2, OdeMethod::TrBdf2, OdeMethod::Esdirk3}) {
    const LocalErrors r = local_errors(p, m, 1e-4);
    EXPECT_EQ(r.above_tolerance, 0) << to_string(m);
    EXPECT_LT(r.worst_true, 1.0) << to_string(m);
  }
  // Without the linearization test ROS34PW2 is back to trusting a wrong estimate.
  const LocalErrors bare = local_errors(p, OdeMethod::Ros34pw2, 1e-4, false);
  EXPECT_GT(bare.worst_true, 10.0);
  EXPECT_LT(bare.est_at_worst, 1.0);
}

// VDPOL (mu = 1e3) at tol 1e-4: with 5x growth ESDIRK3 accepted a step with a true error
// 7600 times the tolerance (mescd -0.03); with 2x none passes the tolerance.
TEST(OdeErrorControl, VanDerPolEsdirk3AcceptedStepsAreWithinTolerance) {
  const LocalErrors r = local_errors(vdpol(), OdeMethod::Esdirk3, 1e-4);
  EXPECT_EQ(r.above_tolerance, 0);
  EXPECT_GT(r.mescd, 3.0);
}

}  // namespace
}  // namespace cvt
