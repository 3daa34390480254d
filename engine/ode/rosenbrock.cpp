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
#include "engine/ode/w_stages.hpp"

namespace cvt {
inline namespace CVT_ODE_ABI {

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
  w_stages(OdeMethod::Ros2, t, h, y, err);
}

void OdeSolverImpl::step_ros34pw2(double t, double h, const Eigen::VectorXd& y, double* err) {
  eval(t, y, f0_);
  prepare_w(t, h, y, kRos34pw2.gamma * h);
  w_stages(OdeMethod::Ros34pw2, t, h, y, err);
}

// The stages (engine/ode/w_stages.hpp) into y_new_, and outside fixed steps the error.
void OdeSolverImpl::w_stages(OdeMethod m, double t, double h, const Eigen::VectorXd& y, double* err) {
  const bool dfdt = static_cast<bool>(sys_.time_derivative);
  if (dfdt) sys_.time_derivative(t, y.data(), dfdt_.data());
  const auto f = [this](double tt, const Eigen::VectorXd& yy, Eigen::VectorXd& dy) { eval(tt, yy, dy); };
  const auto solve = [this](Eigen::VectorXd& x) { solve_w(x); };
  if (m == OdeMethod::Ros2)
    ros2_stages(t, h, y, f0_, dfdt ? &dfdt_ : nullptr, wv_, !fixed_, f, solve);
  else
    ros34pw2_stages(t, h, y, f0_, dfdt ? &dfdt_ : nullptr, wv_, !fixed_, f, solve);
  y_new_.swap(wv_.y_new);
  if (fixed_) {  // no error estimate needed
    *err = 0.0;
    return;
  }
  err_vec_.swap(wv_.err);
  *err = error_norm(err_vec_, y, y_new_);
  *err = std::max(*err, linearization_error(t, h, y));  // after: it overwrites err_vec_
}

Ros34pw2Tableau::Ros34pw2Tableau() {
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
const Ros34pw2Tableau kRos34pw2;

double w_method_gamma(OdeMethod m) {
  if (m == OdeMethod::Ros2) return kRos2Gamma;
  if (m == OdeMethod::Ros34pw2) return kRos34pw2.gamma;
  throw std::invalid_argument(std::string("w_method_gamma: ") + to_string(m) + " is not a W-method");
}

}  // namespace CVT_ODE_ABI
}  // namespace cvt
