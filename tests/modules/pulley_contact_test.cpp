// Pulley contact (docs/model.md 4.5) against its own invariants: the normal forces are minus
// the gradient of the Hertz energy of the pin ends, written here from the documented
// sphere-against-cone geometry; each pin end and its sheave take opposite forces, and the
// sheave's moment is r x F about the pulley centre; an end with a gap exerts nothing; the
// friction laws of contact_laws.hpp (docs/model.md 4.1) in their stick and slide branches;
// the dissipated power is >= 0 and is the power lost by the friction and damping forces.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "engine/rhs/rhs.hpp"
#include "modules/contact_laws.hpp"
#include "modules/inertia.hpp"
#include "modules/pulley_contact.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

// ---- The documented geometry (docs/model.md 2.2, 4.5), independent of the kernel.

int jw(const Model& m, int j) { return ((j % m.links) + m.links) % m.links; }
int ia(const Model& m, int j) { return 21 * jw(m, j); }
int ib(const Model& m, int j) { return 21 * jw(m, j) + 10; }
int ishaft(const Model& m, int k) { return 21 * m.links + 7 * k; }
int ihalf(const Model& m, int j, int h) { return h == 0 ? ia(m, j) : ib(m, j); }
int contact_index(int j, int h, int e, int k) { return ((j * 2 + h) * 2 + e) * 2 + k; }
double midp(const double* h, int p) { return 0.5 * (h[p] + h[5 + p]); }

void link_delta(const Model& m, const double* q, int i, double& dx, double& dy) {
  dx = midp(q + ia(m, i + 1), 0) - midp(q + ib(m, i), 0);
  dy = midp(q + ia(m, i + 1), 1) - midp(q + ib(m, i), 1);
}

// One pin end (joint j, half h = 0 a / 1 b, end e, sigma = -1 / +1) against pulley k.
struct End {
  bool near = false;  // half's mid-point within the outer radius of pulley k
  bool moving = false;
  double sigma = 0;
  double pen = 0;        // Delta
  double d[3] = {};      // c - O - u
  double n[3] = {};      // unit contact normal g_c / |g_c|
  double rs[3] = {};     // contact point P - O - u = d + R n
};

End end_of(const Model& m, const double* q, int j, int h, int e, int k) {
  const Config& c = m.cfg;
  const double R = c.pulley_contact.end_radius;
  const double beta = c.sheave.cone_angle * M_PI / 180.0, sb = std::sin(beta), cb = std::cos(beta);
  const double* hq = q + ihalf(m, j, h);
  const double* p = hq + 5 * e;
  const double* sh = q + ishaft(m, k);
  const Pulley& pu = m.pulley[k];
  End E;
  E.sigma = e == 0 ? -1.0 : 1.0;
  E.near = std::hypot(midp(hq, 0) - pu.centre.x(), midp(hq, 1) - pu.centre.y()) < c.sheave.outer_radius;
  E.moving = E.sigma == pu.moving_side;
  // 4.5.1 sphere centre, 4.5.2 shaft frame, 4.5.3 penetration and gradient.
  const double cx = p[0] - E.sigma * R * p[3], cy = p[1] - E.sigma * R * p[4], cz = p[2] - E.sigma * R;
  E.d[0] = cx - pu.centre.x() - sh[0], E.d[1] = cy - pu.centre.y() - sh[1], E.d[2] = cz - sh[2];
  const double tx = sh[3], ty = sh[4], w = E.moving ? sh[6] : 0.0;
  const double lx = E.d[0] - ty * E.d[2], ly = E.d[1] + tx * E.d[2], lz = E.d[2] - tx * E.d[1] + ty * E.d[0];
  const double r = std::hypot(lx, ly);
  E.pen = R + E.sigma * (lz - pu.face_z[e] - w) * cb - r * sb;
  const double G[3] = {-sb * lx / r, -sb * ly / r, E.sigma * cb};
  const double gc[3] = {G[0] + ty * G[2], G[1] - tx * G[2], -ty * G[0] + tx * G[1] + G[2]};
  const double gl = std::sqrt(gc[0] * gc[0] + gc[1] * gc[1] + gc[2] * gc[2]);
  for (int i = 0; i < 3; ++i) E.n[i] = gc[i] / gl, E.rs[i] = E.d[i] + R * E.n[i];
  return E;
}

