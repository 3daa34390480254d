// Other forces (docs/model.md 4.6): shaft supports, drive, load, clamping, controller,
// against their own invariants: the conservative forces are minus the gradient of the
// documented energies; load torque and clamping follow the ramp rho(t); the reported powers
// are force times velocity and close the energy balance of the module.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <functional>
#include <random>
#include <string>

#include "engine/rhs/rhs.hpp"
#include "modules/other_forces.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

int ishaft(const Model& m, int k) { return 21 * m.links + 7 * k; }
int iload(const Model& m) { return 21 * m.links + 14; }
enum { Ux, Uy, Uz, Tx, Ty, Phi, W };

// The ramp of docs/model.md 4.6.4.
double rho(double t, double tr) {
  if (tr <= 0 || t >= tr) return 1.0;
  if (t <= 0) return 0.0;
  return 0.5 * (1 - std::cos(M_PI * t / tr));
}
double rho_dot(double t, double tr) { return tr > 0 && t > 0 && t < tr ? M_PI / (2 * tr) * std::sin(M_PI * t / tr) : 0.0; }

// The module's energy (docs/model.md 6): bearings (1/2 k1 |delta|^2 + 1/4 k3 |delta|^4 at
// z_b = -+l_b), axial bearing, clamping potential sigma_m F rho w, drive and load springs.
// The clamping forces' potential part of docs/model.md 4.6.4: F_k rho(t).
double documented_clamp(const Model& m, int k, double t) {
  const Config& c = m.cfg;
  return (k == 0 ? c.clamping.driving : c.clamping.driven) * rho(t, c.ramp.time);
}

// The slip-safe clamping's forces of docs/model.md 4.6.4, from the sheave positions of y:
// R_k = R_k0 - sigma_k w_k / (2 tan beta), the torque to transmit M_t = |M_load(t)| +
// J_L omega_in |d target/dt| / target^2 (`target_rate` the profile's slope), the base force
// B = max(min(F1, F2) rho, S M_t cos(beta) / (2 f0 R2)), kappa = F1/F2 * exp(-(kp e + ki I)) within
// [1/limit, limit], and F1 = B max(kappa, 1), F2 = B max(1/kappa, 1).
std::array<double, 2> documented_slip_safe(const Model& m, double t, const Eigen::VectorXd& y, double target,
                                           double target_rate = 0) {
  const Config& c = m.cfg;
  const double tb = std::tan(c.sheave.cone_angle * M_PI / 180);
  const double R1 = m.pulley[0].running_radius - y[ishaft(m, 0) + W] / (2 * tb);  // driving: sigma = +1
  const double R2 = m.pulley[1].running_radius + y[ishaft(m, 1) + W] / (2 * tb);  // driven: sigma = -1
  const double ts = t - c.ramp.load_start;
  const double M = ts <= 0 ? c.ramp.load_from : c.ramp.load_from + (c.load.torque - c.ramp.load_from) * rho(ts, c.ramp.load_time);
  const double Mt = M + c.load.inertia * c.drive.speed * std::abs(target_rate) / (target * target);
  const double B = std::max(std::min(c.clamping.driving, c.clamping.driven) * rho(t, c.ramp.time),
                            c.controller.clamping_safety * Mt * std::cos(c.sheave.cone_angle * M_PI / 180) / (2 * c.friction.f0 * R2));
  const double e = target - R2 / R1;
  double kappa = c.clamping.driving / c.clamping.driven *
                 std::exp(-(c.controller.shift_kp * e + c.controller.shift_ki * y[2 * m.ndof + kCtrlIntegral]));
  kappa = std::clamp(kappa, 1 / c.controller.thrust_limit, c.controller.thrust_limit);
  return {B * std::max(kappa, 1.0), B * std::max(1 / kappa, 1.0)};
}

