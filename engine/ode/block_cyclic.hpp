// LU factorization of a block-tridiagonal matrix with cyclic corners (docs/integrators.md
// 12.2): n diagonal blocks D_l, sub-diagonal blocks S_l = M(l, l-1 mod n) and
// super-diagonal blocks P_l = M(l-1 mod n, l), all B x B, so S_0 = M(0, n-1) and
// P_0 = M(n-1, 0) are the corners. This is the structure of ROS2's matrix for the chain in
// link order (each force couples at most two neighbouring links).
//
// Block Gaussian elimination without pivoting between blocks (the matrix is dominated by its
// diagonal blocks: mass plus damping; each pivot block is inverted with partial pivoting),
// from both ends of the chain that remains without the last block (two tasks; see factor()).
// The couplings to the last block fill its block row and column and nothing else.
// The factor keeps the inverses of the pivot blocks, so that the solves are matrix-vector
// products (independent updates) rather than substitutions. Factorization ~ 9 B^3 n flops,
// a solve ~ 10 B^2 n.
#pragma once

#include <Eigen/Dense>
#include <array>
#include <atomic>
#include <cmath>
#include <thread>
#include <utility>
#include <vector>

#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#endif

namespace cvt {

// t = sum over a few column blocks of (B x n, column-major) times n scalars, in one set of
// registers: the W solve's right side K b_q over a link's dense diagonal block and its
// neighbours' packed nonzero columns (WSolver::solve_untimed). add() sums column by
// column; n may be 0.
template <int B>
class ColumnSum {
 public:
#if defined(__AVX2__) && defined(__FMA__)
  ColumnSum() {
    for (auto& v : acc_) v = _mm256_setzero_pd();
  }
  void add(const double* cols, const double* x, int n) {
    // The sums in locals while the loop runs: the members could alias `cols` for the
    // compiler, which would then store them at every column.
    const __m256i mask = _mm256_set_epi64x(0, kRest > 2 ? -1 : 0, kRest > 1 ? -1 : 0, -1);
    __m256d acc[kRegs];
    for (int i = 0; i < kRegs; ++i) acc[i] = acc_[i];
    for (int c = 0; c < n; ++c) {
      const __m256d xc = _mm256_set1_pd(x[c]);
      const double* col = cols + B * c;
      for (int i = 0; i < kFull; ++i) acc[i] = _mm256_fmadd_pd(_mm256_loadu_pd(col + 4 * i), xc, acc[i]);
      if constexpr (kRest > 0) acc[kFull] = _mm256_fmadd_pd(_mm256_maskload_pd(col + 4 * kFull, mask), xc, acc[kFull]);
    }
    for (int i = 0; i < kRegs; ++i) acc_[i] = acc[i];
  }
  void get(Eigen::Matrix<double, B, 1>& t) const {
    alignas(32) double out[4 * kRegs];
    for (int i = 0; i < kRegs; ++i) _mm256_store_pd(out + 4 * i, acc_[i]);
    for (int r = 0; r < B; ++r) t[r] = out[r];
  }

 private:
  static constexpr int kFull = B / 4, kRest = B % 4, kRegs = kFull + (kRest > 0);
  __m256d acc_[kRegs];
#else
  ColumnSum() { t_.setZero(); }
  void add(const double* cols, const double* x, int n) {
    for (int c = 0; c < n; ++c) t_ += Eigen::Map<const Eigen::Matrix<double, B, 1>>(cols + B * c) * x[c];
  }
  void get(Eigen::Matrix<double, B, 1>& t) const { t = t_; }

