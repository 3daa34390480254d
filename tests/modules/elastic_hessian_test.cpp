// The analytic Hessian of the chain's elastic energy (modules/elastic_hessian) against
// central differences of the generalized forces at rest (no velocity: the forces are the
// conservative ones, -dE/dq), link block by link block: each link's diagonal block and its
// coupling to the link before, over every link of a perturbed, clamped chain whose plates
// are stretched, rocker stations closed and pin ends in the sheaves.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "engine/rhs/rhs.hpp"
#include "engine/simulation.hpp"
#include "modules/chain_forces.hpp"
#include "modules/inertia.hpp"
#include "modules/elastic_hessian.hpp"
#include "modules/pulley_contact.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

// Coordinate of entry i of link l's block: b_l, a_{l+1}, s_l.
int coordinate(const Model& m, int l, int i) {
  return i < half::kSize ? m.half_b(l) + i : i < 2 * half::kSize ? m.half_a(l + 1) + i - half::kSize : m.pack(l);
}

// The generalized forces at (t, y).
Eigen::VectorXd forces(const Model& m, Workspace& ws, double t, const Eigen::VectorXd& y) {
  Eigen::VectorXd dy(m.nstate);
  rhs_serial(m, ws, t, y.data(), dy.data());
  return ws.force;
}

struct Blocks {
  std::vector<LinkHessian> diag, sub;  // K(l, l) and K(l, l-1)
};

// -dF/dq by 4th-order central differences over link l's coordinates, into the blocks of
// links l-1, l, l+1, at the velocities of y.
Blocks differences(const Model& m, Workspace& ws, double t, const Eigen::VectorXd& y) {
  Blocks k;
  k.diag.assign(m.links, LinkHessian::Zero());
  k.sub = k.diag;
  for (int l = 0; l < m.links; ++l)
    for (int i = 0; i < kLinkDim; ++i) {
      const int c = coordinate(m, l, i);
      const int r = (i % half::kSize) % half::kEnd;
      const bool slope = i < 2 * half::kSize && (r == half::kSx || r == half::kSy);
      // Steps well below the smallest penetration and stretch of these states, so that no
      // difference reaches across a contact's or a plate's kink (at 1e-9 m one reference
      // plate or station does, and its column is off by 0.5 %).
      const double h = slope ? 3e-8 : 3e-10;
      auto at = [&](double d) {
        Eigen::VectorXd z = y;
        z[c] += d;
        return forces(m, ws, t, z);
      };
      const Eigen::VectorXd col = -(-at(2 * h) + 8 * at(h) - 8 * at(-h) + at(-2 * h)) / (12 * h);
      for (int row = 0; row < kLinkDim; ++row) {
        k.diag[l](row, i) = col[coordinate(m, l, row)];
        k.sub[m.wrap(l + 1)](row, i) = col[coordinate(m, l + 1, row)];
      }
    }
  return k;
}

struct Case {
  std::string model;
  unsigned seed;
};

class ElasticHessianTest : public ::testing::TestWithParam<Case> {};

TEST_P(ElasticHessianTest, EveryLinkBlockIsTheDifferenceOfTheForcesAtRest) {
  const Case cs = GetParam();
  const Model m = test::model(cs.model);
  Eigen::VectorXd y = test::perturbed_state(m, cs.seed, 4e-6, 2e-4, 0.0);
  y.segment(m.ndof, m.ndof).setZero();
  const double t = 0.5 * m.cfg.ramp.time;  // clamping half ramped
  Workspace ws(m);
  // What the state holds: the test means nothing unless plates pull, rockers and pin ends press.
  int rockers = 0, ends = 0, plates = 0;
  forces(m, ws, t, y);
  for (int j = 0; j < m.links; ++j) {
    rockers += rocker_force(m, ws, j) > 0;
    double T[64];
    plate_tensions(m, ws, j, T);
    plates += std::count_if(T, T + m.plate_zeta.size(), [](double x) { return x > 0; });
  }
  ends = static_cast<int>(pulley_energy(m, y.data(), &ws.status) > 0);
  ASSERT_GT(rockers, m.links / 4);
  ASSERT_GT(plates, m.links);
  ASSERT_GT(ends, 0);

  const Blocks fd = differences(m, ws, t, y);
  std::vector<JointHessian> joints(m.links);
  for (int j = 0; j < m.links; ++j) joint_hessian(m, y.data(), ws.status, j, joints[j]);
  double worst = 0, scale = 0;
  int worst_link = -1;
  for (int l = 0; l < m.links; ++l) {
    LinkHessian diag;
    link_hessian(m, y.data(), ws.status, l, diag);
    diag += joints[l].own + joints[m.wrap(l + 1)].prev;
    const LinkHessian& sub = joints[l].cross;
    // The Hessian is symmetric; so is each diagonal block.
    EXPECT_LE((diag - diag.transpose()).cwiseAbs().maxCoeff(), 1e-9 * diag.cwiseAbs().maxCoeff()) << "link " << l;
    scale = std::max(scale, fd.diag[l].cwiseAbs().maxCoeff());
    const double e = std::max((diag - fd.diag[l]).cwiseAbs().maxCoeff(), (sub - fd.sub[l]).cwiseAbs().maxCoeff());
    if (e > worst) worst = e, worst_link = l;
  }
  std::printf("%s seed %u: %d closed rocker joints, %d stretched plates; max |K - K_fd| / max |K_fd| = %.3g (max %.3g)\n",
              cs.model.c_str(), cs.seed, rockers, plates, worst / scale, scale);
  EXPECT_LE(worst / scale, 1e-6) << "worst link " << worst_link;
}

