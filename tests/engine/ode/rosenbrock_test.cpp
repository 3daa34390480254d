// The W-methods ROS2 and ROS34PW2 and the Rosenbrock method ROS34PRW (engine/ode/rosenbrock.cpp,
// docs/integrators.md 12): their orders with the exact Jacobian and with other matrices J~,
// L-stability, stiff components that an explicit step could not take, and Prothero-Robinson.
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>

#include <gtest/gtest.h>

#include "engine/ode/ode.hpp"
#include "tests/engine/ode/ode_problems.hpp"

namespace cvt {
namespace {

using namespace ode_test;

// Installs W = I - gh J~ with a constant dense J~ as the system's w_factor / w_solve.
struct ConstantW {
  Eigen::MatrixXd jt;
  Eigen::PartialPivLU<Eigen::MatrixXd> lu;
  void install(OdeSystem& sys) {
    sys.w_factor = [this](double, const double*, double gh) {
      lu.compute(Eigen::MatrixXd::Identity(jt.rows(), jt.cols()) - gh * jt);
    };
    sys.w_solve = [this](double* x) {
      Eigen::Map<Eigen::VectorXd> v(x, jt.rows());
      const Eigen::VectorXd r = lu.solve(v);
      v = r;
    };
  }
};

// A stiff component tracking a slow one: y1' = -1e8 (y1 - y2), y2' = -y2; from y(0) = (0, 1),
// y2 = exp(-t) and y1 = y2 after a layer of 1e-8. (The caller installs its W.)
OdeSystem stiff_pair() {
  OdeSystem sys;
  sys.size = 2;
  sys.rhs = [](double, const double* y, double* dy) {
    dy[0] = -1e8 * (y[0] - y[1]);
    dy[1] = -y[1];
  };
  return sys;
}

double observed_order(const OdeSystem& sys, const char* label) { return smooth_order(sys, OdeMethod::Ros2, 40, label); }

TEST(OdeRos2, SecondOrderWithTheFiniteDifferenceJacobian) {
  EXPECT_NEAR(observed_order(smooth_system(), "ros2 (J~ = J by differences)"), 2.0, 0.1);
}

// The W-method property: the order conditions do not involve J~, so a zero matrix (ROS2
// becomes Heun's explicit method) and a wrong one both keep second order (the wrong one
// once h |J~| is small).
TEST(OdeRos2, SecondOrderForAnyMatrix) {
  for (int variant = 0; variant < 2; ++variant) {
    OdeSystem sys = smooth_system();
    ConstantW w;
    w.jt = Eigen::MatrixXd::Zero(3, 3);
    if (variant == 1) w.jt << -3.0, 0.5, 0.0, 0.2, -1.0, 0.7, 0.0, -0.4, -2.0;
    w.install(sys);
    // The wrong matrix approaches 2 from below as h |J~| shrinks (1.73, 1.85 at n = 80, 160).
    EXPECT_NEAR(observed_order(sys, variant == 0 ? "ros2 (J~ = 0)" : "ros2 (J~ wrong)"), 2.0, variant == 0 ? 0.1 : 0.2) << variant;
  }
}

// OdeOptions::w_reuse_steps: the finite-difference Jacobian and its LU kept for 5 steps.
// Still second order (the W-method property), with a fifth of the Jacobians.
TEST(OdeRos2, StaleJacobianKeepsSecondOrder) {
  auto error = [](int n, std::int64_t* jacs) {
    Eigen::VectorXd y = smooth_exact(0);
    OdeOptions opt;
    opt.fixed_step = true;
    opt.h0 = 2.0 / n;
    opt.w_reuse_steps = 5;
    const OdeStats st = integrate(smooth_system(), OdeMethod::Ros2, 0, 2, y, opt);
    *jacs = st.jac_evals;
    return (y - smooth_exact(2)).lpNorm<Eigen::Infinity>();
  };
  std::int64_t j1 = 0, j2 = 0, j3 = 0;
  const double e1 = error(40, &j1), e2 = error(80, &j2), e3 = error(160, &j3);
  std::printf("[ode] order ros2 (Jacobian every 5 steps) n = 40 80 160  errors %.3e %.3e %.3e  orders %.2f %.2f  "
              "Jacobians %lld %lld %lld\n", e1, e2, e3, std::log2(e1 / e2), std::log2(e2 / e3),
              static_cast<long long>(j1), static_cast<long long>(j2), static_cast<long long>(j3));
  EXPECT_NEAR(std::log2(e2 / e3), 2.0, 0.1);
  EXPECT_EQ(j3, 32);
}

// A stiff component tracking a slow one: y1' = -1e8 (y1 - y2), y2' = -y2, y(0) = (0, 1);
// y2 = exp(-t) and y1 = y2 after a layer of 1e-8. At h = 0.05 (h lambda = -5e6) ROS2 with
// J~ = J is L-stable and lands on the slow solution at once; J~ = 0 (explicit) explodes. A
// J~ with only the stiff diagonal entry, exact or off by a factor 3 either way (as the
// CVT's friction blocks capture the friction stiffness per joint only), stays stable, but
// the stiff component then lags its slow manifold by O(h): 12x the error of J~ = J with
// the exact diagonal, 50x with 3x it, and 500x with a third of it. That is the price of a
// partial J~, and what limits ROS2's accuracy on the CVT (docs/integrators.md 12).
TEST(OdeRos2, StiffComponentNeedsTheMatrixOnlyRoughly) {
  auto run = [](bool full, double factor) -> double {
    OdeSystem sys = stiff_pair();
    ConstantW w;
    w.jt = Eigen::MatrixXd::Zero(2, 2);
    w.jt(0, 0) = -1e8 * factor;
    if (full) w.jt(0, 1) = 1e8, w.jt(1, 1) = -1;
    w.install(sys);
    OdeOptions opt;
    opt.fixed_step = true;
    opt.h0 = 0.05;
    Eigen::VectorXd y(2);
    y << 0.0, 1.0;
    try {
      integrate(sys, OdeMethod::Ros2, 0, 1, y, opt);
    } catch (const OdeError&) {
      return std::numeric_limits<double>::infinity();
    }
    return std::max(std::abs(y[0] - std::exp(-1.0)), std::abs(y[1] - std::exp(-1.0)));
  };
  const double exact = run(true, 1.0), diag = run(false, 1.0), third = run(false, 1.0 / 3.0),
               thrice = run(false, 3.0), none = run(false, 0.0);
  std::printf("[ode] ros2 h = 0.05, lambda = -1e8: |error| J~ = J %.3e, diagonal %.3e, diagonal / 3 %.3e, "
              "diagonal x 3 %.3e, 0 %.3e\n", exact, diag, third, thrice, none);
  EXPECT_LT(exact, 2e-3);
  EXPECT_LT(diag, 0.03);
  EXPECT_LT(thrice, 0.1);
  EXPECT_LT(third, 1.0);  // stable, but far off
  EXPECT_LT(exact, diag);
  EXPECT_FALSE(none < 1.0);
}

// Adaptive mode on the smooth problem: the estimate is that of the embedded first-order
// solution, so the steps go like tol^(1/2) and the global error stays near tol (at many
// more steps than TR-BDF2's; ROS2 is here for fixed steps with a cheap matrix).
TEST(OdeRos2, AdaptiveSmoothProblem) {
  for (double tol : {1e-4, 1e-7}) {
    Eigen::VectorXd y = smooth_exact(0);
    OdeOptions opt;
    opt.rtol = opt.atol = tol;
    OdeSystem sys = smooth_system();
    ConstantW w;  // the exact Jacobian of the autonomous part
    w.jt = Eigen::MatrixXd::Zero(3, 3);
    w.jt(0, 1) = 1, w.jt(1, 0) = -1;
    w.install(sys);
    const OdeStats st = integrate(sys, OdeMethod::Ros2, 0, 10, y, opt);
    const double err = (y - smooth_exact(10)).lpNorm<Eigen::Infinity>();
    print_stats(tol > 1e-5 ? "ros2 smooth tol 1e-04" : "ros2 smooth tol 1e-07", st);
    std::printf("[ode]   ros2 smooth tol %.0e: error %.3e\n", tol, err);
    EXPECT_LT(err, 30 * tol);
    EXPECT_EQ(st.rhs_evals, 2 * (st.steps + st.rejected) + 2) << "two evaluations per attempt, two for HINIT";
  }
}

}  // namespace
}  // namespace cvt

