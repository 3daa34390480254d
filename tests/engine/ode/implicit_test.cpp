// The implicit generic integrators (trapezoid, TR-BDF2) and the coloured Jacobian.
#include <cmath>
#include <cstdio>

#include <gtest/gtest.h>

#include "engine/ode/ode.hpp"
#include "tests/engine/ode/ode_problems.hpp"

namespace cvt {
namespace {

using namespace ode_test;

// Newton converged far below the discretization error.
double observed_order(OdeMethod method, int n) {
  return smooth_order(smooth_system(), method, n, to_string(method), 1e-12);
}

TEST(OdeOrder, TrapezoidIsSecond) { EXPECT_NEAR(observed_order(OdeMethod::Trapezoid, 20), 2.0, 0.1); }
TEST(OdeOrder, TrBdf2IsSecond) { EXPECT_NEAR(observed_order(OdeMethod::TrBdf2, 20), 2.0, 0.1); }
TEST(OdeOrder, Esdirk3IsThird) { EXPECT_NEAR(observed_order(OdeMethod::Esdirk3, 20), 3.0, 0.15); }

// y' = -1e8 (y - cos t), y(0) = 0: the initial layer is 1e-8 long. At h = 0.1 (h lambda =
// -1e7) an L-stable method damps it at once; the trapezoid's amplification tends to -1,
// so the initial offset of 1 keeps flipping sign and never decays.
TEST(OdeLStability, TrBdf2AndEsdirk3DampStiffTransientTrapezoidDoesNot) {
  OdeSystem sys;
  sys.size = 1;
  sys.rhs = [](double t, const double* y, double* dy) { dy[0] = -1e8 * (y[0] - std::cos(t)); };
  OdeOptions opt;
  opt.fixed_step = true;
  opt.h0 = 0.1;
  Eigen::VectorXd y = Eigen::VectorXd::Zero(1);
  integrate(sys, OdeMethod::TrBdf2, 0, 1, y, opt);
  const double err_bdf = std::abs(y[0] - std::cos(1.0));
  y.setZero();
  integrate(sys, OdeMethod::Esdirk3, 0, 1, y, opt);
  const double err_esdirk = std::abs(y[0] - std::cos(1.0));
  y.setZero();
  integrate(sys, OdeMethod::Trapezoid, 0, 1, y, opt);
  const double err_tr = std::abs(y[0] - std::cos(1.0));
  std::printf("[ode] L-stability h = 0.1, lambda = -1e8: |error| trbdf2 %.3e, esdirk3 %.3e, trapezoid %.3e\n", err_bdf,
              err_esdirk, err_tr);
  EXPECT_LT(err_bdf, 1e-7);
  EXPECT_LT(err_esdirk, 1e-7);
  EXPECT_GT(err_tr, 0.5);
}

TEST(OdeImplicit, AdaptiveSmoothProblemMeetsTolerance) {
  const OdeSystem sys = smooth_system();
  for (OdeMethod m : {OdeMethod::Trapezoid, OdeMethod::TrBdf2, OdeMethod::Esdirk3}) {
    double err_prev = 0;
    for (double tol : {1e-4, 1e-7}) {
      Eigen::VectorXd y = smooth_exact(0);
      OdeOptions opt;
      opt.rtol = opt.atol = tol;
      const OdeStats st = integrate(sys, m, 0, 10, y, opt);
      const double err = (y - smooth_exact(10)).lpNorm<Eigen::Infinity>();
      char label[64];
      std::snprintf(label, sizeof label, "%s smooth tol %.0e", to_string(m), tol);
      print_stats(label, st);
      std::printf("[ode]   %s smooth tol %.0e: error %.3e\n", to_string(m), tol, err);
      // The tolerance bounds each step's local error; on this undamped oscillator the
      // local errors add up, so the global error is about steps x tol, and it falls like
      // tol^(2/3) for a second-order method (a factor 100 for tol / 1000).
      EXPECT_LT(err, 2 * st.steps * tol);
      if (err_prev > 0) {
        EXPECT_GT(err_prev / err, 50.0);
      }
      err_prev = err;
      EXPECT_LT(st.jac_evals, st.steps / 5 + 3);  // the Jacobian is reused across steps
    }
  }
}

TEST(OdeJacobian, ColoredEqualsDenseOnCyclicBand) {
  const CyclicBand band(1003, 3, 10.0);  // 1003 = 7 * 143 + 2: the ring does not close evenly
  const OdeSystem sparse_sys = band.system(true), dense_sys = band.system(false);
  const int n = band.n;
  Eigen::VectorXd y(n), f(n);
  for (int i = 0; i < n; ++i) y[i] = std::sin(0.37 * i) + 0.2;
  sparse_sys.rhs(0.3, y.data(), f.data());

  FdJacobian fd_sparse(sparse_sys), fd_dense(dense_sys);
  Eigen::SparseMatrix<double> js = sparse_sys.sparsity;
  Eigen::MatrixXd jd(n, n);
  fd_sparse.sparse(0.3, y, f, js);
  fd_dense.dense(0.3, y, f, jd);
  const Eigen::MatrixXd js_dense = Eigen::MatrixXd(js);
  const double diff = (js_dense - jd).lpNorm<Eigen::Infinity>();
  const double diff_exact = (js_dense - band.jacobian(y)).lpNorm<Eigen::Infinity>();
  std::printf("[ode] coloured FD Jacobian n = %d, bandwidth 7 cyclic: %d colours (%d f-evals vs %d dense), "
              "max |coloured - dense| = %.3e, max |coloured - analytic| = %.3e\n",
              n, fd_sparse.colors(), fd_sparse.rhs_evals(), fd_dense.rhs_evals(), diff, diff_exact);
  EXPECT_LE(fd_sparse.colors(), 9);
  EXPECT_EQ(fd_sparse.rhs_evals(), fd_sparse.colors());
  // Each row sees the perturbation of one column only, so the quotients are the same numbers.
  EXPECT_EQ(diff, 0.0);
  // Forward differences: about sqrt(eps) relative to the entries (up to ~10 here).
  EXPECT_LT(diff_exact, 1e-5);

  int colors = 0;
  const std::vector<int> c = color_columns(sparse_sys.sparsity, &colors);
  // A valid colouring: no two columns of a row share a colour.
  for (int i = 0; i < n; ++i)
    for (int a = -3; a <= 3; ++a)
      for (int b = a + 1; b <= 3; ++b) EXPECT_NE(c[((i + a) % n + n) % n], c[((i + b) % n + n) % n]);
}

// The same stiff banded system integrated with the sparse machinery (coloured FD,
// SparseLU) and the dense one (dense FD, dense LU) gives the same answer within tolerance.
TEST(OdeJacobian, SparseAndDenseNewtonAgree) {
  const CyclicBand band(300, 3, 1e4);
  const OdeSystem sparse_sys = band.system(true), dense_sys = band.system(false);
  Eigen::VectorXd y0(band.n);
  for (int i = 0; i < band.n; ++i) y0[i] = std::sin(0.37 * i);
  OdeOptions opt;
  opt.rtol = opt.atol = 1e-6;
  Eigen::VectorXd ys = y0, yd = y0;
  const OdeStats ss = integrate(sparse_sys, OdeMethod::TrBdf2, 0, 2, ys, opt);
  const OdeStats sd = integrate(dense_sys, OdeMethod::TrBdf2, 0, 2, yd, opt);
  print_stats("trbdf2 band sparse", ss);
  print_stats("trbdf2 band dense", sd);
  std::printf("[ode]   band n = 300, stiffness 1e4: colours %d, max |sparse - dense| = %.3e\n", ss.colors,
              (ys - yd).lpNorm<Eigen::Infinity>());
  EXPECT_LT((ys - yd).lpNorm<Eigen::Infinity>(), 1e-6);
  EXPECT_LT(ss.rhs_evals, sd.rhs_evals);

  // The same with an analytic sparse Jacobian: no f-evaluations for J at all.
  OdeSystem analytic_sys = band.system(true);
  analytic_sys.sparse_jacobian = [&band](double, const double* y, Eigen::SparseMatrix<double>& jac) {
    const Eigen::MatrixXd j = band.jacobian(Eigen::Map<const Eigen::VectorXd>(y, band.n));  // test only: allocates
    for (int c = 0; c < jac.outerSize(); ++c)
      for (Eigen::SparseMatrix<double>::InnerIterator it(jac, c); it; ++it) it.valueRef() = j(it.row(), c);
  };
  Eigen::VectorXd ya = y0;
  const OdeStats sa = integrate(analytic_sys, OdeMethod::TrBdf2, 0, 2, ya, opt);
  print_stats("trbdf2 band analytic", sa);
  EXPECT_LT((ya - ys).lpNorm<Eigen::Infinity>(), 1e-6);
  EXPECT_EQ(sa.colors, 0);
  EXPECT_EQ(sa.rhs_evals, sa.newton_iterations + 2);  // + f0 and the starting-step guess
}

}  // namespace
}  // namespace cvt
