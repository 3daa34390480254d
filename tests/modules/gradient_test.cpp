// Every conservative force is minus the gradient of its energy (docs/model.md 4):
// finite differences of the total potential against the gathered generalized forces.
#include <gtest/gtest.h>

#include <cstdio>

#include "engine/rhs/rhs.hpp"
#include "modules/chain_forces.hpp"
#include "modules/other_forces.hpp"
#include "modules/pulley_contact.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

double potential(const Model& m, double t, const Eigen::VectorXd& y) {
  return energies(m, t, y.data()).elastic;
}

// Forces at rest (qdot = 0, no damping) are purely conservative.
Eigen::VectorXd forces(const Model& m, double t, const Eigen::VectorXd& y) {
  Workspace ws(m);
  Eigen::VectorXd dy(m.nstate);
  rhs_serial(m, ws, t, y.data(), dy.data());
  return ws.force;
}

class GradientTest : public ::testing::TestWithParam<unsigned> {};

TEST_P(GradientTest, ForcesAreMinusEnergyGradient) {
  const Model m = test::model("mini", {"damping.scale=0", "load.torque=0"});
  Eigen::VectorXd y = test::perturbed_state(m, GetParam(), 4e-6, 2e-4, 0.0);
  y.segment(m.ndof, m.ndof).setZero();
  const double t = 0.5 * m.cfg.ramp.time;  // clamping half ramped: nonzero potential
  const Eigen::VectorXd Q = forces(m, t, y);
  double worst = 0, scale = Q.cwiseAbs().maxCoeff();
  int worst_i = -1;
  for (int i = 0; i < m.ndof; ++i) {
    // Step sized to the coordinate: lengths 1e-9 m, slopes and angles 1e-7.
    const int r = i < kJointSize * m.links ? (i % kJointSize) % half::kEnd : -1;
    const bool slope = i < kJointSize * m.links && (i % kJointSize) < 20 && (r == half::kSx || r == half::kSy);
    const bool angle = i >= m.shaft(0) && ((i - m.shaft(0)) % kShaftSize == kTx ||
                                           (i - m.shaft(0)) % kShaftSize == kTy ||
                                           (i - m.shaft(0)) % kShaftSize == kPhi || i == m.load_index());
    const double h = (slope || angle) ? 1e-7 : 1e-9;
    // 4th-order central difference.
    auto at = [&](double d) {
      Eigen::VectorXd z = y;
      z[i] += d;
      return potential(m, t, z);
    };
    const double g = (-at(2 * h) + 8 * at(h) - 8 * at(-h) + at(-2 * h)) / (12 * h);
    const double err = std::abs(Q[i] + g);
    if (err > worst) {
      worst = err;
      worst_i = i;
    }
  }
  EXPECT_GT(scale, 1.0) << "perturbation produced no forces";
  std::printf("max |F + grad E| / max |F| = %.3g (max |F| = %.3g N)\n", worst / scale, scale);
  EXPECT_LE(worst / scale, 1e-6) << "worst coordinate " << worst_i << " force " << Q[worst_i];
}

INSTANTIATE_TEST_SUITE_P(RandomStates, GradientTest, ::testing::Values(1u, 2u, 3u));

}  // namespace
}  // namespace cvt
