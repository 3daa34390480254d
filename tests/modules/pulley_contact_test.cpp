// pulley_contact (docs/model.md 4.5) and the friction law of contact_laws.hpp (4.1) against
// their own invariants: the conservative forces are minus the gradient of the pin ends'
// Hertz energy, every force on a pin has its reaction on the sheave's shaft (friction and
// damping included), a pin end that does not touch gives no force, the friction law has
// its branches, and the power of the dissipative forces is what the kernel reports.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "engine/simulation.hpp"
#include "modules/contact_laws.hpp"
#include "tests/modules/kernel_util.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

using test::Kernel;
using test::kernel_forces;

Eigen::VectorXd moving_state(const Model& m, unsigned seed) { return test::perturbed_state(m, seed, 3e-6, 2e-4, 0.05); }

ContactStatus statuses(const Model& m, const Eigen::VectorXd& y) {
  Workspace ws(m);
  update_contact_status(m, ws, 0.0, y.data());
  return ws.status;
}

int active(const ContactStatus& st) {
  int n = 0;
  for (std::uint8_t a : st.pulley) n += a;
  return n;
}

TEST(PulleyContact, ConservativeForcesAreMinusTheHertzEnergyGradient) {
  const Model m = test::model("mini", {"damping.scale=0", "friction.law=\"none\""});
  Eigen::VectorXd y = moving_state(m, 21);
  y.segment(m.ndof, m.ndof).setZero();
  const ContactStatus st = statuses(m, y);
  Workspace ws(m);
  ws.status = st;
  const Eigen::VectorXd F = kernel_forces(m, ws, 0.0, y, Kernel::pulley);
  const double scale = F.cwiseAbs().maxCoeff();
  double worst = 0;
  int worst_i = -1;
  for (int i = 0; i < m.ndof; ++i) {
    const bool pin = i < kJointSize * m.links;
    const int r = pin ? (i % kJointSize) % half::kEnd : (i - m.shaft(0)) % kShaftSize;
    const bool angle = pin ? (i % kJointSize) < 2 * half::kSize && (r == half::kSx || r == half::kSy)
                           : i < m.load_index() && (r == kTx || r == kTy || r == kPhi);
    const double h = angle ? 1e-7 : 1e-9;
    auto at = [&](double d) {
      Eigen::VectorXd z = y;
      z[i] += d;
      return pulley_energy(m, z.data(), &st);
    };
    const double g = (-at(2 * h) + 8 * at(h) - 8 * at(-h) + at(-2 * h)) / (12 * h);
    if (std::abs(F[i] + g) > worst) worst = std::abs(F[i] + g), worst_i = i;
  }
  std::printf("[pulley_contact] max |F + grad E_pulley| / max |F| = %.3g over %d coordinates (max |F| %.3g N, %d "
              "active pin ends)\n", worst / scale, m.ndof, scale, active(st));
  EXPECT_GT(active(st), 4);
  EXPECT_GT(scale, 1.0);
  // 4th-order differences with steps of 1e-9 m on forces of ~1e3 N: ~1e-7 relative.
  EXPECT_LE(worst / scale, 1e-6) << "coordinate " << worst_i << " (" << describe_state_index(m, worst_i) << ")";
}

// The pins' slopes and the shafts' tilts zeroed: the small-angle kinematics of a pin end's
// cap (it turns with omega = (-s_y', s_x', 0)) and of a tilted shaft (omega = (t_x', t_y',
// phi')) follow a rotation about z exactly only there; elsewhere the friction's moment
// about z is off at second order in the slopes and tilts.
Eigen::VectorXd untilted(const Model& m, Eigen::VectorXd y) {
  for (int k = 0; k < 2; ++k) y[m.shaft(k) + kTx] = y[m.shaft(k) + kTy] = 0;
  for (int j = 0; j < m.links; ++j)
    for (int o : {m.half_a(j), m.half_b(j)})
      for (int e = 0; e < 2; ++e) y[o + e * half::kEnd + half::kSx] = y[o + e * half::kEnd + half::kSy] = 0;
  return y;
}

