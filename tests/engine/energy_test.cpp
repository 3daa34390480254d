// Energy (docs/model.md 6): conserved without friction, damping, drive and load; balanced
// (work in = work out + dissipated + change of energy) with everything on.
#include <gtest/gtest.h>

#include <cstdio>

#include "engine/rhs/rhs.hpp"
#include "engine/simulation.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

TEST(EnergyTest, ConservedWithoutFrictionDampingDriveAndLoad) {
  const Model m = test::model("mini", {"friction.law=none", "damping.scale=0", "drive.stiffness=0",
                                       "load.stiffness=0", "load.torque=0", "ramp.time=0"});
  Simulation sim(m);
  const double h = m.cfg.integrator.step;
  const Energies e0 = energies(m, 0.0, sim.state().data());
  const double E0 = e0.kinetic + e0.elastic;
  double worst = 0, max_elastic = 0;
  for (int n = 1; n <= 20000; ++n) {
    sim.step(h);
    if (n % 500 == 0) {
      const Energies e = energies(m, sim.time(), sim.state().data());
      worst = std::max(worst, std::abs(e.kinetic + e.elastic - E0) / E0);
      max_elastic = std::max(max_elastic, std::abs(e.elastic));
    }
  }
  std::printf("E0 = %.6g J, max |elastic| = %.3g J, relative drift of T + Pi over 2e4 steps: %.3g\n", E0,
              max_elastic, worst);
  EXPECT_GT(max_elastic, 1e-3) << "the chain must actually deform for this test to mean something";
  EXPECT_LE(worst, 1e-6);
}

TEST(EnergyTest, BalanceClosesWithEverythingOn) {
  // Loads ramped quickly so that real work flows within a short run.
  const Model m = test::model("mini", {"ramp.time=2e-4", "run.t_end=6e-4"});
  Simulation sim(m);
  const double h = m.cfg.integrator.step;
  const long steps = std::lround(m.cfg.run.t_end / h);
  for (long n = 1; n <= steps; ++n) sim.step(h);
  const Sample s = sim.sample();
  std::printf("work in %.4g J, out %.4g J, dissipated %.4g J, clamping %.4g J, residual %.3g J (%.3g of work in)\n",
              s.work_input, s.work_output, s.work_dissipated, s.work_clamping, s.energy_residual,
              std::abs(s.energy_residual / s.work_input));
  // Real energy flows through the model in this window (the load inertia gives up kinetic
  // energy to the load torque, contacts and dampers dissipate).
  EXPECT_GT(s.work_output + s.work_dissipated, 1.0);
  EXPECT_GT(s.work_input, 0.0);
  EXPECT_GT(s.work_dissipated, 0.0);
  EXPECT_LE(std::abs(s.energy_residual), 1e-3 * std::abs(s.work_input));
}

}  // namespace
}  // namespace cvt
