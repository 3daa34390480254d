// other_forces (docs/model.md 4.6: shaft supports, drive, load, clamping) against its own
// invariants: its conservative forces are minus the gradient of its energy, the loads and
// clamping forces follow the ramp, the powers it reports are force times velocity, the
// explicit time dependence of its potential is the drive's and the clamping's power, and
// its dissipative forces dissipate what it reports.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "engine/rhs/rhs.hpp"
#include "modules/other_forces.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

// The shafts and the load of a state in motion (the chain's coordinates do not enter).
Eigen::VectorXd moving_state(const Model& m, unsigned seed) { return test::perturbed_state(m, seed, 2e-5, 1e-3, 0.3); }

// other_forces at (t, y): ws.other (its f: both shafts' 7 coordinates, then the load angle).
const OtherForces& evaluate(const Model& m, Workspace& ws, double t, const Eigen::VectorXd& y) {
  set_stage_input(m, ws, t, y.data());
  other_forces(m, ws);
  return ws.other;
}

// The coordinates other_forces acts on: the two shafts and the load angle.
int coordinate(const Model& m, int i) { return m.shaft(0) + i; }
constexpr int kOther = 2 * kShaftSize + 1;

TEST(OtherForces, ConservativeForcesAreMinusTheirEnergyGradient) {
  // No damping, at rest, the load torque (external work, not a potential) off; mid-ramp, so
  // that the clamping potential and the drive spring's prescribed angle are both live.
  const Model m = test::model("mini", {"damping.scale=0", "load.torque=0"});
  Eigen::VectorXd y = moving_state(m, 31);
  y.segment(m.ndof, m.ndof).setZero();
  for (int k = 0; k < 2; ++k) y[m.shaft(k) + kUx] += 3e-5, y[m.shaft(k) + kUy] -= 2e-5;  // bearings loaded
  const double t = 0.5 * m.cfg.ramp.time;
  Workspace ws(m);
  const OtherForces o = evaluate(m, ws, t, y);
  double worst = 0, scale = 0;
  for (int i = 0; i < kOther; ++i) {
    const int c = coordinate(m, i);
    const int r = i % kShaftSize;
    const bool angle = i == kOther - 1 || r == kTx || r == kTy || r == kPhi;
    const double h = angle ? 1e-7 : 1e-9;
    auto at = [&](double d) {
      Eigen::VectorXd z = y;
      z[c] += d;
      return other_energy(m, t, z.data());
    };
    const double g = (-at(2 * h) + 8 * at(h) - 8 * at(-h) + at(-2 * h)) / (12 * h);
    worst = std::max(worst, std::abs(o.f[i] + g));
    scale = std::max(scale, std::abs(o.f[i]));
  }
  std::printf("[other_forces] max |f + grad E_other| / max |f| = %.3g (max |f| %.3g)\n", worst / scale, scale);
  EXPECT_GT(scale, 1.0);
  // 4th-order differences, steps of 1e-9 m and 1e-7 rad, the cubic bearing springs.
  EXPECT_LE(worst / scale, 1e-6);
}

TEST(OtherForces, LoadsAndClampingFollowTheRamp) {
  const Model m = test::model("mini", {"damping.scale=0"});
  const double tr = m.cfg.ramp.time, M0 = m.cfg.load.torque;
  const double F[2] = {m.cfg.clamping.driving, m.cfg.clamping.driven};
  Eigen::VectorXd y = m.y0;
  Workspace ws(m);
  double last[3] = {-1, -1, -1};
  for (double frac : {0.0, 0.1, 0.25, 0.5, 0.75, 0.9, 1.0, 1.5}) {
    const OtherForces& o = evaluate(m, ws, frac * tr, y);
    const double r = ramp(frac * tr, tr);
    EXPECT_DOUBLE_EQ(o.load_torque, M0 * r) << frac;
    EXPECT_DOUBLE_EQ(o.clamp[0], F[0] * r) << frac;
    EXPECT_DOUBLE_EQ(o.clamp[1], F[1] * r) << frac;
    // From nothing to the nominal values, never decreasing.
    EXPECT_GE(o.load_torque, last[0]);
    EXPECT_GE(o.clamp[0], last[1]);
    EXPECT_GE(o.clamp[1], last[2]);
    last[0] = o.load_torque, last[1] = o.clamp[0], last[2] = o.clamp[1];
    if (frac == 0.0) EXPECT_EQ(o.clamp[0] + o.clamp[1] + o.load_torque, 0.0);
    if (frac >= 1.0) {
      EXPECT_EQ(o.load_torque, M0);
      EXPECT_EQ(o.clamp[0], F[0]);
      EXPECT_EQ(o.clamp[1], F[1]);
    }
  }
  // The ramp is C1: its rate is 0 at both ends and matches the difference quotient inside.
  EXPECT_EQ(ramp_rate(0.0, tr), 0.0);
  EXPECT_EQ(ramp_rate(tr, tr), 0.0);
  const double t = 0.3 * tr, d = 1e-6 * tr;
  EXPECT_NEAR(ramp_rate(t, tr), (ramp(t + d, tr) - ramp(t - d, tr)) / (2 * d), 1e-6 / tr);
}