TEST(PulleyContact, EveryForceOnAPinHasItsReactionOnTheShaft) {
  // Moving pins and shafts, damping and friction on: the forces on the pins and on the two
  // shafts sum to no net force and no net moment about z (the pins and both shafts
  // rotated together about the origin, the shafts also about their own axes).
  const Model m = test::model("mini", {"ramp.time=1e-4"});
  const char* names[4] = {"x", "y", "z", "moment about z"};
  for (bool tilted : {false, true}) {
    const Eigen::VectorXd y = tilted ? moving_state(m, 22) : untilted(m, moving_state(m, 22));
    Workspace ws(m);
    ws.status = statuses(m, y);
    const Eigen::VectorXd F = kernel_forces(m, ws, 2e-4, y, Kernel::pulley);
    for (int axis = 0; axis < 4; ++axis) {
      const Eigen::VectorXd d = test::rigid_motion(m, y, axis, true);
      const double net = F.dot(d), gross = F.cwiseProduct(d).cwiseAbs().sum();
      std::printf("[pulley_contact] %s: net %s %.3g against a sum of magnitudes %.3g\n",
                  tilted ? "slopes and tilts" : "untilted", names[axis], net, gross);
      EXPECT_GT(gross, 1.0);
      // Translations: to round-off always. The moment: to round-off untilted; with slopes and
      // tilts of ~2e-4 the linearized rotations leave ~1e-5 of it (6e-6 measured).
      const double tol = axis == 3 && tilted ? 1e-4 : 1e-10;
      EXPECT_LE(std::abs(net), tol * gross) << names[axis] << (tilted ? ", slopes and tilts" : ", untilted");
    }
  }
}

TEST(PulleyContact, APinEndThatDoesNotTouchGivesNoForce) {
  // Every status active, in motion: a joint none of whose pin ends penetrates a sheave
  // gets nothing at all, and one that does gets a force.
  const Model m = test::model("mini", {"ramp.time=1e-4"});
  const Eigen::VectorXd y = moving_state(m, 23);
  Workspace ws(m);
  std::fill(ws.status.pulley.begin(), ws.status.pulley.end(), 1);
  set_stage_input(m, ws, 2e-4, y.data());
  link_kinematics(m, ws, 0, m.links);
  int free = 0, touching = 0;
  for (int j = 0; j < m.links; ++j) {
    JointSlot s;
    PinContactReport rep;
    pulley_contact_joint(m, ws, j, s, &rep);
    bool touches = false;
    for (const auto& half : rep.end)
      for (const EndContact& e : half) touches = touches || (e.pulley >= 0 && e.penetration > 0);
    double largest = std::abs(s.tau_prev) + std::abs(s.tau_own) + std::abs(s.p_diss);
    for (double f : s.f) largest = std::max(largest, std::abs(f));
    for (double f : s.shaft) largest = std::max(largest, std::abs(f));
    if (touches) {
      ++touching;
      EXPECT_GT(largest, 0.0) << "joint " << j;
    } else {
      ++free;
      EXPECT_EQ(largest, 0.0) << "joint " << j;
    }
  }
  std::printf("[pulley_contact] %d joints touch a sheave, %d do not\n", touching, free);
  EXPECT_GT(touching, 4);
  EXPECT_GT(free, 4);
}

TEST(PulleyContact, DissipatedPowerIsThePowerOfTheDissipativeForces) {
  for (const char* law : {"\"nonsmooth\"", "\"smooth\""}) {
    const Model m = test::model("mini", {"ramp.time=1e-4", std::string("friction.law=") + law});
    const Eigen::VectorXd y = moving_state(m, 24);
    Eigen::VectorXd rest = y;
    rest.segment(m.ndof, m.ndof).setZero();
    Workspace ws(m);
    ws.status = statuses(m, y);
    const Eigen::VectorXd F = kernel_forces(m, ws, 2e-4, y, Kernel::pulley);
    const double p_diss = ws.p_diss;
    double min_slot = 0;
    for (const JointSlot& s : ws.pulley_slots) min_slot = std::min(min_slot, s.p_diss);
    const Eigen::VectorXd F0 = kernel_forces(m, ws, 2e-4, rest, Kernel::pulley);
    const double power = (F - F0).dot(y.segment(m.ndof, m.ndof));
    std::printf("[pulley_contact] %s law: dissipated %.6g W, power of the dissipative forces %.6g W\n", law, p_diss,
                power);
    EXPECT_GT(p_diss, 0.0);
    EXPECT_GE(min_slot, 0.0);
    EXPECT_NEAR(-power, p_diss, 1e-9 * p_diss + 1e-12);
  }
}