double documented_energy(const Model& m, double t, const double* q) {
  const Config& c = m.cfg;
  double E = 0;
  for (int k = 0; k < 2; ++k) {
    const double* s = q + ishaft(m, k);
    for (double zb : {-c.bearing.half_span, c.bearing.half_span}) {
      const double dx = s[Ux] + s[Ty] * zb, dy = s[Uy] - s[Tx] * zb, d2 = dx * dx + dy * dy;
      E += 0.5 * c.bearing.k1 * d2 + 0.25 * c.bearing.k3 * d2 * d2;
    }
    E += 0.5 * c.bearing.axial_stiffness * s[Uz] * s[Uz];
    E += m.pulley[k].moving_side * documented_clamp(m, k, t) * s[W];
  }
  const double din = c.drive.speed * t - q[ishaft(m, 0) + Phi], dl = q[ishaft(m, 1) + Phi] - q[iload(m)];
  return E + 0.5 * c.drive.stiffness * din * din + 0.5 * c.load.stiffness * dl * dl;
}

OtherForces run_other(const Model& m, double t, const Eigen::VectorXd& y) {
  Workspace ws(m);
  set_stage_input(m, ws, t, y.data());
  other_forces(m, ws);
  return ws.other;
}

// A state with loaded supports and springs: shafts displaced by up to 1.5e-4 m and tilted
// by up to 2e-3 rad (where the cubic bearing term is as large as the linear one), the
// drive and load springs wound by up to 0.02 rad, the sheaves moved by up to 2e-5 m.
Eigen::VectorXd loaded_state(const Model& m, unsigned seed, double t, double dv) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Eigen::VectorXd y = m.y0;
  for (int k = 0; k < 2; ++k) {
    double* s = y.data() + ishaft(m, k);
    double* sv = s + m.ndof;
    s[Ux] = 1.5e-4 * u(rng), s[Uy] = 1.5e-4 * u(rng), s[Uz] = 1e-5 * u(rng);
    s[Tx] = 2e-3 * u(rng), s[Ty] = 2e-3 * u(rng), s[W] = 2e-5 * u(rng);
    for (int i = 0; i < 7; ++i) sv[i] += (i == Phi ? 50.0 : 1.0) * dv * u(rng);
  }
  y[ishaft(m, 0) + Phi] = m.cfg.drive.speed * t + 0.02 * u(rng);
  y[ishaft(m, 1) + Phi] = 0.3 + 0.02 * u(rng);
  y[iload(m)] = 0.3 + 0.02 * u(rng);
  y[m.ndof + iload(m)] += 50.0 * dv * u(rng);
  return y;
}

enum class Part { bearings_linear, bearings_cubic, axial, drive, load, clamping };
const char* name(Part p) {
  switch (p) {
    case Part::bearings_linear: return "bearings_linear";
    case Part::bearings_cubic: return "bearings_cubic";
    case Part::axial: return "axial";
    case Part::drive: return "drive";
    case Part::load: return "load";
    case Part::clamping: return "clamping";
  }
  return "?";
}

// ---- Tests.

TEST(OtherForcesTest, OtherEnergyIsTheDocumentedSum) {
  const Model m = test::model("mini");
  const double tr = m.cfg.ramp.time;
  for (double t : {0.0, 0.3 * tr, 2 * tr}) {
    const Eigen::VectorXd y = loaded_state(m, 1, t, 0.0);
    const double E = documented_energy(m, t, y.data());
    // Same terms, round-off only.
    EXPECT_NEAR(other_energy(m, t, y.data()), E, 1e-13 * std::abs(E)) << "t " << t;
  }
}

class OtherPartGradientTest : public ::testing::TestWithParam<Part> {};

