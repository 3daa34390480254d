// The W-methods of the generic integrators (docs/integrators.md 12): ROS2, ROS34PW2 and
// ROS34PRW.
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

void OdeSolverImpl::step_w4(double t, double h, const Eigen::VectorXd& y, double* err) {
  eval(t, y, f0_);
  prepare_w(t, h, y, w_method_gamma(method_) * h);
  w_stages(method_, t, h, y, err);
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
    w4_stages(w4_tableau(m), t, h, y, f0_, dfdt ? &dfdt_ : nullptr, wv_, !fixed_, f, solve);
  y_new_.swap(wv_.y_new);
  if (fixed_) {  // no error estimate needed
    *err = 0.0;
    return;
  }
  err_vec_.swap(wv_.err);
  *err = error_norm(err_vec_, y, y_new_);
  *err = std::max(*err, linearization_error(t, h, y));  // after: it overwrites err_vec_
}

W4Tableau::W4Tableau(const double (&alpha)[s][s], const double (&gamma_ij)[s][s], double gamma_ii, const double (&b)[s],
                     const double (&bh)[s])
    : gamma(gamma_ii) {
  double g[s][s] = {};
  for (int i = 0; i < s; ++i)
    for (int j = 0; j < i; ++j) g[i][j] = gamma_ij[i][j];
  for (int i = 0; i < s; ++i) g[i][i] = gamma;
  for (int i = 0; i < s; ++i)
    for (int j = 0; j <= i; ++j) gsum[i] += g[i][j];
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

namespace {
// Rang & Angermann's Table (ROS34PW2).
W4Tableau make_ros34pw2() {
  const double alpha[4][4] = {{0, 0, 0, 0},
                              {8.7173304301691801e-01, 0, 0, 0},
                              {8.4457060015369423e-01, -1.1299064236397981e-01, 0, 0},
                              {0, 0, 1.0, 0}};
  const double g[4][4] = {{0, 0, 0, 0},
                          {-8.7173304301691801e-01, 0, 0, 0},
                          {-9.0338057013044082e-01, 5.4180672388095326e-02, 0, 0},
                          {2.4212380706095346e-01, -1.2232505839045147e+00, 5.4526025533510214e-01, 0}};
  const double b[4] = {2.4212380706095346e-01, -1.2232505839045147e+00, 1.5452602553351023e+00,
                       4.3586652150845900e-01};
  const double bh[4] = {3.7810903145819369e-01, -9.6042292212423178e-02, 5.0000000000000000e-01,
                        2.1793326075422950e-01};
  return W4Tableau(alpha, g, 4.3586652150845900e-01, b, bh);
}
// Rang's Table 3 (ROS34PRw). alpha_21 = 3 gamma; the last stage's alpha row equals the third's
// and b_i = alpha_4i + gamma_4i (stiffly accurate).
W4Tableau make_ros34prw() {
  const double alpha[4][4] = {{0, 0, 0, 0}, {1.3075995645253771, 0, 0, 0}, {0.5, 0.5, 0, 0}, {0.5, 0.5, 0, 0}};
  const double g[4][4] = {{0, 0, 0, 0},
                          {-1.3075995645253771, 0, 0, 0},
                          {-0.7098857586097217, -0.55996735960277766, 0, 0},
                          {-0.15550856807552085, -0.95388516575112225, 0.67352721231818413, 0}};
  const double b[4] = {0.34449143192447917, -0.45388516575112231, 0.67352721231818413, 0.435866521508459};
  const double bh[4] = {0.5, -0.25738812086522078, 0.43542008724775044, 0.32196803361747034};
  return W4Tableau(alpha, g, 0.435866521508459, b, bh);
}
}  // namespace
const W4Tableau kRos34pw2 = make_ros34pw2();
const W4Tableau kRos34prw = make_ros34prw();

const W4Tableau& w4_tableau(OdeMethod m) {
  if (m == OdeMethod::Ros34pw2) return kRos34pw2;
  if (m == OdeMethod::Ros34prw) return kRos34prw;
  throw std::invalid_argument(std::string("w4_tableau: ") + to_string(m) + " is not a four-stage W-method");
}

double w_method_gamma(OdeMethod m) {
  if (m == OdeMethod::Ros2) return kRos2Gamma;
  if (!is_w_method(m))
    throw std::invalid_argument(std::string("w_method_gamma: ") + to_string(m) + " is not a W-method");
  return w4_tableau(m).gamma;
}

}  // namespace CVT_ODE_ABI
}  // namespace cvt
