// chain_forces (docs/model.md 4.1-4.3) against its own invariants: its conservative forces
// are minus the gradient of the chain's energy, its forces are internal (no net force or
// moment on the chain, friction and damping included), an open rocker station and a
// contact without slip give no force, and the power of its dissipative forces is exactly
// the power it reports dissipated, which is never negative.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "engine/simulation.hpp"
#include "tests/modules/kernel_util.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

using test::Kernel;
using test::kernel_forces;

// The mini model under load: the rocker stations and the plates carry force.
const Model& loaded() {
  static const Model m = test::model("mini", {"ramp.time=1e-4"});
  return m;
}

// A running-like state: the initial state with positions and velocities perturbed.
Eigen::VectorXd moving_state(const Model& m, unsigned seed) { return test::perturbed_state(m, seed, 3e-6, 2e-4, 0.05); }

// The statuses of the state y (every station that penetrates and pushes is active).
ContactStatus statuses(const Model& m, const Eigen::VectorXd& y) {
  Workspace ws(m);
  update_contact_status(m, ws, 0.0, y.data());
  return ws.status;
}

TEST(ChainForces, ConservativeForcesAreMinusTheChainEnergyGradient) {
  // No damping, no friction, at rest: what is left is elastic (beams, rocker Hertz, keeper,
  // plates, pack).
  const Model m = test::model("mini", {"damping.scale=0", "friction.law=\"none\""});
  Eigen::VectorXd y = moving_state(m, 11);
  y.segment(m.ndof, m.ndof).setZero();
  const ContactStatus st = statuses(m, y);
  Workspace ws(m);
  ws.status = st;
  const Eigen::VectorXd F = kernel_forces(m, ws, 0.0, y, Kernel::chain);
  const auto energy = [&](const Eigen::VectorXd& z) { return chain_energy(m, z.data(), &st); };
  double worst = 0, scale = F.cwiseAbs().maxCoeff();
  int worst_i = -1, active = 0;
  for (std::uint8_t a : st.rocker) active += a;
  for (int i = 0; i < kJointSize * m.links; ++i) {
    const int r = (i % kJointSize) % half::kEnd;
    const bool slope = (i % kJointSize) < 2 * half::kSize && (r == half::kSx || r == half::kSy);
    const double h = slope ? 1e-7 : 1e-9;
    auto at = [&](double d) {
      Eigen::VectorXd z = y;
      z[i] += d;
      return energy(z);
    };
    const double g = (-at(2 * h) + 8 * at(h) - 8 * at(-h) + at(-2 * h)) / (12 * h);
    if (std::abs(F[i] + g) > worst) worst = std::abs(F[i] + g), worst_i = i;
  }
  std::printf("[chain_forces] max |F + grad E_chain| / max |F| = %.3g over %d coordinates (max |F| %.3g N, %d "
              "active rocker stations)\n", worst / scale, kJointSize * m.links, scale, active);
  EXPECT_GT(active, 0);
  EXPECT_GT(scale, 1.0);
  // 4th-order differences of an energy of ~1e-1 J with steps of 1e-9 m: ~1e-7 relative.
  EXPECT_LE(worst / scale, 1e-6) << "coordinate " << worst_i << " (" << describe_state_index(m, worst_i) << ")";
}

TEST(ChainForces, ForcesAreInternalWithDampingAndFriction) {
  // The pins' stiffness-proportional damping beta K u' (docs/model.md 4.1) is the one force
  // that is not objective: its moment about z is beta (R v) . grad E, R the rotation's
  // direction, so for the moment the pins carry no damping (everything else does).
  const Model& m = loaded();
  const Model undamped_pins = test::model("mini", {"ramp.time=1e-4", "pin.damping_time=0"});
  const Eigen::VectorXd y = moving_state(m, 12);
  const char* names[4] = {"x", "y", "z", "moment about z"};
  for (int axis = 0; axis < 4; ++axis) {
    const Model& mm = axis < 3 ? m : undamped_pins;
    Workspace ws(mm);
    ws.status = statuses(mm, y);
    const Eigen::VectorXd F = kernel_forces(mm, ws, 2e-4, y, Kernel::chain);
    const Eigen::VectorXd d = test::rigid_motion(mm, y, axis, false);
    const double net = F.dot(d), gross = F.cwiseProduct(d).cwiseAbs().sum();
    std::printf("[chain_forces] net %s %.3g against a sum of magnitudes %.3g\n", names[axis], net, gross);
    EXPECT_GT(gross, 1.0);
    // Action and reaction pair every force: the sum cancels to round-off of its terms.
    EXPECT_LE(std::abs(net), 1e-10 * gross) << names[axis];
  }
}

