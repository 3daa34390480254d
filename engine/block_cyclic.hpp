// LU factorization of a block-tridiagonal matrix with cyclic corners (docs/integrators.md
// 12.6): n diagonal blocks D_l, sub-diagonal blocks S_l = M(l, l-1 mod n) and
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
#include <cmath>
#include <vector>

namespace cvt {

template <int B>
class CyclicBlockLU {
 public:
  using Mat = Eigen::Matrix<double, B, B>;
  using Vec = Eigen::Matrix<double, B, 1>;

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
    n_ = n;
    for (auto* v : {&d_, &s_, &p_, &inv_, &lsub_, &lsup_, &lrow_, &ucol_}) v->resize(n);
    fill_.assign(n, 1);
  }
  // Block rows of the last factorization that carry a coupling to the last block (the
  // corners' fill, the band's own coupling and what it fills; all n - 1 without the decay,
  // see factor()).
  int fill_blocks() const { return fills_; }
  static constexpr double kNegligible = 1e-30;
  int blocks() const { return n_; }
  // The matrix, filled by the caller before factor().
  Mat& diag(int l) { return d_[l]; }
  Mat& sub(int l) { return s_[l]; }
  Mat& super(int l) { return p_[l]; }

  // Factorizes; false if a pivot block is singular (or not finite). Overwrites the diagonal
  // blocks. Needs n >= 3.
  //
  // The last block n-1 closes the ring; without it the blocks 0 .. n-2 form a chain whose
  // two ends couple to it (block 0 through the corners, block n-2 through the band). The
  // chain is eliminated from both ends at once towards its middle m = (n-1)/2: the top sweep
  // takes 0 .. m-1 downwards, the bottom sweep n-2 .. m+1 upwards, two independent tasks
  // (`both`); then m, then n-1. Each sweep fills the coupling of its next block to n-1, and
  // that fill decays along the chain (by about 1e-4 per link for ROS2's matrix): once it is
  // below kNegligible of the next pivot block it is dropped. That changes M by less than its
  // own rounding, and keeps most links at three blocks.
  bool factor() { return factor(Sequential()); }
  template <class Both>
  bool factor(const Both& both) {
    const int n = n_, last = n - 1, m = (n - 1) / 2;
    bool ok_top = true, ok_bot = true;
    int fills_top = 0, fills_bot = 0;
    auto top = [&] {
      Mat col = s_[0], row = p_[0];  // M(l, last), M(last, l) of the block l being eliminated
      dl_top_.setZero(), dm_top_.setZero();
      bool fill = true;
      for (int l = 0; l < m; ++l) {
        if (!invert(d_[l], inv_[l])) {
          ok_top = false;
          return;
        }
        const Mat& Pi = inv_[l];
        fill_[l] = fill;
        if (fill) {
          ++fills_top;
          ucol_[l] = col;
          lrow_[l].noalias() = row * Pi;
          dl_top_.noalias() -= lrow_[l] * col;
        }
        lsub_[l + 1].noalias() = s_[l + 1] * Pi;
        (l + 1 < m ? d_[l + 1] : dm_top_).noalias() -= lsub_[l + 1] * p_[l + 1];
        if (fill) {
          col = -lsub_[l + 1] * col;
          row = -lrow_[l] * p_[l + 1];
          if (l + 1 < m) fill = above(col, row, d_[l + 1]);
        }
      }
      col_top_ = fill ? col : Mat::Zero();
      row_top_ = fill ? row : Mat::Zero();
    };
    auto bottom = [&] {
      Mat col = p_[last], row = s_[last];  // M(n-2, last), M(last, n-2): the band
      dl_bot_.setZero(), dm_bot_.setZero();
      bool fill = true;
      for (int l = n - 2; l > m; --l) {
        if (!invert(d_[l], inv_[l])) {
          ok_bot = false;
          return;
        }
        const Mat& Pi = inv_[l];
        fill_[l] = fill;
        if (fill) {
          ++fills_bot;
          ucol_[l] = col;
          lrow_[l].noalias() = row * Pi;
          dl_bot_.noalias() -= lrow_[l] * col;
        }
        lsup_[l - 1].noalias() = p_[l] * Pi;
        (l - 1 > m ? d_[l - 1] : dm_bot_).noalias() -= lsup_[l - 1] * s_[l];
        if (fill) {
          col = -lsup_[l - 1] * col;
          row = -lrow_[l] * s_[l];
          if (l - 1 > m) fill = above(col, row, d_[l - 1]);
        }
      }
      col_bot_ = fill ? col : Mat::Zero();
      row_bot_ = fill ? row : Mat::Zero();
    };
    both(top, bottom);
    if (!ok_top || !ok_bot) return false;
    // The middle block, then the last, in a fixed order.
    d_[m] += dm_top_;
    d_[m] += dm_bot_;
    if (!invert(d_[m], inv_[m])) return false;
    fill_[m] = 1;
    ucol_[m] = col_top_ + col_bot_;
    lrow_[m].noalias() = (row_top_ + row_bot_) * inv_[m];
    d_[last] += dl_top_;
    d_[last] += dl_bot_;
    d_[last].noalias() -= lrow_[m] * ucol_[m];
    fills_ = fills_top + fills_bot + 1;
    return invert(d_[last], inv_[last]);
  }

