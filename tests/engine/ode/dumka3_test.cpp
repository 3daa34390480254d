// DUMKA3 (Medovikov's third-order stabilized explicit method, engine/ode/dumka3.cpp): its
// order for every one of its polynomials, their stability intervals, the heat equation far
// beyond RK4's limit, adaptive runs against exact solutions, no allocation while integrating.
// The references are independent of the code: the published degrees and stability intervals
// of dumka3.f (N_DEG, STAB_REG), exact solutions, the theoretical orders.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <numbers>

#include <gtest/gtest.h>

#include "engine/ode/ode.hpp"
#include "tests/alloc_count.hpp"
#include "tests/engine/ode/ode_problems.hpp"

namespace cvt {
namespace {

using namespace ode_test;

// dumka3.f's polynomial degrees and real stability intervals (N_DEG, STAB_REG), less the
// degree-324 polynomial, whose published coefficients do not have its interval.
struct Published {
  int degree;
  double interval;
};
constexpr Published kPublished[] = {{3, 2.5005127005},        {6, 9.784756428464169},    {9, 23.818760475282560},
                                    {15, 68.932817124349140},  {21, 136.648186730571300}, {27, 226.8897061613812},
                                    {36, 404.7232537379578},   {48, 720.7401653373073},   {63, 1337.1268312643200},
                                    {81, 3266.0271134242240},  {135, 9072.0255133253400}, {189, 17784.544093341440},
                                    {243, 27323.320790121520985}, {432, 88860.62470326659968122},
                                    {576, 142602.586088039999594}};

// The semi-discrete heat equation's exact solution from any u0: the discrete sine modes
// decay independently, u(t) = sum_k b_k sin(k pi x_i) exp(-lambda_k t), with b_k from the
// orthogonality sum_i sin(k pi x_i) sin(m pi x_i) = (n + 1) / 2 delta_km.
Eigen::VectorXd heat_solution(const Heat& heat, const Eigen::VectorXd& u0, double t) {
  const int n = heat.n;
  Eigen::VectorXd u = Eigen::VectorXd::Zero(n);
  for (int k = 1; k <= n; ++k) {
    double b = 0;
    for (int i = 0; i < n; ++i) b += u0[i] * std::sin(k * std::numbers::pi * (i + 1) * heat.dx);
    b *= 2.0 / (n + 1) * std::exp(-heat.lambda(k) * t);
    for (int i = 0; i < n; ++i) u[i] += b * std::sin(k * std::numbers::pi * (i + 1) * heat.dx);
  }
  return u;
}

TEST(OdeDumka3, Name) { EXPECT_STREQ(to_string(OdeMethod::Dumka3), "dumka3"); }

// Fixed steps on the smooth problem of the other order tests, with the spectral radius
// estimated (the degree-3 polynomial serves this nonstiff problem).
TEST(OdeDumka3, ThirdOrderOnSmoothProblem) {
  EXPECT_NEAR(smooth_order(smooth_system(), OdeMethod::Dumka3, 10, "dumka3"), 3.0, 0.15);
}

// Every polynomial, forced by a spectral-radius bound just inside its published interval:
// the stage count is the published degree, one evaluation per stage, and the order is 3.
TEST(OdeDumka3, EveryPolynomialIsThirdOrder) {
  const OdeSystem sys = smooth_system();
  for (const Published& p : kPublished) {
    double err[3] = {0, 0, 0};
    for (int k = 0; k < 3; ++k) {
      const int n = 10 << k;
      const double h = 2.0 / n;
      OdeOptions opt;
      opt.fixed_step = true;
      opt.h0 = h;
      opt.spectral_radius = [&](double, const double*) { return 0.999 * p.interval / h; };
      Eigen::VectorXd y = smooth_exact(0);
      const OdeStats st = integrate(sys, OdeMethod::Dumka3, 0, 2, y, opt);
      err[k] = (y - smooth_exact(2)).lpNorm<Eigen::Infinity>();
      EXPECT_EQ(st.max_stages, p.degree);
      EXPECT_EQ(st.rhs_evals, static_cast<std::int64_t>(p.degree) * n + 1) << "s per step and f(y0)";
    }
    const double order = std::log2(err[1] / err[2]);
    std::printf("[ode] dumka3 degree %3d: errors %.3e %.3e %.3e at n = 10 20 40, orders %.2f %.2f\n", p.degree, err[0],
                err[1], err[2], std::log2(err[0] / err[1]), order);
    EXPECT_NEAR(order, 3.0, 0.15) << "degree " << p.degree;
    EXPECT_LT(err[2], 2e-5) << "degree " << p.degree;
  }
}

// y' = -lambda y, one step of h = 1 with each polynomial: the amplification |R(-lambda)| is
// at most 1 on the whole published interval and exceeds 1 within 10 % beyond it (the
// interval is that polynomial's, not a loose bound).
TEST(OdeDumka3, StableOnPublishedIntervals) {
  double lambda = 0;
  OdeSystem sys;
  sys.size = 1;
  sys.rhs = [&](double, const double* y, double* dy) { dy[0] = -lambda * y[0]; };
  for (const Published& p : kPublished) {
    OdeOptions opt;
    opt.fixed_step = true;
    opt.h0 = 1;
    opt.spectral_radius = [&](double, const double*) { return p.interval; };
    OdeSolver solver(sys, OdeMethod::Dumka3, opt);
    const int points = 4000;
    double worst_inside = 0, worst_beyond = 0, first_beyond = 0;
    for (int i = 0; i <= points; ++i) {
      lambda = p.interval * i / points;
      Eigen::VectorXd y = Eigen::VectorXd::Ones(1);
      solver.integrate(0, 1, y);
      worst_inside = std::max(worst_inside, std::abs(y[0]));
    }
    for (int i = 1; i <= points; ++i) {
      lambda = p.interval * (1 + 0.1 * i / points);
      Eigen::VectorXd y = Eigen::VectorXd::Ones(1);
      solver.integrate(0, 1, y);
      if (std::abs(y[0]) > 1 && first_beyond == 0) first_beyond = lambda;
      worst_beyond = std::max(worst_beyond, std::abs(y[0]));
    }
    std::printf("[ode] dumka3 degree %3d: max |R| on [-%.6g, 0] = %.15f; |R| > 1 from %.6g on (x %.4f)\n", p.degree,
                p.interval, worst_inside, first_beyond, first_beyond / p.interval);
    EXPECT_EQ(solver.stats().max_stages, p.degree);
    EXPECT_LE(worst_inside, 1 + 1e-12) << "degree " << p.degree;
    EXPECT_GT(worst_beyond, 1 + 1e-6) << "degree " << p.degree;
  }
}

// The heat equation at h rho from 40 (as OdeRkc.StableFarBeyondRk4Limit) to 4000 with the
// exact spectral radius: RK4 explodes at 40 already; DUMKA3 and RKC stay stable, DUMKA3 with
// under twice RKC's stages per step (and under half the evaluations RK4 would need at its
// largest stable step) and a third-order error, 1000 times smaller per tenfold smaller step,
// against RKC's second-order one.
TEST(OdeDumka3, HeatEquationFarBeyondRk4Limit) {
  const Heat heat(100);
  const OdeSystem sys = heat.system();
  const double rho = heat.lambda(100), t_end = 0.5;
  double err_prev = 0;
  for (double h_rho : {40.0, 400.0, 4000.0}) {
    OdeOptions opt;
    opt.fixed_step = true;
    opt.h0 = h_rho / rho;
    opt.spectral_radius = [&](double, const double*) { return rho; };
    Eigen::VectorXd y = heat.exact(0), y_rkc = y;
    const OdeStats st = integrate(sys, OdeMethod::Dumka3, 0, t_end, y, opt);
    const OdeStats st_rkc = integrate(sys, OdeMethod::Rkc, 0, t_end, y_rkc, opt);
    const double err = (y - heat.exact(t_end)).lpNorm<Eigen::Infinity>();
    const double err_rkc = (y_rkc - heat.exact(t_end)).lpNorm<Eigen::Infinity>();
    std::printf("[ode] heat n = 100, fixed h rho = %5.0f: dumka3 %3d stages, %4lld steps, %5lld f-evals, error %.3e;"
                " rkc %3d stages, %5lld f-evals, error %.3e\n", h_rho, st.max_stages, static_cast<long long>(st.steps),
                static_cast<long long>(st.rhs_evals), err, st_rkc.max_stages, static_cast<long long>(st_rkc.rhs_evals),
                err_rkc);
    EXPECT_LT(err, 0.1 * heat.exact(t_end).lpNorm<Eigen::Infinity>());
    EXPECT_LT(err, err_rkc / 4);
    EXPECT_LT(st.max_stages, 2 * st_rkc.max_stages);
    EXPECT_LT(st.max_stages, 0.5 * 4 * h_rho / 2.785);
    if (err_prev > 0) {
      EXPECT_NEAR(std::log10(err / err_prev), 3.0, 0.4) << "third order in the stiff regime";
    }
    err_prev = err;
  }
  OdeOptions opt;
  opt.fixed_step = true;
  opt.h0 = 40 / rho;
  Eigen::VectorXd y4 = heat.exact(0);
  integrate(sys, OdeMethod::Rk4, 0, 0.05, y4, opt);
  const double err4 = (y4 - heat.exact(0.05)).lpNorm<Eigen::Infinity>();
  EXPECT_TRUE(!std::isfinite(err4) || err4 > 1e3);
}

// Adaptive runs on the heat equation (n = 200) with fast modes in the initial state,
// estimated spectral radius: the error at t = 0.2 against the exact semi-discrete solution
// stays within the tolerance, in far fewer steps than an RK4-stable step allows.
TEST(OdeDumka3, AdaptiveHeatEquationMeetsTolerance) {
  const Heat heat(200);
  const OdeSystem sys = heat.system();
  Eigen::VectorXd u0 = heat.exact(0);
  for (int i = 0; i < heat.n; ++i) u0[i] += 1e-3 * std::sin(150.0 * i);
  const Eigen::VectorXd ref = heat_solution(heat, u0, 0.2);
  ASSERT_LT((heat_solution(heat, u0, 0) - u0).lpNorm<Eigen::Infinity>(), 1e-13);
  for (double tol : {1e-4, 1e-6, 1e-8}) {
    Eigen::VectorXd y = u0, y_rkc = u0;
    OdeOptions opt;
    opt.rtol = opt.atol = tol;
    const OdeStats st = integrate(sys, OdeMethod::Dumka3, 0, 0.2, y, opt);
    const OdeStats st_rkc = integrate(sys, OdeMethod::Rkc, 0, 0.2, y_rkc, opt);
    const double err = (y - ref).lpNorm<Eigen::Infinity>(), err_rkc = (y_rkc - ref).lpNorm<Eigen::Infinity>();
    char label[64];
    std::snprintf(label, sizeof label, "dumka3 heat n=200 tol %.0e", tol);
    print_stats(label, st);
    std::printf("[ode]   dumka3 heat tol %.0e: error %.3e (%.2f tol), max stages %d, rho %.4e (exact %.4e), rho "
                "estimates %lld; rkc: %lld f-evals, error %.3e (%.2f tol)\n",
                tol, err, err / tol, st.max_stages, st.rho_last, heat.lambda(200),
                static_cast<long long>(st.rho_estimates), static_cast<long long>(st_rkc.rhs_evals), err_rkc,
                err_rkc / tol);
    EXPECT_LT(err, tol);
    EXPECT_GT(err, 1e-3 * tol) << "the tolerance is used, not beaten by orders of magnitude";
    EXPECT_LT(st.steps, 0.2 * heat.lambda(200) / 2.8 / 20);
    EXPECT_GT(st.max_stages, 3);
  }
}

// Adaptive on the smooth nonstiff problem over [0, 10]: the global error follows tol (the
// estimate goes like h^3, the solution's local error like h^4, so h ~ tol^(1/3) and the
// global error ~ h^3 ~ tol).
TEST(OdeDumka3, AdaptiveSmoothProblemFollowsTolerance) {
  const OdeSystem sys = smooth_system();
  double err_prev = 0;
  for (double tol : {1e-5, 1e-8}) {
    Eigen::VectorXd y = smooth_exact(0);
    OdeOptions opt;
    opt.rtol = opt.atol = tol;
    const OdeStats st = integrate(sys, OdeMethod::Dumka3, 0, 10, y, opt);
    const double err = (y - smooth_exact(10)).lpNorm<Eigen::Infinity>();
    std::printf("[ode] dumka3 smooth tol %.0e: error %.3e (%.2f tol) in %lld steps, %lld rejected, %lld f-evals\n", tol,
                err, err / tol, static_cast<long long>(st.steps), static_cast<long long>(st.rejected),
                static_cast<long long>(st.rhs_evals));
    EXPECT_LT(err, 10 * tol);
    if (err_prev > 0) {
      EXPECT_NEAR(std::log10(err_prev / err), 3.0, 0.3);
    }
    err_prev = err;
  }
}

// One step of h and of h/2 from the same point: the scaled estimate falls 8 times (h^3),
// the true local error 16 times (h^4), for the degree-3 polynomial and for degree 81.
TEST(OdeDumka3, ErrorEstimateGoesLikeHCubed) {
  const OdeSystem sys = smooth_system();
  for (double forced : {0.0, 3000.0}) {
    double est[2], loc[2];
    for (int k = 0; k < 2; ++k) {
      const double h = 0.1 / (1 << k);
      OdeOptions opt;
      opt.rtol = opt.atol = 1;  // accept the first step whatever its error
      opt.h0 = h;
      if (forced > 0) opt.spectral_radius = [&](double, const double*) { return forced / h; };
      OdeSolver solver(sys, OdeMethod::Dumka3, opt);
      Eigen::VectorXd y = smooth_exact(0.5);
      solver.integrate(0.5, 0.5 + h, y);
      ASSERT_EQ(solver.stats().steps, 1);
      est[k] = solver.stats().err_last;
      loc[k] = (y - smooth_exact(0.5 + h)).norm();
    }
    std::printf("[ode] dumka3 %s: estimate %.3e -> %.3e (/%.2f), local error %.3e -> %.3e (/%.2f)\n",
                forced > 0 ? "degree 81" : "degree 3", est[0], est[1], est[0] / est[1], loc[0], loc[1],
                loc[0] / loc[1]);
    EXPECT_NEAR(std::log2(est[0] / est[1]), 3.0, 0.2);
    EXPECT_NEAR(std::log2(loc[0] / loc[1]), 4.0, 0.3);
  }
}

TEST(OdeDumka3, FixedStepBeyondLargestIntervalThrows) {
  const Heat heat(20);
  const OdeSystem sys = heat.system();
  OdeOptions opt;
  opt.fixed_step = true;
  opt.h0 = 1;
  opt.spectral_radius = [](double, const double*) { return 2e5; };  // h rho = 2e5 > 142602.6
  Eigen::VectorXd y = heat.exact(0);
  EXPECT_THROW(integrate(sys, OdeMethod::Dumka3, 0, 1, y, opt), OdeError);
}

TEST(OdeDumka3, NoAllocationWhileIntegrating) {
  CVT_SKIP_UNLESS_ALLOCATIONS_COUNTED();
  const Heat heat(50);
  const OdeSystem sys = heat.system();
  for (bool fixed : {true, false}) {
    OdeOptions opt;
    opt.rtol = opt.atol = 1e-6;
    if (fixed) opt.fixed_step = true, opt.h0 = 1e-3;  // h rho about 12 (1.2 times the estimate): 9 stages
    OdeSolver solver(sys, OdeMethod::Dumka3, opt);
    Eigen::VectorXd y = heat.exact(0);
    for (int i = 0; i < heat.n; ++i) y[i] += 1e-3 * std::sin(40.0 * i);  // wake the fast modes
    long steps = 0;
    const OdeObserver observer = [&](double, const Eigen::VectorXd&) { ++steps; };
    test::allocations = 0;
    test::counting = true;
    solver.integrate(0, 0.05, y, observer);
    test::counting = false;
    std::printf("[ode] dumka3 %s %ld observed steps, max stages %d, %ld heap allocations while integrating\n",
                fixed ? "fixed   " : "adaptive", steps, solver.stats().max_stages, test::allocations.load());
    EXPECT_EQ(test::allocations.load(), 0);
    EXPECT_GT(steps, 1);
    EXPECT_GT(solver.stats().max_stages, 3);
  }
}

}  // namespace
}  // namespace cvt
