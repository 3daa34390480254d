// Inertia (docs/model.md 3): the structured Woodbury solve against a dense Cholesky solve
// of dense_inertia(), the kinetic energy against 1/2 v^T A v, and the velocity terms of
// inertia_decomposition against Lagrange's equations by finite differences.
#include <gtest/gtest.h>

#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "engine/rhs/rhs.hpp"
#include "modules/inertia.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

Eigen::VectorXd random_vector(int n, unsigned seed, double scale) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Eigen::VectorXd x(n);
  for (int i = 0; i < n; ++i) x[i] = scale * u(rng);
  return x;
}

// Structured solve of A(q) qdd = F as rhs_serial does it (3.2).
Eigen::VectorXd structured_solve(const Model& m, const Eigen::VectorXd& y, const Eigen::VectorXd& F) {
  Workspace ws(m);
  set_stage_input(m, ws, 0.0, y.data());
  link_kinematics(m, ws, 0, m.links);
  inertia_decomposition(m, ws, 0, m.links);
  ws.force = F;
  accelerations(m, ws);
  return ws.accel;
}

struct Case {
  const char* config;
  unsigned seed;
};

const Case kCases[] = {{"mini", 1u}, {"mini", 2u}, {"mini", 3u}, {"reference", 4u}};

void check_solve(const Case& c) {
  const Model m = test::model(c.config);
  const Eigen::VectorXd y = test::perturbed_state(m, c.seed, 1e-5, 1e-3, 1.0);
  const Eigen::MatrixXd A = dense_inertia(m, y.data());
  ASSERT_EQ(A.rows(), m.ndof);
  // Symmetric up to the rounding of J (g g^T).
  EXPECT_LE((A - A.transpose()).cwiseAbs().maxCoeff(), 1e-15 * A.cwiseAbs().maxCoeff()) << "dense A not symmetric";
  const Eigen::LLT<Eigen::MatrixXd> llt(A);
  ASSERT_EQ(llt.info(), Eigen::Success) << "dense A not positive definite";
  double worst = 0;
  for (unsigned r = 0; r < 3; ++r) {
    const Eigen::VectorXd F = random_vector(m.ndof, 1000 * c.seed + r, 1.0);
    const Eigen::VectorXd dense = llt.solve(F);
    const Eigen::VectorXd fast = structured_solve(m, y, F);
    const double rel = (fast - dense).norm() / dense.norm();
    worst = std::max(worst, rel);
    // Also in the residual sense: A qdd - F relative to |F|.
    const double res = (A * fast - F).norm() / F.norm();
    EXPECT_LE(rel, 1e-10) << "force vector " << r;
    EXPECT_LE(res, 1e-10) << "force vector " << r;
  }
  std::printf("[%s seed %u] structured vs dense solve: max rel diff %.3g\n", c.config, c.seed, worst);
}

void check_kinetic_energy(const Case& c) {
  const Model m = test::model(c.config);
  const Eigen::VectorXd y = test::perturbed_state(m, c.seed, 1e-5, 1e-3, 10.0);
  const Eigen::MatrixXd A = dense_inertia(m, y.data());
  const Eigen::VectorXd v = y.segment(m.ndof, m.ndof);
  const double T = kinetic_energy(m, y.data(), v.data());
  const double Tq = 0.5 * v.dot(A * v);
  std::printf("[%s seed %u] T = %.6g J, |T - v'Av/2| / T = %.3g\n", c.config, c.seed, T,
              std::abs(T - Tq) / Tq);
  EXPECT_GT(T, 0.0);
  EXPECT_LE(std::abs(T - Tq), 1e-12 * std::abs(Tq));
  // Through the energies() entry point as well.
  EXPECT_EQ(energies(m, 0.0, y.data()).kinetic, T);
}

