// Hertz normal law and the regularized friction laws (docs/model.md 4.1).
#pragma once

#include <cmath>

#include "engine/config.hpp"

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

}  // namespace cvt
