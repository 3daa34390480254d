// The stages of the linearly implicit methods ROS2, ROS34PW2 and ROS34PRW (docs/integrators.md
// 12), after the step's first evaluation f0 = f(t, y) and with W = I - gamma h J~ set up:
// shared by OdeSolver and the model's production step (engine/wmethod/w_step.hpp), so that
// both run the same arithmetic. eval(t, y, dy) evaluates f, solve(x) overwrites x with W^-1 x.
#pragma once

#include <algorithm>
#include <cmath>

#include <Eigen/Dense>

#include "engine/ode/ode.hpp"

namespace cvt {
inline namespace CVT_ODE_ABI {

// Verwer, Spee, Blom & Hundsdorfer, "A second-order Rosenbrock method applied to
// photochemical dispersion problems", SIAM J. Sci. Comput. 20 (1999) 1456-1480:
//   W = I - gamma h J~,   gamma = 1 + 1/sqrt 2,
//   W k1 = f(t, y),
//   W k2 = f(t + h, y + h k1) - 2 k1,
//   y_1 = y + (3/2) h k1 + (1/2) h k2.
// Second order for ANY matrix J~, L-stable when J~ = J. With df/dt: t as a state whose
// stages are k1_t = 1, k2_t = 1 - 2 = -1, and the t-column of J~ is df/dt, so stage i gains
// gamma h df/dt k_i,t (Verwer et al. 1999, eq. 2.2). Error estimate: y_1 minus the
// first-order solution y + h k1, i.e. (h/2)(k1 + k2).
inline const double kRos2Gamma = 1.0 + 1.0 / std::sqrt(2.0);

// The four-stage methods ROS34PW2 and ROS34PRW, after Hairer & Wanner II, IV.7 (7.25), in the
// form that needs no products with J~: with u_i = sum_j gamma_ij k_j,
//   W u_i = gamma h f(t + alpha_i h, y + sum_{j<i} a_ij u_j) + gamma sum_{j<i} c_ij u_j,
//   y_1 = y + sum_i m_i u_i,
// where a = alpha Gamma^-1, C = diag(1/gamma) - Gamma^-1 and m = b Gamma^-1 are computed once
// from the published tableau (alpha, Gamma, b, b^). The t-column of J~ is zero unless the
// system supplies df/dt: then t is a state with the exact column, u_i's t-component is
// h gamma_i (gamma_i = sum_j gamma_ij) and stage i gains gamma gamma_i h^2 df/dt (Hairer &
// Wanner II, IV.7 (7.4)).
//   ROS34PW2 (Rang & Angermann, BIT 45 (2005) 761-787): a W-method, order 3 for ANY J~,
//   stiffly accurate; second order on the Prothero-Robinson problem y' = lambda (y - g) + g'.
//   ROS34PRW (Rang, J. Comput. Appl. Math. 286 (2015) 128-144, "ROS34PRw"): order 3 with the
//   exact Jacobian and on Prothero-Robinson for any h lambda, stiffly accurate, the same
//   gamma; not a W-method: with J~ = J + O(h) (a matrix kept for several steps) second order.
struct W4Tableau {
  static constexpr int s = 4;
  double gamma = 0;
  double alpha_c[s] = {};  // stage times
  double a[s][s] = {}, c[s][s] = {};
  double m[s] = {}, e[s] = {};  // solution weights and those of the error (m - m^)
  double gsum[s] = {};          // gamma_i = sum_j gamma_ij, the df/dt weights
  // From the published coefficients: alpha_ij and gamma_ij (j < i), gamma, b and b^.
  W4Tableau(const double (&alpha)[s][s], const double (&gamma_ij)[s][s], double gamma_ii, const double (&b)[s],
            const double (&bh)[s]);
};
extern const W4Tableau kRos34pw2, kRos34prw;
// The tableau of OdeMethod::Ros34pw2 or Ros34prw; throws std::invalid_argument otherwise.
const W4Tableau& w4_tableau(OdeMethod m);

// The vectors of a W-step, sized once.
struct WStageVectors {
  Eigen::VectorXd u[4];  // the four-stage methods' u_i; ROS2's k1, k2 in u[0], u[1]
  Eigen::VectorXd y_new, err;
  void resize(int n) {
    for (auto& v : u) v.setZero(n);
    y_new.setZero(n), err.setZero(n);
  }
};

// ROS2's stages from (t, y) with f0: y_new, and with `estimate` err = (h/2)(k1 + k2).
template <class Eval, class Solve>
void ros2_stages(double t, double h, const Eigen::VectorXd& y, const Eigen::VectorXd& f0, const Eigen::VectorXd* dfdt,
                 WStageVectors& w, bool estimate, Eval&& eval, Solve&& solve) {
  Eigen::VectorXd &k1 = w.u[0], &k2 = w.u[1];
  k1 = f0;
  if (dfdt) k1 += (kRos2Gamma * h) * *dfdt;
  solve(k1);
  w.y_new = y + h * k1;
  eval(t + h, w.y_new, k2);
  k2 -= 2.0 * k1;
  if (dfdt) k2 -= (kRos2Gamma * h) * *dfdt;
  solve(k2);
  w.y_new = y + (1.5 * h) * k1 + (0.5 * h) * k2;
  if (estimate) w.err = (0.5 * h) * (k1 + k2);
}

// A four-stage method's stages from (t, y) with f0: y_new, and with `estimate` the embedded
// error in err.
template <class Eval, class Solve>
void w4_stages(const W4Tableau& tb, double t, double h, const Eigen::VectorXd& y, const Eigen::VectorXd& f0,
               const Eigen::VectorXd* dfdt, WStageVectors& w, bool estimate, Eval&& eval, Solve&& solve) {
  const double gh = tb.gamma * h, g = tb.gamma;
  // Each stage's sums in one pass over the vectors (the same operations in the same order as
  // one pass per term, so the same bits).
  Eigen::VectorXd* st = w.u;
  const Eigen::VectorXd &u0 = st[0], &u1 = st[1], &u2 = st[2], &u3 = st[3];
  // Stage i's df/dt term, added apart so that without df/dt the arithmetic is the same.
  auto add_dfdt = [&](int i) {
    if (dfdt) st[i] += (g * tb.gsum[i] * h * h) * *dfdt;
  };
  Eigen::VectorXd& yn = w.y_new;
  st[0] = gh * f0;
  add_dfdt(0);
  solve(st[0]);
  yn = y + tb.a[1][0] * u0;
  eval(t + tb.alpha_c[1] * h, yn, st[1]);
  st[1] = gh * st[1] + (g * tb.c[1][0]) * u0;
  add_dfdt(1);
  solve(st[1]);
  yn = y + tb.a[2][0] * u0 + tb.a[2][1] * u1;
  eval(t + tb.alpha_c[2] * h, yn, st[2]);
  st[2] = gh * st[2] + (g * tb.c[2][0]) * u0 + (g * tb.c[2][1]) * u1;
  add_dfdt(2);
  solve(st[2]);
  yn = y + tb.a[3][0] * u0 + tb.a[3][1] * u1 + tb.a[3][2] * u2;
  eval(t + tb.alpha_c[3] * h, yn, st[3]);
  st[3] = gh * st[3] + (g * tb.c[3][0]) * u0 + (g * tb.c[3][1]) * u1 + (g * tb.c[3][2]) * u2;
  add_dfdt(3);
  solve(st[3]);
  yn = y + tb.m[0] * u0 + tb.m[1] * u1 + tb.m[2] * u2 + tb.m[3] * u3;
  if (estimate) w.err = tb.e[0] * u0 + tb.e[1] * u1 + tb.e[2] * u2 + tb.e[3] * u3;
}

}  // namespace CVT_ODE_ABI
}  // namespace cvt