 private:
  Eigen::Matrix<double, B, 1> t_;
#endif
};

// t = A x for a small fixed-size block (B x B, column-major): the solves' kernel. With AVX2
// the columns are summed in B/4 (rounded up) registers of four rows, the last one a masked
// load, inline; Eigen's general matrix-vector product (an out-of-line call that splits 21
// rows into packets of 4, 2 and 1) took 1.3-1.6x as long on the chain's 21 x 21 blocks.
template <int B>
inline void block_times(const Eigen::Matrix<double, B, B>& A, const Eigen::Matrix<double, B, 1>& x,
                        Eigen::Matrix<double, B, 1>& t) {
  ColumnSum<B> sum;
  sum.add(A.data(), x.data(), B);
  sum.get(t);
}

// T = A X for C columns (solve_columns' kernel). With AVX2 two columns at a time share each
// load of A's columns (2 x B/4 registers of sums); Eigen's product of a 21 x 21 block with
// 2 or 14 columns took 2.5x (2) and 1.1x (14) the time of as many single products.
template <int B, int C>
inline void block_times_columns(const Eigen::Matrix<double, B, B>& A, const Eigen::Matrix<double, B, C>& X,
                                Eigen::Matrix<double, B, C>& T) {
#if defined(__AVX2__) && defined(__FMA__)
  constexpr int kFull = B / 4, kRest = B % 4, kRegs = kFull + (kRest > 0);
  const __m256i mask = _mm256_set_epi64x(0, kRest > 2 ? -1 : 0, kRest > 1 ? -1 : 0, -1);
  const double* a = A.data();
  int j = 0;
  for (; j + 1 < C; j += 2) {
    __m256d s0[kRegs], s1[kRegs];
    for (int i = 0; i < kRegs; ++i) s0[i] = _mm256_setzero_pd(), s1[i] = _mm256_setzero_pd();
    const double* x0 = X.data() + B * j;
    const double* x1 = x0 + B;
    for (int c = 0; c < B; ++c) {
      const __m256d b0 = _mm256_set1_pd(x0[c]), b1 = _mm256_set1_pd(x1[c]);
      const double* col = a + B * c;
      for (int i = 0; i < kFull; ++i) {
        const __m256d v = _mm256_loadu_pd(col + 4 * i);
        s0[i] = _mm256_fmadd_pd(v, b0, s0[i]);
        s1[i] = _mm256_fmadd_pd(v, b1, s1[i]);
      }
      if constexpr (kRest > 0) {
        const __m256d v = _mm256_maskload_pd(col + 4 * kFull, mask);
        s0[kFull] = _mm256_fmadd_pd(v, b0, s0[kFull]);
        s1[kFull] = _mm256_fmadd_pd(v, b1, s1[kFull]);
      }
    }
    double* t0 = T.data() + B * j;
    double* t1 = t0 + B;
    for (int i = 0; i < kFull; ++i) _mm256_storeu_pd(t0 + 4 * i, s0[i]), _mm256_storeu_pd(t1 + 4 * i, s1[i]);
    if constexpr (kRest > 0)
      _mm256_maskstore_pd(t0 + 4 * kFull, mask, s0[kFull]), _mm256_maskstore_pd(t1 + 4 * kFull, mask, s1[kFull]);
  }
  if (j < C) {
    Eigen::Matrix<double, B, 1> t;
    block_times<B>(A, X.col(j), t);
    T.col(j) = t;
  }
#else
  T.noalias() = A * X;
#endif
}
// Y -= A X for C columns.
template <int B, int C>
inline void block_subtract_columns(const Eigen::Matrix<double, B, B>& A, const Eigen::Matrix<double, B, C>& X,
                                   Eigen::Matrix<double, B, C>& Y) {
  Eigen::Matrix<double, B, C> t;
  block_times_columns<B, C>(A, X, t);
  Y -= t;
}

// y -= A x.
template <int B>
inline void block_subtract(const Eigen::Matrix<double, B, B>& A, const Eigen::Matrix<double, B, 1>& x,
                           Eigen::Matrix<double, B, 1>& y) {
  Eigen::Matrix<double, B, 1> t;
  block_times(A, x, t);
  y -= t;
}

// Waits for done() (another task's work, with acquire semantics), spinning a while, then
// yielding the core.
template <class Done>
inline void spin_until(const Done& done) {
  for (int spins = 0; !done();) {
#if defined(__x86_64__) || defined(__i386__)
    __builtin_ia32_pause();
#endif
    if (spins < 4096)
      ++spins;
    else
      std::this_thread::yield();
  }
}

// Phases of work shared by the two tasks of one fork: each phase runs once, on the task that
// claims it first, and a task that needs a phase claimed by the other waits for it. A task
// waits only for a phase that the other has claimed and is running (it claims before it
// runs, and runs without waiting), so the two never wait on each other in a cycle, and one
// task alone (no second thread free, or the sequential fork) runs every phase itself. So a
// chain of phases costs one fork and join instead of one per parallel phase, and each
// phase's arithmetic, and so every bit of its result, is the same whichever task runs it.
// A phase must not itself wait for other tasks of the scheduler unless the fork isolates its
// two tasks (TwoTasks does: a thread waiting inside a phase could otherwise pick up the other
// task of the same fork and spin there on the phase it holds).
class TwoTaskPhases {
 public:
  static constexpr int kMax = 16;
  TwoTaskPhases() {
    for (auto& s : state_) s.store(kFree, std::memory_order_relaxed);
  }
  // Phase i: runs f, or waits until the task that claimed it has run it.
  template <class F>
  void one(int i, const F& f) {
    if (claim(i)) run(i, f);
    wait(i);
  }
  // Phases i (f) and i + 1 (g), the halves of one parallel phase: the task on `side` (0 or 1)
  // runs its own half first, then the other's if still free, then waits for both.
  template <class F, class G>
  void two(int i, int side, const F& f, const G& g) {
    if (side == 0) {
      if (claim(i)) run(i, f);
      if (claim(i + 1)) run(i + 1, g);
    } else {
      if (claim(i + 1)) run(i + 1, g);
      if (claim(i)) run(i, f);
    }
    wait(i), wait(i + 1);
  }

