// The right-hand side y' = f(t, y) (docs/model.md 2.3, 3, 4.0, 6) as rhs_serial assembles
// it: positions advance with the velocities, the accelerations solve A(q) q'' = F with F the
// ordered sum of the modules' slots, the result does not depend on how the joints are split
// into ranges, and along f the energy changes as the powers say.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <random>
#include <vector>

#include "engine/rhs/rhs.hpp"
#include "modules/chain_forces.hpp"
#include "modules/inertia.hpp"
#include "modules/other_forces.hpp"
#include "modules/pulley_contact.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

// A state in motion near the initial one: positions off by up to 3 um / 1.5e-4 rad (contacts,
// plates and beams loaded), velocities off by up to 0.05 m/s from the rolling motion, the
// drive spring wound by only 1e-3 rad so that the input power does not swamp the others.
Eigen::VectorXd moving_state(const Model& m, unsigned seed, double t) {
  Eigen::VectorXd y = test::perturbed_state(m, seed, 3e-6, 1.5e-4, 0.05);
  y[m.shaft(0) + kPhi] = m.cfg.drive.speed * t - 1e-3;
  return y;
}

Eigen::VectorXd rhs(const Model& m, double t, const Eigen::VectorXd& y, Workspace* keep = nullptr) {
  Workspace ws(m);
  Workspace& w = keep ? *keep : ws;
  Eigen::VectorXd dy = Eigen::VectorXd::Constant(m.nstate, std::nan(""));
  rhs_serial(m, w, t, y.data(), dy.data());
  return dy;
}

bool same_bits(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), sizeof(double) * a.size()) == 0;
}

TEST(RhsTest, PositionRatesAreExactlyTheVelocities) {
  const Model m = test::model("mini");
  for (unsigned seed : {1u, 2u}) {
    const Eigen::VectorXd y = moving_state(m, seed, 2e-4);
    const Eigen::VectorXd dy = rhs(m, 2e-4, y);
    EXPECT_TRUE(same_bits(dy.head(m.ndof), y.segment(m.ndof, m.ndof))) << "seed " << seed;
    EXPECT_TRUE(dy.allFinite());
  }
}

// F is the sum of every module's slot entries, link torques through g_i (docs/model.md 4.0,
// 3.1), plus the other forces; P_diss is the other forces' plus every slot's; the work rates
// of dy are the other forces' powers.
TEST(RhsTest, GatheredForceIsTheSumOfTheModulesContributions) {
  const Model m = test::model("mini", {"load.speed_coefficient=0.01"});
  const double t = 3e-4;
  const Eigen::VectorXd y = moving_state(m, 3, t);
  Workspace ws(m);
  const Eigen::VectorXd dy = rhs(m, t, y, &ws);
  const int N = m.links, n = m.ndof;
  Eigen::VectorXd F = Eigen::VectorXd::Zero(n), size = Eigen::VectorXd::Zero(n);
  const auto add = [&](int i, double x) { F[i] += x, size[i] += std::abs(x); };
  const auto torque = [&](int i, double tau) {
    // g_i: +n_i / (2 |Delta_i|) on both ends' x, y of a_{i+1}, the opposite on b_i.
    const double* a = y.data() + 21 * ((i + 1) % N);
    const double* b = y.data() + 21 * i + 10;
    const double dx = 0.5 * (a[0] + a[5] - b[0] - b[5]), dy_ = 0.5 * (a[1] + a[6] - b[1] - b[6]);
    const double l2 = dx * dx + dy_ * dy_, gx = -0.5 * dy_ / l2, gy = 0.5 * dx / l2;
    for (int e = 0; e < 2; ++e) {
      add(21 * ((i + 1) % N) + 5 * e, tau * gx), add(21 * ((i + 1) % N) + 5 * e + 1, tau * gy);
      add(21 * i + 10 + 5 * e, -tau * gx), add(21 * i + 10 + 5 * e + 1, -tau * gy);
    }
  };
  double p_diss = ws.other.p_diss;
  for (const auto* slots : {&ws.chain_slots, &ws.pulley_slots, &ws.inertia_slots})
    for (int j = 0; j < N; ++j) {
      const JointSlot& s = (*slots)[j];
      for (int i = 0; i < 21; ++i) add(21 * j + i, s.f[i]);
      for (int i = 0; i < 10; ++i) add(21 * ((j + 1) % N) + i, s.f_next_a[i]);
      torque((j + N - 1) % N, s.tau_prev);
      torque(j, s.tau_own);
      for (int i = 0; i < 14; ++i) add(21 * N + i, s.shaft[i]);
      p_diss += s.p_diss;
    }
  for (int i = 0; i < 15; ++i) add(21 * N + i, ws.other.f[i]);
  // Same terms in another order: round-off of each coordinate's sum.
  for (int i = 0; i < n; ++i) EXPECT_NEAR(ws.force[i], F[i], 1e-14 * size[i] + 1e-300) << "coordinate " << i;
  EXPECT_GT(ws.force.cwiseAbs().maxCoeff(), 1.0);
  const double* da = dy.data() + 2 * n;
  EXPECT_NEAR(da[kWorkDiss], p_diss, 1e-14 * p_diss);  // same positive terms, same order: round-off at most
  EXPECT_EQ(da[kWorkIn], ws.other.p_in);
  EXPECT_EQ(da[kWorkOut], ws.other.p_out);
  EXPECT_EQ(da[kWorkClamp], ws.other.p_clamp);
  EXPECT_EQ(da[kCtrlIntegral], ws.other.ctrl_rate);
  EXPECT_EQ(da[kWorkSwitch], 0.0);  // incremented between steps, not integrated (4.4)
}

