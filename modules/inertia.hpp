// Inertia (docs/model.md 3): A(q) = A0 + J_link sum_i g_i g_i^T with g_i = d psi_i / dq.
#pragma once

#include <Eigen/Dense>

#include "engine/model/state.hpp"
#include "modules/beam.hpp"

namespace cvt {

// 3.1: e_i, |Delta_i|, psi_dot_i of links [begin, end).
void link_kinematics(const Model& m, Workspace& ws, int begin, int end);

// 3.2 "inertia decomposition": the diagonal capacitance of the Woodbury identity for links
// [begin, end), and the velocity terms -J g_i (qdot^T H_i qdot) as link torques (3.3).
// Depends on q and qdot only, not on the forces.
void inertia_decomposition(const Model& m, Workspace& ws, int begin, int end);

// 3.2 "accelerations": solves A(q) qdd = F for the gathered ws.force into ws.accel.
void accelerations(const Model& m, Workspace& ws);
// The same solve in two pin-range passes (any split gives the same bits):
// y = A0^-1 F on the coordinates of joints [begin, end) ...
void a0_inverse_joints(const Model& m, const double* F, double* y, int begin, int end);
// ... and of the shafts and the load;
void a0_inverse_shafts(const Model& m, const double* F, double* y);
// then qdd = y - A0^-1 G C^-1 G^T y on joints [begin, end): half a_j takes the correction
// of link j-1, half b_j that of link j (reads y of the neighbouring joints, writes qdd
// of its own only).
void woodbury_joints(const Model& m, const Workspace& ws, const double* y, double* qdd, int begin, int end);

// g_i has entries +-(1/2) n / |Delta| on the lateral end translations of a_{i+1} (+) and
// b_i (-): coefficient per (half, plane).
inline void link_g(const LinkKinematics& k, int i, double& gx, double& gy) {
  gx = -0.5 * k.ey[i] * k.inv_len[i];
  gy = 0.5 * k.ex[i] * k.inv_len[i];
}

// Adds tau_i g_i to F for every link (the ordered gather of link torques).
void add_link_torques(const Model& m, const LinkKinematics& kin, const double* tau, double* F);

// T = 1/2 qdot^T A(q) qdot.
double kinetic_energy(const Model& m, const double* q, const double* v);

// Writes the constant mass block of one pin half (A0, 3.1: bending per plane, axial bar)
// into A at rows and columns o .. o + 9 (any matrix type with operator()(r, c)).
template <class Matrix>
void set_half_mass(const Model& m, Matrix& A, int o) {
  for (int p = 0; p < 2; ++p) {
    const auto d = plane_dofs(p);
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) A(o + d[r], o + d[c]) = m.bend_mass(r, c);
  }
  const int z[2] = {o + half::kZ, o + half::kEnd + half::kZ};
  for (int r = 0; r < 2; ++r)
    for (int c = 0; c < 2; ++c) A(z[r], z[c]) = m.axial_mass(r, c);
}

// The dense A(q) (tests and modal analysis).
Eigen::MatrixXd dense_inertia(const Model& m, const double* q);

}  // namespace cvt
