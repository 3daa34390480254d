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

template <int B>
class CyclicBlockLU {
 public:
  using Mat = Eigen::Matrix<double, B, B>;
  using Vec = Eigen::Matrix<double, B, 1>;

  void resize(int n) {
    n_ = n;
    for (auto* v : {&d_, &s_, &p_, &inv_, &lsub_, &lrow_, &ucol_}) v->resize(n);
    fill_.assign(n, 1);
  }
  // Block rows of the last factorization that carry the corners' fill (all n - 1 without the
  // decay; see factor()).
  int fill_blocks() const { return fills_; }
  static constexpr double kNegligible = 1e-30;
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
        lrow_[l].noalias() = row * Pi;
        d_[n - 1].noalias() -= lrow_[l] * col;
      }
      if (l + 2 < n) {
        lsub_[l + 1].noalias() = s_[l + 1] * Pi;
        d_[l + 1].noalias() -= lsub_[l + 1] * p_[l + 1];
        const bool last = l + 2 == n - 1;  // row / column l+1 meet the band there
        if (fill || last) {
          Mat next_col = last ? p_[n - 1] : Mat::Zero();
          Mat next_row = last ? s_[n - 1] : Mat::Zero();
          if (fill) {
            next_col.noalias() -= lsub_[l + 1] * col;
            next_row.noalias() -= lrow_[l] * p_[l + 1];
          }
          col = next_col;
          row = next_row;
          const double scale = kNegligible * d_[l + 1].cwiseAbs().maxCoeff();
          fill = last || col.cwiseAbs().maxCoeff() > scale || row.cwiseAbs().maxCoeff() > scale;
        }
      }
    }
    return invert(d_[n - 1], inv_[n - 1]);
  }

  // Solves M x = b in place (x[l]: block l).
  void solve(Vec* x) const {
    const int n = n_;
    Vec t;
    // L y = b (unit block-lower: the multipliers).
    for (int l = 1; l + 1 < n; ++l) x[l].noalias() -= lsub_[l] * x[l - 1];
    for (int l = 0; l + 1 < n; ++l)
      if (fill_[l]) x[n - 1].noalias() -= lrow_[l] * x[l];
    // U x = y.
    x[n - 1] = inv_[n - 1] * x[n - 1];
    for (int l = n - 2; l >= 0; --l) {
      t = x[l];
      if (fill_[l]) t.noalias() -= ucol_[l] * x[n - 1];
      if (l + 2 < n) t.noalias() -= p_[l + 1] * x[l + 1];
      x[l].noalias() = inv_[l] * t;
    }
  }

 private:
  static bool invert(const Mat& D, Mat& Di) {
    const Eigen::PartialPivLU<Mat> lu(D);
    Di = lu.inverse();
    return Di.allFinite();
  }

  int n_ = 0;
  int fills_ = 0;
  std::vector<char> fill_;
  std::vector<Mat, Eigen::aligned_allocator<Mat>> d_, s_, p_, inv_, lsub_, lrow_, ucol_;
};

}  // namespace cvt