// Lagrange (docs/model.md 3.3): A(q) q'' = F, with A q'' taken from the kinetic energy
// T(q, v) = 1/2 v^T A(q) v of section 3 (kinetic_energy): (A x)_i = dT(q, x)/dv_i, which
// central differences give exactly for a quadratic; and from dense_inertia.
TEST(RhsTest, AccelerationsSolveTheMassMatrixSystem) {
  const Model m = test::model("mini");
  const int n = m.ndof;
  for (unsigned seed : {4u, 5u}) {
    const Eigen::VectorXd y = moving_state(m, seed, 2e-4);
    Workspace ws(m);
    const Eigen::VectorXd dy = rhs(m, 2e-4, y, &ws);
    const Eigen::VectorXd a = dy.segment(n, n);
    const double h = a.cwiseAbs().maxCoeff();
    Eigen::VectorXd Aa(n);
    Eigen::VectorXd x = a;
    for (int i = 0; i < n; ++i) {
      x[i] = a[i] + h;
      const double Tp = kinetic_energy(m, y.data(), x.data());
      x[i] = a[i] - h;
      const double Tm = kinetic_energy(m, y.data(), x.data());
      x[i] = a[i];
      Aa[i] = (Tp - Tm) / (2 * h);
    }
    const Eigen::VectorXd Ad = dense_inertia(m, y.data()) * a;
    const double scale = ws.force.cwiseAbs().maxCoeff();
    const double err_T = (Aa - ws.force).cwiseAbs().maxCoeff(), err_A = (Ad - ws.force).cwiseAbs().maxCoeff();
    std::printf("[seed %u] max |F| = %.4g N, max |A q'' - F| from T: %.3g, from dense A: %.3g\n", seed, scale, err_T,
                err_A);
    EXPECT_GT(scale, 1.0);
    // T ~ 1/2 max|A| |q''|^2 n: the difference loses ~1e-16 T / h ~ 1e-16 n max|A| |q''|,
    // about 1e-11 of max |F| here; the solve itself is good to ~1e-13.
    EXPECT_LE(err_T, 1e-9 * scale);
    EXPECT_LE(err_A, 1e-11 * scale);
  }
}

struct Range {
  int begin, end;
};

// The passes of rhs_serial, each over the ranges in the given order (docs/model.md 4.0:
// each pass writes only its own joints, every sum has a fixed order).
void rhs_in_ranges(const Model& m, Workspace& ws, double t, const Eigen::VectorXd& y, Eigen::VectorXd& dy,
                   const std::vector<Range>& ranges) {
  set_stage_input(m, ws, t, y.data());
  for (const Range& r : ranges) link_kinematics(m, ws, r.begin, r.end);
  for (const Range& r : ranges) chain_forces(m, ws, r.begin, r.end);
  for (auto it = ranges.rbegin(); it != ranges.rend(); ++it) pulley_contact(m, ws, it->begin, it->end);
  other_forces(m, ws);
  for (const Range& r : ranges) inertia_decomposition(m, ws, r.begin, r.end);
  for (auto it = ranges.rbegin(); it != ranges.rend(); ++it) gather_joints(m, ws, it->begin, it->end);
  gather_shafts(m, ws);
  for (const Range& r : ranges) finish_joints(m, ws, dy.data(), nullptr, r.begin, r.end);
  finish_shafts(m, ws, dy.data(), nullptr);
}