struct PulleyEnergy {
  double E = 0;
  double min_abs_pen = std::numeric_limits<double>::infinity();  // over the ends near a pulley
  int penetrating = 0;
};

// Section 6's pulley term: (2/5) c_p Delta_+^(5/2) over every end near a pulley.
PulleyEnergy documented_energy(const Model& m, const double* q) {
  PulleyEnergy P;
  for (int j = 0; j < m.links; ++j)
    for (int h = 0; h < 2; ++h)
      for (int k = 0; k < 2; ++k)
        for (int e = 0; e < 2; ++e) {
          const End E = end_of(m, q, j, h, e, k);
          if (!E.near) continue;
          P.min_abs_pen = std::min(P.min_abs_pen, std::abs(E.pen));
          if (E.pen > 0) P.E += 0.4 * m.cfg.pulley_contact.stiffness * std::pow(E.pen, 2.5), ++P.penetrating;
        }
  return P;
}

// ---- Running the kernel and reading its slots (docs/model.md 4.0).

std::vector<JointSlot> run_pulley(const Model& m, const Eigen::VectorXd& y,
                                  const std::vector<std::uint8_t>* status = nullptr) {
  Workspace ws(m);
  if (status) ws.status.pulley = *status;
  set_stage_input(m, ws, 0.0, y.data());
  link_kinematics(m, ws, 0, m.links);
  pulley_contact(m, ws, 0, m.links);
  return ws.pulley_slots;
}

// Statuses with only contact (j, h, e, k) active.
std::vector<std::uint8_t> only_contact(const Model& m, int j, int h, int e, int k) {
  std::vector<std::uint8_t> s(m.links * 8, 0);
  s[contact_index(j, h, e, k)] = 1;
  return s;
}

// Slot j's (or all slots') generalized forces over q, the link torques through g_i (3.1).
Eigen::VectorXd generalized(const Model& m, const double* q, const std::vector<JointSlot>& slots, int only = -1) {
  Eigen::VectorXd Q = Eigen::VectorXd::Zero(m.ndof);
  const auto torque = [&](int i, double tau) {
    double dx, dy;
    link_delta(m, q, i, dx, dy);
    const double l2 = dx * dx + dy * dy, gx = -0.5 * dy / l2, gy = 0.5 * dx / l2;
    for (int e = 0; e < 2; ++e) {
      Q[ia(m, i + 1) + 5 * e] += tau * gx, Q[ia(m, i + 1) + 5 * e + 1] += tau * gy;
      Q[ib(m, i) + 5 * e] -= tau * gx, Q[ib(m, i) + 5 * e + 1] -= tau * gy;
    }
  };
  for (int j = 0; j < m.links; ++j) {
    if (only >= 0 && j != only) continue;
    const JointSlot& s = slots[j];
    for (int i = 0; i < 21; ++i) Q[21 * j + i] += s.f[i];
    for (int i = 0; i < 10; ++i) Q[ia(m, j + 1) + i] += s.f_next_a[i];
    torque(j - 1, s.tau_prev);
    torque(j, s.tau_own);
    for (int i = 0; i < 14; ++i) Q[ishaft(m, 0) + i] += s.shaft[i];
  }
  return Q;
}

double fd_step(const Model& m, int i) {
  if (i < 21 * m.links) {
    const int r = i % 21;
    return r < 20 && (r % 5 == 3 || r % 5 == 4) ? 1e-7 : 1e-9;  // slopes, lengths
  }
  const int r = (i - ishaft(m, 0)) % 7;
  return i == m.ndof - 1 || r == 3 || r == 4 || r == 5 ? 1e-7 : 1e-9;  // angles, lengths
}

Eigen::VectorXd fd_gradient(const Model& m, const Eigen::VectorXd& y, const std::function<double(const double*)>& E) {
  Eigen::VectorXd g(m.ndof);
  Eigen::VectorXd z = y;
  for (int i = 0; i < m.ndof; ++i) {
    const double h = fd_step(m, i);
    const auto at = [&](double d) {
      z[i] = y[i] + d;
      const double e = E(z.data());
      z[i] = y[i];
      return e;
    };
    g[i] = (-at(2 * h) + 8 * at(h) - 8 * at(-h) + at(-2 * h)) / (12 * h);
  }
  return g;
}

