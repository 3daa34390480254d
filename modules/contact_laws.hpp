// Hertz normal law and the regularized friction laws (docs/model.md 4.1).
#pragma once

#include <cmath>

#include "engine/config.hpp"
#include "engine/state.hpp"

namespace cvt {

// Hertz: elastic normal force c * d^(3/2) and energy (2/5) c d^(5/2) for penetration d > 0.
inline double hertz_force(double c, double d) { return d > 0 ? c * d * std::sqrt(d) : 0.0; }
inline double hertz_energy(double c, double d) { return d > 0 ? 0.4 * c * d * d * std::sqrt(d) : 0.0; }

// Friction coefficient f(v) for sliding speed v >= 0 (docs/model.md 4.1).
inline double friction_coefficient(FrictionLaw law, double f0, double v0, double v) {
  switch (law) {
    case FrictionLaw::nonsmooth: return v < v0 ? f0 * v / v0 : f0;
    case FrictionLaw::smooth: return f0 * (2.0 / M_PI) * std::atan(M_PI * v / (2.0 * v0));
    case FrictionLaw::none: return 0.0;
  }
  return 0.0;
}

// f(v)/v, finite at v = 0 (the slope there), so that R = -N * (f(v)/v) * v_vec.
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

// The friction force R of one contact under the frozen branch (Workspace::friction_branch
// != off): u the tangential slip velocity, n the unit contact normal.
inline void frozen_branch_friction(const Workspace& ws, std::uint8_t& stick, double* dir, double Nel, double f0,
                                   double v0, const double u[3], double speed, const double n[3], double R[3]) {
  if (ws.friction_branch == Workspace::FrictionBranch::record) {
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
// u (|u| = speed, n the unit normal): the configured law, or the frozen branch when the
// workspace asks for it (stick and dir: this contact's entries of the branch record).
// Returns the dissipated power -R . u; *mag (if given) is |R|.
inline double contact_friction(const Workspace& ws, FrictionLaw law, double f0, double v0, double Nel,
                               const double u[3], double speed, const double n[3], std::uint8_t& stick, double* dir,
                               double R[3], double* mag = nullptr) {
  if (law == FrictionLaw::nonsmooth && ws.friction_branch != Workspace::FrictionBranch::off) {
    frozen_branch_friction(ws, stick, dir, Nel, f0, v0, u, speed, n, R);
    if (mag) *mag = std::sqrt(R[0] * R[0] + R[1] * R[1] + R[2] * R[2]);
    return -(R[0] * u[0] + R[1] * u[1] + R[2] * u[2]);
  }
  const double mu = Nel * friction_over_speed(law, f0, v0, speed);
  for (int i = 0; i < 3; ++i) R[i] = -mu * u[i];
  if (mag) *mag = mu * speed;
  return mu * speed * speed;
}

}  // namespace cvt