TEST(RhsTest, SplittingJointsIntoRangesGivesTheSameBits) {
  const Model m = test::model("mini");
  const double t = 4e-4;
  const Eigen::VectorXd y = moving_state(m, 6, t);
  const Eigen::VectorXd ref = rhs(m, t, y);
  const int N = m.links;
  const std::vector<std::vector<Range>> splits = {
      {{0, N}},
      {{0, 1}, {1, 2}, {2, N}},
      {{17, N}, {0, 7}, {7, 8}, {8, 17}},
      {{N - 1, N}, {0, N - 1}},
  };
  // A workspace left dirty by another state: nothing stale may leak into the result.
  Workspace ws(m);
  Eigen::VectorXd dy = Eigen::VectorXd::Zero(m.nstate);
  rhs_in_ranges(m, ws, 0.0, moving_state(m, 7, 0.0), dy, {{0, N}});
  for (std::size_t s = 0; s < splits.size(); ++s) {
    dy.setConstant(std::nan(""));
    rhs_in_ranges(m, ws, t, y, dy, splits[s]);
    EXPECT_TRUE(same_bits(dy, ref)) << "split " << s << ": max diff " << (dy - ref).cwiseAbs().maxCoeff();
  }
  // The gather from per-module sums (a zeroed buffer that each slot is added into, in any
  // order) gives the same forces as the gather from the slots.
  Workspace wr(m);
  rhs(m, t, y, &wr);
  std::vector<double> chain(22 * N, 0.0), pulley(22 * N, 0.0);
  for (int j = N - 1; j >= 0; --j) scatter_slot(m, wr.chain_slots[j], j, chain.data());
  std::vector<int> order(N);
  for (int j = 0; j < N; ++j) order[j] = j;
  std::shuffle(order.begin(), order.end(), std::mt19937(11));
  for (int j : order) scatter_slot(m, wr.pulley_slots[j], j, pulley.data());
  const Eigen::VectorXd F = wr.force;
  gather_joints_from_sums(m, wr, chain.data(), pulley.data(), 0, N);
  EXPECT_TRUE(same_bits(wr.force, F)) << "max diff " << (wr.force - F).cwiseAbs().maxCoeff();
}

// docs/model.md 6: along the flow, dE/dt = P_in + P_clamp - P_out - P_diss, E = T + Pi, with
// every contact active (a fresh workspace) and the contact energy of every penetrating
// pair (energies without statuses: the same pairs).
TEST(RhsTest, EnergyRateEqualsTheBalanceOfPowers) {
  const Model m = test::model("mini", {"load.speed_coefficient=0.01"});
  const int n = m.ndof;
  const double tr = m.cfg.ramp.time;
  for (unsigned seed : {8u, 9u}) {
    const double t = 0.4 * tr;  // mid-ramp: clamping power and load torque both on
    const Eigen::VectorXd y = moving_state(m, seed, t);
    const Eigen::VectorXd dy = rhs(m, t, y);
    const double* da = dy.data() + 2 * n;
    const auto E = [&](double s) {
      const Eigen::VectorXd z = y + s * dy;
      const Energies e = energies(m, t + s, z.data());
      return e.kinetic + e.elastic;
    };
    // Step: positions move by ~5e-9 m (speeds ~5 m/s); round-off ~1e-16 E / h ~ 1e-5 W.
    const double h = 1e-9;
    const double dEdt = (-E(2 * h) + 8 * E(h) - 8 * E(-h) + E(-2 * h)) / (12 * h);
    const double balance = da[kWorkIn] + da[kWorkClamp] - da[kWorkOut] - da[kWorkDiss];
    const double size = std::abs(da[kWorkIn]) + std::abs(da[kWorkClamp]) + std::abs(da[kWorkOut]) + da[kWorkDiss];
    std::printf("[seed %u] E = %.6g J, dE/dt = %.8g W, P_in %.6g + P_clamp %.6g - P_out %.6g - P_diss %.6g = %.8g W, "
                "residual %.3g W\n",
                seed, E(0), dEdt, da[kWorkIn], da[kWorkClamp], da[kWorkOut], da[kWorkDiss], balance, dEdt - balance);
    EXPECT_GT(da[kWorkDiss], 0.0);
    EXPECT_GT(std::abs(da[kWorkClamp]), 0.0);
    // Difference error: truncation ~(omega h)^4 ~ 1e-14 (omega ~ 3e5 rad/s, the stiffest
    // contacts) and round-off ~1e-16 E / h ~ 1.4e-5 W; 1e-7 of the powers is ~5e-4 W.
    EXPECT_NEAR(dEdt, balance, 1e-7 * size);
  }
}

}  // namespace
}  // namespace cvt
