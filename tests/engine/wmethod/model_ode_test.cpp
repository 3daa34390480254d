// The CVT model through the generic integrators (engine/wmethod/model_ode.hpp,
// docs/integrators.md 11): the Jacobian pattern and its values against a dense
// finite-difference Jacobian, RK4 through the adapter against Simulation::step, an implicit
// method against RK4, and the energy balance.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdio>

#include "engine/run.hpp"
#include "engine/simulation.hpp"
#include "engine/wmethod/chain_stiffness.hpp"
#include "engine/wmethod/driver.hpp"
#include "engine/rhs/rhs.hpp"
#include "modules/chain_forces.hpp"
#include "modules/inertia.hpp"
#include "modules/pulley_contact.hpp"
#include <memory>
#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <unistd.h>
#include "tests/test_util.hpp"

namespace cvt {
namespace {

// The mini model running under load (0.1 ms, ramp 0.1 ms), contacts established.
struct Running {
  Model m;
  Eigen::VectorXd y;
  ContactStatus status;
  double t = 0;
  Running() : m(test::model("mini", {"ramp.time=1e-4"})) {
    Simulation sim(m);
    for (int k = 0; k < 10000; ++k) sim.step(m.cfg.integrator.step);
    y = sim.state();
    status = sim.workspace().status;
    t = sim.time();
  }
};

const Running& running() {
  static Running r;
  return r;
}

// Dense forward-difference Jacobian (the same increments as the coloured one).
Eigen::MatrixXd dense_fd(const Model& m, Workspace& ws, double t, const Eigen::VectorXd& y) {
  const int ns = m.nstate;
  Eigen::VectorXd f0(ns), f1(ns), yp = y;
  rhs_serial(m, ws, t, y.data(), f0.data());
  Eigen::MatrixXd J(ns, ns);
  const double eps = std::numeric_limits<double>::epsilon();
  for (int c = 0; c < ns; ++c) {
    const double d = std::sqrt(eps * std::max(1e-5, std::abs(y[c])));
    yp[c] = y[c] + d;
    rhs_serial(m, ws, t, yp.data(), f1.data());
    J.col(c) = (f1 - f0) / d;
    yp[c] = y[c];
  }
  return J;
}

TEST(ModelOde, PatternCoversDenseJacobian) {
  const Running& r = running();
  const Model& m = r.m;
  Workspace ws(m);
  ws.status = r.status;
  const Eigen::MatrixXd D = dense_fd(m, ws, r.t, r.y);
  for (bool exact : {true, false}) {
    Workspace ws2(m);
    ws2.status = r.status;
    auto sched = make_schedule(m, ws2, {});
    ModelOde ode(m, ws2, *sched, {2, exact});
    Eigen::SparseMatrix<double> J = ode.system().sparsity;
    ode.jacobian(r.t, r.y.data(), J);
    const Eigen::MatrixXd S = Eigen::MatrixXd(J);
    // Every entry of the dense Jacobian outside the pattern, by kind.
    const int n = m.ndof, tail0 = m.shaft(0);
    double worst_out = 0, worst_pin_tail = 0, worst_diff = 0, scale = D.cwiseAbs().maxCoeff();
    int max_band = 0;
    std::string worst_at;
    Eigen::MatrixXd P = Eigen::MatrixXd(ode.system().sparsity).cwiseAbs();
    for (int c = 0; c < m.nstate; ++c)
      for (int rr = 0; rr < m.nstate; ++rr) {
        const double v = std::abs(D(rr, c));
        if (v == 0) continue;
        const bool pin_col = c < 2 * n && c % n < tail0, pin_row = rr < 2 * n && rr % n < tail0;
        if (pin_col && pin_row && rr >= n) {
          int d = std::abs((rr % n) / kJointSize - (c % n) / kJointSize);
          d = std::min(d, m.links - d);
          max_band = std::max(max_band, d);
        }
        if (P(rr, c) == 0) {
          if (pin_col && !pin_row) worst_pin_tail = std::max(worst_pin_tail, v);
          else worst_out = std::max(worst_out, v);
        } else {
          // Relative to the entry, with a floor at the row's rounding noise (sums of many
          // pins' forces in the shaft rows).
          const double dd = std::abs(S(rr, c) - D(rr, c)) / (v + 1e-7 * D.row(rr).cwiseAbs().maxCoeff());
          if (dd > worst_diff) {
            worst_diff = dd;
            worst_at = describe_state_index(m, rr) + " / " + describe_state_index(m, c);
          }
        }
      }
    std::printf("[model_ode] mini %s: %d colours, nnz %ld, joint band of the dense FD %d; largest dense entry "
                "outside the pattern %.3g (pins -> tail rows %.3g) of max %.3g; max |coloured - dense| relative "
                "%.3g at %s\n",
                exact ? "exact dense rows" : "approximate", ode.colors(), static_cast<long>(J.nonZeros()), max_band,
                worst_out, worst_pin_tail, scale, worst_diff, worst_at.c_str());
    EXPECT_LE(max_band, 2);
    EXPECT_EQ(worst_out, 0.0);
    if (exact) {
      EXPECT_EQ(worst_pin_tail, 0.0);
    }
    EXPECT_LE(worst_diff, 1e-2);  // 4e-3 measured, in the dissipated-power row (rounding of its sum)
  }
}

// A Simulation at the running state.
std::unique_ptr<Simulation> at_running_state(const Running& r) {
  auto sim = std::make_unique<Simulation>(r.m);
  sim->mutable_state() = r.y;
  sim->workspace().status = r.status;
  sim->set_clock(r.t, 0);
  return sim;
}

// The W-method's friction blocks (FrictionJacobian::blocks, docs/integrators.md 12) are
// the Hessian of the friction dissipation in the joint's own half velocities: with every
// damping off and v0 so large that every contact is on the linear branch, the dissipated
// power is exactly P = sum_c mu_c |P_c G_c v|^2, so for a velocity perturbation d of joint
// j's halves alone, (P(v + d) + P(v - d) - 2 P(v)) / 2 = d^T K_j d, where K_j is built from
// the restriction of each G_c to those coordinates: the joint's own contacts, and those of
// the neighbouring halves that turn with a link through one of joint j's halves (exported).
// The friction damping of the whole chain, assembled from each joint's 40 x 40 blocks
// (lower triangles, over b_{j-1}, a_j, b_j, a_{j+1}) and mirrored: ndof x ndof.
Eigen::MatrixXd assembled_damping(const Model& m, const FrictionJacobian& ws, int* pulley_joints) {
  constexpr int kD = FrictionJacobian::kDim;
  const int n = m.ndof;
  Eigen::MatrixXd K = Eigen::MatrixXd::Zero(n, n);
  *pulley_joints = 0;
  for (int j = 0; j < m.links; ++j) {
    const int base[4] = {m.half_b(j - 1), m.half_a(j), m.half_b(j), m.half_a(j + 1)};
    auto coord = [&](int i) { return base[i / half::kSize] + i % half::kSize; };
    bool pulley = false;
    for (int r = 0; r < kD; ++r)
      for (int c = 0; c < kD; ++c) {
        const double kr = ws.rocker_damping[static_cast<std::size_t>(j) * kD * kD + r * kD + c];
        const double kp = ws.pulley_damping[static_cast<std::size_t>(j) * kD * kD + r * kD + c];
        if (c > r) {  // the kernels fill the lower triangles only
          EXPECT_EQ(kr, 0.0);
          EXPECT_EQ(kp, 0.0);
          continue;
        }
        pulley = pulley || kp != 0;
        K(coord(r), coord(c)) += kr + kp;
        if (c != r) K(coord(c), coord(r)) += kr + kp;
      }
    *pulley_joints += pulley;
    // The sheaves: pins x shaft k (both ways) and shaft k x shaft k.
    for (int k = 0; k < 2; ++k) {
      const int o = m.shaft(k);
      for (int i = 0; i < kD; ++i)
        for (int c = 0; c < kShaftSize; ++c) {
          const double x = ws.pulley_shaft_damping[(static_cast<std::size_t>(j) * 2 + k) * kD * kShaftSize + i * kShaftSize + c];
          K(coord(i), o + c) += x;
          K(o + c, coord(i)) += x;
        }
      for (int r = 0; r < kShaftSize; ++r)
        for (int c = 0; c < kShaftSize; ++c)
          K(o + r, o + c) += ws.pulley_shaft_self[(static_cast<std::size_t>(j) * 2 + k) * kShaftSize * kShaftSize + r * kShaftSize + c];
    }
  }
  return K;
}

TEST(ModelOde, FrictionDampingBlocksAreTheDissipationHessian) {
  const Running& r = running();
  const Model m = test::model("mini", {"ramp.time=1e-4", "friction.v0=1000", "rocker.damping=0",
                                       "pulley_contact.damping=0", "chain.plate_damping=0", "chain.pack_damping=0",
                                       "pin.damping_time=0", "damping.scale=0"});
  Workspace ws(m);
  ws.status = r.status;
  FrictionJacobian jac(m);
  jac.blocks = true;
  Eigen::VectorXd y = r.y, dy(m.nstate);
  rhs_serial(m, ws, r.t, y.data(), dy.data(), nullptr, nullptr, {&jac});
  int pulley_joints = 0;
  const Eigen::MatrixXd K = assembled_damping(m, jac, &pulley_joints);
  const int n = m.ndof;
  const double p0 = ws.p_diss;
  std::srand(7);
  double worst = 0, smallest_form = 1e300;
  // Perturb the half velocities of a few neighbouring joints at a time (and, last, of all
  // joints): the couplings between joints through the link spins are in the quadratic form.
  // With shafts, their velocities too (the sheave blocks).
  auto trial = [&](int j0, int span, bool shafts = false) {
    Eigen::VectorXd d = Eigen::VectorXd::Zero(n);
    for (int k = 0; k < span; ++k)
      for (int i = 0; i < 2 * half::kSize; ++i) d[m.joint(j0 + k) + i] = 1e-2 * (std::rand() / double(RAND_MAX) - 0.5);
    for (int i = 0; shafts && i < 2 * kShaftSize; ++i) d[m.shaft(0) + i] = 1e-2 * (std::rand() / double(RAND_MAX) - 0.5);
    auto power = [&](double sign) {
      Eigen::VectorXd yp = y;
      yp.segment(n, n) += sign * d;
      rhs_serial(m, ws, r.t, yp.data(), dy.data());
      return ws.p_diss;
    };
    const double second = 0.5 * (power(1) + power(-1) - 2 * p0);
    const double form = d.dot(K * d);
    smallest_form = std::min(smallest_form, form);
    worst = std::max(worst, std::abs(second - form) / std::abs(form));
  };
  for (int j = 0; j < m.links; ++j)
    for (int k = 0; k < 2; ++k) trial(j, 3);
  trial(0, m.links);
  trial(0, 0, true);
  trial(0, m.links, true);
  std::printf("[model_ode] friction blocks vs dissipation Hessian: worst relative difference %.2e over %d joints "
              "(%d with pulley contacts), smallest d^T K d %.3e W\n", worst, m.links, pulley_joints, smallest_form);
  // 3e-6 measured with joint-only perturbations (the second difference of a total power of
  // ~1e-2 W); leaving out the couplings between joints made it 8e-2.
  EXPECT_LT(worst, 1e-4);
  EXPECT_GT(smallest_form, 0);
  EXPECT_GT(pulley_joints, 4);
}

// ROS2's solve is W x = b with W = I - gh J~, J~ = [0, I; -A^-1 K, -A^-1 C] on the chain
// (A its mass matrix, link inertia included; C the recorded friction damping; K = -dF/dq
// by dense finite differences here) and, on the other velocities, the identity, whose
// increments reach the pins through the pulley friction (-A^-1 C_ps): checked as
//   (A + gh C + gh^2 K) x_v + gh C_ps x_s = A b_v - gh K b_q,   x_q = b_q + gh x_v;
// with w_shafts the shafts' velocity rows too: M_s x_s + gh (C_ps^T x_v + C_ss x_s) = M_s b_s.
TEST(ModelOde, WSolveIsTheChainsIterationMatrix) {
  const Running& r = running();
  const Model& m = r.m;
  Workspace ws(m);
  ws.status = r.status;
  auto sched = make_schedule(m, ws, {});
  const int n = m.ndof, tail = m.shaft(0);  // the chain's coordinates are 0 .. tail-1
  // K = -dF/dq on the chain from the generalized forces ws.force, dense.
  Eigen::VectorXd dy(m.nstate), yp = r.y;
  rhs_serial(m, ws, r.t, r.y.data(), dy.data());
  const std::vector<double> F0(ws.force.begin(), ws.force.begin() + n);
  Eigen::MatrixXd Kd(tail, tail);
  for (int c = 0; c < tail; ++c) {
    const double d = std::sqrt(std::numeric_limits<double>::epsilon() * std::max(1e-5, std::abs(r.y[c])));
    yp[c] = r.y[c] + d;
    rhs_serial(m, ws, r.t, yp.data(), dy.data());
    for (int i = 0; i < tail; ++i) Kd(i, c) = -(ws.force[i] - F0[i]) / d;
    yp[c] = r.y[c];
  }
  const Eigen::MatrixXd A = dense_inertia(m, r.y.data()).topLeftCorner(tail, tail);
  const double gh = 3e-7;
  ModelOdeOptions opt;
  opt.w_every = 1;
  opt.w_fresh = 0;
  // The analytic stiffness (variant 3) is the Hessian of the elastic energy, the forces'
  // differences at this state's positions with no velocity (central, with steps below the
  // contacts' kinks), plus the pin ends' friction part within each link's block and the
  // rockers' across the joints (add_pulley_friction_stiffness, add_rocker_friction_stiffness,
  // checked against the differences in PulleyFrictionStiffnessTest and
  // RockerFrictionStiffnessTest).
  Eigen::MatrixXd Ke(tail, tail);
  {
    Eigen::VectorXd y0 = r.y;
    y0.segment(n, n).setZero();
    for (int c = 0; c < tail; ++c) {
      const int i = c % kJointSize, e = (i % half::kSize) % half::kEnd;
      const double d = i < 2 * half::kSize && (e == half::kSx || e == half::kSy) ? 3e-8 : 3e-10;
      Eigen::VectorXd yp0 = y0, ym0 = y0;
      yp0[c] += d, ym0[c] -= d;
      rhs_serial(m, ws, r.t, yp0.data(), dy.data());
      const Eigen::VectorXd Fp = ws.force.head(tail);
      rhs_serial(m, ws, r.t, ym0.data(), dy.data());
      Ke.col(c) = -(Fp - ws.force.head(tail)) / (2 * d);
    }
    set_stage_input(m, ws, r.t, r.y.data());
    link_kinematics(m, ws, 0, m.links);
    for (int l = 0; l < m.links; ++l) {
      LinkHessian Kf = LinkHessian::Zero();
      add_pulley_friction_stiffness(m, ws, l, Kf);
      for (int a = 0; a < kLinkDim; ++a)
        for (int b = 0; b < kLinkDim; ++b) Ke(link_coordinate(m, l, a), link_coordinate(m, l, b)) += Kf(a, b);
      JointHessian J;
      J.prev.setZero(), J.own.setZero(), J.cross.setZero(), J.up.setZero();
      add_rocker_friction_stiffness(m, ws, l, J);  // joint l: links l-1 and l
      for (int a = 0; a < kLinkDim; ++a)
        for (int b = 0; b < kLinkDim; ++b) {
          const int p = link_coordinate(m, l - 1, a), o = link_coordinate(m, l, a);
          const int pb = link_coordinate(m, l - 1, b), ob = link_coordinate(m, l, b);
          Ke(p, pb) += J.prev(a, b), Ke(o, ob) += J.own(a, b), Ke(o, pb) += J.cross(a, b), Ke(p, ob) += J.up(a, b);
        }
    }
  }
  // Variant 4: the differences' K with the block LU on seven segments (w_segments).
  for (int variant = 0; variant < 5; ++variant) {
    const bool stiffness = variant > 0;
    opt.w_stiffness = stiffness;
    opt.w_shafts = variant >= 2;
    opt.w_analytic_stiffness = variant == 3;
    opt.w_segments = variant == 4 ? 7 : 0;
    const Eigen::MatrixXd& K = variant == 3 ? Ke : Kd;
    ModelOde ode(m, ws, *sched, opt);
    ode.ask_friction_jacobian(0);
    ode.system().rhs(r.t, r.y.data(), dy.data());
    int pj = 0;
    const FrictionJacobian& jac = ode.friction_jacobian();
    const Eigen::MatrixXd C = assembled_damping(m, jac, &pj).topLeftCorner(tail, tail);
    ode.system().w_factor(r.t, r.y.data(), gh);
    // C_ps: the pins' rows against each shaft's 7 velocities, from the recorded joint blocks.
    constexpr int kD = FrictionJacobian::kDim;
    Eigen::MatrixXd Cps = Eigen::MatrixXd::Zero(tail, 2 * kShaftSize);
    for (int j = 0; j < m.links; ++j) {
      const int base[4] = {m.half_b(j - 1), m.half_a(j), m.half_b(j), m.half_a(j + 1)};
      for (int k = 0; k < 2; ++k)
        for (int i = 0; i < kD; ++i)
          for (int c = 0; c < kShaftSize; ++c)
            Cps(base[i / half::kSize] + i % half::kSize, k * kShaftSize + c) +=
                jac.pulley_shaft_damping[(static_cast<std::size_t>(j) * 2 + k) * kD * kShaftSize + i * kShaftSize + c];
    }
    EXPECT_GT(Cps.norm(), 0);
    Eigen::VectorXd b = Eigen::VectorXd::Random(m.nstate), x = b;
    ode.system().w_solve(x.data());
    const Eigen::VectorXd bq = b.head(tail), bv = b.segment(n, tail), xv = x.segment(n, tail);
    const Eigen::VectorXd xs = x.segment(n + tail, 2 * kShaftSize);
    Eigen::VectorXd lhs = (A + gh * C) * xv + gh * Cps * xs, rhs = A * bv;
    if (stiffness) lhs += gh * gh * K * xv, rhs -= gh * K * bq;
    EXPECT_LT((lhs - rhs).norm(), 1e-6 * rhs.norm()) << "variant " << variant;
    // The stiffness matters at this gh: the same solve without it misses by more.
    if (stiffness) {
      EXPECT_GT((gh * gh * K * xv + gh * K * bq).norm(), 1e-3 * rhs.norm());
    }
    const Eigen::VectorXd bs = b.segment(n + tail, 2 * kShaftSize);
    if (opt.w_shafts) {
      // The shafts' rows: M_s x_s + gh (C_sp x_v + C_ss x_s) = M_s b_s, C_sp = C_ps^T, M_s
      // the shafts' block of the dense inertia.
      const Eigen::MatrixXd Ms = dense_inertia(m, r.y.data()).block(tail, tail, 2 * kShaftSize, 2 * kShaftSize);
      const Eigen::MatrixXd Css = assembled_damping(m, jac, &pj).block(tail, tail, 2 * kShaftSize, 2 * kShaftSize);
      EXPECT_GT(Css.norm(), 0);
      const Eigen::VectorXd ls = Ms * xs + gh * (Cps.transpose() * xv + Css * xs), rs = Ms * bs;
      EXPECT_LT((ls - rs).norm(), 1e-9 * rs.norm());
      // ... which the identity there misses.
      EXPECT_GT((xs - bs).norm(), 1e-6 * bs.norm());
    } else {
      EXPECT_EQ(xs, bs);
    }
    for (int i = 0; i < n; ++i) ASSERT_NEAR(x[i], b[i] + gh * x[n + i], 1e-12 * (std::abs(x[i]) + 1)) << i;
    for (int i = n + tail + 2 * kShaftSize; i < m.nstate; ++i) ASSERT_EQ(x[i], b[i]) << "unknown " << i;
  }
}

// ModelOdeOptions::w_fresh: after a rebuild at y0, a step at y1 (the same positions, so the
// same contact geometry; other velocities, so other slip speeds and mu) corrects the
// factorized W for every contact whose mu moved (threshold ~0): its solve must be the solve
// of the matrix rebuilt at y1, sheaves' coupling included, and the stale one must not be.
TEST(ModelOde, WFreshCorrectionSolvesTheCurrentFrictionMatrix) {
  const Running& r = running();
  const Model& m = r.m;
  const int n = m.ndof, tail = m.shaft(0);
  const double gh = 3e-7;
  Eigen::VectorXd y1 = r.y;
  for (int i = 0; i < tail; ++i) y1[n + i] += 0.02 * std::sin(0.7 * i + 0.3);
  Eigen::VectorXd dy(m.nstate);
  const Eigen::VectorXd b = Eigen::VectorXd::Random(m.nstate);
  // Without and with the shafts' rows in W (their part of each contact's column then in the
  // correction too).
  for (bool shafts : {false, true}) {
  ModelOdeOptions opt;
  opt.w_every = opt.w_k_every = 8;
  opt.w_stiffness = false;  // K = -dF/dq depends on the velocities through the damping forces
  opt.w_shafts = shafts;
  // kind 0: rebuilt at y1; 1: rebuilt at y0, corrected at y1; 2: rebuilt at y0, stale.
  Eigen::VectorXd x[3];
  long long joined = 0, forced = -1;
  for (int kind = 0; kind < 3; ++kind) {
    Workspace ws(m);
    ws.status = r.status;
    auto sched = make_schedule(m, ws, {});
    ModelOdeOptions o = opt;
    o.w_fresh = kind == 1 ? 1e-12 : 0.0;
    o.w_fresh_max = m.links * (m.cfg.rocker.stations + 8);
    ModelOde ode(m, ws, *sched, o);
    ode.ask_friction_jacobian(0);
    const Eigen::VectorXd& y0 = kind == 0 ? y1 : r.y;
    ode.system().rhs(r.t, y0.data(), dy.data());
    ode.system().w_factor(r.t, y0.data(), gh);
    if (kind > 0) {
      ode.ask_friction_jacobian(1);
      ASSERT_FALSE(ode.friction_jacobian().blocks);
      ode.system().rhs(r.t, y1.data(), dy.data());
      ode.system().w_factor(r.t, y1.data(), gh);
    }
    if (kind == 1) joined = ode.w_fresh_contacts(), forced = ode.w_fresh_rebuilds();
    x[kind] = b;
    ode.system().w_solve(x[kind].data());
  }
  std::printf("[model_ode] w_fresh (shafts' rows %s): %lld contacts corrected; |x_fresh - x_rebuilt| / |x_rebuilt| = %.3g, stale %.3g\n",
              shafts ? "in" : "out", joined, (x[1] - x[0]).norm() / x[0].norm(), (x[2] - x[0]).norm() / x[0].norm());
  EXPECT_GT(joined, 4);
  EXPECT_EQ(forced, 0);
  EXPECT_LT((x[1] - x[0]).norm(), 1e-9 * x[0].norm());
  EXPECT_GT((x[2] - x[0]).norm(), 1e-4 * x[0].norm());
  if (shafts) {
    // The shafts' velocities: what the matrix does to them (x_s - b_s), corrected as rebuilt.
    const int sh = n + m.shaft(0);
    const Eigen::VectorXd moved = x[0].segment(sh, 2 * kShaftSize) - b.segment(sh, 2 * kShaftSize);
    const Eigen::VectorXd miss = x[1].segment(sh, 2 * kShaftSize) - x[0].segment(sh, 2 * kShaftSize);
    std::printf("[model_ode] the shafts' part: |x_s - b_s| = %.3g, corrected vs rebuilt %.3g\n", moved.norm(), miss.norm());
    EXPECT_GT(moved.norm(), 1e-4 * b.segment(sh, 2 * kShaftSize).norm());
    EXPECT_LT(miss.norm(), 1e-9 * moved.norm());
  }
  }
}

TEST(ModelOde, Rk4ThroughAdapterMatchesSimulationStep) {
  const Running& r = running();
  const Model& m = r.m;
  const double h = m.cfg.integrator.step;
  const int steps = 300;
  auto a = at_running_state(r), b = at_running_state(r);
  for (int k = 0; k < steps; ++k) a->step(h);
  OdeRunOptions ro;
  ro.method = OdeMethod::Rk4;
  ro.ode.h0 = h;
  ro.jac.scaled = false;
  OdeDriver drv(b->model(), b->workspace(), b->schedule(), ro);
  b->advance(drv, r.t + steps * h);
  const Eigen::VectorXd& ya = a->state();
  const Eigen::VectorXd& yb = b->state();
  const int pins = kJointSize * m.links;
  const double dq = (ya.head(pins) - yb.head(pins)).cwiseAbs().maxCoeff();
  const double dv = (ya.segment(m.ndof, pins) - yb.segment(m.ndof, pins)).cwiseAbs().maxCoeff();
  const double dw = std::abs(ya[2 * m.ndof + kWorkSwitch] - yb[2 * m.ndof + kWorkSwitch]);
  std::printf("[model_ode] RK4 via OdeDriver vs Simulation::step, %d steps: max |dq| %.3g m, |dv| %.3g m/s, "
              "|dW_switch| %.3g J; steps %ld / %ld, t %.17g / %.17g, equal bits: %s\n",
              steps, dq, dv, dw, a->steps(), b->steps(), a->time(), b->time(), ya == yb ? "yes" : "no");
  EXPECT_EQ(drv.rhs_evals(), 4 * steps);
  EXPECT_EQ(b->steps(), steps);
  EXPECT_NEAR(b->time(), a->time(), 1e-18);
  EXPECT_LE(dq, 1e-14);
  EXPECT_LE(dv, 1e-8);
  EXPECT_LE(dw, 1e-12);
}

// a stepped by RK4 at the production step and b advanced by drv, both from the running
// state, over `window` in ten samples: the largest difference of the halves a's axial
// forces, their range, and the pins' largest position difference at the end.
struct BesideRk4 {
  double dq = 0, worst_f = 0, range_lo = 1e300, range_hi = -1e300;
};
BesideRk4 beside_rk4(const Running& r, Simulation& a, Simulation& b, OdeDriver& drv, double window) {
  const Model& m = r.m;
  const double h = m.cfg.integrator.step;
  const long per = std::lround(window / 10 / h);
  BesideRk4 c;
  for (int k = 1; k <= 10; ++k) {
    for (long i = 0; i < per; ++i) a.step(h);
    b.advance(drv, r.t + k * window / 10);
    for (int j = 0; j < m.links; ++j) {
      const double fa = half_axial_force(m, a.state().data(), a.state().data() + m.ndof, m.half_a(j));
      const double fb = half_axial_force(m, b.state().data(), b.state().data() + m.ndof, m.half_a(j));
      c.worst_f = std::max(c.worst_f, std::abs(fa - fb));
      c.range_lo = std::min(c.range_lo, fa), c.range_hi = std::max(c.range_hi, fa);
    }
  }
  const int pins = kJointSize * m.links;
  c.dq = (a.state().head(pins) - b.state().head(pins)).cwiseAbs().maxCoeff();
  return c;
}

// TR-BDF2 (scaled, frozen friction branch) against RK4 at the production step over a short
// window in which the tracked pin's forces change: the pins' positions and the tracked
// half's axial force.
TEST(ModelOde, ImplicitStaysCloseToRk4) {
  const Running& r = running();
  const double window = 2e-5;
  auto a = at_running_state(r), b = at_running_state(r);
  OdeRunOptions ro;
  ro.method = OdeMethod::TrBdf2;
  ro.ode.rtol = ro.ode.atol = 1e-2;
  ro.ode.h0 = 1e-8;
  ro.jac.scaled = true;
  OdeDriver drv(b->model(), b->workspace(), b->schedule(), ro);
  const BesideRk4 c = beside_rk4(r, *a, *b, drv, window);
  const double dq = c.dq, worst_f = c.worst_f, range_lo = c.range_lo, range_hi = c.range_hi;
  const OdeStats& st = drv.stats();
  std::printf("[model_ode] trbdf2 tol 1e-2 over %.3g s: %ld steps (rejected %ld, Newton failures %ld), %ld RHS, "
              "%ld Jacobians, %ld LU; max |dq| vs RK4 %.3g m; max |axial force difference| over all halves a %.3g N "
              "(range of the forces %.1f .. %.1f N)\n",
              window, static_cast<long>(st.steps), static_cast<long>(st.rejected), static_cast<long>(st.newton_failures),
              static_cast<long>(drv.rhs_evals()), static_cast<long>(drv.model_ode().jacobian_evals()),
              static_cast<long>(st.lu_factorizations), dq, worst_f, range_lo, range_hi);
  EXPECT_LT(st.steps, 2000);  // RK4 took 2000
  // 3.3e-6 m measured: mostly the phase of the chain along its path (12 m/s x 0.3 ns).
  EXPECT_LE(dq, 1e-5);
  EXPECT_LE(worst_f, 0.02 * (range_hi - range_lo));
}

// SUNDIALS' CVODE and ARKODE on the model (docs/integrators.md 17): through OdeDriver, one
// step of their own per status update, their own error control over the unscaled state
// (absolute tolerances 0.1 x (1 um, 1 mm/s, 1 mJ)), the chain's W solver as their linear
// solver. Against RK4 at the production step over the window of ImplicitStaysCloseToRk4:
// the pins' positions and the halves' axial forces stay close, in fewer steps than RK4's, and
// the energy balance closes.
TEST(ModelOde, SundialsStayCloseToRk4) {
  if (!sundials_available()) GTEST_SKIP() << "no SUNDIALS in this build";
  const Running& r = running();
  const Model& m = r.m;
  const double window = 2e-5;
  for (OdeMethod method : {OdeMethod::Cvode, OdeMethod::Arkode}) {
    auto a = at_running_state(r), b = at_running_state(r);
    const Sample s0 = b->sample();
    OdeRunOptions ro;
    ro.method = method;
    ro.ode.rtol = 0;
    ro.ode.h0 = 1e-8;
    ModelOdeOptions units;
    units.scaled = true;
    const Eigen::VectorXd u = model_state_units(m, units);
    ro.ode.atol_vector.assign(u.data(), u.data() + u.size());
    for (double& x : ro.ode.atol_vector) x *= 0.1;
    OdeDriver drv(b->model(), b->workspace(), b->schedule(), ro);
    const BesideRk4 c = beside_rk4(r, *a, *b, drv, window);
    const double dq = c.dq, worst_f = c.worst_f, range_lo = c.range_lo, range_hi = c.range_hi;
    const Sample sb = b->sample();
    const double flow = (sb.work_input - s0.work_input) + std::abs(sb.work_clamping - s0.work_clamping) +
                        (sb.work_dissipated - s0.work_dissipated);
    const double res = sb.energy_residual - s0.energy_residual;
    const OdeStats& st = drv.stats();
    std::printf("[model_ode] %s atol 0.1 units over %.3g s: %ld steps (rejected %ld, Newton failures %ld), %ld RHS, "
                "%ld setups; max |dq| vs RK4 %.3g m; max |axial force difference| %.3g N (range %.1f .. %.1f N); "
                "energy residual %.3g J of %.3g J flowing\n",
                to_string(method), window, static_cast<long>(st.steps), static_cast<long>(st.rejected),
                static_cast<long>(st.newton_failures), static_cast<long>(drv.rhs_evals()),
                static_cast<long>(st.lu_factorizations), dq, worst_f, range_lo, range_hi, res, flow);
    EXPECT_GT(st.lu_factorizations, 0) << to_string(method) << ": the W solver was not used";
    EXPECT_LT(st.steps, 2000) << to_string(method);  // RK4 took 2000
    EXPECT_LE(dq, 1e-5) << to_string(method);
    EXPECT_LE(worst_f, 0.02 * (range_hi - range_lo)) << to_string(method);
    EXPECT_GT(flow, 0.0);
    EXPECT_LE(std::abs(res), 0.05 * flow) << to_string(method);
  }
}

// The energy balance of docs/model.md 6 with an implicit method: the residual stays a small
// fraction of the work that flows.
TEST(ModelOde, EnergyBalanceWithImplicitMethod) {
  const Running& r = running();
  const Model& m = r.m;
  auto a = at_running_state(r), b = at_running_state(r);
  const Sample s0 = b->sample();
  OdeRunOptions ro;
  ro.method = OdeMethod::TrBdf2;
  ro.ode.rtol = ro.ode.atol = 1e-1;
  ro.ode.h0 = 1e-8;
  ro.jac.scaled = true;
  OdeDriver drv(b->model(), b->workspace(), b->schedule(), ro);
  const double window = 5e-5;
  b->advance(drv, r.t + window);
  for (long k = 0; k < std::lround(window / m.cfg.integrator.step); ++k) a->step(m.cfg.integrator.step);
  const Sample sb = b->sample(), sa = a->sample();
  const double win = sb.work_input - s0.work_input, flow = win + std::abs(sb.work_clamping - s0.work_clamping) +
                                                          (sb.work_dissipated - s0.work_dissipated);
  const double res_b = sb.energy_residual - s0.energy_residual, res_a = sa.energy_residual - s0.energy_residual;
  std::printf("[model_ode] energy balance over %.3g s: residual change trbdf2 %.3g J, rk4 %.3g J; work in %.4g J, "
              "dissipated %.4g J, clamping %.3g J, switching %.3g J (trbdf2) / %.3g J (rk4); %ld steps\n",
              window, res_b, res_a, win, sb.work_dissipated - s0.work_dissipated, sb.work_clamping - s0.work_clamping,
              sb.work_contact_switching - s0.work_contact_switching, sa.work_contact_switching - s0.work_contact_switching,
              static_cast<long>(drv.stats().steps));
  EXPECT_GT(flow, 0.0);
  EXPECT_LE(std::abs(res_b), 0.05 * flow);
}

// The whole text of a file ("" if it cannot be read).
std::string slurp(const std::filesystem::path& p) {
  std::ifstream f(p);
  return std::string(std::istreambuf_iterator<char>(f), {});
}

// `cvt-engine study integrators` in its short mode (mini model, 0.1 ms window): both parts,
// the table, the CSV and the curves; a candidate that blows up is reported with its reason.
TEST(ModelOde, StudyIntegratorsShortMode) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("cvt_study_test_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const std::string csv = (dir / "study.csv").string();
  const std::string cmd = test::shell_quote(CVT_ENGINE_EXE) + " study integrators " +
                          test::shell_quote(test::config_path("mini")) +
                          " --t-warm 1e-4 --t-sample 1e-4 --set ramp.time=1e-4 --methods rk4,trbdf2,ros2 --one-step --no-cache "
                          "--one-step-h 1e-8,1e-7 --rk4-steps 1e-5,5e-8 --ros2-steps 1e-7 --tols 1 --max-dev 0.2 --out " +
                          test::shell_quote(csv) + " > " + test::shell_quote((dir / "out.txt").string()) + " 2>&1";
  ASSERT_EQ(std::system(cmd.c_str()), 0);
  const std::string out = slurp(dir / "out.txt"), table = slurp(csv), curves = slurp(dir / "study-curves.csv");
  std::printf("%s", out.c_str());
  EXPECT_NE(out.find("(a) error after one step"), std::string::npos);
  EXPECT_NE(out.find("(b) sample curve"), std::string::npos);
  EXPECT_NE(table.find("one_step,trbdf2,h,1e-07"), std::string::npos);
  EXPECT_NE(table.find("curve,rk4,h,5e-08"), std::string::npos);
  // RK4 at 1e-5 (past its stable step) blows up, and the study says where and why.
  const size_t why = out.find("(blow-up: the ");
  ASSERT_NE(why, std::string::npos);
  EXPECT_NE(out.find(" at t = ", why), std::string::npos);
  EXPECT_NE(table.find("curve,trbdf2,tol,1"), std::string::npos);
  EXPECT_NE(table.find("one_step,ros2,h,1e-07"), std::string::npos);
  EXPECT_NE(table.find("curve,ros2,h,1e-07"), std::string::npos);
  EXPECT_EQ(curves.rfind("t_s,reference,rk4,trbdf2,ros2", 0), 0u) << curves.substr(0, 80);
  EXPECT_GE(std::count(curves.begin(), curves.end(), '\n'), 11);
  fs::remove_all(dir);
}

// The study's cache: a second run takes the running state and the reference curve from it
// and gives the same curves; a candidate with its own matrix intervals, repeated, reports
// them and the median; a bad candidate is refused with its text.
TEST(ModelOde, StudyIntegratorsCacheRepeatAndIntervals) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("cvt_study_cache_" + std::to_string(::getpid()));
  fs::create_directories(dir / "cache");
  auto study = [&](const std::string& name, const std::string& extra) {
    const std::string cmd = test::shell_quote(CVT_ENGINE_EXE) + " study integrators " +
                            test::shell_quote(test::config_path("mini")) +
                            " --t-warm 1e-4 --t-sample 1e-4 --set ramp.time=1e-4 --methods ros2 --no-one-step "
                            "--max-dev 0.2 --cache " + test::shell_quote((dir / "cache").string()) + " --out " +
                            test::shell_quote((dir / (name + ".csv")).string()) + " " + extra + " > " +
                            test::shell_quote((dir / (name + ".txt")).string()) + " 2>&1";
    return std::system(cmd.c_str());
  };
  ASSERT_EQ(study("first", "--ros2-steps 1e-7"), 0);
  ASSERT_EQ(study("second", "--ros2-steps 1e-7,1e-7:2:4 --all --repeat 2"), 0);
  const std::string first = slurp(dir / "first.txt"), second = slurp(dir / "second.txt");
  std::printf("%s", second.c_str());
  EXPECT_EQ(first.find("from the cache"), std::string::npos);
  EXPECT_NE(second.find("running state from the cache"), std::string::npos);
  EXPECT_NE(second.find("reference curve from the cache"), std::string::npos);
  EXPECT_NE(second.find("W2/4"), std::string::npos);
  EXPECT_NE(second.find("median of 2 runs"), std::string::npos);
  // The default candidate gives the same curve from the cached start as from the computed one.
  const std::string c1 = slurp(dir / "first-curves.csv"), c2 = slurp(dir / "second-curves.csv");
  EXPECT_EQ(c1, c2);
  const std::string t2 = slurp(dir / "second.csv");
  EXPECT_NE(t2.find(",0,2,4,2\n"), std::string::npos) << t2;  // not chosen (--all), W 2 / 4, 2 repeats
  EXPECT_NE(study("bad", "--ros2-steps 1e-7:2:3"), 0);
  EXPECT_NE(slurp(dir / "bad.txt").find("'1e-7:2:3' is not [METHOD@]H, [METHOD@]tol=T or either with :W:K"),
            std::string::npos);
  // A fixed step that does not divide the sample spacing (1e-5 s) is an error row, with why.
  ASSERT_EQ(study("long", "--methods ros2 --ros2-steps 1e-7,2e-5 --all"), 0);
  EXPECT_NE(slurp(dir / "long.txt").find("(error: the step 2e-05 s does not divide the sample spacing 1e-05 s"),
            std::string::npos) << slurp(dir / "long.txt");
  EXPECT_NE(study("bad2", "--w-steps rk4@1e-7"), 0);
  EXPECT_NE(slurp(dir / "bad2.txt").find("'rk4@1e-7' names no W-method"), std::string::npos);
  // Candidates kept to one method: ROS2 runs only its own, ROS34PW2 (from the cache's start)
  // only its own two, the second with its intervals.
  ASSERT_EQ(study("per", "--methods ros34pw2 --w-steps ros2@1e-7,ros34pw2@2e-7,ros34pw2@2e-7:2:4 --all"), 0);
  const std::string per = slurp(dir / "per.csv");
  std::printf("%s", per.c_str());
  size_t n34 = 0;
  for (size_t at = per.find("curve,ros34pw2,"); at != std::string::npos; at = per.find("curve,ros34pw2,", at + 1)) ++n34;
  EXPECT_EQ(n34, 2u) << per;
  EXPECT_NE(per.find(",0,2,4,1\n"), std::string::npos) << per;  // the second with W 2 / 4
  EXPECT_NE(per.find("curve,ros2,h,1e-07"), std::string::npos);
  EXPECT_NE(per.find("curve,ros34pw2,h,2e-07"), std::string::npos);
  EXPECT_EQ(per.find("curve,ros2,h,2e-07"), std::string::npos);
  EXPECT_EQ(per.find("curve,ros34pw2,h,1e-07"), std::string::npos);
  // An adaptive W candidate (tol=), the implicit methods with Newton on the chain's matrix
  // and DUMKA3, each with the chain's error norm: their rows.
  ASSERT_EQ(study("adaptive", "--methods ros34pw2,trbdf2,dumka3 --w-steps ros34pw2@tol=1 --tols 1 --newton-w --chain-norm"), 0);
  const std::string ad = slurp(dir / "adaptive.csv");
  std::printf("%s", ad.c_str());
  EXPECT_NE(ad.find("curve,ros34pw2,tol,1,,,,ok"), std::string::npos) << ad;
  EXPECT_NE(ad.find("curve,trbdf2,tol,1,"), std::string::npos) << ad;
  EXPECT_NE(ad.find("curve,dumka3,tol,1,"), std::string::npos) << ad;
  // --perturb: the same seed gives the same curve, which is not the unperturbed one; the
  // table says that the runs were perturbed; a negative size is refused.
  ASSERT_EQ(study("pert", "--ros2-steps 1e-7 --perturb 1e-9 --seed 3"), 0);
  ASSERT_EQ(study("pert2", "--ros2-steps 1e-7 --perturb 1e-9 --seed 3"), 0);
  const std::string p1 = slurp(dir / "pert-curves.csv"), p2 = slurp(dir / "pert2-curves.csv");
  EXPECT_EQ(p1, p2);
  EXPECT_NE(p1, c1);
  EXPECT_NE(slurp(dir / "pert.txt").find("moved by 1e-09 |q| u (seed 3)"), std::string::npos);
  EXPECT_NE(study("pert3", "--ros2-steps 1e-7 --perturb -1e-9"), 0);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace cvt

namespace cvt {
namespace {

// A W matrix taken at a state whose forces are not finite is singular, and says where: the
// time, the step, the first link with a non-finite block and where that came from.
TEST(WSolver, ASingularMatrixNamesTheTimeTheStepAndTheLink) {
  const Model m = test::model("mini");
  Workspace ws(m);
  auto sched = make_schedule(m, ws, {});
  Eigen::VectorXd y = m.y0, dy(m.nstate);
  update_contact_status(m, ws, 0.0, y.data());
  y[m.half_a(12) + half::kX] = std::nan("");
  ModelOde ode(m, ws, *sched, {});
  ode.ask_friction_jacobian(5);
  ode.system().rhs(1.5e-6, y.data(), dy.data());
  try {
    ode.system().w_factor(1.5e-6, y.data(), 1e-7);
    FAIL() << "a matrix of non-finite blocks was factorized";
  } catch (const std::runtime_error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("singular at t = 1.5e-06 s (step 5"), std::string::npos) << msg;
    EXPECT_NE(msg.find("holds a non-finite number in the stiffness"), std::string::npos) << msg;
    EXPECT_NE(msg.find("integrator.step"), std::string::npos) << msg;
  }
}

}  // namespace
}  // namespace cvt