 private:
  enum : int { kFree = 0, kClaimed = 1, kDone = 2 };
  bool claim(int i) {
    int expected = kFree;
    return state_[i].compare_exchange_strong(expected, kClaimed, std::memory_order_acq_rel);
  }
  // A phase that throws is marked done before the exception goes on to the fork's join, so
  // that the other task does not wait for it forever.
  template <class F>
  void run(int i, const F& f) {
    try {
      f();
    } catch (...) {
      state_[i].store(kDone, std::memory_order_release);
      throw;
    }
    state_[i].store(kDone, std::memory_order_release);
  }
  void wait(int i) const {
    spin_until([&] { return state_[i].load(std::memory_order_acquire) == kDone; });
  }
  std::array<std::atomic<int>, kMax> state_;
};

// What CyclicBlockLU and SegmentedBlockLU share: the blocks of the block-tridiagonal matrix
// with cyclic corners (n diagonal blocks D_l, sub-diagonal S_l = M(l, l-1 mod n),
// super-diagonal P_l = M(l-1 mod n, l)), the pivots' inverses, and one elimination sweep
// with its forward and backward solves. A sweep eliminates `count` blocks at(0), at(1), ...
// in that order, each into the next, and stops at at(count), whose pivot update it returns
// (dm); it carries the fill (col, row) that couples the swept blocks to one outside block
// (the ring's last block, a segment's separator: `outer`), U's column ucol and L's row lrow
// of each swept block, and that block's pivot update (dl), and drops the fill once it is
// below the drop tolerance of the next pivot block.
//
// It also gives both their shorter solves, each the derived class's full solve (Derived::solve
// with prepare, finish, serial and last; solve_columns with finish, serial and last) with
// the phases it leaves out doing nothing.
template <int B, class Derived>
class BlockSweeps {
 public:
  using Mat = Eigen::Matrix<double, B, B>;
  using Vec = Eigen::Matrix<double, B, 1>;
  using Mats = std::vector<Mat, Eigen::aligned_allocator<Mat>>;

  // Solves M x = b in place (x[l]: block l): serially, on the caller's tasks, and with the
  // caller's prepare(l) and finish(l) (see the derived class's solve).
  void solve(Vec* x) const { self().solve(x, typename Derived::Sequential()); }
  template <class Tasks>
  void solve(Vec* x, const Tasks& tasks) const {
    const auto none = [](int) {};
    self().solve(x, tasks, none, none);
  }
  template <class Tasks, class Prepare, class Finish>
  void solve(Vec* x, const Tasks& tasks, const Prepare& prepare, const Finish& finish) const {
    self().solve(x, tasks, prepare, finish, [] {}, [](int) {});
  }
  // Solves M X = B for a block of right sides in place (X[l]: block l's rows, B x C).
  template <int C, class Tasks>
  void solve_columns(Eigen::Matrix<double, B, C>* x, const Tasks& tasks) const {
    self().template solve_columns<C>(x, tasks, [](int) {}, [] {}, [](int) {});
  }

