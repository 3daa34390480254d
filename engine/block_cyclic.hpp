// LU factorization of a block-tridiagonal matrix with cyclic corners (docs/integrators.md
// 12.6): n diagonal blocks D_l, sub-diagonal blocks S_l = M(l, l-1 mod n) and
// super-diagonal blocks P_l = M(l-1 mod n, l), all B x B, so S_0 = M(0, n-1) and
// P_0 = M(n-1, 0) are the corners. This is the structure of ROS2's matrix for the chain in
// link order (each force couples at most two neighbouring links).
//
// Block Gaussian elimination in the natural order without pivoting between blocks (the
// matrix is dominated by its diagonal blocks: mass plus damping; each pivot block is inverted
// with partial pivoting). The corners fill the last block row and column and nothing else.
// The factor keeps the inverses of the pivot blocks, so that the solves are matrix-vector
// products (independent updates) rather than substitutions. Factorization ~ 9 B^3 n flops,
// a solve ~ 10 B^2 n.
#pragma once

#include <Eigen/Dense>
#include <cmath>
#include <vector>

namespace cvt {

// Products of small fixed-size blocks as column sweeps (y += a_k x_k): Eigen sends a 21 x 21
// product to its general GEMV / GEMM kernels (run-time sizes, packing), which cost more than
// the arithmetic at this size (block_lu_bench).
namespace small {
template <class M, class V, class X>
inline void mv_sub(V& y, const M& a, const X& x) {  // y -= a x
  for (int k = 0; k < a.cols(); ++k) y -= a.col(k).template cast<double>() * x[k];
}
template <class M, class V, class X>
inline void mv(V& y, const M& a, const X& x) {  // y = a x
  y = a.col(0).template cast<double>() * x[0];
  for (int k = 1; k < a.cols(); ++k) y += a.col(k).template cast<double>() * x[k];
}
template <class C, class M, class N>
inline void mm_sub(C& c, const M& a, const N& b) {  // c -= a b
  for (int j = 0; j < b.cols(); ++j) {
    auto cj = c.col(j);
    for (int k = 0; k < a.cols(); ++k) cj -= a.col(k) * b(k, j);
  }
}
template <class C, class M, class N>
inline void mm(C& c, const M& a, const N& b) {  // c = a b
  for (int j = 0; j < b.cols(); ++j) {
    auto cj = c.col(j);
    cj = a.col(0) * b(0, j);
    for (int k = 1; k < a.cols(); ++k) cj += a.col(k) * b(k, j);
  }
}
}  // namespace small

template <int B>
class CyclicBlockLU {
 public:
  using Mat = Eigen::Matrix<double, B, B>;
  using Vec = Eigen::Matrix<double, B, 1>;

  using MatF = Eigen::Matrix<float, B, B>;

  void resize(int n) {
    n_ = n;
    for (auto* v : {&d_, &s_, &p_, &inv_, &lsub_, &lrow_, &ucol_}) v->resize(n);
    fill_.assign(n, 1);
  }
  // Block rows of the last factorization that carry the corners' fill (all n - 1 without the
  // decay; see factor()).
  int fill_blocks() const { return fills_; }
  static constexpr double kNegligible = 1e-30;
  // Compact: after factor(), keep the factors the solves read in single precision (the solve
  // still computes in double). The solve is then exact, to double rounding, for the matrix
  // these rounded factors make, which differs from M by about 1e-7 relative: a matrix of its
  // own, as good for a W-method as any (docs/integrators.md 12.8), and the solves read half
  // the bytes (they run from the cache's far levels: the factors are 1.5 MB for the chain).
  void set_compact(bool on) { compact_ = on; }
  bool compact() const { return compact_; }
  int blocks() const { return n_; }
  // The matrix, filled by the caller before factor().
  Mat& diag(int l) { return d_[l]; }
  Mat& sub(int l) { return s_[l]; }
  Mat& super(int l) { return p_[l]; }