// At rest, without damping and load torque, each element's forces on the shafts and the
// load are -grad of its energy (the others' stiffnesses zeroed in the model's configuration).
TEST_P(OtherPartGradientTest, ConservativeForcesAreMinusTheEnergyGradient) {
  const Part p = GetParam();
  Model m = test::model("mini", {"damping.scale=0", "load.torque=0"});
  Config& c = m.cfg;
  if (p != Part::bearings_linear) c.bearing.k1 = 0;
  if (p != Part::bearings_cubic) c.bearing.k3 = 0;
  if (p != Part::axial) c.bearing.axial_stiffness = 0;
  if (p != Part::drive) c.drive.stiffness = 0;
  if (p != Part::load) c.load.stiffness = 0;
  if (p != Part::clamping) c.clamping.driving = c.clamping.driven = 0;
  const double t = 0.4 * c.ramp.time;  // clamping partly ramped, drive angle nonzero
  for (unsigned seed : {1u, 2u}) {
    Eigen::VectorXd y = loaded_state(m, seed, t, 0.0);
    y.segment(m.ndof, m.ndof).setZero();
    const OtherForces o = run_other(m, t, y);
    double worst = 0, scale = 0;
    Eigen::VectorXd z = y;
    for (int i = 0; i < 15; ++i) {
      const int qi = ishaft(m, 0) + i;
      const int r = i % 7;
      const double h = (i == 14 || r == Tx || r == Ty || r == Phi) ? 1e-7 : 1e-9;  // angles, lengths
      const auto at = [&](double d) {
        z[qi] = y[qi] + d;
        const double e = documented_energy(m, t, z.data());
        z[qi] = y[qi];
        return e;
      };
      const double g = (-at(2 * h) + 8 * at(h) - 8 * at(-h) + at(-2 * h)) / (12 * h);
      worst = std::max(worst, std::abs(o.f[i] + g));
      scale = std::max(scale, std::abs(o.f[i]));
    }
    std::printf("[%s, seed %u] max |F| = %.4g, max |F + grad E| / max |F| = %.3g\n", name(p), seed, scale,
                worst / scale);
    EXPECT_GT(scale, 10.0);
    // The energies are polynomials of degree <= 4 in q, which the 4th-order stencil
    // differentiates exactly: round-off only, ~1e-16 E/h (E < 1e3 J) against forces > 10 N.
    EXPECT_LE(worst, 1e-8 * scale);
  }
}

INSTANTIATE_TEST_SUITE_P(Parts, OtherPartGradientTest,
                         ::testing::Values(Part::bearings_linear, Part::bearings_cubic, Part::axial, Part::drive,
                                           Part::load, Part::clamping),
                         [](const ::testing::TestParamInfo<Part>& i) { return std::string(name(i.param)); });