// The documented friction law f(v) (4.1), for the expected values.
double law_f(FrictionLaw law, double f0, double v0, double v) {
  switch (law) {
    case FrictionLaw::nonsmooth: return v < v0 ? f0 * v / v0 : f0;
    case FrictionLaw::smooth: return f0 * 2 / M_PI * std::atan(M_PI * v / (2 * v0));
    case FrictionLaw::none: return 0;
  }
  return 0;
}

double dot3(const double* a, const double* b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
double norm3(const double* a) { return std::sqrt(dot3(a, a)); }

// ---- Tests.

TEST(PulleyContactTest, PulleyEnergyIsTheDocumentedHertzSum) {
  const Model m = test::model("mini");
  for (unsigned seed : {1u, 2u}) {
    const Eigen::VectorXd y = test::perturbed_state(m, seed, 4e-6, 2e-4, 0.0);
    const PulleyEnergy P = documented_energy(m, y.data());
    EXPECT_GT(P.penetrating, 10);
    // Same terms, round-off only.
    EXPECT_NEAR(pulley_energy(m, y.data()), P.E, 1e-12 * P.E) << "seed " << seed;
  }
}

// Friction and damping off, at rest: the forces on the pins, the link torques and the
// forces on both shafts (u, tilts, phi, w) are -grad of the Hertz energy.
TEST(PulleyContactTest, NormalForcesAreMinusTheHertzEnergyGradient) {
  const Model m = test::model("mini", {"damping.scale=0", "friction.law=none"});
  for (unsigned seed : {1u, 2u}) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    Eigen::VectorXd y = test::perturbed_state(m, seed, 4e-6, 2e-4, 0.0);
    y.segment(m.ndof, m.ndof).setZero();
    const PulleyEnergy P = documented_energy(m, y.data());
    // Delta^(3/2) is not smooth at 0: no stencil (+-2 h moves Delta by < 5e-9 m) may straddle 0.
    ASSERT_GT(P.min_abs_pen, 1e-8);
    const Eigen::VectorXd Q = generalized(m, y.data(), run_pulley(m, y));
    const Eigen::VectorXd g = fd_gradient(m, y, [&](const double* q) { return documented_energy(m, q).E; });
    const double scale = Q.cwiseAbs().maxCoeff();
    int worst = 0;
    const double err = (Q + g).cwiseAbs().maxCoeff(&worst);
    std::printf("[seed %u] %d ends penetrate, max |F| = %.4g N, max |F + grad E| / max |F| = %.3g\n", seed,
                P.penetrating, scale, err / scale);
    EXPECT_GT(scale, 1.0);
    // The shafts take their share (u, tilts, w): the test covers them.
    EXPECT_GT(Q.segment(ishaft(m, 0), 14).cwiseAbs().maxCoeff(), 1.0);
    // 4th-order differences: truncation and round-off well below 1e-9 of max|F|; 1e-7
    // leaves room for the Hertz law's large higher derivatives at small Delta.
    EXPECT_LE(err, 1e-7 * scale) << "coordinate " << worst << ": F = " << Q[worst] << ", -grad E = " << -g[worst];
  }
}