// The friction law of one contact (docs/model.md 4.1): R = -N f(|u|) u/|u| on the tangent
// plane, f(v) = f0 min(v/v0, 1) (nonsmooth), f0 (2/pi) atan(pi v/(2 v0)) (smooth), 0 (none).
TEST(FrictionLaw, BranchesOfTheRegularizedLaws) {
  const double f0 = 0.09, v0 = 1e-3, N = 250.0;
  const double n[3] = {0, 0, 1};
  for (double speed : {0.0, 0.3e-3, 0.999e-3, 1.001e-3, 5e-3, 2.0}) {
    const double u[3] = {0.6 * speed, -0.8 * speed, 0.0};
    double R[3], mag = -1;
    // nonsmooth: linear in u below v0 (stick), magnitude f0 N and against u above (slide).
    const double p = contact_friction(FrozenBranch{}, FrictionLaw::nonsmooth, f0, v0, N, u, speed, n, R, &mag);
    const double expect_mag = N * f0 * std::min(speed / v0, 1.0);
    EXPECT_NEAR(mag, expect_mag, 1e-12 * N) << speed;
    for (int i = 0; i < 3; ++i)
      EXPECT_NEAR(R[i], speed > 0 ? -expect_mag * u[i] / speed : 0.0, 1e-12 * N) << speed;
    EXPECT_NEAR(p, expect_mag * speed, 1e-12 * N);  // -R . u
    EXPECT_GE(p, 0.0);
    // smooth: the arctangent, never above f0 N, the same slope f0/v0 at rest.
    contact_friction(FrozenBranch{}, FrictionLaw::smooth, f0, v0, N, u, speed, n, R, &mag);
    EXPECT_NEAR(mag, N * f0 * (2 / M_PI) * std::atan(M_PI * speed / (2 * v0)), 1e-12 * N) << speed;
    EXPECT_LE(mag, N * f0);
    // none: nothing.
    EXPECT_EQ(contact_friction(FrozenBranch{}, FrictionLaw::none, f0, v0, N, u, speed, n, R, &mag), 0.0);
    EXPECT_EQ(mag, 0.0);
  }
}

TEST(FrictionLaw, FrozenBranchKeepsWhatItRecorded) {
  // Recorded sliding along +x; later the slip turns and slows below v0: the frozen law
  // keeps sliding along the recorded direction (projected on the tangent plane) with f0 N.
  const double f0 = 0.09, v0 = 1e-3, N = 100.0;
  const double n[3] = {0, 0, 1};
  std::uint8_t stick = 0;
  double dir[3] = {0, 0, 0}, R[3];
  const double u1[3] = {2e-3, 0, 0};
  contact_friction(FrozenBranch{true, &stick, dir}, FrictionLaw::nonsmooth, f0, v0, N, u1, 2e-3, n, R);
  EXPECT_EQ(stick, 0);
  EXPECT_NEAR(R[0], -f0 * N, 1e-12);
  const double u2[3] = {0, 0.2e-3, 0};
  contact_friction(FrozenBranch{false, &stick, dir}, FrictionLaw::nonsmooth, f0, v0, N, u2, 0.2e-3, n, R);
  EXPECT_NEAR(R[0], -f0 * N, 1e-12);
  EXPECT_NEAR(R[1], 0.0, 1e-12);
  // Recorded sticking: linear in the slip, whatever its later size.
  contact_friction(FrozenBranch{true, &stick, dir}, FrictionLaw::nonsmooth, f0, v0, N, u2, 0.2e-3, n, R);
  EXPECT_EQ(stick, 1);
  contact_friction(FrozenBranch{false, &stick, dir}, FrictionLaw::nonsmooth, f0, v0, N, u1, 2e-3, n, R);
  EXPECT_NEAR(R[0], -N * f0 / v0 * 2e-3, 1e-9);  // twice f0 N: the stick branch, extended
}

}  // namespace
}  // namespace cvt
