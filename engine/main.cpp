// The cvt-engine command line (docs/cli.md).
#include <CLI/CLI.hpp>
#include <cstdio>
#include <iostream>

#include "engine/config.hpp"
#include "engine/h5_writer.hpp"
#include "engine/model.hpp"
#include "engine/simulation.hpp"

namespace {

int cmd_run(const std::string& config_path, std::vector<std::string> overrides, const std::string& t_end,
            const std::string& step, const std::string& out, bool quiet) {
  using namespace cvt;
  // Command-line shortcuts are overrides too, passed as typed: validated like any key and
  // recorded in the resolved TOML.
  if (!t_end.empty()) overrides.push_back("run.t_end=" + t_end);
  if (!step.empty()) overrides.push_back("integrator.step=" + step);
  const Config cfg = load_config(config_path, overrides);
  const Model model = build_model(cfg);
  std::printf("cvt-engine %s: %s\n", CVT_VERSION, config_path.c_str());
  std::printf("  %d links, %d coordinates, %d first-order unknowns\n", model.links, model.ndof, model.nstate);
  std::printf("  geometry: R1 = %.4f mm, R2 = %.4f mm, closure residual = %.3g m\n",
              1e3 * model.pulley[0].running_radius, 1e3 * model.pulley[1].running_radius, model.closure_residual);
  std::printf("  t_end = %g s, step = %g s, friction %s\n", cfg.run.t_end, cfg.integrator.step,
              to_string(cfg.friction.law));
  std::fflush(stdout);
  RunOptions opt;
  opt.out_path = out;
  opt.progress = !quiet;
  const RunSummary r = run_simulation(model, opt);
  std::printf("\nrun complete: %s\n", out.c_str());
  std::printf("  steps                      %ld\n", r.steps);
  std::printf("  wall time                  %.3f s\n", r.wall_s);
  std::printf("  time per step              %.2f us\n", r.us_per_step);
  std::printf("  model seconds per wall hour %.4g\n", r.model_s_per_hour);
  std::printf("  last 20 %% of the run:\n");
  std::printf("    speed ratio              %.5f\n", r.speed_ratio);
  std::printf("    geometric ratio          %.5f\n", r.geometric_ratio);
  std::printf("    input torque             %.3f N m\n", r.input_torque);
  std::printf("    output torque            %.3f N m\n", r.output_torque);
  std::printf("    efficiency               %.4f\n", r.efficiency);
  std::printf("  energy balance residual    %.4g J (%.3g of the work in)\n", r.energy_residual,
              r.work_input != 0 ? std::abs(r.energy_residual / r.work_input) : 0.0);
  return kExitOk;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"cvt-engine: dynamics of a chain-type continuously variable transmission"};
  app.require_subcommand(1);
  app.set_version_flag("--version", std::string(CVT_VERSION));

  auto* run = app.add_subcommand("run", "simulate a configuration and write the results to HDF5");
  std::string config, out = "results.h5";
  std::vector<std::string> overrides;
  std::string t_end, step;
  bool quiet = false;
  run->add_option("CONFIG", config, "TOML configuration (configs/reference.toml)")->required();
  run->add_option("--t-end", t_end, "model time to simulate [s] (run.t_end)");
  run->add_option("--step", step, "integration step [s] (integrator.step)");
  run->add_option("--out", out, "output HDF5 file")->capture_default_str();
  run->add_option("--set", overrides, "override a key: section.key=value (repeatable)");
  run->add_flag("--quiet", quiet, "no progress line");

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  try {
    if (*run) return cmd_run(config, overrides, t_end, step, out, quiet);
  } catch (const cvt::ConfigError& e) {
    std::fprintf(stderr, "cvt-engine: %s\n", e.what());
    return cvt::kExitConfig;
  } catch (const cvt::BlowUpError& e) {
    std::fprintf(stderr, "cvt-engine: %s\n", e.what());
    return cvt::kExitBlowUp;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "cvt-engine: error: %s\n", e.what());
    return cvt::kExitFailure;
  }
  return cvt::kExitOk;
}
