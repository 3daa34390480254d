// The Hessian of the chain's elastic energy (docs/model.md 4.1-4.5: the beams, tilt holds,
// plates, packs, rocker Hertz and keeper of chain_energy, and the pin ends' Hertz of
// pulley_energy, each under the contact status), in the chain's link blocks: the stiffness
// K = -dF/dq of the conservative forces, for the W-method's matrix (docs/integrators.md 12.2).
// Link l's coordinates: half b_l (0..9), half a_{l+1} (10..19), the pack s_l (20).
#pragma once

#include <Eigen/Core>

#include "engine/model/state.hpp"

namespace cvt {

inline constexpr int kLinkDim = 2 * half::kSize + 1;
using LinkHessian = Eigen::Matrix<double, kLinkDim, kLinkDim>;

// Joint j's rocker stations (the active ones) and keeper couple links j-1 and j: their
// Hessian over link j-1's coordinates (prev), link j's (own), the cross block (rows of link
// j, columns of link j-1) and its counterpart up (rows of link j-1, columns of link j):
// cross^T for the Hessian, which a friction part (add_rocker_friction_stiffness) makes
// unsymmetric. Written, not added to.
struct JointHessian {
  LinkHessian prev, own, cross, up;
};
void joint_hessian(const Model& m, const double* q, const ContactStatus& status, int j, JointHessian& out);

// Link l's own elements, within its block: the beams and tilt holds of halves b_l and
// a_{l+1}, the Hertz of their active pin ends (the shafts held), link l's plates and pack.
// Written, not added to.
void link_hessian(const Model& m, const double* q, const ContactStatus& status, int l, LinkHessian& out);

}  // namespace cvt