namespace cvt {
namespace {

using namespace ode_test;

// ROS34PW2 (Rang & Angermann 2005): third order with the exact Jacobian and, being a
// W-method of order 3, with any other matrix, including zero (then it is an explicit
// 4-stage Runge-Kutta method of order 3); the non-autonomous term enters through the
// zero t-column of J~ that a W-method allows.
TEST(OdeRos34pw2, ThirdOrderForAnyMatrix) {
  EXPECT_NEAR(smooth_order(smooth_system(), OdeMethod::Ros34pw2, 40, "ros34pw2 (J~ = J by differences)"), 3.0, 0.15);
  for (int variant = 0; variant < 2; ++variant) {
    OdeSystem sys = smooth_system();
    ConstantW w;
    w.jt = Eigen::MatrixXd::Zero(3, 3);
    if (variant == 1) w.jt << -3.0, 0.5, 0.0, 0.2, -1.0, 0.7, 0.0, -0.4, -2.0;
    w.install(sys);
    EXPECT_NEAR(smooth_order(sys, OdeMethod::Ros34pw2, 40, variant == 0 ? "ros34pw2 (J~ = 0)" : "ros34pw2 (J~ wrong)"),
                3.0, 0.2)
        << variant;
  }
}

// ROS34PRW: third order with the exact Jacobian (the classical Rosenbrock conditions; the
// smooth system is driven by t, so with its exact t-column, df/dt) but not a W-method: with
// a wrong constant matrix its order falls (to about 1.4 here), and with the Jacobian kept
// for 5 steps (J~ = J + O(h)) to 2, where ROS34PW2 keeps 3.
OdeSystem smooth_system_with_dfdt() {
  OdeSystem sys = smooth_system();
  sys.time_derivative = [](double, const double* y, double* ft) { ft[0] = 0, ft[1] = 0, ft[2] = -y[2] * y[2]; };
  return sys;
}

TEST(OdeRos34prw, ThirdOrderOnlyWithTheCurrentJacobian) {
  EXPECT_NEAR(smooth_order(smooth_system_with_dfdt(), OdeMethod::Ros34prw, 40, "ros34prw (J~ = J by differences)"), 3.0,
              0.15);
  OdeSystem sys = smooth_system_with_dfdt();
  ConstantW w;
  w.jt = Eigen::MatrixXd::Zero(3, 3);
  w.jt << -3.0, 0.5, 0.0, 0.2, -1.0, 0.7, 0.0, -0.4, -2.0;
  w.install(sys);
  EXPECT_LT(smooth_order(sys, OdeMethod::Ros34prw, 40, "ros34prw (J~ wrong)"), 2.0);
  auto stale_order = [](OdeMethod m) {
    double e[2];
    for (int k = 0; k < 2; ++k) {
      Eigen::VectorXd y = smooth_exact(0);
      OdeOptions opt;
      opt.fixed_step = true;
      opt.h0 = 2.0 / (160 << k);
      opt.w_reuse_steps = 5;
      integrate(smooth_system_with_dfdt(), m, 0, 2, y, opt);
      e[k] = (y - smooth_exact(2)).lpNorm<Eigen::Infinity>();
    }
    std::printf("[ode] %s, Jacobian kept 5 steps, n = 160 320: errors %.3e %.3e  order %.2f\n", to_string(m), e[0],
                e[1], std::log2(e[0] / e[1]));
    return std::log2(e[0] / e[1]);
  };
  EXPECT_NEAR(stale_order(OdeMethod::Ros34prw), 2.0, 0.25);
  EXPECT_NEAR(stale_order(OdeMethod::Ros34pw2), 3.0, 0.25);
}

// Stiffly accurate and L-stable: on the stiff pair of OdeRos2.StiffComponentNeedsTheMatrixOnlyRoughly
// the stiff component sits on its slow manifold after each step, to third order in h.
TEST(OdeRos34pw2, StiffComponentOnItsSlowManifold) {
  auto run = [](double h) {
    OdeSystem sys = stiff_pair();
    ConstantW w;
    w.jt = Eigen::MatrixXd::Zero(2, 2);
    w.jt(0, 0) = -1e8, w.jt(0, 1) = 1e8, w.jt(1, 1) = -1;
    w.install(sys);
    OdeOptions opt;
    opt.fixed_step = true;
    opt.h0 = h;
    Eigen::VectorXd y(2);
    y << 0.0, 1.0;
    integrate(sys, OdeMethod::Ros34pw2, 0, 1, y, opt);
    return std::max(std::abs(y[0] - std::exp(-1.0)), std::abs(y[1] - std::exp(-1.0)));
  };
  const double e1 = run(0.05), e2 = run(0.025), e3 = run(0.0125);
  std::printf("[ode] ros34pw2 lambda = -1e8, h = 0.05 0.025 0.0125: |error| %.3e %.3e %.3e  orders %.2f %.2f\n", e1, e2,
              e3, std::log2(e1 / e2), std::log2(e2 / e3));
  EXPECT_LT(e1, 1e-4);
  EXPECT_NEAR(std::log2(e2 / e3), 3.0, 0.3);
}

// Adaptive mode: the embedded second-order solution sets the steps (tol^(1/3)). Each attempt
// takes four evaluations for the stages and one for the linearization test.
TEST(OdeRos34pw2, AdaptiveSmoothProblem) {
  for (double tol : {1e-4, 1e-7}) {
    Eigen::VectorXd y = smooth_exact(0);
    OdeOptions opt;
    opt.rtol = opt.atol = tol;
    const OdeStats st = integrate(smooth_system(), OdeMethod::Ros34pw2, 0, 10, y, opt);
    const double err = (y - smooth_exact(10)).lpNorm<Eigen::Infinity>();
    print_stats(tol > 1e-5 ? "ros34pw2 smooth tol 1e-04" : "ros34pw2 smooth tol 1e-07", st);
    std::printf("[ode]   ros34pw2 smooth tol %.0e: error %.3e\n", tol, err);
    EXPECT_LT(err, 30 * tol);
    EXPECT_EQ(st.rhs_evals - st.jac_evals * (st.colors > 0 ? st.colors : 3), 5 * (st.steps + st.rejected) + 2);
  }
}

}  // namespace
}  // namespace cvt

