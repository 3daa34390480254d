// Hertz normal law and the regularized friction laws (docs/model.md 4.1).
#pragma once

#include <cmath>

#include "engine/model/config.hpp"
#include "engine/model/state.hpp"

namespace cvt {

// Hertz: elastic normal force c * d^(3/2) and energy (2/5) c d^(5/2) for penetration d > 0.
inline double hertz_force(double c, double d) { return d > 0 ? c * d * std::sqrt(d) : 0.0; }
inline double hertz_energy(double c, double d) { return d > 0 ? 0.4 * c * d * d * std::sqrt(d) : 0.0; }

// f(v)/v for the friction coefficient f(v) at sliding speed v >= 0 (docs/model.md 4.1:
// nonsmooth f0 min(v / v0, 1), smooth f0 (2/pi) atan(pi v / (2 v0))), finite at v = 0 (the
// slope there), so that R = -N * (f(v)/v) * v_vec.
inline double friction_over_speed(FrictionLaw law, double f0, double v0, double v) {
  switch (law) {
    case FrictionLaw::nonsmooth: return v < v0 ? f0 / v0 : f0 / v;
    case FrictionLaw::smooth:
      if (v < 1e-12 * v0) return f0 / v0;
      return f0 * (2.0 / M_PI) * std::atan(M_PI * v / (2.0 * v0)) / v;
    case FrictionLaw::none: return 0.0;
  }
  return 0.0;
}

// The friction force R of one contact under its frozen branch b (FrozenFriction): u the
// tangential slip velocity, n the unit contact normal.
inline void frozen_branch_friction(const FrozenBranch& b, double Nel, double f0, double v0, const double u[3],
                                   double speed, const double n[3], double R[3]) {
  std::uint8_t& stick = *b.stick;
  double* dir = b.dir;
  if (b.record) {
    stick = speed < v0;
    if (!stick)
      for (int i = 0; i < 3; ++i) dir[i] = u[i] / speed;
  }
  if (stick) {
    for (int i = 0; i < 3; ++i) R[i] = -Nel * f0 / v0 * u[i];
  } else {
    const double dn = dir[0] * n[0] + dir[1] * n[1] + dir[2] * n[2];
    for (int i = 0; i < 3; ++i) R[i] = -Nel * f0 * (dir[i] - dn * n[i]);
  }
}

// The friction force R of one contact with elastic normal force Nel and tangential slip
// u (|u| = speed, n the unit normal): the configured law, or with the nonsmooth law the
// contact's frozen branch when the evaluation has one (b.on()).
// Returns the dissipated power -R . u; *mag (if given) is |R|.
inline double contact_friction(const FrozenBranch& b, FrictionLaw law, double f0, double v0, double Nel,
                               const double u[3], double speed, const double n[3], double R[3],
                               double* mag = nullptr) {
  if (law == FrictionLaw::nonsmooth && b.on()) {
    frozen_branch_friction(b, Nel, f0, v0, u, speed, n, R);
    if (mag) *mag = std::sqrt(R[0] * R[0] + R[1] * R[1] + R[2] * R[2]);
    return -(R[0] * u[0] + R[1] * u[1] + R[2] * u[2]);
  }
  const double mu = Nel * friction_over_speed(law, f0, v0, speed);
  for (int i = 0; i < 3; ++i) R[i] = -mu * u[i];
  if (mag) *mag = mu * speed;
  return mu * speed * speed;
}

// df/dv of the law at speed v >= 0 (the slope along the sliding direction).
inline double friction_slope(FrictionLaw law, double f0, double v0, double v) {
  switch (law) {
    case FrictionLaw::nonsmooth: return v < v0 ? f0 / v0 : 0.0;
    case FrictionLaw::smooth: {
      const double x = M_PI * v / (2.0 * v0);
      return f0 / v0 / (1.0 + x * x);
    }
    case FrictionLaw::none: return 0.0;
  }
  return 0.0;
}

// The friction damping D = -dR/du of R = -N f(|u|) u/|u| at fixed N, for a contact whose
// slip velocity u lies in the tangent plane of the unit normal n: D = mu (P - t t^T) +
// mu_t t t^T (P = I - n n^T, t = u/|u|), mu = N f(v)/v (the secant: turning the sliding
// direction) and mu_t = N f'(v) (along it), i.e. D = mu_t t t^T + mu s s^T with s = n x t.
// FrictionAxes holds t and s (at v = 0, any unit tangent t: D = mu P then, as mu_t = mu).
struct FrictionAxes {
  double t[3], s[3];
  FrictionAxes(const double n[3], const double u[3], double speed) {
    if (speed > 0) {
      for (int i = 0; i < 3; ++i) t[i] = u[i] / speed;
    } else {
      const int k = std::abs(n[0]) < 0.6 ? 0 : std::abs(n[1]) < 0.6 ? 1 : 2;
      double e[3] = {0, 0, 0};
      e[k] = 1;
      const double en = n[k];
      double l = 0;
      for (int i = 0; i < 3; ++i) t[i] = e[i] - en * n[i], l += t[i] * t[i];
      l = 1 / std::sqrt(l);
      for (double& x : t) x *= l;
    }
    s[0] = n[1] * t[2] - n[2] * t[1], s[1] = n[2] * t[0] - n[0] * t[2], s[2] = n[0] * t[1] - n[1] * t[0];
  }
  // t . G_c and s . G_c for each of the dim columns of G (Gc[c]: the 3 entries of column c).
  void project(int dim, const double (*Gc)[3], double* gt, double* gs) const {
    for (int c = 0; c < dim; ++c) {
      gt[c] = t[0] * Gc[c][0] + t[1] * Gc[c][1] + t[2] * Gc[c][2];
      gs[c] = s[0] * Gc[c][0] + s[1] * Gc[c][1] + s[2] * Gc[c][2];
    }
  }
};

// Adds G^T D G (FrictionAxes) to the lower triangle (row >= column) of the row-major
// dim x dim block K (symmetric; the upper triangle is left alone) for a contact whose slip
// velocity is u = G v (FrictionJacobian::blocks).
inline void add_friction_damping(double* K, int dim, const double (*Gc)[3], const double n[3],
                                 const double u[3], double speed, double mu, double mu_t) {
  const FrictionAxes ax(n, u, speed);
  double gt[FrictionJacobian::kDim], gs[FrictionJacobian::kDim];
  ax.project(dim, Gc, gt, gs);
  for (int a = 0; a < dim; ++a) {
    const double ta = mu_t * gt[a], sa = mu * gs[a];
    if (ta == 0 && sa == 0) continue;
    double* row = K + a * dim;
    for (int b = 0; b <= a; ++b) row[b] += ta * gt[b] + sa * gs[b];  // lower triangle
  }
}

// FrictionJacobian::mu: a contact's columns G^T t and G^T s (the tangent plane's basis), so
// that with the secant slope (mu_t = mu) its damping block is mu (gt gt^T + gs gs^T).
inline void friction_columns(int dim, const double (*Gc)[3], const double n[3], const double u[3], double speed,
                             double* gt, double* gs) {
  FrictionAxes(n, u, speed).project(dim, Gc, gt, gs);
}

// Adds G_r^T D G_c to the row-major rows x cols block X: the cross damping between two sets
// of coordinates when u = G_r v_r + G_c v_c (a pin and the shaft it touches).
inline void add_friction_cross(double* X, int rows, const double (*Gr)[3], int cols, const double (*Gc)[3],
                               const double n[3], const double u[3], double speed, double mu, double mu_t) {
  const FrictionAxes ax(n, u, speed);
  double rt[FrictionJacobian::kDim], rs[FrictionJacobian::kDim], ct[FrictionJacobian::kDim], cs[FrictionJacobian::kDim];
  ax.project(rows, Gr, rt, rs);
  ax.project(cols, Gc, ct, cs);
  for (int a = 0; a < rows; ++a) {
    const double ta = mu_t * rt[a], sa = mu * rs[a];
    if (ta == 0 && sa == 0) continue;
    double* row = X + a * cols;
    for (int b = 0; b < cols; ++b) row[b] += ta * ct[b] + sa * cs[b];
  }
}

// The slip velocity's dependence on a link spin through one half (its 10 columns Gh):
// u += psi_dot (l_x, l_y, 0) with psi_dot's part c (n_l,x (x0 + x1) + n_l,y (y0 + y1)) through
// this half's mid-point (c = +-1/(2|Delta|) times the sign of u).
inline void add_spin_columns(double (*Gh)[3], double c, double nlx, double nly, double lx, double ly) {
  for (int e = 0; e < 2; ++e) {
    double* gx = Gh[e * half::kEnd + half::kX];
    double* gy = Gh[e * half::kEnd + half::kY];
    gx[0] += c * nlx * lx, gx[1] += c * nlx * ly;
    gy[0] += c * nly * lx, gy[1] += c * nly * ly;
  }
}

}  // namespace cvt
