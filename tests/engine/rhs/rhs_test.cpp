// One evaluation of f (engine/rhs/rhs.cpp, docs/model.md 3, 4.0, 6) against its own
// invariants: positions move with the velocities, the accelerations solve M(q) q'' = F,
// the passes over any split of the joints give the same bits as the serial evaluation, and
// along f the energy changes by the power that flows in, out and is dissipated.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "engine/rhs/rhs.hpp"
#include "modules/chain_forces.hpp"
#include "modules/inertia.hpp"
#include "modules/other_forces.hpp"
#include "modules/pulley_contact.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

const Model& model() {
  static const Model m = test::model("mini", {"ramp.time=1e-4"});
  return m;
}

Eigen::VectorXd moving_state(const Model& m, unsigned seed) { return test::perturbed_state(m, seed, 3e-6, 2e-4, 0.05); }

TEST(Rhs, PositionsMoveWithTheVelocities) {
  const Model& m = model();
  const Eigen::VectorXd y = moving_state(m, 41);
  Workspace ws(m);
  update_contact_status(m, ws, 0.0, y.data());
  Eigen::VectorXd dy(m.nstate);
  rhs_serial(m, ws, 2e-4, y.data(), dy.data());
  EXPECT_EQ((dy.head(m.ndof) - y.segment(m.ndof, m.ndof)).cwiseAbs().maxCoeff(), 0.0);
}

TEST(Rhs, AccelerationsSolveTheEquationsOfMotion) {
  // The structured solve (A0^-1 and the Woodbury correction for the link inertia, 3.2)
  // against the dense mass matrix: M(q) q'' = F, F the gathered forces with the velocity
  // terms of the q-dependent inertia.
  const Model& m = model();
  const Eigen::VectorXd y = moving_state(m, 42);
  Workspace ws(m);
  update_contact_status(m, ws, 0.0, y.data());
  Eigen::VectorXd dy(m.nstate);
  rhs_serial(m, ws, 2e-4, y.data(), dy.data());
  const Eigen::MatrixXd M = dense_inertia(m, y.data());
  const Eigen::VectorXd residual = M * dy.segment(m.ndof, m.ndof) - ws.force;
  std::printf("[rhs] |M q'' - F| / |F| = %.3g (|F| = %.3g)\n", residual.norm() / ws.force.norm(), ws.force.norm());
  EXPECT_GT(ws.force.norm(), 1.0);
  EXPECT_LE(residual.norm(), 1e-10 * ws.force.norm());
}

TEST(Rhs, AnySplitOfTheJointsGivesTheSameBits) {
  // The passes as a parallel schedule runs them, over uneven joint ranges in a scrambled
  // order, against rhs_serial: every pass writes its own joints and every sum has a fixed
  // order, so the bits are the same.
  const Model& m = model();
  const Eigen::VectorXd y = moving_state(m, 43);
  const double t = 2e-4;
  Workspace a(m), b(m);
  update_contact_status(m, a, 0.0, y.data());
  b.status = a.status;
  Eigen::VectorXd dy_serial(m.nstate), dy_split(m.nstate);
  rhs_serial(m, a, t, y.data(), dy_serial.data());
  const int N = m.links;
  const std::vector<std::pair<int, int>> ranges = {{N / 2, N - 3}, {0, 1}, {N - 3, N}, {1, N / 2}};
  set_stage_input(m, b, t, y.data());
  for (auto [lo, hi] : ranges) link_kinematics(m, b, lo, hi);
  for (auto [lo, hi] : ranges) chain_forces(m, b, lo, hi);
  for (auto [lo, hi] : ranges) pulley_contact(m, b, lo, hi);
  other_forces(m, b);
  for (auto [lo, hi] : ranges) inertia_decomposition(m, b, lo, hi);
  for (auto [lo, hi] : ranges) gather_joints(m, b, lo, hi);
  gather_shafts(m, b);
  for (auto [lo, hi] : ranges) finish_joints(m, b, dy_split.data(), nullptr, lo, hi);
  finish_shafts(m, b, dy_split.data(), nullptr);
  for (int i = 0; i < m.nstate; ++i) ASSERT_EQ(dy_split[i], dy_serial[i]) << "unknown " << i;
}

TEST(Rhs, EnergyChangesByThePowerThatFlows) {
  // d(E_kin + E_el)/dt along f, by differences of the energies at y -+ eps f(y) with the
  // statuses as they are, against the work integrals' rates in f: W_in' + W_clamp' - W_out'
  // - W_diss' (docs/model.md 6; no status switches inside an evaluation).
  const Model& m = model();
  const Eigen::VectorXd y = moving_state(m, 44);
  const double t = 2e-4;
  Workspace ws(m);
  update_contact_status(m, ws, 0.0, y.data());
  Eigen::VectorXd dy(m.nstate);
  rhs_serial(m, ws, t, y.data(), dy.data());
  const double* w = dy.data() + 2 * m.ndof;
  const double flow = w[kWorkIn] + w[kWorkClamp] - w[kWorkOut] - w[kWorkDiss];
  const double eps = 1e-9;
  const auto energy = [&](double s) {
    const Eigen::VectorXd z = y + s * dy;
    const Energies e = energies(m, t + s, z.data(), &ws.status);
    return e.kinetic + e.elastic;
  };
  const double rate = (-energy(2 * eps) + 8 * energy(eps) - 8 * energy(-eps) + energy(-2 * eps)) / (12 * eps);
  const double scale = std::abs(w[kWorkIn]) + std::abs(w[kWorkClamp]) + std::abs(w[kWorkOut]) + std::abs(w[kWorkDiss]);
  std::printf("[rhs] dE/dt %.6g W, in %.6g + clamping %.6g - out %.6g - dissipated %.6g = %.6g W\n", rate, w[kWorkIn],
              w[kWorkClamp], w[kWorkOut], w[kWorkDiss], flow);
  EXPECT_GT(w[kWorkDiss], 0.0);
  // The differences of an energy of ~1 J over 1e-9 s resolve its rate to ~1e-6 of the flows.
  EXPECT_NEAR(rate, flow, 1e-5 * scale);
}

}  // namespace
}  // namespace cvt