// Action and reaction, contact by contact (untilted shafts, friction and damping on, in
// motion): the sheave takes -F, F the force on the pin end; its moment about the pulley
// centre is -(r x F) with r from the centre to the contact point; the moving sheave takes
// the axial reaction on its face, the fixed sheave's face gives w nothing.
TEST(PulleyContactTest, EachEndAndItsSheaveTakeOppositeForcesAndMoments) {
  const Model m = test::model("mini");
  Eigen::VectorXd y = test::perturbed_state(m, 4, 4e-6, 2e-4, 0.05);
  for (int k = 0; k < 2; ++k) y[ishaft(m, k) + 3] = y[ishaft(m, k) + 4] = 0.0;  // untilted
  int tested = 0, with_friction = 0;
  for (int j = 0; j < m.links; ++j)
    for (int h = 0; h < 2; ++h)
      for (int k = 0; k < 2; ++k)
        for (int e = 0; e < 2; ++e) {
          const End E = end_of(m, y.data(), j, h, e, k);
          if (!E.near || E.pen <= 0) continue;
          const auto status = only_contact(m, j, h, e, k);
          const JointSlot s = run_pulley(m, y, &status)[j];
          const double* F = s.f.data() + (h == 0 ? 0 : 10) + 5 * e;
          const double* S = s.shaft.data() + 7 * k;
          const double* other = s.shaft.data() + 7 * (1 - k);
          const double Fn = norm3(F);
          const double moment[3] = {E.rs[1] * F[2] - E.rs[2] * F[1], E.rs[2] * F[0] - E.rs[0] * F[2],
                                    E.rs[0] * F[1] - E.rs[1] * F[0]};
          const std::string where = "joint " + std::to_string(j) + " half " + std::to_string(h) + " end " +
                                    std::to_string(e) + " pulley " + std::to_string(k);
          // Round-off of sums of a few products.
          for (int i = 0; i < 3; ++i) {
            EXPECT_NEAR(S[i], -F[i], 1e-13 * Fn) << where;
            EXPECT_NEAR(S[3 + i], -moment[i], 1e-12 * Fn * norm3(E.rs)) << where << " moment " << i;
          }
          if (E.moving) {
            EXPECT_NEAR(S[6], -F[2], 1e-13 * Fn) << where;
          } else {
            EXPECT_EQ(S[6], 0.0) << where;
          }
          for (int i = 0; i < 7; ++i) EXPECT_EQ(other[i], 0.0) << where;
          // The tangential part (friction) is in F too where it is sizeable.
          const double Fnn = dot3(F, E.n);
          if (std::sqrt(std::max(0.0, Fn * Fn - Fnn * Fnn)) > 0.01 * Fn) ++with_friction;
          ++tested;
        }
  std::printf("%d penetrating ends, %d with friction over 1 %% of the force\n", tested, with_friction);
  EXPECT_GE(tested, 10);
  EXPECT_GE(with_friction, 5);
}

// Joint 0 sits on the driving arc (docs/model.md 5.2); its half a's +z end touches the
// driving pulley's moving sheave with Delta ~ 0 in the initial state. Returns that state with
// the end moved axially by dz (outward: Delta grows by cos(beta) dz) and every velocity zero.
Eigen::VectorXd end_on_sheave(const Model& m, double dz) {
  Eigen::VectorXd y = m.y0;
  y.segment(m.ndof, m.ndof).setZero();
  y[ia(m, 0) + 5 + 2] += dz;
  return y;
}

TEST(PulleyContactTest, EndWithAGapGivesExactlyZeroForce) {
  const Model m = test::model("mini");
  const auto status = only_contact(m, 0, 0, 1, 0);
  Eigen::VectorXd y = end_on_sheave(m, -1e-6);
  // Approaching the sheave at 0.1 m/s (the damping would push) while it turns (slip).
  y[m.ndof + ia(m, 0) + 5 + 2] = 0.1;
  y[m.ndof + ishaft(m, 0) + 5] = 200.0;
  ASSERT_TRUE(end_of(m, y.data(), 0, 0, 1, 0).near);
  ASSERT_LT(end_of(m, y.data(), 0, 0, 1, 0).pen, -9e-7);
  const auto slots = run_pulley(m, y, &status);
  for (int j = 0; j < m.links; ++j) {
    const JointSlot& s = slots[j];
    for (double x : s.f) EXPECT_EQ(x, 0.0) << "joint " << j;
    for (double x : s.f_next_a) EXPECT_EQ(x, 0.0) << "joint " << j;
    for (double x : s.shaft) EXPECT_EQ(x, 0.0) << "joint " << j;
    EXPECT_EQ(s.tau_prev, 0.0);
    EXPECT_EQ(s.tau_own, 0.0);
    EXPECT_EQ(s.p_diss, 0.0);
  }
  // Pressed in by 1 um instead, the same end pushes (the test is not vacuous).
  Eigen::VectorXd in = end_on_sheave(m, 1e-6);
  in.segment(m.ndof, m.ndof) = y.segment(m.ndof, m.ndof);
  EXPECT_GT(std::abs(run_pulley(m, in, &status)[0].f[5 + 2]), 1.0);
}

