// The W-methods of the generic integrators (docs/integrators.md 12): ROS2 and ROS34PW2.
//
// Verwer, Spee, Blom & Hundsdorfer, "A second-order Rosenbrock method applied to
// photochemical dispersion problems", SIAM J. Sci. Comput. 20 (1999) 1456-1480:
//
//   W = I - gamma h J~,   gamma = 1 + 1/sqrt 2,
//   W k1 = f(t, y),
//   W k2 = f(t + h, y + h k1) - 2 k1,
//   y_1 = y + (3/2) h k1 + (1/2) h k2.
//
// Second order for ANY matrix J~ (a W-method: the order conditions do not involve J~), and
// L-stable when J~ = J. Two evaluations per step and two solves with one matrix, no Newton
// iteration. The non-autonomous case is the autonomous one with t as a state whose column
// of J~ is zero, which a W-method allows, or df/dt when the system supplies it (then
// W k1 = f + gamma h f_t, W k2 = ... - gamma h f_t, which keeps second order on stiff
// problems driven by t; Verwer et al., eq. 2.2). Error estimate: y_1 minus the first-order
// solution y + h k1, i.e. (h/2)(k1 + k2). Each step evaluates f(t, y) itself (so the
// drivers do not evaluate f at the start of a call for ROS2).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>

#include "engine/base/timing.hpp"
#include "engine/ode/ode_impl.hpp"