// The generalized forces of one kernel alone at (t, y): the pin ends' contacts or the
// chain's (rockers, plates, beams), the other's and the inertia's slots empty.
Eigen::VectorXd kernel_forces(const Model& m, Workspace& ws, double t, const Eigen::VectorXd& y, bool pulley) {
  set_stage_input(m, ws, t, y.data());
  link_kinematics(m, ws, 0, m.links);
  if (pulley)
    pulley_contact(m, ws, 0, m.links);
  else
    chain_forces(m, ws, 0, m.links);
  for (int j = 0; j < m.links; ++j) (pulley ? ws.chain_slots : ws.pulley_slots)[j].clear(), ws.inertia_slots[j].clear();
  gather_joints(m, ws, 0, m.links);
  return ws.force;
}

// A running mini chain (6000 steps from rest), judged without damping so that what the
// velocities add to a kernel's force differences is its friction's alone: that part, by
// central differences at the state and at its positions with no velocity, in link blocks;
// ws is left with the state's link kinematics.
struct RunningFriction {
  Model m = test::model("mini", {"ramp.time=1e-4", "damping.scale=0"});
  Workspace ws{m};
  double t = 0;
  Eigen::VectorXd y;
  std::vector<LinkHessian> diag, sub, super;  // K(l, l), K(l, l-1), K(l-1, l)
  explicit RunningFriction(bool pulley) {
    const Model run = test::model("mini", {"ramp.time=1e-4"});
    Simulation sim(run);
    for (int k = 0; k < 6000; ++k) sim.step(run.cfg.integrator.step);
    t = sim.time(), y = sim.state();
    ws.status = sim.workspace().status;
    Eigen::VectorXd y0 = y;
    y0.segment(m.ndof, m.ndof).setZero();
    diag.assign(m.links, LinkHessian::Zero()), sub = diag, super = diag;
    for (int l = 0; l < m.links; ++l)
      for (int i = 0; i < kLinkDim; ++i) {
        const int c = coordinate(m, l, i);
        const int r = (i % half::kSize) % half::kEnd;
        const double h = i < 2 * half::kSize && (r == half::kSx || r == half::kSy) ? 3e-8 : 3e-10;
        const auto col = [&](const Eigen::VectorXd& at) {
          Eigen::VectorXd p = at, q = at;
          p[c] += h, q[c] -= h;
          return Eigen::VectorXd(-(kernel_forces(m, ws, t, p, pulley) - kernel_forces(m, ws, t, q, pulley)) / (2 * h));
        };
        const Eigen::VectorXd dv = col(y) - col(y0);
        for (int row = 0; row < kLinkDim; ++row) {
          diag[l](row, i) = dv[coordinate(m, l, row)];
          super[l](row, i) = dv[coordinate(m, l - 1, row)];
          sub[m.wrap(l + 1)](row, i) = dv[coordinate(m, l + 1, row)];
        }
      }
    set_stage_input(m, ws, t, y.data());
    link_kinematics(m, ws, 0, m.links);
  }
};

// The pin ends' friction stiffness (add_pulley_friction_stiffness) against that part of
// the pulley contacts' differences: the friction's change with the Hertz force, with the
// sheave's spin and with the link's spin at the contact point, within each link's block.
// What it leaves out (the contact normal's and the levers' turning) is below 1e-3 of it.
TEST(PulleyFrictionStiffnessTest, CarriesWhatTheVelocitiesAddToThePinEndsStiffness) {
  RunningFriction r(true);
  double err = 0, part = 0;
  for (int l = 0; l < r.m.links; ++l) {
    LinkHessian K = LinkHessian::Zero();
    add_pulley_friction_stiffness(r.m, r.ws, l, K);
    err += (r.diag[l] - K).squaredNorm() + r.sub[l].squaredNorm() + r.super[l].squaredNorm();
    part += r.diag[l].squaredNorm() + r.sub[l].squaredNorm() + r.super[l].squaredNorm();
  }
  std::printf("|velocities' part - K_f| / |velocities' part| = %.3g (|part| = %.3g N/m)\n", std::sqrt(err / part),
              std::sqrt(part));
  ASSERT_GT(part, 1e10);
  EXPECT_LT(std::sqrt(err / part), 1e-3);
}

// The rocker's friction stiffness (add_rocker_friction_stiffness) against that part of the
// chain kernel's differences: every link's diagonal block and both couplings.
TEST(RockerFrictionStiffnessTest, CarriesWhatTheVelocitiesAddToTheRockersStiffness) {
  RunningFriction r(false);
  std::vector<JointHessian> J(r.m.links);
  for (int j = 0; j < r.m.links; ++j) {
    J[j].prev.setZero(), J[j].own.setZero(), J[j].cross.setZero(), J[j].up.setZero();
    add_rocker_friction_stiffness(r.m, r.ws, j, J[j]);
  }
  double err = 0, part = 0;
  for (int l = 0; l < r.m.links; ++l) {
    const LinkHessian d = J[l].own + J[r.m.wrap(l + 1)].prev;
    err += (r.diag[l] - d).squaredNorm() + (r.sub[l] - J[l].cross).squaredNorm() + (r.super[l] - J[l].up).squaredNorm();
    part += r.diag[l].squaredNorm() + r.sub[l].squaredNorm() + r.super[l].squaredNorm();
  }
  std::printf("|velocities' part - K_f| / |velocities' part| = %.3g (|part| = %.3g N/m)\n", std::sqrt(err / part),
              std::sqrt(part));
  ASSERT_GT(part, 1e10);
  EXPECT_LT(std::sqrt(err / part), 1e-3);
}

INSTANTIATE_TEST_SUITE_P(States, ElasticHessianTest,
                         ::testing::Values(Case{"mini", 1}, Case{"mini", 2}, Case{"reference", 3}),
                         [](const auto& info) { return info.param.model + std::to_string(info.param.seed); });

}  // namespace
}  // namespace cvt