// M_load = M0 rho(t) + c_w phi_L', clamping forces F_k rho(t) on the moving sheaves (towards
// the chain: -sigma_m F rho on w), P_clamp = sum sigma_m F_k rho'(t) w_k: at the start,
// during and after the ramp.
TEST(OtherForcesTest, LoadTorqueAndClampingFollowTheRamp) {
  const Model m = test::model("mini", {"load.speed_coefficient=0.01"});
  const Config& c = m.cfg;
  const double tr = c.ramp.time, F[2] = {c.clamping.driving, c.clamping.driven};
  Eigen::VectorXd y = m.y0;
  y[ishaft(m, 0) + W] = 1e-5, y[ishaft(m, 1) + W] = -2e-5;
  y[m.ndof + iload(m)] += 7.0;  // the load turning faster than the driven pulley
  const double wL = y[m.ndof + iload(m)];
  ASSERT_GT(wL, 100.0);
  for (double t : {0.0, 0.25 * tr, 0.5 * tr, 0.75 * tr, tr, 2 * tr}) {
    const OtherForces o = run_other(m, t, y);
    const double r = rho(t, tr), rd = rho_dot(t, tr);
    const double Mload = c.load.torque * r + c.load.speed_coefficient * wL;
    // Round-off of a few operations.
    EXPECT_NEAR(o.load_torque, Mload, 1e-14 * c.load.torque) << "t " << t;
    // The load angle takes M_s - M_load, the driven pulley -M_s.
    EXPECT_NEAR(o.f[14] + o.f[7 + Phi], -Mload, 1e-12 * c.load.torque) << "t " << t;
    double p_clamp = 0;
    for (int k = 0; k < 2; ++k) {
      const int s = m.pulley[k].moving_side;
      EXPECT_NEAR(o.clamp[k], F[k] * r, 1e-14 * F[k]) << "t " << t << " pulley " << k;
      EXPECT_NEAR(o.f[7 * k + W], -s * F[k] * r, 1e-14 * F[k]) << "t " << t << " pulley " << k;
      p_clamp += s * F[k] * rd * y[ishaft(m, k) + W];
    }
    EXPECT_NEAR(o.p_clamp, p_clamp, 1e-14 * (F[0] + F[1]) * 2e-5 * M_PI / tr) << "t " << t;
  }
  // The documented values themselves: nothing at t = 0, half at mid-ramp, all from t_r on,
  // and a C1 ramp (no jump in rho nor in rho' at either end).
  const auto at = [&](double t) { return run_other(m, t, y); };
  EXPECT_EQ(at(0.0).clamp[0], 0.0);
  EXPECT_EQ(at(0.0).p_clamp, 0.0);
  EXPECT_EQ(at(0.0).load_torque, c.load.speed_coefficient * wL);
  EXPECT_NEAR(at(0.5 * tr).clamp[1], 0.5 * F[1], 1e-12 * F[1]);  // cos(pi / 2) ~ 6e-17, round-off
  EXPECT_EQ(at(tr).clamp[1], F[1]);
  EXPECT_EQ(at(3 * tr).load_torque, c.load.torque + c.load.speed_coefficient * wL);
  EXPECT_NEAR(at(tr * (1 - 1e-7)).clamp[1], F[1], 1e-12 * F[1]);  // 1 - rho ~ (pi 1e-7)^2 / 4
  EXPECT_NEAR(at(tr * 1e-7).clamp[1], 0.0, 1e-12 * F[1]);  // rho ~ (pi 1e-7)^2 / 4
  EXPECT_NEAR(at(tr * (1 - 1e-7)).p_clamp, 0.0, 1e-6 * std::abs(at(0.5 * tr).p_clamp));  // rho' ~ pi 1e-7 of its peak
  EXPECT_NEAR(at(tr * 1e-7).p_clamp, 0.0, 1e-6 * std::abs(at(0.5 * tr).p_clamp));  // rho' ~ pi 1e-7 of its peak
  EXPECT_NE(at(0.5 * tr).p_clamp, 0.0);
}

// The load torque on its own ramp (docs/model.md 4.6.3): load_from until load_start, then
// to load.torque over load_time, while the clamping forces follow ramp.time.
TEST(OtherForcesTest, LoadTorqueHasItsOwnRamp) {
  const Model m = test::model("mini", {"ramp.load_time=4e-3", "ramp.load_start=2e-3", "ramp.load_from=3.0"});
  const Config& c = m.cfg;
  const double tr = c.ramp.time, tl = 4e-3, ts = 2e-3, M0 = c.load.torque, Mf = 3.0;
  ASSERT_LT(tr, ts);
  const Eigen::VectorXd y = m.y0;
  for (double t : {0.0, 0.5 * tr, ts, ts + 0.25 * tl, ts + 0.5 * tl, ts + tl, ts + 3 * tl}) {
    const OtherForces o = run_other(m, t, y);
    const double want = Mf + (M0 - Mf) * rho(t - ts, tl);
    EXPECT_NEAR(o.load_torque, want, 1e-14 * M0) << "t " << t;
    EXPECT_NEAR(o.clamp[0], c.clamping.driving * rho(t, tr), 1e-14 * c.clamping.driving) << "t " << t;
  }
  const auto at = [&](double t) { return run_other(m, t, y).load_torque; };
  EXPECT_EQ(at(0.0), Mf);
  EXPECT_EQ(at(ts), Mf);
  EXPECT_NEAR(at(ts + 0.5 * tl), 0.5 * (Mf + M0), 1e-12 * M0);
  EXPECT_EQ(at(ts + tl), M0);
  EXPECT_EQ(ramps_end(c), ts + tl);
  // Not given, the load's ramp is the clamping's: ramp.load_time = ramp.time.
  const Model d = test::model("mini");
  EXPECT_EQ(d.cfg.ramp.load_time, d.cfg.ramp.time);
  EXPECT_EQ(ramps_end(d.cfg), d.cfg.ramp.time);
}

