// What the kernel tests share: one kernel's generalized forces alone, and the rigid
// motions of docs/model.md 2 as directions in the coordinates.
#pragma once

#include <Eigen/Dense>

#include "engine/rhs/rhs.hpp"
#include "modules/chain_forces.hpp"
#include "modules/inertia.hpp"
#include "modules/pulley_contact.hpp"

namespace cvt::test {

enum class Kernel { chain, pulley };

// The generalized forces F (ws.force, link torques mapped through g_i as in 4.0) of one
// kernel alone at (t, y), and its dissipated power in ws.p_diss: every other slot cleared.
inline Eigen::VectorXd kernel_forces(const Model& m, Workspace& ws, double t, const Eigen::VectorXd& y, Kernel k,
                                     const FrictionExtras& x = {}) {
  set_stage_input(m, ws, t, y.data());
  link_kinematics(m, ws, 0, m.links);
  for (auto* slots : {&ws.chain_slots, &ws.pulley_slots, &ws.inertia_slots})
    for (JointSlot& s : *slots) s.clear();
  ws.other = OtherForces{};
  if (k == Kernel::chain)
    chain_forces(m, ws, 0, m.links, x);
  else
    pulley_contact(m, ws, 0, m.links, x);
  gather_forces(m, ws);
  return ws.force;
}

// A rigid motion of the chain (and, with shafts, of both shafts) as a direction in the
// coordinates: translation along axis 0, 1, 2 (x, y, z), or (axis 3) a rotation about z
// through the origin. Pin ends move with it, slopes turn with a rotation; the pack
// coordinates s are axial positions.
inline Eigen::VectorXd rigid_motion(const Model& m, const Eigen::VectorXd& y, int axis, bool shafts) {
  Eigen::VectorXd d = Eigen::VectorXd::Zero(m.ndof);
  for (int j = 0; j < m.links; ++j) {
    for (int h = 0; h < 2; ++h) {
      const int o = h == 0 ? m.half_a(j) : m.half_b(j);
      for (int e = 0; e < 2; ++e) {
        const int b = o + e * half::kEnd;
        if (axis < 3) {
          d[b + axis] = 1;  // kX, kY, kZ are 0, 1, 2
        } else {
          d[b + half::kX] = -y[b + half::kY], d[b + half::kY] = y[b + half::kX];
          d[b + half::kSx] = -y[b + half::kSy], d[b + half::kSy] = y[b + half::kSx];
        }
      }
    }
    if (axis == 2) d[m.pack(j)] = 1;
  }
  if (shafts)
    for (int k = 0; k < 2; ++k) {
      const int s = m.shaft(k);
      if (axis < 3) {
        d[s + axis] = 1;  // kUx, kUy, kUz are 0, 1, 2
      } else {
        // The shaft's centre is its pulley's nominal centre moved by (u_x, u_y).
        const double cx = m.pulley[k].centre.x() + y[s + kUx], cy = m.pulley[k].centre.y() + y[s + kUy];
        d[s + kUx] = -cy, d[s + kUy] = cx;
        d[s + kTx] = -y[s + kTy], d[s + kTy] = y[s + kTx];
        d[s + kPhi] = 1;
      }
    }
  return d;
}

}  // namespace cvt::test
