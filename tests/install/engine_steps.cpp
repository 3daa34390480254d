// An outside program on cvt::engine: the installed mini model (its path is the first
// argument) from rest for 2 ms with its configured step, then the channels of the state.
// Exits 1 unless the clock, the drive and the energy balance (within the 5 % of the energy
// turned over that the engine's own guard allows) say the run went as it should.
#include <cmath>
#include <cstdio>

#include "engine/guards.hpp"
#include "engine/model/config.hpp"
#include "engine/model/model.hpp"
#include "engine/simulation.hpp"

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: outside_engine MINI.toml\n");
    return 2;
  }
  const cvt::Model m = cvt::build_model(cvt::load_config(argv[1]));
  cvt::Simulation sim(m);
  const double h = m.cfg.integrator.step;
  const long n = std::lround(2e-3 / h);
  for (long i = 0; i < n; ++i) sim.step(h);
  sim.check_finite();
  const cvt::Sample s = sim.sample();
  const double turnover = cvt::energy_turnover(s);
  std::printf("t = %.6f s after %ld steps: input speed %.3f rad/s, energy residual %.3g J of %.4g J turned over\n",
              s.t, sim.steps(), s.input_speed, s.energy_residual, turnover);
  const bool ok = std::abs(s.t - 2e-3) < 1e-9 && sim.steps() == n && s.input_speed > 0 && turnover > 0 &&
                  std::abs(s.energy_residual) <= cvt::EnergyGuard{}.limit * turnover;
  return ok ? 0 : 1;
}