// The powers are force times velocity (P_in = M_in omega_in, P_out = M_load phi_L'), each
// damper dissipates (P_diss >= 0), and together they close the module's balance
//   Q . v + dE/dq . v + dE/dt = P_in + P_clamp - P_out - P_diss
// (docs/model.md 6: Q . v is the power the module's forces deliver to the coordinates,
// E its energy), with and without the ratio controller.
TEST(OtherForcesTest, PowersAreForceTimesVelocityAndCloseTheBalance) {
  for (const int ctrl : {0, 1, 2}) {
    std::vector<std::string> ov = {"load.speed_coefficient=0.01"};
    if (ctrl) ov.insert(ov.end(), {"controller.enabled=true", "controller.target_ratio=1.05"});
    if (ctrl == 1) ov.insert(ov.end(), {"controller.kp=2e3", "controller.ki=1e6"});
    // The slip-safe clamping (S M cos(beta) / (2 f0 R2) = 3.7 kN rho above the 2 kN floor),
    // on the load's own later ramp.
    if (ctrl == 2) ov.insert(ov.end(), {"controller.clamping_safety=1.3", "controller.shift_kp=2", "controller.shift_ki=300",
                                        "clamping.driven=2e3", "clamping.driving=2.3e3", "ramp.load_time=5e-4",
                                        "ramp.load_start=2e-4", "ramp.load_from=1.0"});
    const Model m = test::model("mini", ov);
    const double tr = m.cfg.ramp.time;
    for (unsigned seed : {3u, 4u}) {
      const double t = 0.37 * tr;
      Eigen::VectorXd y = loaded_state(m, seed, t, 1.0);
      y[2 * m.ndof + kCtrlIntegral] = 3e-4;
      const OtherForces o = run_other(m, t, y);
      const double* v = y.data() + m.ndof;
      const int pl = iload(m);
      const double w_in = m.cfg.drive.speed;
      // Round-off of one product.
      EXPECT_NEAR(o.p_in, o.f[Phi] * w_in, 1e-14 * std::abs(o.p_in));
      const double Mload = -(o.f[7 + Phi] + o.f[14]);
      EXPECT_NEAR(o.p_out, Mload * v[pl], 1e-12 * std::abs(o.p_out));
      EXPECT_GT(o.p_diss, 0.0);
      // Power delivered to the coordinates, and the energy's rate along v and in t (4th-order
      // differences of a polynomial in q: exact; in t: truncation ~(pi h / t_r)^4, nil).
      double Qv = 0, size = 0;
      for (int i = 0; i < 15; ++i) Qv += o.f[i] * v[ishaft(m, 0) + i], size += std::abs(o.f[i] * v[ishaft(m, 0) + i]);
      const auto along = [&](double s) {
        Eigen::VectorXd z = y;
        for (int i = ishaft(m, 0); i < m.ndof; ++i) z[i] += s * v[i];
        return documented_energy(m, t, z.data());
      };
      const auto in_time = [&](double s) { return documented_energy(m, t + s, y.data()); };
      const double hs = 1e-7, ht = 1e-6 * tr;
      const double dEdq_v = (-along(2 * hs) + 8 * along(hs) - 8 * along(-hs) + along(-2 * hs)) / (12 * hs);
      const double dEdt = (-in_time(2 * ht) + 8 * in_time(ht) - 8 * in_time(-ht) + in_time(-2 * ht)) / (12 * ht);
      const double lhs = Qv + dEdq_v + dEdt, rhs = o.p_in + o.p_clamp - o.p_out - o.p_diss;
      std::printf("[controller %d, seed %u] Q.v = %.6g, dE/dq.v = %.6g, dE/dt = %.6g | P_in %.6g P_clamp %.4g "
                  "P_out %.6g P_diss %.6g W | residual %.3g\n",
                  ctrl, seed, Qv, dEdq_v, dEdt, o.p_in, o.p_clamp, o.p_out, o.p_diss, lhs - rhs);
      // Round-off of the sums (~1e-16 of the largest power) and of the differences
      // (~1e-16 E / h with E ~ 1e3 J, h = 1e-7 s: ~1e-6 W); powers are ~1e4-1e5 W.
      EXPECT_NEAR(lhs, rhs, 1e-10 * (size + std::abs(o.p_in) + std::abs(o.p_out) + o.p_diss) + 1e-5);
      if (ctrl) {
        EXPECT_NE(o.clamp[0], m.cfg.clamping.driving * rho(t, tr)) << "the controller must act";
      }
      if (ctrl == 2) {
        const auto Fs = documented_slip_safe(m, t, y, 1.05);
        EXPECT_GT(std::min(Fs[0], Fs[1]), m.cfg.clamping.driven * rho(t, tr)) << "the torque must set the forces";
        for (int k = 0; k < 2; ++k) EXPECT_NEAR(o.clamp[k], Fs[k], 1e-12 * Fs[k]) << "pulley " << k;
      }
    }
  }
}

