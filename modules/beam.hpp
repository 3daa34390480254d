// Cubic Hermite beam interpolation of a pin half (docs/model.md 2.1).
// A point of the half at parameter xi in [0,1] has lateral position
//   x(xi) = H0 x1 + H1 L0 sx1 + H2 x2 + H3 L0 sx2   (same for y)
// and axial position z(xi) = (1 - xi) z1 + xi z2.
#pragma once

#include <array>

#include "engine/model/model.hpp"

namespace cvt {

struct HermiteWeights {
  // Weights on (x1, sx1, x2, sx2) of one plane; the same for x and y.
  std::array<double, 4> w;
  // d/dxi of the weights.
  std::array<double, 4> dw;
};

inline HermiteWeights hermite(double xi, double L0) {
  const double x2 = xi * xi, x3 = x2 * xi;
  HermiteWeights h;
  h.w = {1 - 3 * x2 + 2 * x3, L0 * (xi - 2 * x2 + x3), 3 * x2 - 2 * x3, L0 * (-x2 + x3)};
  h.dw = {-6 * xi + 6 * x2, L0 * (1 - 4 * xi + 3 * x2), 6 * xi - 6 * x2, L0 * (-2 * xi + 3 * x2)};
  return h;
}

// Indices (relative to the half) of (x1, sx1, x2, sx2) for plane 0 (x) or 1 (y).
inline constexpr std::array<int, 4> plane_dofs(int plane) {
  return {plane, half::kSx + plane, half::kEnd + plane, half::kEnd + half::kSx + plane};
}

// Lateral position (plane) of a half at weights h: sum w_i q_i.
inline double lateral(const double* half_q, const HermiteWeights& h, int plane) {
  const auto d = plane_dofs(plane);
  return h.w[0] * half_q[d[0]] + h.w[1] * half_q[d[1]] + h.w[2] * half_q[d[2]] + h.w[3] * half_q[d[3]];
}
inline double lateral_dxi(const double* half_q, const HermiteWeights& h, int plane) {
  const auto d = plane_dofs(plane);
  return h.dw[0] * half_q[d[0]] + h.dw[1] * half_q[d[1]] + h.dw[2] * half_q[d[2]] + h.dw[3] * half_q[d[3]];
}
// Adds a lateral force f (plane) acting at weights h to the half's generalized forces.
inline void add_lateral(double* half_f, const HermiteWeights& h, int plane, double f) {
  const auto d = plane_dofs(plane);
  for (int i = 0; i < 4; ++i) half_f[d[i]] += h.w[i] * f;
}

// Mid-point of the half in the xy plane: mean of the two end positions (the point that
// defines the link direction, docs/model.md 3.1).
inline double mid(const double* half_q, int plane) {
  return 0.5 * (half_q[plane] + half_q[half::kEnd + plane]);
}

}  // namespace cvt