  int blocks() const { return n_; }
  // The matrix, filled by the caller before the factorization.
  Mat& diag(int l) { return d_[l]; }
  Mat& sub(int l) { return s_[l]; }
  Mat& super(int l) { return p_[l]; }

  // Di = D^-1 by Gauss-Jordan elimination in place with partial pivoting (row swaps, undone
  // as column swaps at the end), column by column so that every update is a contiguous
  // axpy of B entries: faster than Eigen's PartialPivLU(D).inverse() on 21 x 21 blocks,
  // whose blocked triangular solves are built for large matrices (block_lu_bench's
  // BM_PivotInverse), with the same residual |D Di - I| (1.4e-15 against 1.2e-15 on a
  // diagonally dominant block). False if D is singular or Di not finite.
  static bool invert(const Mat& D, Mat& Di) {
    Di = D;
    double* a = Di.data();
    int pivot[B];
    for (int k = 0; k < B; ++k) {
      double* ck = a + B * k;
      int p = k;
      double best = std::abs(ck[k]);
      for (int r = k + 1; r < B; ++r)
        if (std::abs(ck[r]) > best) best = std::abs(ck[r]), p = r;
      if (!(best > 0)) return false;
      pivot[k] = p;
      if (p != k)
        for (int j = 0; j < B; ++j) std::swap(a[B * j + k], a[B * j + p]);
      const double d = 1.0 / ck[k];
      for (int i = 0; i < B; ++i) ck[i] *= -d;
      ck[k] = d;
      for (int j = 0; j < B; ++j) {
        if (j == k) continue;
        double* cj = a + B * j;
        const double s = cj[k];
        if (s == 0) continue;
        for (int i = 0; i < B; ++i) cj[i] += s * ck[i];
        cj[k] = s * d;
      }
    }
    for (int k = B - 1; k >= 0; --k)
      if (pivot[k] != k)
        for (int i = 0; i < B; ++i) std::swap(a[B * k + i], a[B * pivot[k] + i]);
    return Di.allFinite();
  }