// The target follows controller.target_profile: linear between its points, held before
// the first and after the last, a step where two points share a time.
TEST(OtherForcesTest, TargetFollowsItsProfile) {
  const Config c = test::model("mini", {"controller.target_profile=[[0.01, 1.0], [0.02, 1.2], [0.03, 1.2], [0.03, 0.8]]"}).cfg;
  EXPECT_EQ(target_ratio(c, 0.0), 1.0);
  EXPECT_EQ(target_ratio(c, 0.01), 1.0);
  EXPECT_NEAR(target_ratio(c, 0.015), 1.1, 1e-15);
  EXPECT_EQ(target_ratio(c, 0.025), 1.2);
  EXPECT_EQ(target_ratio(c, 0.03), 0.8);
  EXPECT_EQ(target_ratio(c, 1.0), 0.8);
  EXPECT_EQ(target_ratio(test::model("mini", {"controller.target_ratio=1.1"}).cfg, 0.5), 1.1);  // no profile
  // A ratio the chain cannot run at is named as the controller's key.
  for (const std::string& ov : {std::string("controller.target_ratio=3.0"), std::string("controller.target_profile=[[0, 1.0], [0.1, 3.0]]")}) {
    try {
      test::model("mini", {"controller.enabled=true", ov});
      ADD_FAILURE() << "no error for " << ov;
    } catch (const ConfigError& e) {
      EXPECT_EQ(e.key(), ov.substr(0, ov.find('=')));
      EXPECT_NE(std::string(e.what()).find("impossible ratio"), std::string::npos) << e.what();
    }
  }
}

// The slip-safe clamping keeps both forces at or above the slip-safe force S M_t cos(beta)
// / (2 f0 R2), whichever way the PI shifts: the thrust ratio at its limit, the smaller force
// at that floor, and the integral held while the error pushes the limit further.
TEST(OtherForcesTest, SlipSafeClampingKeepsBothForcesSafe) {
  for (const double target : {1.5, 0.7}) {
    const Model m = test::model("mini", {"controller.enabled=true", "controller.shift_kp=100", "controller.shift_ki=10",
                                         "controller.target_ratio=" + std::to_string(target), "controller.clamping_safety=1.3",
                                         "controller.thrust_limit=2.5", "clamping.driven=2e3", "clamping.driving=2.3e3"});
    const double tr = m.cfg.ramp.time;
    for (double t : {0.2 * tr, 0.5 * tr, 2 * tr}) {
      const OtherForces o = run_other(m, t, m.y0);
      const double floor = 1.3 * m.cfg.load.torque * rho(t, tr) * std::cos(11 * M_PI / 180) /
                           (2 * m.cfg.friction.f0 * m.pulley[1].running_radius);
      EXPECT_GT(floor, m.cfg.clamping.driven * rho(t, tr));
      const int low = target > 1 ? 0 : 1;  // towards underdrive F1 is the smaller force
      EXPECT_NEAR(o.clamp[low], floor, 1e-12 * floor) << "t " << t;
      EXPECT_NEAR(o.clamp[1 - low], 2.5 * floor, 1e-12 * floor) << "t " << t;
      EXPECT_EQ(o.ctrl_rate, 0.0) << "the integral must hold at the limit";
    }
  }
}

