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
