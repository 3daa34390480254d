// The chain's stiffness K = -dF/dq for the W-method's matrix (docs/integrators.md 12.2):
// finite differences of the generalized forces over link colours, or the analytic Hessian
// of the chain's elastic energy (modules/elastic_hessian); per link the diagonal block and
// the couplings to its neighbours, in the link order of WSolver.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <vector>

#include "engine/ode/block_cyclic.hpp"
#include "graph/schedule.hpp"
#include "modules/elastic_hessian.hpp"

namespace cvt {

// A link's coordinates in W's link order (kLinkDim): b_l, a_{l+1}, then the plate pack s_l.
using LinkBlock = CyclicBlockLU<kLinkDim>::Mat;
using LinkVector = CyclicBlockLU<kLinkDim>::Vec;
using LinkBlocks = std::vector<LinkBlock, Eigen::aligned_allocator<LinkBlock>>;
using LinkVectors = std::vector<LinkVector, Eigen::aligned_allocator<LinkVector>>;

// Coordinate index of entry i of link l (W's link order).
inline int link_coordinate(const Model& m, int l, int i) {
  return i < half::kSize ? m.half_b(l) + i : i < 2 * half::kSize ? m.half_a(l + 1) + i - half::kSize : m.pack(l);
}

class ChainStiffness {
 public:
  // Over the schedule's workspace ws (the differences leave it as one evaluation at the
  // unperturbed state does: the assembly reads its link directions).
  // analytic: the Hessian of the elastic energy with the friction parts of the pin ends and
  // the rockers (add_pulley_friction_stiffness, add_rocker_friction_stiffness), else the
  // differences.
  ChainStiffness(const Model& m, Workspace& ws, Schedule& schedule, bool analytic = false);
  // K at the physical state y. The differences: 21 evaluations per colour (63 for 3
  // colours), in two halves on two workspaces when the schedule has threads. The Hessian:
  // per joint, then per link, over the schedule's threads.
  void take(double t, const double* y);
  // K's blocks of link l: M(l, l), M(l, l-1) (sub) and M(l-1, l) (super).
  const LinkBlock& diag(int l) const { return diag_[l]; }
  const LinkBlock& sub(int l) const { return sub_[l]; }
  const LinkBlock& super(int l) const { return super_[l]; }
  // The coupling blocks by their nonzero columns (a coupling between links reaches about 12
  // of a link's 21 coordinates: the halves at the joint and the link spins), for the solve's
  // K b_q: [0] sub, [1] super.
  struct PackedColumns {
    int n = 0;
    std::array<int, kLinkDim> index{};
    LinkBlock cols;
  };
  const std::array<PackedColumns, 2>& packed(int l) const { return packed_[l]; }
  // The force evaluations taken (each about 3/4 of an RHS; none for the Hessian), the
  // stiffnesses and their wall time.
  std::int64_t evaluations() const { return evaluations_; }
  std::int64_t takes() const { return takes_; }
  double seconds() const { return seconds_; }

 private:
  // The differences of items [k0, k1) (item k: colour k / kLinkDim, link coordinate
  // k % kLinkDim) on workspace w, from the unperturbed state ys_ copied in yp (left as it
  // was), with delta as the per-link scratch; serial on the calling thread.
  void items(Workspace& w, Eigen::VectorXd& yp, std::vector<double>& delta, double t, int k0, int k1);
  // ws.force of the chain at (t, y) on workspace w; with a colour, the differences'
  // evaluation that perturbs that colour's links (only the joints next to them are computed).
  // Serially on the calling thread or (threads) over the schedule's threads.
  void forces(Workspace& w, double t, const double* y, int color, bool threads);
  // K as the Hessian of the elastic energy at y (ws_ left with y's link kinematics).
  void hessian(double t, const double* y);
  static void pack_columns(const LinkBlock& b, PackedColumns& p);
  int coord(int l, int i) const { return coord_[l * kLinkDim + i]; }

  const Model& m_;
  Workspace& ws_;
  Schedule& schedule_;
  bool analytic_;
  std::vector<JointHessian, Eigen::aligned_allocator<JointHessian>> joints_;  // the Hessian's per joint
  std::vector<int> coord_;  // [l * kLinkDim + i]: link_coordinate(m, l, i)
  std::vector<int> color_;  // link colours: links within two of each other differ
  int colors_ = 0;
  Eigen::VectorXd ys_, yp_;  // the unperturbed state, and the perturbed one
  std::vector<double> force0_, delta_;
  std::vector<JointSlot> chain0_, pulley0_;  // the slots at the unperturbed state
  // The second workspace of the differences on two threads (a copy of ws_ at the
  // unperturbed evaluation), its perturbed state and per-link steps.
  std::unique_ptr<Workspace> ws2_;
  Eigen::VectorXd yp2_;
  std::vector<double> delta2_;
  LinkBlocks diag_, sub_, super_;
  std::vector<std::array<PackedColumns, 2>> packed_;
  std::int64_t evaluations_ = 0, takes_ = 0;
  double seconds_ = 0;
};

}  // namespace cvt
