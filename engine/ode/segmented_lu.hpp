// LU factorization of the block-tridiagonal matrix with cyclic corners of CyclicBlockLU
// (docs/integrators.md 12.2) on S segments instead of two sweeps, so that the work divides
// over up to S threads (docs/performance.md 3).
//
// The ring of n blocks is cut at S separator blocks s_k = floor(k n / S). The blocks between
// two separators, s_k + 1 .. s_{k+1} - 1, form segment k's interior; it couples to the rest
// only through s_k (above) and s_{k+1} (below). Each segment eliminates its interior
// downwards from s_k + 1, independently of the others (S tasks): like CyclicBlockLU's sweeps,
// it fills the coupling of its next block to s_k, a fill that decays along the segment and is
// dropped below the drop tolerance, and it leaves the reduced system of the separators, a
// block-tridiagonal matrix with cyclic corners of S blocks (the separators' pivots updated by
// both segments next to them, each separator coupled to its neighbours through the fill that
// reached the segment's end), factorized serially by a CyclicBlockLU. A solve is the same:
// the segments' forward sweeps (S tasks), the reduced system (serial), the segments' backward
// sweeps (S tasks).
//
// The partition depends on n and S alone, and each segment's arithmetic is fixed, so the
// result is the same to the bit for any number of threads and any order of the tasks.
#pragma once

#include <Eigen/Dense>
#include <array>
#include <atomic>
#include <stdexcept>
#include <vector>

#include "engine/ode/block_cyclic.hpp"

namespace cvt {

// Phases of work shared by several tasks of one fork, as TwoTaskPhases for more than two:
// a phase has `parts` parts; every task claims parts of it (an atomic counter) until none is
// left, runs them, and waits until all are done. A task waits only for parts that other
// tasks have claimed and are running (they claim before they run, and run without waiting),
// so the tasks never wait on each other in a cycle, and one task alone runs every part of
// every phase. Each part's arithmetic, and so every bit of its result, is the same whichever
// task runs it.
class TaskPhases {
 public:
  static constexpr int kMax = 8;
  TaskPhases() {
    for (auto& a : next_) a.store(0, std::memory_order_relaxed);
    for (auto& a : done_) a.store(0, std::memory_order_relaxed);
  }
  template <class F>
  void run(int phase, int parts, const F& f) {
    for (int p; (p = next_[phase].fetch_add(1, std::memory_order_acq_rel)) < parts;) {
      try {
        f(p);
      } catch (...) {
        done_[phase].fetch_add(1, std::memory_order_release);  // nobody waits for it forever
        throw;
      }
      done_[phase].fetch_add(1, std::memory_order_release);
    }
    spin_until([&] { return done_[phase].load(std::memory_order_acquire) >= parts; });
  }

 private:
  std::array<std::atomic<int>, kMax> next_, done_;
};

template <int B>
class SegmentedBlockLU : public BlockSweeps<B, SegmentedBlockLU<B>> {
  using Base = BlockSweeps<B, SegmentedBlockLU<B>>;
  using typename Base::Fill;
  using Base::n_;
  using Base::d_;

 public:
  using Base::solve;
  using Base::solve_columns;
  using Mat = typename Base::Mat;
  using Vec = typename Base::Vec;
  static constexpr double kNegligible = CyclicBlockLU<B>::kNegligible;

  // Runs task(t) for the tasks t = 0, 1, ..., concurrently or not; the default one task,
  // which then runs every part itself. A caller with threads passes one that forks several
  // (ManyTasks): the arithmetic, and so every bit of the result, is the same.
  struct Sequential {
    template <class F>
    void operator()(const F& task) const {
      task(0);
    }
  };

