// The reference model in a running state, shared by the benchmark programs.
#pragma once

#include "engine/model/config.hpp"
#include "engine/model/model.hpp"
#include "engine/rhs/rhs.hpp"
#include "engine/simulation.hpp"
#include "modules/inertia.hpp"

namespace cvt::bench {

// The reference model after 0.3 ms of its run, so that contacts are established, with RK4
// at 1e-8 s (the benchmarks time RHS evaluations and RK4 steps; the config's own method
// is ROS34PW2).
struct Fixture {
  Model m;
  Eigen::VectorXd y;
  ContactStatus status;
  explicit Fixture(const std::string& name)
      : m(build_model(load_config(std::string(CVT_SOURCE_DIR) + "/configs/" + name + ".toml",
                                  {"integrator.method=rk4", "integrator.step=1e-8"}))) {
    Simulation sim(m);
    for (int n = 0; n < 30000; ++n) sim.step(m.cfg.integrator.step);
    y = sim.state();
    status = sim.workspace().status;
  }
};

inline Fixture& reference() {
  static Fixture f("reference");
  return f;
}

inline Workspace prepared(const Fixture& f) {
  Workspace ws(f.m);
  ws.status = f.status;
  set_stage_input(f.m, ws, 3e-4, f.y.data());
  link_kinematics(f.m, ws, 0, f.m.links);
  return ws;
}

}  // namespace cvt::bench