  // Factorizes; false if a pivot block is singular (or not finite). Overwrites the diagonal
  // blocks. Needs n >= 3.
  bool factor() {
    const int n = n_;
    Mat row = p_[0];  // M(n-1, l) (at first the corner M(n-1, 0)), updated, for the l being eliminated
    Mat col = s_[0];  // M(l, n-1) (at first the corner M(0, n-1)), updated
    // The corners' fill decays along the chain (by about 1e-4 per link for ROS2's matrix):
    // once both the fill row and column are below kNegligible of the next pivot block they are
    // dropped, and come back only where the band meets the last block row and column. That
    // changes M by less than its own rounding, and keeps most links at three blocks.
    bool fill = true;
    fills_ = 0;
    for (int l = 0; l + 1 < n; ++l) {
      if (!invert(d_[l], inv_[l])) return false;
      const Mat& Pi = inv_[l];
      fill_[l] = fill;
      if (fill) {
        ++fills_;
        ucol_[l] = col;
        small::mm(lrow_[l], row, Pi);
        small::mm_sub(d_[n - 1], lrow_[l], col);
      }
      if (l + 2 < n) {
        small::mm(lsub_[l + 1], s_[l + 1], Pi);
        small::mm_sub(d_[l + 1], lsub_[l + 1], p_[l + 1]);
        const bool last = l + 2 == n - 1;  // row / column l+1 meet the band there
        if (fill || last) {
          Mat next_col = last ? p_[n - 1] : Mat::Zero();
          Mat next_row = last ? s_[n - 1] : Mat::Zero();
          if (fill) {
            small::mm_sub(next_col, lsub_[l + 1], col);
            small::mm_sub(next_row, lrow_[l], p_[l + 1]);
          }
          col = next_col;
          row = next_row;
          const double scale = kNegligible * d_[l + 1].cwiseAbs().maxCoeff();
          fill = last || col.cwiseAbs().maxCoeff() > scale || row.cwiseAbs().maxCoeff() > scale;
        }
      }
    }
    if (!invert(d_[n - 1], inv_[n - 1])) return false;
    if (compact_) {
      for (auto* v : {&fsub_, &frow_, &finv_, &fcol_, &fp_}) v->resize(n);
      for (int l = 0; l < n; ++l) {
        fsub_[l] = lsub_[l].template cast<float>(), frow_[l] = lrow_[l].template cast<float>();
        finv_[l] = inv_[l].template cast<float>(), fcol_[l] = ucol_[l].template cast<float>();
        fp_[l] = p_[l].template cast<float>();
      }
    }
    return true;
  }

  // Solves M x = b in place (x[l]: block l).
  void solve(Vec* x) const {
    if (compact_)
      solve_with(x, fsub_, frow_, finv_, fcol_, fp_);
    else
      solve_with(x, lsub_, lrow_, inv_, ucol_, p_);
  }

 private:
  template <class Blocks>
  void solve_with(Vec* x, const Blocks& lsub, const Blocks& lrow, const Blocks& inv, const Blocks& ucol,
                  const Blocks& p) const {
    const int n = n_;
    Vec t;
    // L y = b (unit block-lower: the multipliers).
    for (int l = 1; l + 1 < n; ++l) small::mv_sub(x[l], lsub[l], x[l - 1]);
    for (int l = 0; l + 1 < n; ++l)
      if (fill_[l]) small::mv_sub(x[n - 1], lrow[l], x[l]);
    // U x = y.
    t = x[n - 1];
    small::mv(x[n - 1], inv[n - 1], t);
    for (int l = n - 2; l >= 0; --l) {
      t = x[l];
      if (fill_[l]) small::mv_sub(t, ucol[l], x[n - 1]);
      if (l + 2 < n) small::mv_sub(t, p[l + 1], x[l + 1]);
      small::mv(x[l], inv[l], t);
    }
  }

  static bool invert(const Mat& D, Mat& Di) {
    const Eigen::PartialPivLU<Mat> lu(D);
    Di = lu.inverse();
    return Di.allFinite();
  }

  int n_ = 0;
  bool compact_ = false;
  int fills_ = 0;
  std::vector<char> fill_;
  std::vector<Mat, Eigen::aligned_allocator<Mat>> d_, s_, p_, inv_, lsub_, lrow_, ucol_;
  std::vector<MatF, Eigen::aligned_allocator<MatF>> fsub_, frow_, finv_, fcol_, fp_;
};

}  // namespace cvt