  // n blocks on `segments` segments: at least 3, and each interior at least one block.
  void resize(int n, int segments) {
    if (segments < 3 || n < 2 * segments) throw std::invalid_argument("SegmentedBlockLU: needs 3 <= segments <= n / 2");
    this->resize_blocks(n);
    segs_ = segments;
    mult_.resize(n);
    seg_.assign(segments, Fill{});
    sep_.resize(segments + 1);
    for (int k = 0; k <= segments; ++k) sep_[k] = static_cast<int>(static_cast<long>(k) * n / segments);
    red_.resize(segments);
    red_.set_drop_tolerance(this->drop_);
  }
  void set_drop_tolerance(double tol) {
    this->drop_ = tol;
    red_.set_drop_tolerance(tol);
  }
  int segments() const { return segs_; }
  // Interior blocks of the last factorization that carry a fill to their segment's separator.
  int fill_blocks() const { return fills_; }
  // Factorizes; false if a pivot block is singular (or not finite). Overwrites the diagonal
  // blocks of the interiors.
  bool factor() { return factor(Sequential()); }
  template <class Tasks>
  bool factor(const Tasks& tasks) {
    TaskPhases ph;
    bool ok = true;
    tasks([&](int) {
      ph.run(0, segs_, [&](int k) { eliminate(k); });
      ph.run(1, 1, [&](int) { ok = reduce(); });
    });
    return ok;
  }

  // Solves M x = b in place (x[l]: block l; the shorter forms: BlockSweeps) with the caller's
  // work per block fused into the tasks, as CyclicBlockLU's:
  // prepare(l) writes b_l into x[l] before its segment's forward sweep, finish(l) reads the
  // solution x[l] after its segment's backward sweep, then serial() once, then last(l) for
  // every block; each on the task that runs the block's segment.
  template <class Tasks, class Prepare, class Finish, class Serial, class Last>
  void solve(Vec* x, const Tasks& tasks, const Prepare& prepare, const Finish& finish, const Serial& serial,
             const Last& last) const {
    Scratch<Vec>& sc = scratch<Vec>();
    auto &xm = sc.xm, &xl = sc.xl;
    phases(
        tasks,
        [&](int k) {
          each(k, prepare);
          forward(x, k, xm[k], xl[k]);
        },
        [&] { reduced(x, xm, xl, [&](Vectors<Vec>& y) { red_.solve(y.data()); }); },
        [&](int k) {
          backward(x, k);
          each(k, finish);
        },
        serial, last);
  }

  // Solves M X = B for a block of right sides in place (X[l]: block l's rows, B x C), with
  // the caller's finish, serial and last as solve()'s.
  template <int C, class Tasks, class Finish, class Serial, class Last>
  void solve_columns(Eigen::Matrix<double, B, C>* x, const Tasks& tasks, const Finish& finish, const Serial& serial,
                     const Last& last) const {
    using Cols = Eigen::Matrix<double, B, C>;
    Scratch<Cols>& sc = scratch<Cols>();
    auto &xm = sc.xm, &xl = sc.xl;
    phases(
        tasks, [&](int k) { forward(x, k, xm[k], xl[k]); },
        [&] {
          reduced(x, xm, xl,
                  [&](Vectors<Cols>& y) { red_.template solve_columns<C>(y.data(), typename CyclicBlockLU<B>::Sequential()); });
        },
        [&](int k) {
          backward(x, k);
          each(k, finish);
        },
        serial, last);
  }