 protected:
  const Derived& self() const { return static_cast<const Derived&>(*this); }
  // What a sweep leaves: its pivot update of the block it stops at (dm), that of the outer
  // block (dl), and the fill that reached the stop, col = M(stop, outer), row = M(outer, stop).
  struct Fill {
    bool ok = true;
    int fills = 0;
    Mat dm = Mat::Zero(), dl = Mat::Zero(), col = Mat::Zero(), row = Mat::Zero();
  };
  void resize_blocks(int n) {
    n_ = n;
    for (auto* v : {&d_, &s_, &p_, &inv_, &lrow_, &ucol_}) v->resize(n);
    fill_.assign(n, 1);
  }
  // M(r, c) of two neighbours on the ring.
  const Mat& block(int r, int c) const { return r == (c + 1 == n_ ? 0 : c + 1) ? s_[r] : p_[c]; }
  // The sweep's elimination, from the fill (col, row) = (M(at(0), outer), M(outer, at(0)));
  // its multipliers M(at(i+1), at(i)) D^-1 go to mult[at(i+1)].
  template <class At>
  void sweep(int count, const At& at, Mats& mult, Mat col, Mat row, Fill& sw) {
    bool fill = true;
    for (int i = 0; i < count; ++i) {
      const int l = at(i), nb = at(i + 1);
      const bool stop = i + 1 == count;
      if (!invert(d_[l], inv_[l])) {
        sw.ok = false;
        return;
      }
      const Mat& Pi = inv_[l];
      fill_[l] = fill;
      if (fill) {
        ++sw.fills;
        ucol_[l] = col;
        lrow_[l].noalias() = row * Pi;
        sw.dl.noalias() -= lrow_[l] * col;
      }
      mult[nb].noalias() = block(nb, l) * Pi;
      (!stop ? d_[nb] : sw.dm).noalias() -= mult[nb] * block(l, nb);
      if (fill) {
        col = -mult[nb] * col;
        row = -lrow_[l] * block(l, nb);
        if (!stop) fill = above(col, row, d_[nb]);
      }
    }
    if (fill) sw.col = col, sw.row = row;
  }
  // The sweep's part of L y = b (one right side or several): its blocks in elimination order,
  // the multiplier into the stop block (xm) and the fill's couplings into the outer one,
  // added to xl.
  template <class V, class At>
  void sweep_forward(V* x, int count, const At& at, const Mats& mult, V& xm, V& xl) const {
    if (count == 0) return;
    for (int i = 1; i < count; ++i) sub_times(mult[at(i)], x[at(i - 1)], x[at(i)]);
    times(mult[at(count)], x[at(count - 1)], xm);
    V t;
    for (int i = 0; i < count; ++i)
      if (fill_[at(i)]) {
        times(lrow_[at(i)], x[at(i)], t);
        xl += t;
      }
  }
  // Its part of U x = y, from the stop block back to at(0), with the outer block's x[outer].
  template <class V, class At>
  void sweep_backward(V* x, int count, const At& at, int outer) const {
    V u;
    for (int i = count - 1; i >= 0; --i) {
      const int l = at(i), nb = at(i + 1);
      u = x[l];
      if (fill_[l]) sub_times(ucol_[l], x[outer], u);
      sub_times(block(l, nb), x[nb], u);
      times(inv_[l], u, x[l]);
    }
  }
  // t = A v and y -= A v, for one right side or several.
  static void times(const Mat& A, const Vec& v, Vec& t) { block_times<B>(A, v, t); }
  template <int C>
  static void times(const Mat& A, const Eigen::Matrix<double, B, C>& v, Eigen::Matrix<double, B, C>& t) {
    block_times_columns<B, C>(A, v, t);
  }
  static void sub_times(const Mat& A, const Vec& v, Vec& y) { block_subtract<B>(A, v, y); }
  template <int C>
  static void sub_times(const Mat& A, const Eigen::Matrix<double, B, C>& v, Eigen::Matrix<double, B, C>& y) {
    block_subtract_columns<B, C>(A, v, y);
  }
  // Whether a fill (col, row) still matters next to the pivot block D.
  bool above(const Mat& col, const Mat& row, const Mat& D) const {
    const double scale = drop_ * D.cwiseAbs().maxCoeff();
    return col.cwiseAbs().maxCoeff() > scale || row.cwiseAbs().maxCoeff() > scale;
  }

  int n_ = 0;
  double drop_ = 1e-30;
  std::vector<char> fill_;
  // lrow_ / ucol_: the fill's couplings of each swept block to its sweep's outer block.
  Mats d_, s_, p_, inv_, lrow_, ucol_;
};

template <int B>
class CyclicBlockLU : public BlockSweeps<B, CyclicBlockLU<B>> {
  using Base = BlockSweeps<B, CyclicBlockLU<B>>;
  using typename Base::Fill;
  using Base::n_;
  using Base::d_;
  using Base::s_;
  using Base::p_;
  using Base::inv_;
  using Base::lrow_;
  using Base::ucol_;

 public:
  using Base::invert;
  using Base::solve;
  using Base::solve_columns;
  using Mat = typename Base::Mat;
  using Vec = typename Base::Vec;

  // Runs two independent tasks; the default one after the other. A caller with threads passes
  // one that runs them concurrently (tbb::parallel_invoke): the arithmetic, and so every bit
  // of the result, is the same either way.
  struct Sequential {
    template <class F, class G>
    void operator()(const F& f, const G& g) const {
      f();
      g();
    }
  };

  void resize(int n) {
    this->resize_blocks(n);
    lsub_.resize(n), lsup_.resize(n);
  }
  // Block rows of the last factorization that carry a coupling to the last block (the
  // corners' fill, the band's own coupling and what it fills; all n - 1 without the decay,
  // see factor()).
  int fill_blocks() const { return fills_; }
  // The fill below this fraction of the next pivot block is dropped (see factor()). The
  // default changes M by far less than its own rounding; a caller whose matrix is an
  // approximation anyway (a W-method's) may drop more: the factors are then the exact LU of
  // M + E with |E| below tolerance * |pivot block|, the same matrix for every solve.
  static constexpr double kNegligible = 1e-30;
  void set_drop_tolerance(double tol) { this->drop_ = tol; }

