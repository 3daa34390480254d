// Initial geometry (docs/model.md 5) of every shipped configuration: the chain closes,
// every elastic element starts unloaded, the ratio is the requested one, and no pin end
// starts inside a sheave.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include "engine/rhs/rhs.hpp"
#include "modules/chain_forces.hpp"
#include "modules/inertia.hpp"
#include "modules/pulley_contact.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

const char* const kConfigs[] = {"mini", "reference", "ratio-0.5", "ratio-2.0"};

TEST(GeometryTest, ChainCloses) {
  for (const char* name : kConfigs) {
    const Model m = test::model(name);
    std::printf("[%s] closure residual %.3g m after %d iterations\n", name, m.closure_residual,
                m.geometry_iterations);
    EXPECT_LT(m.closure_residual, 1e-6) << name;
  }
}

// At t = 0 the ramps are zero and damping is off: only elastic forces act, and they vanish.
TEST(GeometryTest, ElasticForcesVanishInitially) {
  for (const char* name : kConfigs) {
    const Model m = test::model(name, {"damping.scale=0"});
    Workspace ws(m);
    Eigen::VectorXd dy(m.nstate);
    rhs_serial(m, ws, 0.0, m.y0.data(), dy.data());
    const int nchain = kJointSize * m.links;
    const double with_inertia = ws.force.head(nchain).cwiseAbs().maxCoeff();
    // The gathered force also holds the velocity terms of the inertia (3.3); drop them.
    for (auto& s : ws.inertia_slots) s.clear();
    gather_forces(m, ws);
    int worst = 0;
    const double fmax = ws.force.head(nchain).cwiseAbs().maxCoeff(&worst);
    const double E = energies(m, 0.0, m.y0.data()).elastic;
    std::printf("[%s] max |F| over chain coordinates %.3g N (coordinate %d; %.3g N with the "
                "velocity terms), elastic energy %.3g J\n",
                name, fmax, worst, with_inertia, E);
    EXPECT_LT(fmax, 1.0) << name << ": coordinate " << worst << " (joint " << worst / kJointSize << ", offset "
                         << worst % kJointSize << ")";
    EXPECT_LT(E, 1e-6) << name;
    EXPECT_GE(E, 0.0) << name;
  }
}

TEST(GeometryTest, RatioIsTheRequestedOne) {
  for (const char* name : kConfigs) {
    const Model m = test::model(name);
    const double R1 = m.pulley[0].running_radius, R2 = m.pulley[1].running_radius;
    const double measured = R2 / R1, target = m.cfg.geometry.ratio;
    std::printf("[%s] R1 = %.6g m, R2 = %.6g m, R2/R1 = %.6g (target %.6g, rel err %.3g)\n", name, R1, R2,
                measured, target, std::abs(measured / target - 1));
    EXPECT_GT(R1, 0.0) << name;
    EXPECT_GT(R2, 0.0) << name;
    EXPECT_LE(std::abs(measured / target - 1), 1e-3) << name;
  }
}

TEST(GeometryTest, NoPinEndStartsInsideASheave) {
  for (const char* name : kConfigs) {
    const Model m = test::model(name);
    Workspace ws(m);  // contact statuses default to all active
    set_stage_input(m, ws, 0.0, m.y0.data());
    link_kinematics(m, ws, 0, m.links);
    double worst = -1e300;
    int worst_j = -1, contacts = 0;
    for (int j = 0; j < m.links; ++j) {
      PinContactReport report;
      JointSlot s;
      pulley_contact_joint(m, ws, j, s, &report);
      for (int h = 0; h < 2; ++h)
        for (int e = 0; e < 2; ++e) {
          const EndContact& ec = report.end[h][e];
          if (ec.pulley < 0) continue;
          ++contacts;
          if (ec.penetration > worst) {
            worst = ec.penetration;
            worst_j = j;
          }
        }
    }
    std::printf("[%s] %d pin ends near a pulley, max penetration %.3g m (joint %d)\n", name, contacts, worst,
                worst_j);
    EXPECT_GT(contacts, 0) << name;
    EXPECT_LE(worst, 1e-9) << name << ": joint " << worst_j;
  }
}

// Every plate of every link sits at its rest length: no link carries tension.
TEST(GeometryTest, PlatesAtRestLength) {
  for (const char* name : kConfigs) {
    const Model m = test::model(name, {"damping.scale=0"});
    Workspace ws(m);
    set_stage_input(m, ws, 0.0, m.y0.data());
    link_kinematics(m, ws, 0, m.links);
    double worst = 0;
    int worst_j = -1;
    for (int j = 0; j < m.links; ++j) {
      const double T = std::abs(link_tension(m, ws, j));
      if (T > worst) {
        worst = T;
        worst_j = j;
      }
    }
    std::printf("[%s] max |link tension| %.3g N (link %d)\n", name, worst, worst_j);
    // The closing link carries what the closure residual leaves: n_pl k_pl |residual|.
    const double bound = 1e-6 + m.cfg.chain.plates_per_link * m.cfg.chain.plate_stiffness * m.closure_residual;
    EXPECT_LE(worst, bound) << name << ": link " << worst_j;
  }
}

}  // namespace
}  // namespace cvt