// Along a sloped stretch of the target profile the transmitted torque adds what accelerates
// the load, J_L omega_in |d target/dt| / target^2: a shift towards overdrive speeds the
// load up, and the clamping must carry that torque too.
TEST(OtherForcesTest, SlipSafeClampingCarriesTheShiftsAcceleration) {
  const Model m = test::model("mini", {"controller.enabled=true", "controller.shift_kp=2", "controller.shift_ki=10",
                                       "controller.clamping_safety=1.3", "clamping.driven=2e3", "clamping.driving=2.3e3",
                                       "controller.target_profile=[[0.002, 1.0], [0.012, 0.8]]"});
  const double t = 0.007, target = 0.9, rate = -20.0;  // halfway along the profile
  EXPECT_NEAR(target_rate(m.cfg, t), rate, 1e-12);
  EXPECT_NEAR(transmitted_torque(m.cfg, t), m.cfg.load.torque + m.cfg.load.inertia * m.cfg.drive.speed * 20 / 0.81, 1e-9);
  EXPECT_EQ(transmitted_torque(m.cfg, 0.02), m.cfg.load.torque);  // past the profile: the load alone
  Eigen::VectorXd y = loaded_state(m, 7, t, 1.0);
  y[2 * m.ndof + kCtrlIntegral] = -2e-4;
  const OtherForces o = run_other(m, t, y);
  const auto Fs = documented_slip_safe(m, t, y, target, rate);
  for (int k = 0; k < 2; ++k) EXPECT_NEAR(o.clamp[k], Fs[k], 1e-12 * Fs[k]) << "pulley " << k;
  const auto still = documented_slip_safe(m, t, y, target, 0.0);  // the same target held still
  EXPECT_GT(std::min(Fs[0], Fs[1]), 1.5 * std::min(still[0], still[1])) << "the load's acceleration doubles M_t";
}

// Without damping and speed-proportional load, nothing dissipates whatever the velocities.
TEST(OtherForcesTest, NoDampingNoDissipation) {
  const Model m = test::model("mini", {"damping.scale=0"});
  const Eigen::VectorXd y = loaded_state(m, 5, 0.5e-3, 1.0);
  EXPECT_EQ(run_other(m, 0.5e-3, y).p_diss, 0.0);
}

// The controller may lower the driving clamping force but never below zero: F1 rho + Fc >= 0.
TEST(OtherForcesTest, ControllerNeverPullsTheDrivingSheaveOpen) {
  const Model m = test::model("mini", {"controller.enabled=true", "controller.kp=1e7", "controller.ki=0",
                                       "controller.target_ratio=1.5"});
  const double tr = m.cfg.ramp.time;
  for (double t : {0.2 * tr, 0.5 * tr, 2 * tr}) {
    const OtherForces o = run_other(m, t, m.y0);
    // The demand is far beyond F1 (error 0.5 x 1e7 N): saturated at F1 rho + Fc = 0.
    EXPECT_GE(o.clamp[0], 0.0) << "t " << t;
    EXPECT_NEAR(o.clamp[0], 0.0, 1e-12 * m.cfg.clamping.driving) << "t " << t;
    EXPECT_NEAR(o.f[W], 0.0, 1e-12 * m.cfg.clamping.driving) << "t " << t;
    EXPECT_GT(o.ctrl_rate, 0.4);
  }
}

}  // namespace
}  // namespace cvt
