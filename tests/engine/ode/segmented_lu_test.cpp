// SegmentedBlockLU against a dense LU of the same matrix, and against itself on any number
// of tasks.
#include "engine/ode/segmented_lu.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <thread>
#include <vector>

#include "tests/engine/ode/cyclic_matrix.hpp"

namespace cvt {
namespace {

// `count` tasks, each on a thread of its own (the first on the caller's).
struct OnThreads {
  int tasks;
  template <class F>
  void operator()(const F& f) const {
    std::vector<std::thread> th;
    for (int t = 1; t < tasks; ++t) th.emplace_back([&f, t] { f(t); });
    f(0);
    for (auto& x : th) x.join();
  }
};

template <int B>
using Blocks = std::vector<Eigen::Matrix<double, B, 1>, Eigen::aligned_allocator<Eigen::Matrix<double, B, 1>>>;

// Factorizes the random matrix on `segments` segments and checks the solves; returns the
// factorization's fill_blocks().
template <int B>
int check(int n, int segments, unsigned seed, double coupling, double diagonal = 0.1,
          double drop = SegmentedBlockLU<B>::kNegligible) {
  using LU = SegmentedBlockLU<B>;
  const int N = n * B;
  const Eigen::MatrixXd M = random_cyclic_matrix(n, B, seed, coupling, diagonal);
  LU lu;
  lu.resize(n, segments);
  lu.set_drop_tolerance(drop);
  load_cyclic_blocks(M, n, B, lu);
  // The factors on one task and on several, to the bit (a fresh copy of the blocks each).
  LU many = lu;
  if (!lu.factor()) {
    ADD_FAILURE() << "singular pivot";
    return -1;
  }
  EXPECT_TRUE(many.factor(OnThreads{segments}));
  const Eigen::VectorXd b = Eigen::VectorXd::Random(N);
  Blocks<B> x(n), xt(n);
  for (int l = 0; l < n; ++l) x[l] = xt[l] = b.segment(l * B, B);
  lu.solve(x.data());
  many.solve(xt.data(), OnThreads{3});
  for (int l = 0; l < n; ++l) EXPECT_TRUE(x[l] == xt[l]) << "n " << n << " block " << l << ": factors on threads";
  check_solve_phases(lu, b, x, typename LU::Sequential(), "one task");
  for (int rep = 0; rep < 10; ++rep)
    for (int t : {2, 3, segments + 1}) check_solve_phases(lu, b, x, OnThreads{t}, "tasks on threads");
  // Backward error at rounding level (or the drop tolerance's), as CyclicBlockLU's.
  Eigen::VectorXd xs(N);
  for (int l = 0; l < n; ++l) xs.segment(l * B, B) = x[l];
  const Eigen::VectorXd xd = M.partialPivLu().solve(b);
  const double scale = M.norm() * xs.norm();
  EXPECT_LT((M * xs - b).norm(), std::max(1e-12, 10 * drop) * scale) << "n " << n << " segments " << segments;
  EXPECT_LT((xs - xd).norm(), 1e-6 * xd.norm());
  // Several right sides at once: each column as its own solve, to the bit where both use the
  // AVX2 kernels.
  constexpr int kC = 3;
  using Cols = Eigen::Matrix<double, B, kC>;
  const Eigen::MatrixXd R = Eigen::MatrixXd::Random(N, kC);
  std::vector<Cols, Eigen::aligned_allocator<Cols>> X(n), Xt(n);
  for (int l = 0; l < n; ++l) X[l] = Xt[l] = R.middleRows(l * B, B);
  lu.template solve_columns<kC>(X.data(), typename LU::Sequential());
  lu.template solve_columns<kC>(Xt.data(), OnThreads{2});
  for (int c = 0; c < kC; ++c) {
    for (int l = 0; l < n; ++l) x[l] = R.col(c).segment(l * B, B);
    lu.solve(x.data());
    double diff = 0, size = 0;
    for (int l = 0; l < n; ++l) {
      EXPECT_TRUE(X[l].col(c) == Xt[l].col(c)) << "columns on threads, block " << l;
      diff += (X[l].col(c) - x[l]).squaredNorm(), size += x[l].squaredNorm();
    }
    EXPECT_LT(std::sqrt(diff), 1e-12 * std::sqrt(size)) << "n " << n << " column " << c;
#if defined(__AVX2__) && defined(__FMA__)
    EXPECT_EQ(diff, 0.0) << "n " << n << " column " << c;
#endif
  }
  return lu.fill_blocks();
}

TEST(SegmentedBlockLU, SolvesLikeDenseLUOnAnyNumberOfSegmentsAndTasks) {
  for (int segments : {3, 4, 7}) {
    for (int n : {2 * segments, 2 * segments + 1, 30, 84}) {
      check<2>(n, segments, 1u + n, 1.0);
      check<5>(n, segments, 2u + n, 10.0);
      check<21>(n, segments, 3u + n, 30.0);  // the chain's link blocks, strongly coupled
    }
  }
  check<21>(84, 12, 5u, 30.0);
  check<21>(84, 42, 6u, 30.0);  // one interior block per segment
}

TEST(SegmentedBlockLU, DropsTheFillWhereItHasDecayed) {
  // Each segment's fill to its upper separator decays along the segment: with the W-method's
  // tolerance (ModelOdeOptions::w_fill_drop, 1e-12) and a strong diagonal it is dropped past
  // the segments' first blocks; a weak diagonal or the default tolerance keeps more.
  const int interior = 84 - 8;
  const int strong = check<21>(84, 8, 7u, 1.0, 1000.0, 1e-12);
  const int weak = check<21>(84, 8, 7u, 1.0, 0.01, 1e-12);
  const int exact = check<21>(84, 8, 7u, 1.0, 1000.0);
  std::printf("fill blocks of %d interior blocks on 8 segments, drop 1e-12: strong diagonal %d, weak %d; "
              "strong with drop 1e-30: %d\n",
              interior, strong, weak, exact);
  EXPECT_GE(strong, 8);
  EXPECT_LT(strong, interior / 2);
  EXPECT_GT(weak, strong);
  EXPECT_GE(exact, strong);
  EXPECT_LE(exact, interior);
}

TEST(SegmentedBlockLU, RejectsASingularPivotAndTooFewBlocks) {
  for (int zero : {1, 0}) {  // an interior block, a separator
    SegmentedBlockLU<2> lu;
    lu.resize(6, 3);
    for (int l = 0; l < 6; ++l) {
      lu.diag(l) = Eigen::Matrix2d::Identity();
      lu.sub(l) = lu.super(l) = Eigen::Matrix2d::Zero();
    }
    lu.diag(zero)(1, 1) = 0;  // a zero row
    EXPECT_FALSE(lu.factor()) << "block " << zero;
  }
  SegmentedBlockLU<2> lu;
  EXPECT_THROW(lu.resize(5, 3), std::invalid_argument);
  EXPECT_THROW(lu.resize(84, 2), std::invalid_argument);
}

}  // namespace
}  // namespace cvt
