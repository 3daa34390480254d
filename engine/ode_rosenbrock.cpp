// The ROS2 W-method of the generic integrators (docs/integrators.md 12).
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
// of J~ is zero, which a W-method allows. Error estimate: y_1 minus the first-order
// solution y + h k1, i.e. (h/2)(k1 + k2). Each step evaluates f(t, y) itself (so the
// drivers do not evaluate f at the start of a call for ROS2).
#include <chrono>
#include <cmath>

#include "engine/ode_impl.hpp"

namespace cvt {

namespace {
const double kRos2Gamma = 1.0 + 1.0 / std::sqrt(2.0);
double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}
}  // namespace

void OdeSolverImpl::step_ros2(double t, double h, const Eigen::VectorXd& y, double* err) {
  const double gh = kRos2Gamma * h;
  auto t0 = std::chrono::steady_clock::now();
  // f(t, y) afresh at every step: callers such as OdeDriver change the system between
  // calls (contact statuses), and a system's J~ comes from its evaluation at (t, y).
  eval(t, y, f0_);
  t0 = std::chrono::steady_clock::now();  // the matrix's time, not the evaluation's
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
    if (!newton_->ok()) throw OdeError(t, h, "ROS2: the matrix I - gamma h J is singular");
  }
  auto solve = [&](Eigen::VectorXd& x) {
    const auto s0 = std::chrono::steady_clock::now();
    if (sys_.w_solve)
      sys_.w_solve(x.data());
    else
      newton_->solve_in_place(x);
    stats.solve_seconds += seconds_since(s0);
  };
  // k1 in z_, k2 in k2_.
  z_ = f0_;
  solve(z_);
  y_new_ = y + h * z_;
  eval(t + h, y_new_, k2_);
  k2_ -= 2.0 * z_;
  solve(k2_);
  y_new_ = y + (1.5 * h) * z_ + (0.5 * h) * k2_;
  err_vec_ = (0.5 * h) * (z_ + k2_);
  *err = fixed_ ? 0.0 : error_norm(err_vec_, y, y_new_);
}

}  // namespace cvt
