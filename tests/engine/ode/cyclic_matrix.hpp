// A random matrix with the W matrix's structure for the block LU tests: block-tridiagonal
// with cyclic corners, not symmetric.
#pragma once

#include <Eigen/Dense>
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <random>
#include <vector>

namespace cvt {

// M = D + sum over l of G_l^T H_l, each G_l, H_l over blocks l-1 and l, D diagonal and
// positive (diagonal + |u|); the couplings scale with `coupling`.
inline Eigen::MatrixXd random_cyclic_matrix(int n, int B, unsigned seed, double coupling, double diagonal) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  const int N = n * B;
  Eigen::MatrixXd M = Eigen::MatrixXd::Zero(N, N);
  for (int i = 0; i < N; ++i) M(i, i) = diagonal + std::abs(u(rng));
  for (int l = 0; l < n; ++l) {
    Eigen::MatrixXd G(3, 2 * B), H(3, 2 * B);
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 2 * B; ++c) G(r, c) = coupling * u(rng), H(r, c) = G(r, c) + 0.2 * coupling * u(rng);
    const Eigen::MatrixXd K = G.transpose() * H;
    const int o[2] = {((l - 1 + n) % n) * B, l * B};
    for (int a = 0; a < 2; ++a)
      for (int b = 0; b < 2; ++b) M.block(o[a], o[b], B, B) += K.block(a * B, b * B, B, B);
  }
  return M;
}

// Its blocks into an LU of the CyclicBlockLU interface (diag, sub, super).
template <class LU>
void load_cyclic_blocks(const Eigen::MatrixXd& M, int n, int B, LU& lu) {
  for (int l = 0; l < n; ++l) {
    lu.diag(l) = M.block(l * B, l * B, B, B);
    lu.sub(l) = M.block(l * B, ((l - 1 + n) % n) * B, B, B);
    lu.super(l) = M.block(((l - 1 + n) % n) * B, l * B, B, B);
  }
}

// The solve with a serial and a last phase (a bordered system's step), on the LU's tasks
// (`tasks`: its runner, two tasks or several): every block's prepare, finish and last run
// once, serial once after every finish and before every last, and the result is that of the
// one-task solve (x0), to the bit, whichever task runs which phase.
template <class LU, class Vecs, class Tasks>
void check_solve_phases(const LU& lu, const Eigen::VectorXd& b, const Vecs& x0, const Tasks& tasks, const char* name) {
  const int n = static_cast<int>(x0.size());
  constexpr int B = LU::Vec::RowsAtCompileTime;
  Vecs y(n);
  std::vector<std::atomic<int>> prepared(n), finished(n), lasted(n);
  std::atomic<int> serial_runs{0};
  double total = 0;
  lu.solve(
      y.data(), tasks,
      [&](int l) {
        y[l] = b.segment(l * B, B);
        ++prepared[l];
      },
      [&](int l) { ++finished[l]; },
      [&] {
        ++serial_runs;
        for (int l = 0; l < n; ++l) {
          EXPECT_EQ(finished[l].load(), 1) << name << ": block " << l << " not finished before the serial phase";
          total += y[l].sum();
        }
      },
      [&](int l) {
        EXPECT_EQ(serial_runs.load(), 1) << name;
        y[l].array() += total;
        ++lasted[l];
      });
  EXPECT_EQ(serial_runs.load(), 1) << name;
  double total0 = 0;
  for (int l = 0; l < n; ++l) total0 += x0[l].sum();
  EXPECT_EQ(total, total0) << name;
  for (int l = 0; l < n; ++l) {
    EXPECT_EQ(prepared[l].load(), 1) << name << " block " << l;
    EXPECT_EQ(lasted[l].load(), 1) << name << " block " << l;
    typename LU::Vec want = x0[l];
    want.array() += total0;
    EXPECT_TRUE(y[l] == want) << name << ": block " << l << " differs from the one-task solve";
  }
}

}  // namespace cvt
