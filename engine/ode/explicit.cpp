// Explicit steps of the generic integrators: DOPRI5(4), RKC and adaptive RK4
// (docs/integrators.md 2-4); DUMKA3 is in dumka3.cpp. Fixed-step RK4 is cvt::Rk4 itself (engine/ode/rk4.hpp), called
// from the fixed-step driver.
#include <algorithm>
#include <cmath>

#include "engine/ode/ode_impl.hpp"

namespace cvt {
inline namespace CVT_ODE_ABI {

// Dormand & Prince (1980), as tabulated in Hairer, Norsett & Wanner I, Table II.5.2 and
// coded in dopri5.f: the 5th-order solution is propagated (local extrapolation), the
// 4th-order one gives the error estimate; the last stage is f(t + h, y_new) (FSAL).
namespace dp {
constexpr double c2 = 1.0 / 5, c3 = 3.0 / 10, c4 = 4.0 / 5, c5 = 8.0 / 9;
constexpr double a21 = 1.0 / 5;
constexpr double a31 = 3.0 / 40, a32 = 9.0 / 40;
constexpr double a41 = 44.0 / 45, a42 = -56.0 / 15, a43 = 32.0 / 9;
constexpr double a51 = 19372.0 / 6561, a52 = -25360.0 / 2187, a53 = 64448.0 / 6561, a54 = -212.0 / 729;
constexpr double a61 = 9017.0 / 3168, a62 = -355.0 / 33, a63 = 46732.0 / 5247, a64 = 49.0 / 176,
                 a65 = -5103.0 / 18656;
constexpr double a71 = 35.0 / 384, a73 = 500.0 / 1113, a74 = 125.0 / 192, a75 = -2187.0 / 6784, a76 = 11.0 / 84;
// e = b(5th) - b(4th)
constexpr double e1 = 71.0 / 57600, e3 = -71.0 / 16695, e4 = 71.0 / 1920, e5 = -17253.0 / 339200,
                 e6 = 22.0 / 525, e7 = -1.0 / 40;
}  // namespace dp

void OdeSolverImpl::step_dopri5(double t, double h, const Eigen::VectorXd& y, double* err) {
  using namespace dp;
  const Eigen::VectorXd& k1 = f0_;
  tmp_ = y + (h * a21) * k1;
  eval(t + c2 * h, tmp_, k2_);
  tmp_ = y + h * (a31 * k1 + a32 * k2_);
  eval(t + c3 * h, tmp_, k3_);
  tmp_ = y + h * (a41 * k1 + a42 * k2_ + a43 * k3_);
  eval(t + c4 * h, tmp_, k4_);
  tmp_ = y + h * (a51 * k1 + a52 * k2_ + a53 * k3_ + a54 * k4_);
  eval(t + c5 * h, tmp_, k5_);
  tmp_ = y + h * (a61 * k1 + a62 * k2_ + a63 * k3_ + a64 * k4_ + a65 * k5_);
  eval(t + h, tmp_, k6_);
  y_new_ = y + h * (a71 * k1 + a73 * k3_ + a74 * k4_ + a75 * k5_ + a76 * k6_);
  eval(t + h, y_new_, f_new_);
  if (fixed_) return;
  err_vec_ = h * (e1 * k1 + e3 * k3_ + e4 * k4_ + e5 * k5_ + e6 * k6_ + e7 * f_new_);
  *err = error_norm(err_vec_, y, y_new_);
}

// Classical RK4 in the arithmetic of cvt::Rk4, y + h/6 (((k1 + 2 k2) + 2 k3) + k4), but
// with k1 given (the step doubling below shares it).
void OdeSolverImpl::rk4_from(double t, double h, const Eigen::VectorXd& y, const Eigen::VectorXd& k1,
                             Eigen::VectorXd& out) {
  const double hh = 0.5 * h;
  tmp_ = y + hh * k1;
  eval(t + hh, tmp_, k2_);
  tmp_ = y + hh * k2_;
  eval(t + hh, tmp_, k3_);
  tmp_ = y + h * k3_;
  eval(t + h, tmp_, k4_);
  out = y + (h / 6.0) * (((k1 + 2.0 * k2_) + 2.0 * k3_) + k4_);
}

// Adaptive RK4 by step doubling (Hairer, Norsett & Wanner I, II.4): one step of h and two of
// h/2 from the same point; the two half steps are propagated and their error is estimated
// by Richardson extrapolation, (y_h/2 - y_h) / (2^4 - 1). 11 evaluations per step, the last
// one f(t + h, y_new), which starts the next step.
void OdeSolverImpl::step_rk4_doubling(double t, double h, const Eigen::VectorXd& y, double* err) {
  rk4_from(t, h, y, f0_, k5_);  // one step of h
  rk4_from(t, 0.5 * h, y, f0_, k6_);  // first half step
  eval(t + 0.5 * h, k6_, f_new_);
  rk4_from(t + 0.5 * h, 0.5 * h, k6_, f_new_, y_new_);  // second half step
  eval(t + h, y_new_, f_new_);
  err_vec_ = (y_new_ - k5_) / 15.0;
  *err = error_norm(err_vec_, y, y_new_);
}

// RKC: the second-order Runge-Kutta-Chebyshev method with damping eps = 2/13 of Sommeijer,
// Shampine & Verwer, "RKC: an explicit solver for parabolic PDEs", J. Comput. Appl. Math.
// 88 (1997) 315-326, transcribed from their rkc.f (subroutines STEP and RKCLOW). Its
// stability interval on the negative real axis is about 0.653 s^2 for s stages, so the
// step needs s = 1 + sqrt(1 + 1.54 h rho) stages for a spectral radius rho.
// The spectral radius for RKC and DUMKA3 when it is due: the user's bound, or 1.2 times the
// power method's estimate (rkc.f's and Medovikov's dumka3 safety factor), with f0_ = f(t, y).
void OdeSolverImpl::update_spectral_radius(double t, const Eigen::VectorXd& y) {
  if (!need_rho_) return;
  int evals = 0;
  rho_ = opt_.spectral_radius ? opt_.spectral_radius(t, y.data()) : 1.2 * rho_est_->estimate(sys_, t, y, f0_, &evals);
  stats.rhs_evals += evals;
  ++stats.rho_estimates;
  stats.rho_last = rho_;
  need_rho_ = false, rho_fresh_ = true;
  steps_since_rho_ = 0;
}

void OdeSolverImpl::step_rkc(double t, double& h, const Eigen::VectorXd& y, double* err) {
  update_spectral_radius(t, y);
  // The most stages rkc.f allows: beyond them rounding errors of the recursion grow past
  // the tolerance. In fixed-step mode the step is given and the stage count follows.
  const int s_max = std::max(2, static_cast<int>(std::sqrt(opt_.rtol / (10 * std::numeric_limits<double>::epsilon()))));
  int s = 1 + static_cast<int>(std::sqrt(1.0 + 1.54 * h * rho_));
  s = std::max(s, 2);
  if (!fixed_ && s > s_max) {
    s = s_max;
    h = 0.653 * (static_cast<double>(s) * s - 1) / rho_;
  }
  stats.max_stages = std::max(stats.max_stages, s);

  const double sd = s;
  const double w0 = 1 + 2 / (13 * sd * sd);
  const double temp1 = w0 * w0 - 1, temp2 = std::sqrt(temp1);
  const double arg = sd * std::log(w0 + temp2);
  const double w1 = std::sinh(arg) * temp1 / (std::cosh(arg) * sd * temp2 - w0 * std::sinh(arg));
  double bjm1 = 1 / ((2 * w0) * (2 * w0)), bjm2 = bjm1;
  // Stage 1
  yjm2_ = y;
  double mus = w1 * bjm1;
  yjm1_ = y + (h * mus) * f0_;
  double thjm2 = 0, thjm1 = mus;
  double zjm1 = w0, zjm2 = 1, dzjm1 = 1, dzjm2 = 0, d2zjm1 = 0, d2zjm2 = 0;
  // Stages 2..s: the three-term Chebyshev recursion
  for (int j = 2; j <= s; ++j) {
    const double zj = 2 * w0 * zjm1 - zjm2;
    const double dzj = 2 * w0 * dzjm1 - dzjm2 + 2 * zjm1;
    const double d2zj = 2 * w0 * d2zjm1 - d2zjm2 + 4 * dzjm1;
    const double bj = d2zj / (dzj * dzj);
    const double ajm1 = 1 - zjm1 * bjm1;
    const double mu = 2 * w0 * bj / bjm1;
    const double nu = -bj / bjm2;
    mus = mu * w1 / w0;
    eval(t + h * thjm1, yjm1_, f_new_);  // f_new_ is scratch until the last stage
    tmp_ = mu * yjm1_ + nu * yjm2_ + (1 - mu - nu) * y + (h * mus) * (f_new_ - ajm1 * f0_);
    const double thj = mu * thjm1 + nu * thjm2 + mus * (1 - ajm1);
    // Rotate the three stage buffers without copying: yjm2 <- yjm1 <- yj.
    std::swap(yjm2_, yjm1_);
    std::swap(yjm1_, tmp_);
    thjm2 = thjm1, thjm1 = thj;
    bjm2 = bjm1, bjm1 = bj;
    zjm2 = zjm1, zjm1 = zj;
    dzjm2 = dzjm1, dzjm1 = dzj;
    d2zjm2 = d2zjm1, d2zjm1 = d2zj;
  }
  std::swap(y_new_, yjm1_);
  eval(t + h, y_new_, f_new_);  // reused as f0 of the next step
  if (fixed_) return;
  // rkc.f's estimate: (12 (y_n - y_n+1) + 6 h (f_n + f_n+1)) / 15, the difference with the
  // Hermite-type 3rd-order reconstruction.
  err_vec_ = (12.0 * (y - y_new_) + (6.0 * h) * (f0_ + f_new_)) / 15.0;
  *err = error_norm(err_vec_, y, y_new_);
}

}  // namespace CVT_ODE_ABI
}  // namespace cvt
