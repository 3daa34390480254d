// CyclicBlockLU against a dense LU of the same matrix.
#include "engine/ode/block_cyclic.hpp"
#include "tests/engine/ode/cyclic_matrix.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <thread>

namespace cvt {
namespace {

// The two tasks on two threads at once, and the second task first and alone (it then runs
// every phase: TwoTaskPhases).
struct OnTwoThreads {
  template <class F, class G>
  void operator()(const F& f, const G& g) const {
    std::thread t(f);
    g();
    t.join();
  }
};
struct SecondFirst {
  template <class F, class G>
  void operator()(const F& f, const G& g) const {
    g();
    f();
  }
};

// The same for a block of right sides (solve_columns with finish, serial and last): every
// block's finish and last once, serial once between them, and the result that of the
// solve_columns without phases (X0), to the bit.
template <class C, class Cols, class Both>
void check_column_phases(const C& lu, const std::vector<Cols, Eigen::aligned_allocator<Cols>>& b,
                         const std::vector<Cols, Eigen::aligned_allocator<Cols>>& x0, const Both& both, const char* name) {
  const int n = static_cast<int>(x0.size());
  std::vector<Cols, Eigen::aligned_allocator<Cols>> y = b;
  std::vector<int> finished(n, 0), lasted(n, 0);
  int serial_runs = 0;
  lu.solve_columns(
      y.data(), both, [&](int l) { ++finished[l]; },
      [&] {
        ++serial_runs;
        for (int l = 0; l < n; ++l) EXPECT_EQ(finished[l], 1) << name << ": block " << l << " not finished before the serial phase";
      },
      [&](int l) {
        EXPECT_EQ(serial_runs, 1) << name;
        ++lasted[l];
      });
  EXPECT_EQ(serial_runs, 1) << name;
  for (int l = 0; l < n; ++l) {
    EXPECT_EQ(lasted[l], 1) << name << " block " << l;
    EXPECT_TRUE(y[l] == x0[l]) << name << ": block " << l << " differs from solve_columns without phases";
  }
}

// Returns the factorization's fill_blocks().
template <int B>
int check(int n, unsigned seed, double coupling, double diagonal = 0.1, double drop = CyclicBlockLU<B>::kNegligible) {
  using C = CyclicBlockLU<B>;
  const int N = n * B;
  // A random matrix with the structure (block-tridiagonal with cyclic corners, not symmetric).
  const Eigen::MatrixXd M = random_cyclic_matrix(n, B, seed, coupling, diagonal);
  C lu;
  lu.resize(n);
  lu.set_drop_tolerance(drop);
  load_cyclic_blocks(M, n, B, lu);
  if (!lu.factor()) {
    ADD_FAILURE() << "singular pivot";
    return -1;
  }
  const Eigen::VectorXd b = Eigen::VectorXd::Random(N);
  std::vector<typename C::Vec, Eigen::aligned_allocator<typename C::Vec>> x(n);
  for (int l = 0; l < n; ++l) x[l] = b.segment(l * B, B);
  lu.solve(x.data());
  Eigen::VectorXd xs(N);
  for (int l = 0; l < n; ++l) xs.segment(l * B, B) = x[l];
  check_solve_phases(lu, b, x, typename C::Sequential(), "sequential");
  check_solve_phases(lu, b, x, SecondFirst(), "second task first");
  for (int rep = 0; rep < 20; ++rep) check_solve_phases(lu, b, x, OnTwoThreads(), "two threads");
  const Eigen::VectorXd xd = M.partialPivLu().solve(b);
  // A block of right sides at once (solve_columns): each column as its own solve gives, to
  // the bit where both use the AVX2 kernels (the same sums in the same order), with an odd
  // count of columns (pairs, then one alone).
  constexpr int kC = 3;
  const Eigen::MatrixXd R = Eigen::MatrixXd::Random(N, kC);
  std::vector<Eigen::Matrix<double, B, kC>, Eigen::aligned_allocator<Eigen::Matrix<double, B, kC>>> X(n);
  for (int l = 0; l < n; ++l) X[l] = R.middleRows(l * B, B);
  const auto X_in = X;
  lu.solve_columns(X.data(), typename C::Sequential());
  check_column_phases(lu, X_in, X, typename C::Sequential(), "columns, sequential");
  check_column_phases(lu, X_in, X, SecondFirst(), "columns, second task first");
  for (int rep = 0; rep < 20; ++rep) check_column_phases(lu, X_in, X, OnTwoThreads(), "columns, two threads");
  for (int c = 0; c < kC; ++c) {
    for (int l = 0; l < n; ++l) x[l] = R.col(c).segment(l * B, B);
    lu.solve(x.data());
    double diff = 0, size = 0;
    for (int l = 0; l < n; ++l) diff += (X[l].col(c) - x[l]).squaredNorm(), size += x[l].squaredNorm();
    EXPECT_LT(std::sqrt(diff), 1e-12 * std::sqrt(size)) << "n " << n << " column " << c;
#if defined(__AVX2__) && defined(__FMA__)
    EXPECT_EQ(diff, 0.0) << "n " << n << " column " << c;
#endif
  }
  // Backward error at rounding level (no pivoting between blocks: the growth is that of the
  // matrix, compared with a dense partial-pivoting LU of it).
  // A coarser drop tolerance factors M + E, |E| ~ drop |M|: backward error of that order.
  const double scale = M.norm() * xs.norm();
  EXPECT_LT((M * xs - b).norm(), std::max(1e-12, 10 * drop) * scale) << "n " << n << " coupling " << coupling;
  EXPECT_LT((M * xd - b).norm(), 1e-12 * scale);
  EXPECT_LT((xs - xd).norm(), 1e-6 * xd.norm());
  return lu.fill_blocks();
}

TEST(CyclicBlockLU, SolvesLikeDenseLU) {
  for (int n : {3, 4, 5, 12, 84}) {
    check<2>(n, 1u + n, 1.0);
    check<5>(n, 2u + n, 10.0);
    check<21>(n, 3u + n, 30.0);  // the chain's link blocks, strongly coupled
  }
}

TEST(CyclicBlockLU, DropsTheCornersFillOnlyWhereItHasDecayed) {
  // Strong diagonal: the fill decays geometrically along the ring and is dropped past the
  // first links (it comes back where the band meets the last block row), still solving to
  // rounding. Weak diagonal with the same couplings: little decay, more (or all) fill kept.
  const int strong = check<21>(84, 7u, 1.0, 100.0);
  EXPECT_LT(strong, 40);
  EXPECT_GT(strong, 2);
  const int weak = check<21>(84, 7u, 1.0, 0.01);
  std::printf("fill blocks of 83: strong diagonal %d, weak %d\n", strong, weak);
  EXPECT_GT(weak, strong);
  EXPECT_LE(weak, 83);
}

TEST(CyclicBlockLU, ACoarserDropToleranceDropsMoreFillAndStillSolves) {
  // The W-method's setting (ModelOdeOptions::w_fill_drop): the backward error stays at the
  // tolerance's level (checked in check()), with fewer fill rows than the default keeps.
  for (double diagonal : {100.0, 1.0, 0.01}) {
    const int exact = check<21>(84, 7u, 1.0, diagonal);
    const int coarse = check<21>(84, 7u, 1.0, diagonal, 1e-12);
    std::printf("diagonal %g: fill blocks of 83, drop 1e-30 %d, drop 1e-12 %d\n", diagonal, exact, coarse);
    EXPECT_LE(coarse, exact);
    if (exact > 10) {
      EXPECT_LT(coarse, exact);
    }
  }
}

TEST(CyclicBlockLU, RejectsASingularPivot) {
  CyclicBlockLU<2> lu;
  lu.resize(3);
  for (int l = 0; l < 3; ++l) {
    lu.diag(l) = Eigen::Matrix2d::Identity();
    lu.sub(l) = lu.super(l) = Eigen::Matrix2d::Zero();
  }
  lu.diag(1)(1, 1) = 0;  // a zero row
  EXPECT_FALSE(lu.factor());
}

}  // namespace
}  // namespace cvt

namespace cvt {
namespace {

// block_times (the solves' inline kernel) against Eigen's product, for every remainder of
// the rows modulo the 4-row registers, including the chain's 21.
template <int B>
void check_block_times(unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  Eigen::Matrix<double, B, B> A;
  Eigen::Matrix<double, B, 1> x, t;
  for (int c = 0; c < B; ++c) {
    x[c] = u(rng);
    for (int r = 0; r < B; ++r) A(r, c) = u(rng) * std::pow(10.0, 3 * u(rng));
  }
  t.setConstant(1e300);  // every entry must be overwritten
  block_times(A, x, t);
  const Eigen::Matrix<double, B, 1> e = A * x;
  const double scale = (A.cwiseAbs() * x.cwiseAbs()).maxCoeff();
  EXPECT_LT((t - e).cwiseAbs().maxCoeff(), 1e-14 * scale) << "B = " << B;
}

TEST(CyclicBlockLU, BlockTimesIsTheMatrixProduct) {
  check_block_times<1>(1u);
  check_block_times<2>(2u);
  check_block_times<3>(3u);
  check_block_times<4>(4u);
  check_block_times<5>(5u);
  check_block_times<8>(8u);
  check_block_times<21>(21u);
}

}  // namespace
}  // namespace cvt