 private:
  // Segment k's interior blocks, a + 1 .. b - 1 for its separators a and b, then b (n wraps to 0).
  auto at(int k) const {
    return [a = sep_[k], n = n_](int i) { return a + 1 + i == n ? 0 : a + 1 + i; };
  }
  int interior(int k) const { return sep_[k + 1] - sep_[k] - 1; }
  // A solve's per-segment parts (the multipliers' and the fills' into the separators) and the
  // reduced system's right sides: the calling thread's, grown once, so that a solve does not
  // allocate (a solve runs within one call on one thread, its tasks reading the caller's).
  template <class V>
  using Vectors = std::vector<V, Eigen::aligned_allocator<V>>;
  template <class V>
  struct Scratch {
    Vectors<V> xm, xl, y;
  };
  template <class V>
  Scratch<V>& scratch() const {
    thread_local Scratch<V> sc;
    if (static_cast<int>(sc.y.size()) < segs_) sc.xm.resize(segs_), sc.xl.resize(segs_), sc.y.resize(segs_);
    return sc;
  }
  template <class F>
  void each(int k, const F& f) const {
    for (int l = sep_[k]; l < sep_[k + 1]; ++l) f(l);
  }
  // A solve's phases in one fork and join: the segments' forward sweeps (with prepare), the
  // reduced system, the backward sweeps (with finish), serial(), the blocks' last(l).
  template <class Tasks, class Forward, class Middle, class Backward, class Serial, class Last>
  void phases(const Tasks& tasks, const Forward& forward, const Middle& middle, const Backward& backward,
              const Serial& serial, const Last& last) const {
    TaskPhases ph;
    tasks([&](int) {
      ph.run(0, segs_, forward);
      ph.run(1, 1, [&](int) { middle(); });
      ph.run(2, segs_, backward);
      ph.run(3, 1, [&](int) { serial(); });
      ph.run(4, segs_, [&](int k) { each(k, last); });
    });
  }

  // Segment k's interior, eliminated downwards from its upper separator a (the sweep's
  // outer block) into its lower one b (the stop).
  void eliminate(int k) {
    seg_[k] = Fill{};
    const int a = sep_[k];
    this->sweep(interior(k), at(k), mult_, this->s_[a + 1], this->p_[a + 1], seg_[k]);  // M(a + 1, a), M(a, a + 1)
  }
  // The separators' system, in a fixed order, and its factorization.
  bool reduce() {
    fills_ = 0;
    for (int k = 0; k < segs_; ++k) {
      if (!seg_[k].ok) return false;
      fills_ += seg_[k].fills;
    }
    for (int k = 0; k < segs_; ++k) {
      const Fill& above_k = seg_[k == 0 ? segs_ - 1 : k - 1];  // the segment that ends at separator k
      red_.diag(k) = d_[sep_[k]];
      red_.diag(k) += seg_[k].dl;
      red_.diag(k) += above_k.dm;
      red_.sub(k) = above_k.col;
      red_.super(k) = above_k.row;
    }
    return red_.factor();
  }
  // Segment k's part of L y = b: the multiplier into its lower separator (xm) and the fill's
  // couplings into its upper one (xl).
  template <class V>
  void forward(V* x, int k, V& xm, V& xl) const {
    xl.setZero();
    this->sweep_forward(x, interior(k), at(k), mult_, xm, xl);
  }
  // The reduced system's right sides (each separator's, less the fill's and the multiplier's
  // parts), its solve, and the solution back into x.
  template <class V, class Solve>
  void reduced(V* x, const Vectors<V>& xm, const Vectors<V>& xl, const Solve& solve) const {
    Vectors<V>& y = scratch<V>().y;
    for (int k = 0; k < segs_; ++k) {
      y[k] = x[sep_[k]];
      y[k] -= xl[k];
      y[k] -= xm[k == 0 ? segs_ - 1 : k - 1];
    }
    solve(y);
    for (int k = 0; k < segs_; ++k) x[sep_[k]] = y[k];
  }
  // Segment k's part of U x = y, upwards from its lower separator.
  template <class V>
  void backward(V* x, int k) const {
    this->sweep_backward(x, interior(k), at(k), sep_[k]);
  }

  int segs_ = 0, fills_ = 0;
  std::vector<int> sep_;
  // What each segment's sweep left for the reduced system (Fill: its updates of the upper
  // separator's pivot, dl, and the lower one's, dm; the fill col = M(lower, upper), row =
  // M(upper, lower) that couples them).
  std::vector<Fill, Eigen::aligned_allocator<Fill>> seg_;
  // mult_[l] = M(l, l-1) D_{l-1}^-1 for the interiors' blocks past their first and for the
  // separators (the multiplier from the segment above); the base's lrow_ / ucol_: the fill's
  // couplings to the segment's upper separator.
  typename Base::Mats mult_;
  CyclicBlockLU<B> red_;  // the separators' system
};

}  // namespace cvt