// The end of end_on_sheave pressed in (Delta ~ 2 um) against a sheave that turns at Omega:
// the slip is u = -Omega z x r_s (tangential), and the friction force on the pin is the
// difference between the configured law and no friction.
struct Slip {
  double Nel, speed, u[3], Ft[3], p_diss;
};
Slip slip_at(const Model& m, const Model& none, double speed) {
  Eigen::VectorXd y = end_on_sheave(m, 2e-6 / std::cos(m.cfg.sheave.cone_angle * M_PI / 180.0));
  const End E = end_of(m, y.data(), 0, 0, 1, 0);
  const double Omega = speed / std::hypot(E.rs[0], E.rs[1]);
  y[m.ndof + ishaft(m, 0) + 5] = Omega;
  const auto status = only_contact(m, 0, 0, 1, 0);
  const JointSlot s = run_pulley(m, y, &status)[0], s0 = run_pulley(none, y, &status)[0];
  Slip r;
  r.Nel = m.cfg.pulley_contact.stiffness * std::pow(E.pen, 1.5);
  r.speed = speed;
  r.u[0] = Omega * E.rs[1], r.u[1] = -Omega * E.rs[0], r.u[2] = 0;
  for (int i = 0; i < 3; ++i) r.Ft[i] = s.f[5 + i] - s0.f[5 + i];
  r.p_diss = s.p_diss;
  return r;
}

// cos of the angle between F_t and the slip u: -1 for a force opposite the slip.
double cos_to_slip(const Slip& s) { return dot3(s.Ft, s.u) / (norm3(s.Ft) * norm3(s.u)); }

TEST(PulleyContactTest, NonsmoothFrictionIsLinearBelowV0AndCoulombAbove) {
  const Model m = test::model("mini", {"friction.law=nonsmooth"});
  const Model none = test::model("mini", {"friction.law=none"});
  const double f0 = m.cfg.friction.f0, v0 = m.cfg.friction.v0;
  // Stick: F_t = -(f0 N / v0) u, proportional to the slip.
  const Slip a = slip_at(m, none, 0.25 * v0), b = slip_at(m, none, 0.5 * v0);
  EXPECT_GT(a.Nel, 10.0);
  for (const Slip& s : {a, b})
    for (int i = 0; i < 3; ++i)  // relative round-off of Delta (~1e-12) and of the sums
      EXPECT_NEAR(s.Ft[i], -f0 * s.Nel / v0 * s.u[i], 1e-9 * f0 * s.Nel) << "speed " << s.speed << " axis " << i;
  EXPECT_NEAR(norm3(b.Ft), 2 * norm3(a.Ft), 1e-9 * norm3(b.Ft));
  // Slide: |F_t| = f0 N, opposite the slip, whatever the speed.
  for (double v : {2.0 * v0, 50.0 * v0}) {
    const Slip s = slip_at(m, none, v);
    EXPECT_NEAR(norm3(s.Ft), f0 * s.Nel, 1e-9 * f0 * s.Nel) << "speed " << v;
    EXPECT_NEAR(cos_to_slip(s), -1.0, 1e-12) << "speed " << v;
  }
}

TEST(PulleyContactTest, SmoothFrictionFollowsTheArctanLaw) {
  const Model m = test::model("mini", {"friction.law=smooth"});
  const Model none = test::model("mini", {"friction.law=none"});
  const double f0 = m.cfg.friction.f0, v0 = m.cfg.friction.v0;
  for (double v : {0.01 * v0, 0.5 * v0, 2 * v0, 1000 * v0}) {
    const Slip s = slip_at(m, none, v);
    EXPECT_NEAR(norm3(s.Ft), s.Nel * law_f(FrictionLaw::smooth, f0, v0, v), 1e-9 * f0 * s.Nel) << "speed " << v;
    EXPECT_NEAR(cos_to_slip(s), -1.0, 1e-12) << "speed " << v;
    EXPECT_LT(norm3(s.Ft), f0 * s.Nel);
  }
  // Stick side: slope f0/v0 at 0 (arctan x = x (1 - x^2/3 ...), x = pi v / (2 v0) = 0.016).
  const Slip st = slip_at(m, none, 0.01 * v0);
  EXPECT_NEAR(norm3(st.Ft), f0 * st.Nel * 0.01, 1e-4 * f0 * st.Nel * 0.01);
  // Slide side: within 2 / (pi x) = 4e-4 of f0 N at 1000 v0.
  const Slip sl = slip_at(m, none, 1000 * v0);
  EXPECT_NEAR(norm3(sl.Ft), f0 * sl.Nel, 1e-3 * f0 * sl.Nel);
}