namespace cvt {
inline namespace CVT_ODE_ABI {

namespace {
const double kRos2Gamma = 1.0 + 1.0 / std::sqrt(2.0);
}  // namespace

// W = I - gh J~ at (t, y), right after f0_ = f(t, y): the system's own (w_factor), or the
// Jacobian above and its LU, kept for w_reuse_steps steps while gh stays the same.
void OdeSolverImpl::prepare_w(double t, double h, const Eigen::VectorXd& y, double gh) {
  auto t0 = std::chrono::steady_clock::now();
  if (sys_.w_factor) {
    sys_.w_factor(t, y.data(), gh);
    ++stats.jac_evals;
    ++stats.lu_factorizations;
    stats.lu_seconds += seconds_since(t0);
  } else if (!newton_->factored() || ++w_age_ >= opt_.w_reuse_steps ||
             std::abs(newton_->factored_dh() / gh - 1) > 1e-9) {
    // A fresh Jacobian (every step by default: Rosenbrock proper) and its LU.
    w_age_ = 0;
    newton_->evaluate_jacobian(t, y, f0_, stats);
    stats.jac_seconds += seconds_since(t0);
    t0 = std::chrono::steady_clock::now();
    newton_->factorize(gh, stats);
    stats.lu_seconds += seconds_since(t0);
    if (!newton_->ok())
      throw OdeError(t, h, std::string(to_string(method_)) + ": the matrix I - gamma h J is singular");
  }
}

void OdeSolverImpl::solve_w(Eigen::VectorXd& x) {
  const auto s0 = std::chrono::steady_clock::now();
  if (sys_.w_solve)
    sys_.w_solve(x.data());
  else
    newton_->solve_in_place(x);
  stats.solve_seconds += seconds_since(s0);
}

// The remainder of f beyond W's linearization at (t, y), r = f(t, y1) - f(t, y) - J (y1 - y),
// integrated over the step as the stiff part sees it, W^-1 h r: in the norm of the error
// test. It vanishes for linear f and is O(h^3) where f is smooth, like ROS34PW2's embedded
// estimate, so it binds only where the solution moves through a region in which J changes
// much within one step (the stages then sample a linearization that no longer holds, and
// the embedded pair, sharing it, agrees on a wrong answer). Taken at the step's start time so
// that a non-autonomous f(t) adds nothing. Scratch: f_new_, tmp_, k2_, err_vec_.
double OdeSolverImpl::linearization_error(double t, double h, const Eigen::VectorXd& y) {
  if (fixed_ || sys_.w_factor || !opt_.w_linearization_test) return 0;
  eval(t, y_new_, f_new_);
  tmp_ = y_new_ - y;
  newton_->jacobian_times(tmp_, k2_);
  err_vec_ = h * (f_new_ - f0_ - k2_);
  solve_w(err_vec_);
  return error_norm(err_vec_, y, y_new_);
}

void OdeSolverImpl::step_ros2(double t, double h, const Eigen::VectorXd& y, double* err) {
  // f(t, y) afresh at every step: callers such as OdeDriver change the system between
  // calls (contact statuses), and a system's J~ comes from its evaluation at (t, y).
  eval(t, y, f0_);
  prepare_w(t, h, y, kRos2Gamma * h);
  // With df/dt: t as a state whose stages are k1_t = 1, k2_t = 1 - 2 = -1, and the t-column
  // of J~ is df/dt, so stage i gains gamma h df/dt k_i,t (Verwer et al. 1999, eq. 2.2).
  const bool dfdt = static_cast<bool>(sys_.time_derivative);
  if (dfdt) sys_.time_derivative(t, y.data(), dfdt_.data());
  // k1 in z_, k2 in k2_.
  z_ = f0_;
  if (dfdt) z_ += (kRos2Gamma * h) * dfdt_;
  solve_w(z_);
  y_new_ = y + h * z_;
  eval(t + h, y_new_, k2_);
  k2_ -= 2.0 * z_;
  if (dfdt) k2_ -= (kRos2Gamma * h) * dfdt_;
  solve_w(k2_);
  y_new_ = y + (1.5 * h) * z_ + (0.5 * h) * k2_;
  err_vec_ = (0.5 * h) * (z_ + k2_);
  if (fixed_) {
    *err = 0.0;
    return;
  }
  *err = error_norm(err_vec_, y, y_new_);
  *err = std::max(*err, linearization_error(t, h, y));  // after: it overwrites err_vec_
}

// ROS34PW2 in the form that needs no products with J~ (Hairer & Wanner II, IV.7, (7.25)):
// with u_i = sum_j gamma_ij k_j,
//   W u_i = gamma h f(t + alpha_i h, y + sum_{j<i} a_ij u_j) + gamma sum_{j<i} c_ij u_j,
//   y_1 = y + sum_i m_i u_i,
// where a = alpha Gamma^-1, C = diag(1/gamma) - Gamma^-1 and m = b Gamma^-1 are computed once
// from the published tableau (alpha, Gamma, b, b^) below. The t-column of J~ is zero, as a
// W-method allows, unless the system supplies df/dt: then t is a state with the exact
// column, u_i's t-component is h gamma_i (gamma_i = sum_j gamma_ij) and stage i gains
// gamma gamma_i h^2 df/dt (Hairer & Wanner II, IV.7 (7.4)).
namespace {
struct Ros34pw2Tableau {
  static constexpr int s = 4;
  double gamma = 4.3586652150845900e-01;
  double alpha_c[s] = {};  // stage times
  double a[s][s] = {}, c[s][s] = {};
  double m[s] = {}, e[s] = {};  // solution weights and those of the error (m - m^)
  double gsum[s] = {};          // gamma_i = sum_j gamma_ij, the df/dt weights
  Ros34pw2Tableau() {
    double alpha[s][s] = {};
    alpha[1][0] = 8.7173304301691801e-01;
    alpha[2][0] = 8.4457060015369423e-01, alpha[2][1] = -1.1299064236397981e-01;
    alpha[3][2] = 1.0;
    double g[s][s] = {};
    g[1][0] = -8.7173304301691801e-01;
    g[2][0] = -9.0338057013044082e-01, g[2][1] = 5.4180672388095326e-02;
    g[3][0] = 2.4212380706095346e-01, g[3][1] = -1.2232505839045147e+00, g[3][2] = 5.4526025533510214e-01;
    for (int i = 0; i < s; ++i) g[i][i] = gamma;
    for (int i = 0; i < s; ++i)
      for (int j = 0; j <= i; ++j) gsum[i] += g[i][j];
    const double b[s] = {2.4212380706095346e-01, -1.2232505839045147e+00, 1.5452602553351023e+00,
                         4.3586652150845900e-01};
    const double bh[s] = {3.7810903145819369e-01, -9.6042292212423178e-02, 5.0000000000000000e-01,
                          2.1793326075422950e-01};
    // Gamma^-1 by forward substitution (lower triangular).
    double gi[s][s] = {};
    for (int j = 0; j < s; ++j) {
      gi[j][j] = 1.0 / g[j][j];
      for (int i = j + 1; i < s; ++i) {
        double sum = 0;
        for (int k = j; k < i; ++k) sum += g[i][k] * gi[k][j];
        gi[i][j] = -sum / g[i][i];
      }
    }
    for (int i = 0; i < s; ++i) {
      for (int j = 0; j < i; ++j) {
        alpha_c[i] += alpha[i][j];
        for (int k = j; k < i; ++k) a[i][j] += alpha[i][k] * gi[k][j];
        c[i][j] = -gi[i][j];
      }
      for (int k = i; k < s; ++k) m[i] += b[k] * gi[k][i], e[i] += (b[k] - bh[k]) * gi[k][i];
    }
  }
};
const Ros34pw2Tableau kRos34pw2;
}  // namespace

double w_method_gamma(OdeMethod m) {
  if (m == OdeMethod::Ros2) return kRos2Gamma;
  if (m == OdeMethod::Ros34pw2) return kRos34pw2.gamma;
  throw std::invalid_argument(std::string("w_method_gamma: ") + to_string(m) + " is not a W-method");
}

void OdeSolverImpl::step_ros34pw2(double t, double h, const Eigen::VectorXd& y, double* err) {
  const Ros34pw2Tableau& tb = kRos34pw2;
  const double gh = tb.gamma * h;
  eval(t, y, f0_);
  prepare_w(t, h, y, gh);
  // Each stage's sums in one pass over the vectors (the same operations in the same order as
  // one pass per term, so the same bits).
  static_assert(Ros34pw2Tableau::s == 4);
  const Eigen::VectorXd &u0 = stages_[0], &u1 = stages_[1], &u2 = stages_[2], &u3 = stages_[3];
  const double g = tb.gamma;
  const bool dfdt = static_cast<bool>(sys_.time_derivative);
  if (dfdt) sys_.time_derivative(t, y.data(), dfdt_.data());
  // Stage i's df/dt term, added apart so that without df/dt the arithmetic is the same.
  auto add_dfdt = [&](int i) {
    if (dfdt) stages_[i] += (g * tb.gsum[i] * h * h) * dfdt_;
  };
  stages_[0] = gh * f0_;
  add_dfdt(0);
  solve_w(stages_[0]);
  y_new_ = y + tb.a[1][0] * u0;
  eval(t + tb.alpha_c[1] * h, y_new_, stages_[1]);
  stages_[1] = gh * stages_[1] + (g * tb.c[1][0]) * u0;
  add_dfdt(1);
  solve_w(stages_[1]);
  y_new_ = y + tb.a[2][0] * u0 + tb.a[2][1] * u1;
  eval(t + tb.alpha_c[2] * h, y_new_, stages_[2]);
  stages_[2] = gh * stages_[2] + (g * tb.c[2][0]) * u0 + (g * tb.c[2][1]) * u1;
  add_dfdt(2);
  solve_w(stages_[2]);
  y_new_ = y + tb.a[3][0] * u0 + tb.a[3][1] * u1 + tb.a[3][2] * u2;
  eval(t + tb.alpha_c[3] * h, y_new_, stages_[3]);
  stages_[3] = gh * stages_[3] + (g * tb.c[3][0]) * u0 + (g * tb.c[3][1]) * u1 + (g * tb.c[3][2]) * u2;
  add_dfdt(3);
  solve_w(stages_[3]);
  y_new_ = y + tb.m[0] * u0 + tb.m[1] * u1 + tb.m[2] * u2 + tb.m[3] * u3;
  if (fixed_) {  // no error estimate needed
    *err = 0.0;
    return;
  }
  err_vec_ = tb.e[0] * u0 + tb.e[1] * u1 + tb.e[2] * u2 + tb.e[3] * u3;
  *err = error_norm(err_vec_, y, y_new_);
  *err = std::max(*err, linearization_error(t, h, y));  // after: it overwrites err_vec_
}

}  // namespace CVT_ODE_ABI
}  // namespace cvt
