// Fresh friction between rebuilds of the W-method's matrix (docs/integrators.md 12.4): the
// factorized W corrected by a low-rank (Woodbury) term for the contacts whose friction
// coefficient moved since the rebuild. Part of WSolver, whose factors solve its columns.
#pragma once

#include <cstdint>
#include <utility>
#include <vector>

#include "engine/wmethod/chain_stiffness.hpp"
#include "engine/wmethod/options.hpp"

namespace cvt {

class WSolver;

class FreshFriction {
 public:
  using ShaftVector = Eigen::Matrix<double, 2 * kShaftSize, 1>;
  using ShaftVectors = std::vector<ShaftVector, Eigen::aligned_allocator<ShaftVector>>;
  // Sized here for up to opt.w_fresh_max contacts: nothing is allocated inside a step.
  FreshFriction(const Model& m, const ModelOdeOptions& opt, WSolver& w, FrictionJacobian& fjac, bool on);
  // A rebuild: no contact in the correction.
  void clear();
  // After a step's first evaluation without a rebuild: the contacts whose mu moved by more
  // than the tolerance join the correction (two solves each), the capacitance matrix for gh.
  void update(double gh);
  // x -= the correction, after the solve with the factors (which left W^-1 r in w's rhs_).
  void correct(double* x) const;
  // More contacts moved than w_fresh_max: the next step rebuilds the friction blocks.
  bool force_rebuild() const { return force_; }
  // Whether force_rebuild() was set; clears it (at a rebuild).
  bool take_force() { return std::exchange(force_, false); }
  std::int64_t joined() const { return joined_; }

 private:
  // A contact in the correction: its U (2 x 40) and, for a pin end, the sheave part V (2 x 7).
  struct Contact {
    FrictionJacobian::FreshMu* kind;  // fjac.rocker_fresh or fjac.pulley_fresh
    int idx, joint, shaft;            // shaft: the sheave of a pin end, -1 for a rocker station
    const double* columns() const;
    const double* sheave_columns(const FrictionJacobian& f) const;  // nullptr: a rocker station
  };
  struct Candidate {
    double dmu;
    int rank, kind, idx;  // rank: the order of ties (rocker stations, then pin ends)
  };
  void join(const Contact& c);
  // [U; V](:, col)^T [z; zs] (zs: the shafts' part, 14 entries; nullptr: the chain's alone)
  double dot(const Contact& c, int col, const double* z, const double* zs = nullptr) const;

  const Model& m_;
  const ModelOdeOptions& opt_;
  WSolver& w_;
  FrictionJacobian& fjac_;
  std::vector<Candidate> cand_;
  std::vector<Contact> set_;
  // Z = W^-1 [U; V] (chain velocities in link order, physical units; zs_ its shaft rows
  // with w_shafts), G = [U; V]^T Z, D = gh (mu - mu_w) on both columns of each contact.
  Eigen::MatrixXd z_, g_, zs_;
  Eigen::VectorXd d_;
  // The capacitance matrix I + D G and its LU, one of each size 2, 4, .., 2 w_fresh_max.
  std::vector<Eigen::MatrixXd> cap_m_;
  std::vector<Eigen::PartialPivLU<Eigen::MatrixXd>> cap_;
  mutable Eigen::VectorXd s_, t_, p_, b_, corr_;  // correct()'s scratch
  // A contact's two columns [U; V], solved together; the second column's chain part and
  // its shafts' product.
  using LinkPair = Eigen::Matrix<double, kLinkDim, 2>;
  std::vector<LinkPair, Eigen::aligned_allocator<LinkPair>> pair_;
  LinkVectors rhs2_;
  ShaftVectors bz2_;
  bool force_ = false;
  std::int64_t joined_ = 0;
};

}  // namespace cvt