TEST(OtherForces, ReportedPowersAreForceTimesVelocity) {
  const Model m = test::model("mini", {"ramp.time=1e-4"});
  const Eigen::VectorXd y = moving_state(m, 32);
  Workspace ws(m);
  const OtherForces& o = evaluate(m, ws, 2e-4, y);
  // The drive turns at the prescribed speed; the load at its own.
  EXPECT_DOUBLE_EQ(o.p_in, o.input_torque * m.cfg.drive.speed);
  EXPECT_DOUBLE_EQ(o.p_out, o.load_torque * y[m.ndof + m.load_index()]);
  EXPECT_GE(o.p_diss, 0.0);
}

TEST(OtherForces, TimeDependenceOfThePotentialIsTheDrivesAndClampingsPower) {
  // At rest and without damping the drive torque is its spring's: the energy's explicit
  // rate at fixed q, dE/dt = k (phi_in - phi_1) omega_in + sigma F r'(t) w, is p_in + p_clamp.
  const Model m = test::model("mini", {"damping.scale=0"});
  Eigen::VectorXd y = moving_state(m, 33);
  y.segment(m.ndof, m.ndof).setZero();
  for (int k = 0; k < 2; ++k) y[m.shaft(k) + kW] += 1e-4;  // sheaves off their rest: a clamping potential
  const double t = 0.4 * m.cfg.ramp.time, d = 1e-6 * m.cfg.ramp.time;
  Workspace ws(m);
  const OtherForces o = evaluate(m, ws, t, y);
  const double rate = (other_energy(m, t + d, y.data()) - other_energy(m, t - d, y.data())) / (2 * d);
  std::printf("[other_forces] dE/dt at fixed q %.9g W, p_in + p_clamp %.9g W\n", rate, o.p_in + o.p_clamp);
  EXPECT_GT(std::abs(o.p_clamp), 0.0);
  EXPECT_NEAR(rate, o.p_in + o.p_clamp, 1e-6 * (std::abs(o.p_in) + std::abs(o.p_clamp)));
}

TEST(OtherForces, DissipatedPowerIsThePowerOfTheDampers) {
  // Bearings, sheaves and the load's torsion damper: both ends of each move with the
  // coordinates, so the power of f(q, v) - f(q, 0) is minus the dissipation. (The drive's
  // damper has one end at the prescribed speed: its dissipation is not a power of these
  // coordinates alone, so it is off here.)
  const Model m = test::model("mini", {"ramp.time=1e-4", "drive.damping=0", "load.speed_coefficient=0"});
  const Eigen::VectorXd y = moving_state(m, 34);
  Eigen::VectorXd rest = y;
  rest.segment(m.ndof, m.ndof).setZero();
  Workspace ws(m);
  const OtherForces moving = evaluate(m, ws, 2e-4, y);
  const OtherForces still = evaluate(m, ws, 2e-4, rest);
  double power = 0;
  for (int i = 0; i < kOther; ++i) power += (moving.f[i] - still.f[i]) * y[m.ndof + coordinate(m, i)];
  // The load torque M0 r(t) is the same in both: it is not in the difference.
  std::printf("[other_forces] dissipated %.6g W, power of the dissipative forces %.6g W\n", moving.p_diss, power);
  EXPECT_GT(moving.p_diss, 0.0);
  EXPECT_NEAR(-power, moving.p_diss, 1e-9 * moving.p_diss);
}

}  // namespace
}  // namespace cvt
