// No heap allocation inside a W-method step of the model (the house rule: nothing is
// allocated inside a step): ROS34PW2 through Simulation::step on the serial schedule,
// counted over steps that rebuild the matrix, its stiffness and the fresh-friction
// correction, once every buffer has been sized by the first steps.
#include <cstdio>
#include <string>

#include <gtest/gtest.h>

#include "engine/simulation.hpp"
#include "engine/wmethod/model_ode.hpp"
#include "tests/alloc_count.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

TEST(WAlloc, NoAllocationInsideRos34pw2Steps) {
  CVT_SKIP_UNLESS_ALLOCATIONS_COUNTED();
  // Past the start-up sub-steps (integrator.startup_time) and the ramp, so that the steps
  // counted are the production ones; a tiny threshold makes the fresh-friction
  // correction take contacts at most steps.
  // With the block LU's two sweeps, and on four segments (integrator.w_segments).
  for (const char* segments : {"0", "4"}) {
    const Model m = test::model("mini", {"integrator.method=\"ros34pw2\"", "integrator.startup_time=2e-5",
                                         "ramp.time=5e-5", "integrator.w_fresh=1e-9",
                                         std::string("integrator.w_segments=") + segments});
    Simulation sim(m);
    const double h = m.cfg.integrator.step;
    const int warm = 2 * m.cfg.integrator.w_k_every + static_cast<int>(1e-4 / h);
    for (int k = 0; k < warm; ++k) sim.step(h);
    const int steps = 2 * m.cfg.integrator.w_k_every;
    test::allocations = 0;
    test::counting = true;
    for (int k = 0; k < steps; ++k) sim.step(h);
    test::counting = false;
    std::printf("[w_alloc] ros34pw2, w_segments %s: %d steps (matrix every %d, stiffness every %d), %ld heap allocations\n",
                segments, steps, m.cfg.integrator.w_every, m.cfg.integrator.w_k_every, test::allocations.load());
    ASSERT_TRUE(sim.state().allFinite());
    EXPECT_EQ(test::allocations.load(), 0) << "w_segments " << segments;
  }
}

}  // namespace
}  // namespace cvt