  // Solves M x = b in place (x[l]: block l), the two halves as two tasks (`both`).
  void solve(Vec* x) const { solve(x, Sequential()); }
  template <class Both>
  void solve(Vec* x, const Both& both) const {
    const int n = n_, last = n - 1, m = (n - 1) / 2;
    Vec xm_top = Vec::Zero(), xm_bot = Vec::Zero(), xl_top = Vec::Zero(), xl_bot = Vec::Zero();
    // L y = b (unit block-lower: the multipliers), each sweep in its elimination order.
    both(
        [&] {
          for (int l = 1; l < m; ++l) x[l].noalias() -= lsub_[l] * x[l - 1];
          if (m >= 1) xm_top.noalias() = lsub_[m] * x[m - 1];
          for (int l = 0; l < m; ++l)
            if (fill_[l]) xl_top.noalias() += lrow_[l] * x[l];
        },
        [&] {
          for (int l = n - 3; l > m; --l) x[l].noalias() -= lsup_[l] * x[l + 1];
          if (m + 1 <= n - 2) xm_bot.noalias() = lsup_[m] * x[m + 1];
          for (int l = n - 2; l > m; --l)
            if (fill_[l]) xl_bot.noalias() += lrow_[l] * x[l];
        });
    x[m] -= xm_top;
    x[m] -= xm_bot;
    x[last] -= xl_top;
    x[last] -= xl_bot;
    x[last].noalias() -= lrow_[m] * x[m];
    // U x = y: the last block, the middle, then both halves outwards.
    x[last] = inv_[last] * x[last];
    Vec t = x[m];
    t.noalias() -= ucol_[m] * x[last];
    x[m].noalias() = inv_[m] * t;
    both(
        [&] {
          Vec u;
          for (int l = m - 1; l >= 0; --l) {
            u = x[l];
            if (fill_[l]) u.noalias() -= ucol_[l] * x[last];
            u.noalias() -= p_[l + 1] * x[l + 1];
            x[l].noalias() = inv_[l] * u;
          }
        },
        [&] {
          Vec u;
          for (int l = m + 1; l <= n - 2; ++l) {
            u = x[l];
            if (fill_[l]) u.noalias() -= ucol_[l] * x[last];
            u.noalias() -= s_[l] * x[l - 1];
            x[l].noalias() = inv_[l] * u;
          }
        });
  }

 private:
  static bool invert(const Mat& D, Mat& Di) {
    const Eigen::PartialPivLU<Mat> lu(D);
    Di = lu.inverse();
    return Di.allFinite();
  }
  // Whether a fill (col, row) still matters next to the pivot block D.
  static bool above(const Mat& col, const Mat& row, const Mat& D) {
    const double scale = kNegligible * D.cwiseAbs().maxCoeff();
    return col.cwiseAbs().maxCoeff() > scale || row.cwiseAbs().maxCoeff() > scale;
  }

  int n_ = 0;
  int fills_ = 0;
  std::vector<char> fill_;
  // lsub_[l] = M(l, l-1) D_{l-1}^-1 (top sweep, l = 1 .. m); lsup_[l] = M(l, l+1) D_{l+1}^-1
  // (bottom sweep, l = m .. n-3); lrow_ / ucol_: the couplings to the last block.
  std::vector<Mat, Eigen::aligned_allocator<Mat>> d_, s_, p_, inv_, lsub_, lsup_, lrow_, ucol_;
  // The sweeps' contributions to the middle and last pivot blocks and the middle's coupling
  // to the last block, summed in a fixed order after both.
  Mat dm_top_, dm_bot_, dl_top_, dl_bot_, col_top_, row_top_, col_bot_, row_bot_;
};

}  // namespace cvt