  // Factorizes; false if a pivot block is singular (or not finite). Overwrites the diagonal
  // blocks. Needs n >= 3.
  //
  // The last block n-1 closes the ring; without it the blocks 0 .. n-2 form a chain whose
  // two ends couple to it (block 0 through the corners, block n-2 through the band). The
  // chain is eliminated from both ends at once towards its middle m = (n-1)/2: the top sweep
  // takes 0 .. m-1 downwards, the bottom sweep n-2 .. m+1 upwards, two independent tasks
  // (`both`); then m, then n-1. Each sweep fills the coupling of its next block to n-1, and
  // that fill decays along the chain (by about 1e-4 per link for ROS2's matrix): once it is
  // below the drop tolerance of the next pivot block it is dropped. By default (kNegligible)
  // that changes M by less than its own rounding, and keeps most links at three blocks.
  bool factor() { return factor(Sequential()); }
  template <class Both>
  bool factor(const Both& both) {
    const int n = n_, last = n - 1, m = (n - 1) / 2;
    Fill top, bottom;
    // The top sweep starts from the corners, the bottom one from the band's coupling.
    both([&] { this->sweep(m, top_at(), lsub_, s_[0], p_[0], top); },
         [&] { this->sweep(n - 2 - m, bottom_at(), lsup_, p_[last], s_[last], bottom); });
    if (!top.ok || !bottom.ok) return false;
    // The middle block, then the last, in a fixed order.
    d_[m] += top.dm;
    d_[m] += bottom.dm;
    if (!invert(d_[m], inv_[m])) return false;
    this->fill_[m] = 1;
    ucol_[m] = top.col + bottom.col;
    lrow_[m].noalias() = (top.row + bottom.row) * inv_[m];
    d_[last] += top.dl;
    d_[last] += bottom.dl;
    d_[last].noalias() -= lrow_[m] * ucol_[m];
    fills_ = top.fills + bottom.fills + 1;
    return invert(d_[last], inv_[last]);
  }

  // Solves M x = b in place (x[l]: block l), the two halves as two tasks (`both`; the
  // shorter forms: BlockSweeps), with the caller's work per block fused into the two tasks
  // (no extra fork and join): prepare(l) writes b_l into x[l] just before the task's sweep
  // (blocks 0 .. m on the top task, m+1 .. n-1 on the bottom one, m = (n-1)/2); finish(l)
  // reads the solution x[l] after it (the same split); then once serial(), then last(l) for
  // every block (the same split into halves): a caller's step that needs the whole solution
  // (a bordered system's Schur complement) and its per-block completion, all within the one
  // fork and join (TwoTaskPhases). Each block's prepare, finish and last run once, on one task.
  template <class Both, class Prepare, class Finish, class Serial, class Last>
  void solve(Vec* x, const Both& both, const Prepare& prepare, const Finish& finish, const Serial& serial,
             const Last& last) const {
    const int n = n_, lastb = n - 1, m = (n - 1) / 2;
    // L y = b (unit block-lower: the multipliers), each sweep in its elimination order.
    Vec xm_top = Vec::Zero(), xm_bot = Vec::Zero(), xl_top = Vec::Zero(), xl_bot = Vec::Zero();
    in_phases(
        both, prepare,
        [&](int half) {
          if (half == 0) this->sweep_forward(x, m, top_at(), lsub_, xm_top, xl_top);
          else this->sweep_forward(x, n - 2 - m, bottom_at(), lsup_, xm_bot, xl_bot);
        },
        [&] {
          x[m] -= xm_top;
          x[m] -= xm_bot;
          x[lastb] -= xl_top;
          x[lastb] -= xl_bot;
          block_subtract(lrow_[m], x[m], x[lastb]);
          // U x = y: the last block, the middle, then both halves outwards.
          Vec t = x[lastb];
          block_times(inv_[lastb], t, x[lastb]);
          t = x[m];
          block_subtract(ucol_[m], x[lastb], t);
          block_times(inv_[m], t, x[m]);
        },
        [&](int half) {
          if (half == 0) this->sweep_backward(x, m, top_at(), lastb);
          else this->sweep_backward(x, n - 2 - m, bottom_at(), lastb);
        },
        finish, serial, last);
  }

