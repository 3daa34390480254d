// The explicit generic integrators: RK4 (against cvt::Rk4), DOPRI5(4), RKC.
#include <algorithm>
#include <cmath>
#include <cstdio>

#include <gtest/gtest.h>

#include "engine/ode/rk4.hpp"
#include "engine/ode/ode.hpp"
#include "tests/engine/ode/ode_problems.hpp"

namespace cvt {
namespace {

using namespace ode_test;

double observed_order(OdeMethod method, int n) { return smooth_order(smooth_system(), method, n, to_string(method)); }

TEST(OdeRk4, AgreesWithRk4ClassBitForBit) {
  const OdeSystem sys = smooth_system();
  Eigen::VectorXd y = smooth_exact(0), y_ref = y;
  OdeOptions opt;
  opt.fixed_step = true;
  opt.h0 = 0.01;
  int observed = 0;
  const OdeStats st = integrate(sys, OdeMethod::Rk4, 0, 1, y, opt, [&](double, const Eigen::VectorXd&) { ++observed; });
  Rk4 rk4(3);
  auto f = [&](double t, const double* yy, double* dy) { sys.rhs(t, yy, dy); };
  const double h = 1.0 / 100;
  for (int i = 0; i < 100; ++i) rk4.step(f, i * h, h, y_ref);
  EXPECT_EQ(st.steps, 100);
  EXPECT_EQ(st.rhs_evals, 400);
  EXPECT_EQ(observed, 101);
  for (int i = 0; i < 3; ++i) EXPECT_EQ(y[i], y_ref[i]) << i;
}

TEST(OdeOrder, Rk4IsFourth) { EXPECT_NEAR(observed_order(OdeMethod::Rk4, 10), 4.0, 0.2); }

// A step h0 without fixed_step keeps RK4 on fixed steps, as before (OdeDriver relies on it):
// the same bits as with fixed_step.
TEST(OdeRk4, StepWithoutFixedStepStaysFixed) {
  const OdeSystem sys = smooth_system();
  Eigen::VectorXd a = smooth_exact(0), b = a;
  OdeOptions opt;
  opt.h0 = 0.01;
  const OdeStats sa = integrate(sys, OdeMethod::Rk4, 0, 1, a, opt);
  opt.fixed_step = true;
  const OdeStats sb = integrate(sys, OdeMethod::Rk4, 0, 1, b, opt);
  EXPECT_EQ(sa.steps, 100);
  EXPECT_EQ(sa.rhs_evals, sb.rhs_evals);
  for (int i = 0; i < 3; ++i) EXPECT_EQ(a[i], b[i]) << i;
}

// Without h0 and fixed_step RK4 is adaptive like the others: Hairer's starting step, then
// step doubling (one step of h against two of h/2, whose difference / 15 estimates the
// error of the two half steps, which are kept). The estimate is asymptotically exact: on
// the smooth problem each accepted step's true local error (against DOPRI5 at tol 1e-14
// from the same point) is within 15 % of it. The error is controlled per step and the half
// steps are kept unextrapolated, so the global error is the local ones added up: below
// 2 tol per step (DOPRI5, which propagates its higher order, ends closer to tol).
TEST(OdeRk4, AdaptiveByStepDoubling) {
  const OdeSystem sys = smooth_system();
  for (double tol : {1e-5, 1e-8}) {
    OdeOptions opt;
    opt.rtol = opt.atol = tol;
    OdeSolver solver(sys, OdeMethod::Rk4, opt);
    Eigen::VectorXd y = smooth_exact(0), y_prev = y;
    double t_prev = 0, worst_ratio = 0, best_ratio = 1e300, first_h = 0;
    const OdeObserver observer = [&](double t, const Eigen::VectorXd& y_new) {
      if (t == 0) return;
      if (first_h == 0) first_h = t;
      Eigen::VectorXd exact = y_prev;
      OdeOptions tight;
      tight.rtol = tight.atol = 1e-14;
      integrate(sys, OdeMethod::Dopri5, t_prev, t, exact, tight);
      double sum = 0;
      for (int i = 0; i < 3; ++i) {
        const double e = (y_new[i] - exact[i]) / (tol + tol * std::max(std::abs(y_prev[i]), std::abs(y_new[i])));
        sum += e * e;
      }
      const double est = solver.stats().err_last;
      if (est > 0.05) {
        worst_ratio = std::max(worst_ratio, std::sqrt(sum / 3) / est);
        best_ratio = std::min(best_ratio, std::sqrt(sum / 3) / est);
      }
      y_prev = y_new, t_prev = t;
    };
    solver.integrate(0, 10, y, observer);
    const OdeStats& st = solver.stats();
    const double err = (y - smooth_exact(10)).lpNorm<Eigen::Infinity>();
    char label[64];
    std::snprintf(label, sizeof label, "rk4 adaptive smooth tol %.0e", tol);
    print_stats(label, st);
    std::printf("[ode]   rk4 adaptive smooth tol %.0e: error %.3e, first step %.3g, true / estimated local error "
                "%.3f-%.3f\n", tol, err, first_h, best_ratio, worst_ratio);
    EXPECT_LT(err, 2 * tol * static_cast<double>(st.steps));
    EXPECT_GT(st.steps, 10);
    EXPECT_EQ(st.rhs_evals, 11 * (st.steps + st.rejected) + 2) << "11 per attempt, f0 and one for the starting step";
    EXPECT_GT(best_ratio, 0.85);
    EXPECT_LT(worst_ratio, 1.15);
  }
}
TEST(OdeOrder, Dopri5IsFifth) { EXPECT_NEAR(observed_order(OdeMethod::Dopri5, 5), 5.0, 0.25); }
TEST(OdeOrder, RkcIsSecond) { EXPECT_NEAR(observed_order(OdeMethod::Rkc, 20), 2.0, 0.15); }

// The Arenstorf orbit (Hairer, Norsett & Wanner I, II.0, eq. 0.1 and the constants after
// it): the restricted three-body problem whose solution is periodic with period
// T = 17.0652165601579625588917206249, so y(T) = y(0) is the exact reference.
TEST(OdeDopri5, ArenstorfOrbitClosesToTolerance) {
  const double mu = 0.012277471, mu1 = 1 - mu;
  OdeSystem sys;
  sys.size = 4;
  sys.rhs = [=](double, const double* y, double* dy) {
    const double d1 = std::pow((y[0] + mu) * (y[0] + mu) + y[1] * y[1], 1.5);
    const double d2 = std::pow((y[0] - mu1) * (y[0] - mu1) + y[1] * y[1], 1.5);
    dy[0] = y[2];
    dy[1] = y[3];
    dy[2] = y[0] + 2 * y[3] - mu1 * (y[0] + mu) / d1 - mu * (y[0] - mu1) / d2;
    dy[3] = y[1] - 2 * y[2] - mu1 * y[1] / d1 - mu * y[1] / d2;
  };
  const double period = 17.0652165601579625588917206249;
  Eigen::VectorXd y0(4);
  y0 << 0.994, 0, 0, -2.00158510637908252240537862224;
  double err_prev = 0;
  for (double tol : {1e-7, 1e-10}) {
    Eigen::VectorXd y = y0;
    OdeOptions opt;
    opt.rtol = opt.atol = tol;
    const OdeStats st = integrate(sys, OdeMethod::Dopri5, 0, period, y, opt);
    const double err = (y - y0).lpNorm<Eigen::Infinity>();
    char label[64];
    std::snprintf(label, sizeof label, "dopri5 arenstorf tol %.0e", tol);
    print_stats(label, st);
    std::printf("[ode]   arenstorf tol %.0e: |y(T) - y(0)|_inf = %.3e\n", tol, err);
    // The tolerance bounds the local error of each step; along this orbit, with its close
    // passages by the moon, the global error at T grows to about 1e4 times it (Hairer I,
    // section II.4 shows the same growth), and it falls in proportion to tol^(5/6)
    // or better.
    EXPECT_LT(err, 3e4 * tol);
    if (err_prev > 0) {
      EXPECT_GT(err_prev / err, 300.0);
    }
    err_prev = err;
    EXPECT_EQ(st.rhs_evals, 6 * (st.steps + st.rejected) + 2);  // FSAL: 6 per attempt, + f0 and hinit
  }
}

TEST(OdeDopri5, SmoothProblemMeetsTolerance) {
  const OdeSystem sys = smooth_system();
  for (double tol : {1e-5, 1e-8, 1e-11}) {
    Eigen::VectorXd y = smooth_exact(0);
    OdeOptions opt;
    opt.rtol = opt.atol = tol;
    const OdeStats st = integrate(sys, OdeMethod::Dopri5, 0, 10, y, opt);
    const double err = (y - smooth_exact(10)).lpNorm<Eigen::Infinity>();
    std::printf("[ode] dopri5 smooth tol %.0e: error %.3e in %lld steps\n", tol, err,
                static_cast<long long>(st.steps));
    EXPECT_LT(err, 10 * tol);
  }
}

TEST(OdeRkc, SpectralRadiusOfLaplacianWithin10Percent) {
  for (int n : {50, 400}) {
    const Heat heat(n);
    const OdeSystem sys = heat.system();
    Eigen::VectorXd y = heat.exact(0), f(n);
    // A generic state: the pure lowest mode would hide the top of the spectrum from the
    // power method only if it were exactly an eigenvector; add a little of everything.
    for (int i = 0; i < n; ++i) y[i] += 0.01 * std::cos(7.0 * i);
    sys.rhs(0, y.data(), f.data());
    SpectralRadius est(n);
    int evals = 0;
    const double sigma = est.estimate(sys, 0, y, f, &evals);
    const double exact = heat.lambda(n);
    std::printf("[ode] rho laplacian n = %3d: estimate %.6e exact %.6e ratio %.4f in %d f-evals\n", n, sigma, exact,
                sigma / exact, evals);
    EXPECT_TRUE(est.converged());
    EXPECT_NEAR(sigma / exact, 1.0, 0.10);
    // Warm start from the direction found: converges in a few evaluations.
    int evals2 = 0;
    const double sigma2 = est.estimate(sys, 0, y, f, &evals2);
    EXPECT_NEAR(sigma2 / exact, 1.0, 0.10);
    EXPECT_LE(evals2, evals);
  }
}

TEST(OdeRkc, DiagonalSpectrumWithin10Percent) {
  // Eigenvalues -1 ... -1e4 spread geometrically; the largest is 1e4.
  const int n = 60;
  Eigen::VectorXd lam(n);
  for (int i = 0; i < n; ++i) lam[i] = -std::pow(10.0, 4.0 * i / (n - 1));
  OdeSystem sys;
  sys.size = n;
  sys.rhs = [lam](double, const double* y, double* dy) {
    for (int i = 0; i < lam.size(); ++i) dy[i] = lam[i] * (y[i] - 1.0);
  };
  Eigen::VectorXd y = Eigen::VectorXd::Constant(n, 2.0), f(n);
  sys.rhs(0, y.data(), f.data());
  SpectralRadius est(n);
  int evals = 0;
  const double sigma = est.estimate(sys, 0, y, f, &evals);
  std::printf("[ode] rho diagonal: estimate %.6e exact 1e4 in %d f-evals\n", sigma, evals);
  EXPECT_NEAR(sigma / 1e4, 1.0, 0.10);
}

// h rho = 40, far beyond RK4's real stability limit 2.785: RK4 blows up, RKC with the
// stage count it picks stays stable and second-order accurate.
TEST(OdeRkc, StableFarBeyondRk4Limit) {
  const Heat heat(100);
  const OdeSystem sys = heat.system();
  const double rho = heat.lambda(100), h = 40 / rho, t_end = 0.05;
  OdeOptions opt;
  opt.fixed_step = true;
  opt.h0 = h;
  Eigen::VectorXd y = heat.exact(0);
  const OdeStats st = integrate(sys, OdeMethod::Rkc, 0, t_end, y, opt);
  const double err = (y - heat.exact(t_end)).lpNorm<Eigen::Infinity>();
  std::printf("[ode] rkc fixed h*rho = %.1f: stages %d, steps %lld, f-evals %lld, error %.3e (|u| %.3e)\n",
              h * rho, st.max_stages, static_cast<long long>(st.steps), static_cast<long long>(st.rhs_evals), err,
              heat.exact(t_end).lpNorm<Eigen::Infinity>());
  EXPECT_LT(err, 1e-4);
  EXPECT_GE(st.max_stages, 6);

  Eigen::VectorXd y4 = heat.exact(0);
  integrate(sys, OdeMethod::Rk4, 0, t_end, y4, opt);
  const double err4 = (y4 - heat.exact(t_end)).lpNorm<Eigen::Infinity>();
  std::printf("[ode] rk4 fixed h*rho = %.1f: error %.3e (unstable)\n", h * rho, err4);
  EXPECT_TRUE(!std::isfinite(err4) || err4 > 1e3);
}

TEST(OdeRkc, AdaptiveHeatEquationMeetsTolerance) {
  const Heat heat(200);
  const OdeSystem sys = heat.system();
  for (double tol : {1e-4, 1e-6}) {
    Eigen::VectorXd y = heat.exact(0);
    for (int i = 0; i < heat.n; ++i) y[i] += 1e-3 * std::sin(150.0 * i);  // fast modes to damp
    OdeOptions opt;
    opt.rtol = opt.atol = tol;
    const OdeStats st = integrate(sys, OdeMethod::Rkc, 0, 0.2, y, opt);
    const double err = (y - heat.exact(0.2)).lpNorm<Eigen::Infinity>();
    char label[64];
    std::snprintf(label, sizeof label, "rkc heat n=200 tol %.0e", tol);
    print_stats(label, st);
    std::printf("[ode]   rkc heat tol %.0e: error %.3e, max stages %d, rho %.4e (exact %.4e), rho estimates %lld\n",
                tol, err, st.max_stages, st.rho_last, heat.lambda(200), static_cast<long long>(st.rho_estimates));
    // Error per step control: the global error stays below (steps x tol).
    EXPECT_LT(err, st.steps * tol);
    // An explicit method of RK4's stability would need h < 2.8 / rho: count its steps.
    EXPECT_LT(st.steps, 0.2 * heat.lambda(200) / 2.8 / 10);
  }
}

TEST(OdeErrors, BlowUpGivesClearError) {
  OdeSystem sys;
  sys.size = 1;
  sys.rhs = [](double, const double* y, double* dy) { dy[0] = y[0] * y[0]; };  // y = 1 / (1 - t)
  for (OdeMethod m : {OdeMethod::Dopri5, OdeMethod::Rkc, OdeMethod::TrBdf2}) {
    Eigen::VectorXd y = Eigen::VectorXd::Ones(1);
    try {
      integrate(sys, m, 0, 2, y);
      ADD_FAILURE() << to_string(m) << " integrated through the singularity at t = 1";
    } catch (const OdeError& e) {
      std::printf("[ode] %s blow-up: %s\n", to_string(m), e.what());
      EXPECT_NEAR(e.t, 1.0, 1e-2) << e.what();
    }
  }
}

}  // namespace
}  // namespace cvt
