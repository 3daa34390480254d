// The chain's block LU in the W matrix (docs/integrators.md 12.2): CyclicBlockLU's two
// sweeps, or with integrator.w_segments SegmentedBlockLU's segments and the reduced system of
// their separators (docs/performance.md 3). Either gives the same bits for any number of
// threads; the two give different roundings of the same solve.
#pragma once

#include "engine/ode/block_cyclic.hpp"
#include "engine/ode/segmented_lu.hpp"
#include "engine/wmethod/chain_stiffness.hpp"
#include "engine/wmethod/parallel.hpp"

namespace cvt {

class ChainLU {
 public:
  // segments: 0 for the two sweeps, else at least 3 and at most links / 2.
  void resize(int links, int segments, double drop) {
    segments_ = segments;
    if (segments_ > 0) {
      seg_.resize(links, segments);
      seg_.set_drop_tolerance(drop);
    } else {
      two_.resize(links);
      two_.set_drop_tolerance(drop);
    }
  }
  LinkBlock& diag(int l) { return segments_ ? seg_.diag(l) : two_.diag(l); }
  LinkBlock& sub(int l) { return segments_ ? seg_.sub(l) : two_.sub(l); }
  LinkBlock& super(int l) { return segments_ ? seg_.super(l) : two_.super(l); }

  // On `threads` threads of the caller's arena (1: serially); false if a pivot is singular.
  bool factor(int threads) {
    if (segments_) return seg_.factor(ManyTasks{threads});
    return two_.factor(TwoTasks{threads > 1});
  }
  // The solves of CyclicBlockLU / SegmentedBlockLU with the caller's phases (prepare,
  // finish; or finish, serial, last for the columns; see there).
  template <class... Phases>
  void solve(LinkVector* x, int threads, const Phases&... phases) const {
    if (segments_)
      seg_.solve(x, ManyTasks{threads}, phases...);
    else
      two_.solve(x, TwoTasks{threads > 1}, phases...);
  }
  template <int C, class... Phases>
  void solve_columns(Eigen::Matrix<double, kLinkDim, C>* x, int threads, const Phases&... phases) const {
    if (segments_)
      seg_.template solve_columns<C>(x, ManyTasks{threads}, phases...);
    else
      two_.template solve_columns<C>(x, TwoTasks{threads > 1}, phases...);
  }

 private:
  int segments_ = 0;
  CyclicBlockLU<kLinkDim> two_;
  SegmentedBlockLU<kLinkDim> seg_;
};

}  // namespace cvt