  // Solves M X = B for a block of right sides in place (X[l]: block l's rows, B x C), the
  // two halves as two tasks: the steps of solve() as block products, with the caller's
  // per-block finish(l) after the backward sweep, then once serial(), then last(l) for every
  // block, all within one fork and join as in solve().
  template <int C, class Both, class Finish, class Serial, class Last>
  void solve_columns(Eigen::Matrix<double, B, C>* x, const Both& both, const Finish& finish, const Serial& serial,
                     const Last& last) const {
    using Cols = Eigen::Matrix<double, B, C>;
    const int n = n_, lastb = n - 1, m = (n - 1) / 2;
    Cols xm_top = Cols::Zero(), xm_bot = Cols::Zero(), xl_top = Cols::Zero(), xl_bot = Cols::Zero();
    in_phases(
        both, [](int) {},
        [&](int half) {
          if (half == 0) this->sweep_forward(x, m, top_at(), lsub_, xm_top, xl_top);
          else this->sweep_forward(x, n - 2 - m, bottom_at(), lsup_, xm_bot, xl_bot);
        },
        [&] {
          x[m] -= xm_top;
          x[m] -= xm_bot;
          x[lastb] -= xl_top;
          x[lastb] -= xl_bot;
          block_subtract_columns<B, C>(lrow_[m], x[m], x[lastb]);
          Cols t = x[lastb];
          block_times_columns<B, C>(inv_[lastb], t, x[lastb]);
          t = x[m];
          block_subtract_columns<B, C>(ucol_[m], x[lastb], t);
          block_times_columns<B, C>(inv_[m], t, x[m]);
        },
        [&](int half) {
          if (half == 0) this->sweep_backward(x, m, top_at(), lastb);
          else this->sweep_backward(x, n - 2 - m, bottom_at(), lastb);
        },
        finish, serial, last);
  }

 private:
  // A solve's phases in one fork and join (TwoTaskPhases), the blocks split into the top half
  // 0 .. m and the bottom half m+1 .. n-1 (m = (n-1)/2): each half's prepare(l) and forward
  // sweep forward(half), the middle, each half's backward sweep backward(half) and finish(l),
  // serial(), each half's last(l).
  template <class Both, class Prepare, class Forward, class Middle, class Backward, class Finish, class Serial,
            class Last>
  void in_phases(const Both& both, const Prepare& prepare, const Forward& forward, const Middle& middle,
                 const Backward& backward, const Finish& finish, const Serial& serial, const Last& last) const {
    const int n = n_, m = (n - 1) / 2;
    const auto each = [m, n](int half, const auto& f) {
      for (int l = half == 0 ? 0 : m + 1; l < (half == 0 ? m + 1 : n); ++l) f(l);
    };
    TwoTaskPhases ph;
    const auto task = [&](int side) {
      ph.two(
          0, side, [&] { each(0, prepare), forward(0); }, [&] { each(1, prepare), forward(1); });
      ph.one(2, middle);
      ph.two(
          3, side, [&] { backward(0), each(0, finish); }, [&] { backward(1), each(1, finish); });
      ph.one(5, serial);
      ph.two(
          6, side, [&] { each(0, last); }, [&] { each(1, last); });
    };
    both([&] { task(0); }, [&] { task(1); });
  }

  // The sweeps' blocks: the top one's 0, 1, .. m (m = (n-1)/2), the bottom one's n-2, n-3, .. m.
  static auto top_at() {
    return [](int i) { return i; };
  }
  auto bottom_at() const {
    return [n = n_](int i) { return n - 2 - i; };
  }

  int fills_ = 0;
  // lsub_[l] = M(l, l-1) D_{l-1}^-1 (top sweep, l = 1 .. m); lsup_[l] = M(l, l+1) D_{l+1}^-1
  // (bottom sweep, l = m .. n-3); the base's lrow_ / ucol_: the couplings to the last block.
  typename Base::Mats lsub_, lsup_;
};

}  // namespace cvt
