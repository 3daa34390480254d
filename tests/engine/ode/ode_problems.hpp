// Test problems for the generic integrators (tests/engine/ode_*_test.cpp).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>

#include "engine/ode/ode.hpp"

namespace cvt::ode_test {

// A smooth nonstiff system with a known solution on any interval: a harmonic oscillator
// y1' = y2, y2' = -y1 (y = (sin t, cos t)) and y3' = -t y3^2 (y3 = 2 / (2 + t^2)).
inline OdeSystem smooth_system() {
  OdeSystem s;
  s.size = 3;
  s.rhs = [](double t, const double* y, double* dy) {
    dy[0] = y[1];
    dy[1] = -y[0];
    dy[2] = -t * y[2] * y[2];
  };
  return s;
}
inline Eigen::VectorXd smooth_exact(double t) {
  Eigen::VectorXd y(3);
  y << std::sin(t), std::cos(t), 2 / (2 + t * t);
  return y;
}

// 1D heat equation u_t = u_xx on (0, 1), u = 0 at both ends, n interior points, central
// differences. The semi-discrete solution from u_i(0) = sin(pi x_i) is exactly
// sin(pi x_i) exp(-lambda_1 t), lambda_k = (4 / dx^2) sin^2(k pi dx / 2); the spectral
// radius is lambda_n.
struct Heat {
  int n;
  double dx;
  explicit Heat(int n_) : n(n_), dx(1.0 / (n_ + 1)) {}
  double lambda(int k) const {
    const double s = std::sin(k * std::numbers::pi * dx / 2);
    return 4 / (dx * dx) * s * s;
  }
  OdeSystem system() const {
    OdeSystem s;
    s.size = n;
    const int nn = n;
    const double c = 1 / (dx * dx);
    s.rhs = [nn, c](double, const double* u, double* du) {
      for (int i = 0; i < nn; ++i) {
        const double l = i > 0 ? u[i - 1] : 0.0, r = i + 1 < nn ? u[i + 1] : 0.0;
        du[i] = c * (l - 2 * u[i] + r);
      }
    };
    return s;
  }
  Eigen::VectorXd exact(double t) const {
    Eigen::VectorXd u(n);
    for (int i = 0; i < n; ++i) u[i] = std::sin(std::numbers::pi * (i + 1) * dx) * std::exp(-lambda(1) * t);
    return u;
  }
};

// A nonlinear cyclic-banded system like the chain's coupling (each unknown talks to its
// neighbours up to distance w around a ring): f_i = sum_k a_k y_(i+k) - stiff y_i + 0.5 sin(y_i y_(i+1)).
struct CyclicBand {
  int n, w;
  double stiff;
  CyclicBand(int n_, int w_, double stiff_) : n(n_), w(w_), stiff(stiff_) {}
  OdeSystem system(bool with_pattern) const {
    OdeSystem s;
    s.size = n;
    const int nn = n, ww = w;
    const double k = stiff;
    s.rhs = [nn, ww, k](double t, const double* y, double* dy) {
      for (int i = 0; i < nn; ++i) {
        double acc = -k * y[i] + 0.5 * std::sin(y[i] * y[(i + 1) % nn]) + std::cos(t + i);
        for (int d = 1; d <= ww; ++d) acc += (1.0 / (d + 1)) * (y[(i + d) % nn] - y[(i - d + nn) % nn]);
        dy[i] = acc;
      }
    };
    if (with_pattern) {
      std::vector<std::pair<int, int>> nz;
      for (int i = 0; i < nn; ++i)
        for (int d = -ww; d <= ww; ++d) nz.emplace_back(i, ((i + d) % nn + nn) % nn);
      s.set_sparsity(nz);
    }
    return s;
  }
  Eigen::MatrixXd jacobian(const Eigen::VectorXd& y) const {
    Eigen::MatrixXd j = Eigen::MatrixXd::Zero(n, n);
    for (int i = 0; i < n; ++i) {
      const int ip = (i + 1) % n;
      const double c = 0.5 * std::cos(y[i] * y[ip]);
      j(i, i) += -stiff + c * y[ip];
      j(i, ip) += c * y[i];
      for (int d = 1; d <= w; ++d) j(i, (i + d) % n) += 1.0 / (d + 1), j(i, (i - d + n) % n) -= 1.0 / (d + 1);
    }
    return j;
  }
};

// Stiff problems of the Test Set for IVP Solvers (F. Mazzia, C. Magherini et al.,
// University of Bari, https://archimede.uniba.it/~testset/; also in Hairer & Wanner,
// "Solving ODEs II", section IV.10) with their published reference solutions at t_end.
// Each reference is the `solut` subroutine of the test set's Fortran problem file, named
// below; none of the numbers comes from this code.
struct TestSetProblem {
  const char* name;
  OdeSystem sys;
  Eigen::VectorXd y0, ref;
  double t_end;
};

// HIRES, hires.f: 8 equations, t in [0, 321.8122]; reference "computed using true double
// precision RADAU5 on Cray C90, rtol = atol = h0 = 1.1d-18".
inline TestSetProblem hires() {
  TestSetProblem p{"hires", {}, Eigen::VectorXd(8), Eigen::VectorXd(8), 321.8122};
  p.sys.size = 8;
  p.sys.rhs = [](double, const double* y, double* f) {
    f[0] = -1.71 * y[0] + 0.43 * y[1] + 8.32 * y[2] + 0.0007;
    f[1] = 1.71 * y[0] - 8.75 * y[1];
    f[2] = -10.03 * y[2] + 0.43 * y[3] + 0.035 * y[4];
    f[3] = 8.32 * y[1] + 1.71 * y[2] - 1.12 * y[3];
    f[4] = -1.745 * y[4] + 0.43 * y[5] + 0.43 * y[6];
    f[5] = -280 * y[5] * y[7] + 0.69 * y[3] + 1.71 * y[4] - 0.43 * y[5] + 0.69 * y[6];
    f[6] = 280 * y[5] * y[7] - 1.81 * y[6];
    f[7] = -280 * y[5] * y[7] + 1.81 * y[6];
  };
  p.y0 << 1, 0, 0, 0, 0, 0, 0, 0.0057;
  p.ref << 0.7371312573325668e-3, 0.1442485726316185e-3, 0.5888729740967575e-4, 0.1175651343283149e-2,
      0.2386356198831331e-2, 0.6238968252742796e-2, 0.2849998395185769e-2, 0.2850001604814231e-2;
  return p;
}

// Van der Pol modified, vdpolm.f: y1' = y2, y2' = 1e3 (1 - y1^2) y2 - y1, y(0) = (2, 0),
// t in [0, 2000]; reference computed with RADAU, rtol = atol = h0 = 1.1d-18.
inline TestSetProblem vdpol() {
  TestSetProblem p{"vdpol mu=1e3", {}, Eigen::VectorXd(2), Eigen::VectorXd(2), 2000};
  p.sys.size = 2;
  p.sys.rhs = [](double, const double* y, double* f) {
    f[0] = y[1];
    f[1] = 1e3 * (1 - y[0] * y[0]) * y[1] - y[0];
  };
  p.sys.dense_jacobian = [](double, const double* y, Eigen::MatrixXd& j) {
    j(0, 0) = 0, j(0, 1) = 1;
    j(1, 0) = -2e3 * y[0] * y[1] - 1, j(1, 1) = 1e3 * (1 - y[0] * y[0]);
  };
  p.y0 << 2, 0;
  p.ref << 0.1706167732170469e1, -0.8928097010248125e-3;
  return p;
}

// Robertson, rober.f: t in [0, 1e11]; reference values 0.2083340149701255e-7,
// 0.8333360770334713e-13, 0.9999999791665050 (rober.f `solut`).
inline TestSetProblem rober() {
  TestSetProblem p{"rober", {}, Eigen::VectorXd(3), Eigen::VectorXd(3), 1e11};
  p.sys.size = 3;
  p.sys.rhs = [](double, const double* y, double* f) {
    f[0] = -0.04 * y[0] + 1e4 * y[1] * y[2];
    f[1] = 0.04 * y[0] - 1e4 * y[1] * y[2] - 3e7 * y[1] * y[1];
    f[2] = 3e7 * y[1] * y[1];
  };
  p.y0 << 1, 0, 0;
  p.ref << 0.2083340149701255e-7, 0.8333360770334713e-13, 0.9999999791665050;
  return p;
}

// Oregonator, orego.f: t in [0, 360], y(0) = (1, 2, 3); reference computed with RADAU,
// rtol = h0 = 1.1d-18, atol = 1.1d-40.
inline TestSetProblem orego() {
  TestSetProblem p{"orego", {}, Eigen::VectorXd(3), Eigen::VectorXd(3), 360};
  p.sys.size = 3;
  p.sys.rhs = [](double, const double* y, double* f) {
    f[0] = 77.27 * (y[1] + y[0] * (1 - 8.375e-6 * y[0] - y[1]));
    f[1] = (y[2] - (1 + y[0]) * y[1]) / 77.27;
    f[2] = 0.161 * (y[0] - y[2]);
  };
  p.y0 << 1, 2, 3;
  p.ref << 0.1000814870318523e1, 0.1228178521549917e4, 0.1320554942846706e3;
  return p;
}

// The Test Set for IVP Solvers' measures (Mazzia & Magherini, report of the Bari test set,
// section "how the results are measured"): significant correct digits of the maximum
// relative error, scd, and of the mixed error with weights atol/rtol + |y_ref|, mescd.
inline double scd(const Eigen::VectorXd& y, const Eigen::VectorXd& ref) {
  double e = 0;
  for (int i = 0; i < y.size(); ++i) e = std::max(e, std::abs(y[i] - ref[i]) / std::abs(ref[i]));
  return -std::log10(e);
}
inline double mescd(const Eigen::VectorXd& y, const Eigen::VectorXd& ref, double atol, double rtol) {
  double e = 0;
  for (int i = 0; i < y.size(); ++i) e = std::max(e, std::abs(y[i] - ref[i]) / (atol / rtol + std::abs(ref[i])));
  return -std::log10(e);
}

// Error at t = 2 of a fixed-step run of n steps of `method` on the smooth system `sys`
// (smooth_system(), possibly with a W added); tol > 0 sets rtol = atol (Newton's tolerance).
inline double smooth_fixed_step_error(const OdeSystem& sys, OdeMethod method, int n, double tol = 0) {
  Eigen::VectorXd y = smooth_exact(0);
  OdeOptions opt;
  opt.fixed_step = true;
  opt.h0 = 2.0 / n;
  if (tol > 0) opt.rtol = opt.atol = tol;
  integrate(sys, method, 0, 2, y, opt);
  return (y - smooth_exact(2)).lpNorm<Eigen::Infinity>();
}

// Observed order from n, 2n, 4n steps (the last halving); printed for docs/integrators.md.
inline double smooth_order(const OdeSystem& sys, OdeMethod method, int n, const char* label, double tol = 0) {
  const double e1 = smooth_fixed_step_error(sys, method, n, tol), e2 = smooth_fixed_step_error(sys, method, 2 * n, tol),
               e3 = smooth_fixed_step_error(sys, method, 4 * n, tol);
  const double p = std::log2(e2 / e3);
  std::printf("[ode] order %-10s n = %4d %4d %4d  errors %.3e %.3e %.3e  orders %.2f %.2f\n", label, n, 2 * n, 4 * n,
              e1, e2, e3, std::log2(e1 / e2), p);
  return p;
}

inline void print_stats(const char* label, const OdeStats& s) {
  std::printf(
      "[ode] %-28s steps %7lld  rejected %5lld  f-evals %8lld  jac %5lld  lu %5lld  newton %7lld  "
      "newton-fail %4lld\n",
      label, static_cast<long long>(s.steps), static_cast<long long>(s.rejected), static_cast<long long>(s.rhs_evals),
      static_cast<long long>(s.jac_evals), static_cast<long long>(s.lu_factorizations),
      static_cast<long long>(s.newton_iterations), static_cast<long long>(s.newton_failures));
}

}  // namespace cvt::ode_test