TEST(ChainForces, OpenRockerStationsGiveNoForce) {
  // Every station open: nothing of the rocker contact (its stiffness, damping, friction)
  // can change the chain's forces, bit for bit, and no joint carries a rocker force.
  const Model& m = loaded();
  const Model other = test::model("mini", {"ramp.time=1e-4", "rocker.stiffness=1.6e11", "rocker.damping=90",
                                           "friction.f0=0.2"});
  const Eigen::VectorXd y = moving_state(m, 13);
  Workspace open(m), open_other(other);
  open.status = statuses(m, y);
  int were_active = 0;
  for (std::uint8_t a : open.status.rocker) were_active += a;
  std::fill(open.status.rocker.begin(), open.status.rocker.end(), 0);
  open_other.status = open.status;
  const Eigen::VectorXd F_open = kernel_forces(m, open, 2e-4, y, Kernel::chain);
  const Eigen::VectorXd F_other = kernel_forces(other, open_other, 2e-4, y, Kernel::chain);
  EXPECT_GT(were_active, 0);
  EXPECT_EQ((F_open - F_other).cwiseAbs().maxCoeff(), 0.0);
  for (int j = 0; j < m.links; ++j) EXPECT_EQ(rocker_force(m, open, j), 0.0) << "joint " << j;
  // With the stations active the same change does change the forces.
  Workspace closed(m), closed_other(other);
  closed.status = closed_other.status = statuses(m, y);
  EXPECT_GT((kernel_forces(m, closed, 2e-4, y, Kernel::chain) -
             kernel_forces(other, closed_other, 2e-4, y, Kernel::chain)).cwiseAbs().maxCoeff(), 1.0);
}

TEST(ChainForces, NoSlipNoFriction) {
  // At rest the slip velocities are zero, and so is the friction, under every law.
  Eigen::VectorXd y = moving_state(loaded(), 14);
  y.segment(loaded().ndof, loaded().ndof).setZero();
  Eigen::VectorXd F[3];
  int k = 0;
  for (const char* law : {"\"none\"", "\"nonsmooth\"", "\"smooth\""}) {
    const Model m = test::model("mini", {"ramp.time=1e-4", std::string("friction.law=") + law});
    Workspace ws(m);
    ws.status = statuses(m, y);
    F[k++] = kernel_forces(m, ws, 2e-4, y, Kernel::chain);
  }
  EXPECT_EQ((F[1] - F[0]).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_EQ((F[2] - F[0]).cwiseAbs().maxCoeff(), 0.0);
}

TEST(ChainForces, DissipatedPowerIsThePowerOfTheDissipativeForces) {
  // With velocities v, the forces F(q, v) - F(q, 0) are the dissipative ones (damping and
  // friction; the elastic part depends on q alone): their power is minus what the kernel
  // reports dissipated, joint by joint never negative.
  for (const char* law : {"\"nonsmooth\"", "\"smooth\""}) {
    const Model m = test::model("mini", {"ramp.time=1e-4", std::string("friction.law=") + law});
    for (unsigned seed : {15u, 16u}) {
      const Eigen::VectorXd y = moving_state(m, seed);
      Eigen::VectorXd rest = y;
      rest.segment(m.ndof, m.ndof).setZero();
      Workspace ws(m);
      ws.status = statuses(m, y);
      const Eigen::VectorXd F = kernel_forces(m, ws, 2e-4, y, Kernel::chain);
      const double p_diss = ws.p_diss;
      double min_slot = 0;
      for (const JointSlot& s : ws.chain_slots) min_slot = std::min(min_slot, s.p_diss);
      const Eigen::VectorXd F0 = kernel_forces(m, ws, 2e-4, rest, Kernel::chain);
      const Eigen::VectorXd v = y.segment(m.ndof, m.ndof);
      const double power = (F - F0).dot(v);
      std::printf("[chain_forces] %s law: dissipated %.6g W, power of the dissipative forces %.6g W\n", law, p_diss,
                  power);
      EXPECT_GT(p_diss, 0.0);
      EXPECT_GE(min_slot, 0.0);
      EXPECT_NEAR(-power, p_diss, 1e-9 * p_diss + 1e-12);
    }
  }
}

}  // namespace
}  // namespace cvt