TEST(PulleyContactTest, NoFrictionLawGivesNoTangentialForce) {
  const Model m = test::model("mini", {"friction.law=none"});
  for (double v : {1e-4, 1e-2, 1.0}) {
    Eigen::VectorXd y = end_on_sheave(m, 2e-6);
    y[m.ndof + ishaft(m, 0) + 5] = v / 0.02;
    const auto status = only_contact(m, 0, 0, 1, 0);
    const JointSlot s = run_pulley(m, y, &status)[0];
    const End E = end_of(m, y.data(), 0, 0, 1, 0);
    // The force on the end is along the normal only, and nothing turns the pulley.
    const double* F = s.f.data() + 5;
    const double Fnn = dot3(F, E.n);
    for (int i = 0; i < 3; ++i) EXPECT_NEAR(F[i], Fnn * E.n[i], 1e-13 * std::abs(Fnn));
    EXPECT_LT(Fnn, 0.0) << "the sheave pushes the end back";
    EXPECT_EQ(s.shaft[5], 0.0);
    EXPECT_EQ(s.p_diss, 0.0);
  }
}

// The isolated contact's dissipation is -F_t . u = N f(v) v >= 0 (damping idle: Delta is
// constant when only the sheave turns).
TEST(PulleyContactTest, FrictionDissipationIsMinusForceTimesSlip) {
  const Model none = test::model("mini", {"friction.law=none"});
  for (const char* law : {"nonsmooth", "smooth"}) {
    const Model m = test::model("mini", {std::string("friction.law=") + law});
    const double f0 = m.cfg.friction.f0, v0 = m.cfg.friction.v0;
    for (double v : {0.3 * v0, 3 * v0, 30 * v0}) {
      const Slip s = slip_at(m, none, v);
      const double expected = s.Nel * law_f(m.cfg.friction.law, f0, v0, v) * v;
      EXPECT_GT(s.p_diss, 0.0);
      // Round-off of a 3-term dot product and of Delta (~1e-12 relative).
      EXPECT_NEAR(s.p_diss, -dot3(s.Ft, s.u), 1e-9 * s.p_diss) << law << " speed " << v;
      EXPECT_NEAR(s.p_diss, expected, 1e-9 * expected) << law << " speed " << v;
    }
  }
}

// Everywhere (tilted shafts, friction and damping, stick and slide): per joint
// p_diss_j >= 0 and p_diss_j = -(Q_j(q, v) - Q_j(q, 0)) . v, the power of the velocity-
// dependent forces (damping through dDelta/dq, friction through the slip's Jacobian).
TEST(PulleyContactTest, DissipatedPowerIsNonNegativeAndThePowerOfDampingAndFriction) {
  const Model m = test::model("mini");
  for (const auto& [seed, dv] : {std::pair{5u, 0.05}, std::pair{6u, 1e-4}, std::pair{7u, 0.5}}) {
    const Eigen::VectorXd y = test::perturbed_state(m, seed, 4e-6, 2e-4, dv);
    Eigen::VectorXd rest = y;
    rest.segment(m.ndof, m.ndof).setZero();
    const auto s = run_pulley(m, y), s0 = run_pulley(m, rest);
    const double* v = y.data() + m.ndof;
    double total = 0;
    for (int j = 0; j < m.links; ++j) {
      EXPECT_GE(s[j].p_diss, 0.0) << "joint " << j;
      const Eigen::VectorXd Qnc = generalized(m, y.data(), s, j) - generalized(m, y.data(), s0, j);
      double power = 0, size = 0;
      for (int i = 0; i < m.ndof; ++i) power += Qnc[i] * v[i], size += std::abs(Qnc[i] * v[i]);
      // Round-off of ~50 products of mixed sign.
      EXPECT_NEAR(s[j].p_diss, -power, 1e-10 * size + 1e-13) << "seed " << seed << " joint " << j;
      total += s[j].p_diss;
    }
    std::printf("[seed %u, dv %.0e] pulley p_diss = %.4g W\n", seed, dv, total);
    EXPECT_GT(total, 0.0);
  }
}