namespace cvt {
namespace {

using namespace ode_test;

// Prothero-Robinson: y' = lambda (y - g(t)) + g'(t), g = sin, y(0) = g(0), so y = g; lambda =
// -1e4. Stiff and driven by t: with the t-column of J~ zero (no df/dt) ROS2 falls to order
// 1 while h |lambda| >> 1; with OdeSystem::time_derivative it keeps order 2.
OdeSystem prothero_robinson(bool with_dfdt) {
  constexpr double lambda = -1e4;
  OdeSystem sys;
  sys.size = 1;
  sys.rhs = [](double t, const double* y, double* f) { f[0] = lambda * (y[0] - std::sin(t)) + std::cos(t); };
  if (with_dfdt)
    sys.time_derivative = [](double t, const double*, double* ft) { ft[0] = -lambda * std::cos(t) - std::sin(t); };
  return sys;
}

double prothero_robinson_order(OdeMethod m, bool with_dfdt, double* error_at_n10) {
  const OdeSystem sys = prothero_robinson(with_dfdt);
  double e[4];
  const int ns[4] = {10, 20, 40, 80};  // h |lambda| from 1000 to 125
  for (int k = 0; k < 4; ++k) {
    OdeOptions opt;
    opt.fixed_step = true;
    opt.h0 = 1.0 / ns[k];
    Eigen::VectorXd y = Eigen::VectorXd::Zero(1);
    integrate(sys, m, 0, 1, y, opt);
    e[k] = std::abs(y[0] - std::sin(1.0));
  }
  const double p = std::log2(e[2] / e[3]);
  std::printf("[ode] prothero-robinson lambda -1e4 %-9s %s: n = 10 20 40 80  errors %.3e %.3e %.3e %.3e  orders %.2f "
              "%.2f %.2f\n",
              to_string(m), with_dfdt ? "with df/dt   " : "without df/dt", e[0], e[1], e[2], e[3], std::log2(e[0] / e[1]),
              std::log2(e[1] / e[2]), p);
  *error_at_n10 = e[0];
  return p;
}

TEST(OdeTimeDerivative, Ros2KeepsSecondOrderOnProtheroRobinson) {
  double e_without = 0, e_with = 0;
  EXPECT_NEAR(prothero_robinson_order(OdeMethod::Ros2, false, &e_without), 1.0, 0.1);
  EXPECT_NEAR(prothero_robinson_order(OdeMethod::Ros2, true, &e_with), 2.0, 0.1);
  EXPECT_LT(e_with, e_without / 10);
}

// ROS34PW2 (built for index-1 DAEs) is second order on stiff Prothero-Robinson either way:
// df/dt moves its result only at the level of rounding here.
TEST(OdeTimeDerivative, Ros34pw2IsSecondOrderOnProtheroRobinsonEitherWay) {
  double e_without = 0, e_with = 0;
  EXPECT_NEAR(prothero_robinson_order(OdeMethod::Ros34pw2, false, &e_without), 2.0, 0.15);
  EXPECT_NEAR(prothero_robinson_order(OdeMethod::Ros34pw2, true, &e_with), 2.0, 0.15);
  EXPECT_NEAR(e_with, e_without, 1e-3 * e_without);
}

// ROS34PRW (Rang 2015) satisfies the Prothero-Robinson conditions ROS34PW2 lacks: third order
// on the stiff problem, with df/dt (its stage times enter through the exact t-column), and
// at n = 10 far closer than ROS34PW2.
TEST(OdeTimeDerivative, Ros34prwIsThirdOrderOnProtheroRobinson) {
  double e_pw2 = 0, e_prw = 0;
  prothero_robinson_order(OdeMethod::Ros34pw2, true, &e_pw2);
  EXPECT_NEAR(prothero_robinson_order(OdeMethod::Ros34prw, true, &e_prw), 3.0, 0.2);
  EXPECT_LT(e_prw, e_pw2 / 10);
}

// With df/dt a W-step is the step of the autonomous system (y, t)' = (f, 1) whose Jacobian
// has the exact t-column: the same numbers to rounding, for a nonlinear f.
TEST(OdeTimeDerivative, IsTheAutonomousFormWithTheExactTColumn) {
  constexpr double lambda = -50;
  auto f = [](double t, double y) { return lambda * (y - std::sin(3 * t)) + 3 * std::cos(3 * t) + y * y * std::cos(t); };
  auto fy = [](double t, double y) { return lambda + 2 * y * std::cos(t); };
  auto ft = [](double t, double y) { return -3 * lambda * std::cos(3 * t) - 9 * std::sin(3 * t) - y * y * std::sin(t); };
  OdeSystem sys;
  sys.size = 1;
  sys.rhs = [=](double t, const double* y, double* dy) { dy[0] = f(t, y[0]); };
  sys.dense_jacobian = [=](double t, const double* y, Eigen::MatrixXd& j) { j(0, 0) = fy(t, y[0]); };
  sys.time_derivative = [=](double t, const double* y, double* d) { d[0] = ft(t, y[0]); };
  OdeSystem aut;  // z = (y, t)
  aut.size = 2;
  aut.rhs = [=](double, const double* z, double* dz) { dz[0] = f(z[1], z[0]), dz[1] = 1; };
  aut.dense_jacobian = [=](double, const double* z, Eigen::MatrixXd& j) {
    j << fy(z[1], z[0]), ft(z[1], z[0]), 0, 0;
  };
  for (OdeMethod m : {OdeMethod::Ros2, OdeMethod::Ros34pw2}) {
    OdeOptions opt;
    opt.fixed_step = true;
    opt.h0 = 0.05;
    Eigen::VectorXd y(1), z(2);
    y << 0.2;
    z << 0.2, 0.0;
    integrate(sys, m, 0, 1, y, opt);
    integrate(aut, m, 0, 1, z, opt);
    EXPECT_NEAR(y[0], z[0], 1e-14) << to_string(m);
    OdeSystem plain = sys;  // and without df/dt the result differs by far more
    plain.time_derivative = nullptr;
    Eigen::VectorXd y0(1);
    y0 << 0.2;
    integrate(plain, m, 0, 1, y0, opt);
    EXPECT_GT(std::abs(y0[0] - y[0]), 1e-4) << to_string(m);
  }
}

// Adaptive ROS2 on Prothero-Robinson at tol 1e-6 over [0, 2]: the first-order error without
// df/dt makes the controller crawl.
TEST(OdeTimeDerivative, AdaptiveRos2NeedsFarFewerStepsWithIt) {
  std::int64_t steps[2];
  for (int with = 0; with < 2; ++with) {
    OdeOptions opt;
    opt.rtol = opt.atol = 1e-6;
    Eigen::VectorXd y = Eigen::VectorXd::Zero(1);
    steps[with] = integrate(prothero_robinson(with), OdeMethod::Ros2, 0, 2, y, opt).steps;
    EXPECT_LT(std::abs(y[0] - std::sin(2.0)), 1e-4) << with;
  }
  std::printf("[ode] prothero-robinson adaptive ros2 tol 1e-6: %lld steps without df/dt, %lld with\n",
              static_cast<long long>(steps[0]), static_cast<long long>(steps[1]));
  EXPECT_LT(steps[1] * 10, steps[0]);
}

}  // namespace
}  // namespace cvt
