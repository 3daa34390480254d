// The W matrix's stiffness follows the chain's speed (stiffness_every,
// docs/integrators.md 12.3): it is taken again at least every quarter of a
// pitch of chain travel, never more often than the matrix itself, and always at
// the multiples of integrator.w_k_every; the run's judged steps take that
// interval, integrator.fixed_steps the configured one.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "engine/io/checkpoint.hpp"
#include "engine/simulation.hpp"
#include "engine/wmethod/driver.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

// The chain's travel over k sub-steps of hs, in pitches.
double travel(const Model& m, int k, double hs) {
  return k * hs * m.cfg.drive.speed * m.pulley[0].running_radius / m.cfg.chain.pitch;
}

TEST(StiffnessInterval, AQuarterPitchOfTravelBoundsIt) {
  for (const char* speed : {"drive.speed=60", "drive.speed=209.4", "drive.speed=550", "drive.speed=2000"})
    for (const char* ratio : {"geometry.ratio=0.5", "geometry.ratio=1.0", "geometry.ratio=2.0"})
      for (const double hs : {2.5e-6, 1.25e-6, 5e-6}) {
        const Model m = test::model("reference", {speed, ratio});
        const int k = stiffness_every(m, hs, 8, 32);
        SCOPED_TRACE(std::string(speed) + " " + ratio + " hs " + std::to_string(hs) + ": every " + std::to_string(k));
        EXPECT_EQ(32 % k, 0) << "a divisor of w_k_every: checkpoints at its multiples fall on a take";
        EXPECT_EQ(k % 8, 0) << "a multiple of w_every: taken only where the matrix is rebuilt";
        if (k > 8) {
          EXPECT_LE(travel(m, k, hs), kStiffnessTravel);
        }
        if (k < 32) {
          EXPECT_GT(travel(m, 2 * k, hs), kStiffnessTravel) << "shortened no more than needed";
        }
      }
  // The reference point keeps its interval; the same chain at 550 rad/s halves it, at 2000
  // rad/s it is the matrix's own; a half that is no multiple of w_every is not taken.
  const Model ref = test::model("reference");
  EXPECT_EQ(stiffness_every(ref, 2.5e-6, 8, 32), 32);
  EXPECT_EQ(stiffness_every(test::model("reference", {"drive.speed=550"}), 2.5e-6, 8, 32), 16);
  EXPECT_EQ(stiffness_every(test::model("reference", {"drive.speed=2000"}), 2.5e-6, 8, 32), 8);
  EXPECT_EQ(stiffness_every(test::model("reference", {"drive.speed=2000"}), 2.5e-6, 8, 24), 24);
}

// The reference model at 550 rad/s, from its state at the settling phase's end
// (its interval 32 halved to 16 there), 200 steps on: the same bits as
// integrator.w_k_every = 16 given; with fixed steps, not those.
TEST(StiffnessInterval, TheRunTakesItAndFixedStepsKeepTheConfigured) {
  const auto cfg = [](std::vector<std::string> more) {
    std::vector<std::string> o = {"integrator.method=ros34pw2", "integrator.step=2.5e-6", "drive.speed=550"};
    o.insert(o.end(), more.begin(), more.end());
    return test::model("reference", o);
  };
  const Model m = cfg({});
  const double h = m.cfg.integrator.step;
  Simulation start(m);
  while (start.time() < settle_end(m.cfg) - 0.5 * h) start.step(h);
  start.check_finite();
  const Checkpoint c = start.checkpoint();
  ASSERT_EQ(c.steps % 32, 0);
  const auto run = [&](const Model& mm) {
    Simulation sim(mm);
    sim.restore(c);
    for (int i = 0; i < 200; ++i) sim.step(h);
    sim.check_finite();
    return Eigen::VectorXd(sim.state());
  };
  const Model given16 = cfg({"integrator.w_k_every=16"});
  EXPECT_TRUE(run(m) == run(given16)) << "the judged steps take the stiffness every 16 steps at this speed";
  const Model fixed = cfg({"integrator.fixed_steps=true"}),
              fixed16 = cfg({"integrator.fixed_steps=true", "integrator.w_k_every=16"});
  EXPECT_FALSE(run(fixed) == run(fixed16)) << "fixed steps take the configured interval, 32";
}

}  // namespace
}  // namespace cvt