// The friction coefficient f(v) as docs/model.md 4.1 writes it.
double documented_f(FrictionLaw law, double f0, double v0, double v) {
  switch (law) {
    case FrictionLaw::nonsmooth: return v < v0 ? f0 * v / v0 : f0;
    case FrictionLaw::smooth: return f0 * (2.0 / M_PI) * std::atan(M_PI * v / (2.0 * v0));
    case FrictionLaw::none: return 0.0;
  }
  return 0.0;
}

// The kernels' law, f(v) = (f(v)/v) v (contact_laws.hpp).
double friction_coefficient(FrictionLaw law, double f0, double v0, double v) {
  return friction_over_speed(law, f0, v0, v) * v;
}

// The laws themselves (contact_laws.hpp, docs/model.md 4.1).
TEST(PulleyContactTest, FrictionLawsAreRegularizedCoulomb) {
  const double f0 = 0.09, v0 = 1e-3;
  for (FrictionLaw law : {FrictionLaw::nonsmooth, FrictionLaw::smooth}) {
    EXPECT_EQ(friction_coefficient(law, f0, v0, 0.0), 0.0);
    // Slope f0/v0 at 0, and f(v)/v finite there.
    EXPECT_DOUBLE_EQ(friction_over_speed(law, f0, v0, 0.0), f0 / v0);
    // atan x = x (1 - x^2/3 ...) at x ~ 1e-9: relative error ~1e-18, round-off ~1e-16.
    EXPECT_NEAR(friction_coefficient(law, f0, v0, 1e-9 * v0) / (1e-9 * v0), f0 / v0, 1e-9 * f0 / v0);
    double prev = 0;
    for (double x = 1e-6; x < 1e6; x *= 1.7) {
      const double v = x * v0, f = friction_coefficient(law, f0, v0, v);
      // The documented law (round-off), nondecreasing, bounded by f0.
      EXPECT_NEAR(f, documented_f(law, f0, v0, v), 1e-14 * f0) << "v/v0 " << x;
      // (f/v) v carries the round-off of one division and one product: 2 ulp.
      EXPECT_GE(f, prev * (1 - 4e-16)) << "v/v0 " << x;
      EXPECT_LE(f, f0 * (1 + 4e-16)) << "v/v0 " << x;
      prev = f;
    }
    // Saturated: the arctan is within 2 / (pi x) ~ 4e-7 of its limit at x = pi 1e6 / 2.
    EXPECT_NEAR(friction_coefficient(law, f0, v0, 1e6 * v0), f0, 1e-6 * f0);
  }
  // Nonsmooth: exactly f0 v/v0 below v0, exactly f0 from v0 on, continuous at v0.
  EXPECT_DOUBLE_EQ(friction_coefficient(FrictionLaw::nonsmooth, f0, v0, 0.3 * v0), 0.3 * f0);
  EXPECT_EQ(friction_coefficient(FrictionLaw::nonsmooth, f0, v0, v0), f0);
  EXPECT_EQ(friction_coefficient(FrictionLaw::nonsmooth, f0, v0, 7 * v0), f0);
  EXPECT_NEAR(friction_coefficient(FrictionLaw::nonsmooth, f0, v0, v0 * (1 - 1e-12)), f0, 1e-11 * f0);  // f0 (1 - 1e-12)
  // Smooth: the arctan, below f0 at every finite speed, f(v0) = f0 (2/pi) atan(pi/2).
  EXPECT_DOUBLE_EQ(friction_coefficient(FrictionLaw::smooth, f0, v0, v0), f0 * 2 / M_PI * std::atan(M_PI / 2));
  EXPECT_LT(friction_coefficient(FrictionLaw::smooth, f0, v0, 1e3 * v0), f0);
  // None: nothing.
  for (double v : {0.0, 0.5 * v0, 10 * v0}) {
    EXPECT_EQ(friction_coefficient(FrictionLaw::none, f0, v0, v), 0.0);
    EXPECT_EQ(friction_over_speed(FrictionLaw::none, f0, v0, v), 0.0);
  }
}

// The implicit methods' frozen branch (FrozenFriction, docs/integrators.md 11).
TEST(PulleyContactTest, FrozenFrictionBranchKeepsWhatItRecorded) {
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