// Lagrange: d/dt(dT/dqdot) - dT/dq = A(q) qdd + c(q, qdot), and inertia_decomposition
// delivers -c as link torques (tau_own times g_i), so
//   A(q) qdd - F_vel = d/dt(A(q) qdot) - dT/dq
// along q(t) = q + v t + qdd t^2/2. Both derivatives by 4th-order central differences.
void check_lagrange(const Case& c) {
  const Model m = test::model(c.config);
  const int n = m.ndof;
  const Eigen::VectorXd y = test::perturbed_state(m, c.seed, 1e-5, 1e-3, 10.0);
  const Eigen::VectorXd q = y.head(n);
  const Eigen::VectorXd v = y.segment(n, n);
  // Accelerations of the order of v^2/R on the chain coordinates; small on the heavy shafts
  // and the load, whose A0 terms would otherwise swamp the velocity terms.
  Eigen::VectorXd qdd = random_vector(n, 7000 + c.seed, 1e4);
  qdd.tail(n - kJointSize * m.links) *= 1e-4;

  // F_vel from the structured kernels.
  Workspace ws(m);
  set_stage_input(m, ws, 0.0, y.data());
  link_kinematics(m, ws, 0, m.links);
  inertia_decomposition(m, ws, 0, m.links);
  std::vector<double> tau(m.links);
  for (int i = 0; i < m.links; ++i) {
    const JointSlot& s = ws.inertia_slots[i];
    EXPECT_EQ(s.tau_prev, 0.0);
    tau[i] = s.tau_own;
  }
  Eigen::VectorXd F_vel = Eigen::VectorXd::Zero(n);
  add_link_torques(m, ws.kin, tau.data(), F_vel.data());

  const Eigen::MatrixXd A = dense_inertia(m, q.data());
  const Eigen::VectorXd lhs = A * qdd - F_vel;

  // d/dt (A(q(t)) qdot(t)) at t = 0.
  const double ht = 1e-6;  // [s]; the link turns by ~ v ht / |Delta| ~ 1e-3 rad
  auto momentum = [&](double t) {
    const Eigen::VectorXd qt = q + v * t + 0.5 * qdd * t * t;
    const Eigen::VectorXd vt = v + qdd * t;
    return Eigen::VectorXd(dense_inertia(m, qt.data()) * vt);
  };
  const Eigen::VectorXd dp =
      (-momentum(2 * ht) + 8 * momentum(ht) - 8 * momentum(-ht) + momentum(-2 * ht)) / (12 * ht);

  // dT/dq at fixed qdot.
  const double hq = 1e-6;  // [m] or [rad]
  Eigen::VectorXd dTdq(n);
  Eigen::VectorXd z = q;
  auto T_at = [&](int i, double d) {
    z[i] = q[i] + d;
    const double T = kinetic_energy(m, z.data(), v.data());
    z[i] = q[i];
    return T;
  };
  for (int i = 0; i < n; ++i)
    dTdq[i] = (-T_at(i, 2 * hq) + 8 * T_at(i, hq) - 8 * T_at(i, -hq) + T_at(i, -2 * hq)) / (12 * hq);

  const Eigen::VectorXd rhs = dp - dTdq;
  const double rel = (lhs - rhs).norm() / rhs.norm();
  // The velocity terms alone: c = d/dt(A v) - dT/dq - A qdd against -F_vel.
  const Eigen::VectorXd c_fd = rhs - A * qdd;
  const double rel_c = (c_fd + F_vel).norm() / F_vel.norm();
  std::printf("[%s seed %u] |A qdd| = %.4g, |F_vel| = %.4g, identity rel err %.3g, "
              "velocity term rel err %.3g\n",
              c.config, c.seed, (A * qdd).norm(), F_vel.norm(), rel, rel_c);
  EXPECT_GT(F_vel.norm(), 1e-3 * (A * qdd).norm()) << "velocity terms too small to test";
  EXPECT_LE(rel, 1e-6);
  EXPECT_LE(rel_c, 1e-5);
}

TEST(InertiaTest, StructuredSolveMatchesDenseCholesky) {
  for (const Case& c : kCases) {
    SCOPED_TRACE(std::string(c.config) + " seed " + std::to_string(c.seed));
    check_solve(c);
  }
}

TEST(InertiaTest, KineticEnergyIsQuadraticForm) {
  for (const Case& c : kCases) {
    SCOPED_TRACE(std::string(c.config) + " seed " + std::to_string(c.seed));
    check_kinetic_energy(c);
  }
}

// Dense finite differences: on the mini model only.
TEST(InertiaTest, VelocityTermsSatisfyLagrange) {
  for (const Case& c : kCases) {
    if (std::string(c.config) != "mini") continue;
    SCOPED_TRACE(std::string(c.config) + " seed " + std::to_string(c.seed));
    check_lagrange(c);
  }
}

}  // namespace
}  // namespace cvt
