// The cvt-engine command line (docs/cli.md).
#include <CLI/CLI.hpp>
#include <signal.h>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <thread>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <fstream>
#include <iostream>
#include <optional>
#include <sstream>
#include <unistd.h>

#include "engine/base/commit.h"  // generated into the build folder at every build (tools/commit_header.cmake)
#include "engine/cli/exit_codes.hpp"
#include "engine/base/timing.hpp"
#include "engine/io/checkpoint.hpp"
#include "engine/model/config.hpp"
#include "engine/model/envelope.hpp"
#include "engine/io/h5_writer.hpp"
#include "engine/model/model.hpp"
#include "engine/studies/modes.hpp"
#include "engine/studies/scale.hpp"
#include "engine/studies/integrators.hpp"
#include "engine/studies/shift.hpp"
#include "engine/studies/slip.hpp"
#include "engine/studies/sweep.hpp"
#include "engine/studies/sweep_mpi.hpp"
#include "engine/run.hpp"
#include "engine/simulation.hpp"
#include "engine/guards.hpp"
#include "engine/wmethod/driver.hpp"
#include "engine/wmethod/w_step.hpp"
#include "graph/schedule.hpp"
#include "numa/arenas.hpp"
#include "numa/describe.hpp"
#include "numa/topology.hpp"

namespace {

std::string fmt_g(double x) {
  char b[32];
  std::snprintf(b, sizeof b, "%g", x);
  return b;
}

// When the command started: what run.max_wall counts from.
const cvt::WallClock::time_point g_command_start = cvt::WallClock::now();

// A wall time as a job scheduler writes it: seconds ("3600", "90s"), minutes ("90m"), hours
// ("23.5h"), or [D-]H:MM[:SS] ("23:50:00", "1-00:00:00", Slurm's --time). Seconds > 0.
double parse_duration(const std::string& option, const std::string& text) {
  const auto bad = [&] {
    return cvt::ConfigError(option, text,
                            "a wall time: seconds (3600), minutes or hours (90m, 23.5h), or [D-]H:MM[:SS] (23:50:00)");
  };
  double s = 0;
  if (text.find(':') != std::string::npos) {
    std::string rest = text;
    long days = 0;
    if (const auto dash = rest.find('-'); dash != std::string::npos) {
      std::size_t used = 0;
      try {
        days = std::stol(rest.substr(0, dash), &used);
      } catch (const std::exception&) {
        throw bad();
      }
      if (used != dash || days < 0) throw bad();
      rest = rest.substr(dash + 1);
    }
    std::vector<long> parts;
    std::size_t at = 0;
    while (at <= rest.size()) {
      const std::size_t end = std::min(rest.find(':', at), rest.size());
      const std::string p = rest.substr(at, end - at);
      if (p.empty() || p.size() > 6 || p.find_first_not_of("0123456789") != std::string::npos) throw bad();
      parts.push_back(std::stol(p));
      at = end + 1;
    }
    if (parts.size() < 2 || parts.size() > 3 || parts[1] >= 60 || (parts.size() == 3 && parts[2] >= 60)) throw bad();
    s = 86400.0 * days + 3600.0 * parts[0] + 60.0 * parts[1] + (parts.size() == 3 ? parts[2] : 0);
  } else {
    double unit = 1;
    std::string num = text;
    if (!num.empty() && (num.back() == 's' || num.back() == 'm' || num.back() == 'h')) {
      unit = num.back() == 'h' ? 3600 : num.back() == 'm' ? 60 : 1;
      num.pop_back();
    }
    double v = 0;
    if (num.empty() || !CLI::detail::lexical_cast(num, v) || !std::isfinite(v)) throw bad();
    s = v * unit;
  }
  if (!(s > 0) || !std::isfinite(s)) throw bad();
  return s;
}

// --continue: OUT's own checkpoint, if one exists, for a run made by this configuration
// (run.t_end and run.max_wall aside: the one extends the run, the other is the job's);
// nullopt when there is none (the run starts from rest). Another configuration is refused
// (exit 78), naming the first key that differs.
std::optional<cvt::Checkpoint> continuation(const cvt::Config& cfg, const std::string& out) {
  using namespace cvt;
  const std::string path = out + ".ckpt";
  if (!std::filesystem::exists(path)) return std::nullopt;
  Checkpoint c = read_checkpoint(path);
  const std::string theirs = continuation_toml(c.config_toml, true), ours = continuation_toml(cfg.resolved_toml, true);
  if (theirs != ours) {
    std::istringstream a(theirs), b(ours);
    std::string la, lb, section;
    while (std::getline(a, la) && std::getline(b, lb) && la == lb)
      if (!la.empty() && la[0] == '[') section = la;
    for (std::string* l : {&la, &lb})
      if (const auto hash = l->find("  #"); hash != std::string::npos) l->resize(hash);  // the unit comment
    throw ConfigError("--continue", path,
                      "the checkpoint was made by another configuration (" + section + " " + la + " there, " + lb +
                          " here): give the command it was started with, or another --out to start anew");
  }
  return c;
}

// --continue of a run that has ended (t_end reached, or steady or slipping under
// run.until_steady): said, and nothing run.
bool already_complete(const cvt::Checkpoint& c, const cvt::Config& cfg, const std::string& out) {
  const bool ended = c.stopped == "steady" || c.stopped == "slip" ||
                     (c.stopped == "t_end" && cfg.run.t_end <= c.t + 0.5 * cvt::grid_step(cfg));
  if (ended)
    std::printf("cvt-engine: %s is complete (stopped: %s at t = %.9g s): nothing to continue; raise --t-end to go "
                "further\n", out.c_str(), c.stopped.c_str(), c.t);
  return ended;
}

// Numbers of the command line: finite and > 0, or >= 0 (CLI11's PositiveNumber and
// NonNegativeNumber let nan and inf through).
std::string number_check(const std::string& text, bool zero) {
  double v = 0;
  if (!CLI::detail::lexical_cast(text, v) || !std::isfinite(v) || !(zero ? v >= 0 : v > 0))
    return std::string("must be a finite number ") + (zero ? ">= 0" : "> 0") + ", not " + text.substr(0, 40);
  return {};
}
const CLI::Validator kPositive([](std::string& t) { return number_check(t, false); }, "POSITIVE");
const CLI::Validator kNonNegative([](std::string& t) { return number_check(t, true); }, "NONNEGATIVE");
// An output path: an empty one would write a hidden or default file.
const CLI::Validator kPath([](std::string& t) { return t.empty() ? std::string("an empty path") : std::string(); },
                           "PATH");

// A configuration outside the envelope (docs/envelope.md) runs, warned about on stderr
// first; `where` names the sweep's point ("" for a run).
void warn_outside_envelope(const cvt::Config& c, const std::string& where = "") {
  for (const auto& w : cvt::envelope_warnings(c)) std::fprintf(stderr, "cvt-engine: warning: %s%s\n", where.c_str(), w.c_str());
  std::fflush(stderr);
}

struct ScheduleArgs {
  std::string scheduler;  // empty: serial on one thread, the flow graph on more
  int threads = 1;
  int grain = 4;
  cvt::ScheduleOptions options() const {
    cvt::ScheduleOptions o;
    o.kind = cvt::parse_scheduler(scheduler.empty() ? (threads > 1 ? "flowgraph" : "serial") : scheduler);
    o.threads = threads;
    o.grain = grain;
    return o;
  }
};

void add_schedule_options(CLI::App* cmd, ScheduleArgs& a) {
  auto* scheduler = cmd->add_option("--scheduler", a.scheduler,
                                    a.scheduler.empty()
                                        ? "serial | flowgraph | paper-omp (default: serial on 1 thread, flowgraph on more)"
                                        : "serial | flowgraph | paper-omp")
                        ->check(CLI::IsMember({"serial", "flowgraph", "paper-omp"}));
  if (!a.scheduler.empty()) scheduler->capture_default_str();
  cmd->add_option("--threads", a.threads, "threads (flowgraph, paper-omp)")->check(CLI::Range(1, 4096))->capture_default_str();
  // The serial schedule runs on one thread: more asked of it is a contradiction, not a hint.
  cmd->callback([&a] {
    if (a.scheduler == "serial" && a.threads > 1)
      throw CLI::ValidationError("--threads", "--scheduler serial runs on one thread; " + std::to_string(a.threads) +
                                                   " threads need --scheduler flowgraph or paper-omp (or no --scheduler)");
    // More threads than the machine runs at once only wait on each other (and thousands of
    // them never finish a step): capped, with the same bits (any thread count gives them).
    const int hw = static_cast<int>(std::thread::hardware_concurrency());
    if (hw > 0 && a.threads > hw) {
      std::fprintf(stderr, "cvt-engine: warning: --threads %d is more than the %d hardware threads here: running on %d\n",
                   a.threads, hw, hw);
      a.threads = hw;
    }
  });
  cmd->add_option("--grain", a.grain, "pins per task in the flow-graph module nodes")
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
}

int cmd_graph(const std::string& config_path, const std::vector<std::string>& overrides, const ScheduleArgs& sa,
              bool w_step) {
  using namespace cvt;
  const Model model = build_model(load_config(config_path, overrides));
  Workspace ws(model);
  const auto schedule = make_schedule(model, ws, sa.options());
  if (w_step) {  // the W-method's step around the stage graph (docs/performance.md)
    if (model.cfg.integrator.method == IntegratorMethod::rk4)
      throw ConfigError("integrator.method", "rk4", "--w-step draws a W-method's step (ros2, ros34pw2, ros34prw)");
    std::printf("// %s\n%s", schedule->describe().c_str(), w_step_graphviz(model.cfg, schedule->threads()).c_str());
    return kExitOk;
  }
  std::printf("// %s\n// view: cvt-engine graph CONFIG > graph.dot && dot -Tsvg graph.dot -o graph.svg (graphviz)\n%s",
              schedule->describe().c_str(), schedule->graphviz().c_str());

  if (isatty(fileno(stdout)))
    std::fprintf(stderr, "(GraphViz text: save it and draw it with dot, e.g. cvt-engine graph %s > graph.dot && dot -Tsvg "
                         "graph.dot -o graph.svg)\n", config_path.c_str());
  return kExitOk;
}

int cmd_topology(const std::string& config_path, int threads) {
  using namespace cvt;
  int pins = 84;
  if (!config_path.empty()) pins = build_model(load_config(config_path, {})).links;
  const numa::Topology topo = numa::discover_topology();
  if (threads < 1) threads = topo.total_cores();
  const numa::NodeArenas arenas(topo, threads);
  std::printf("%s", numa::describe(topo, &arenas, pins).c_str());
  return kExitOk;
}

int cmd_scale(const std::string& config_path, const std::vector<std::string>& overrides, const std::vector<int>& threads,
              const std::vector<std::string>& schedulers, const std::vector<std::string>& layouts, long steps, int repeat,
              double warmup, int grain, const std::string& csv, const std::string& json) {
  using namespace cvt;
  const Model model = build_model(load_config(config_path, overrides));
  ScaleOptions o;
  o.threads = threads;
  o.schedulers.clear();
  for (const auto& s : schedulers) o.schedulers.push_back(parse_scheduler(s));
  o.layouts = layouts;
  o.steps = steps;
  o.repeat = repeat;
  o.warmup = warmup;
  o.grain = grain;
  // The output files are created first: a bad path fails now, not after the study.
  std::optional<std::ofstream> csv_file, json_file;
  for (auto [path, file] : {std::pair{&csv, &csv_file}, std::pair{&json, &json_file}})
    if (!path->empty()) {
      file->emplace(*path);
      if (!**file) throw std::runtime_error("cannot write '" + *path + "'");
    }
  const int cores = numa::discover_topology().total_cores();
  std::printf("cvt-engine %s scale: %s, %d links, %ld steps x %d repeats per combination, %d cores here\n", CVT_VERSION,
              config_path.c_str(), model.links, steps, repeat, cores);
  for (int t : threads)
    if (t > cores) std::printf("  note: %d threads on %d cores: oversubscribed, the figures show contention\n", t, cores);
  std::fflush(stdout);
  const auto rows = run_scaling_study(model, o, [](const std::string& line) {
    std::fprintf(stderr, "  %s\n", line.c_str());
  });
  std::printf("\n%s", scale_table(rows).c_str());
  std::printf("(medians over the repeats; speedups against the serial schedule in the same run; chain/pulley us:\n"
              " the module's largest busy time over the threads per step; zero+gath, compute: per thread and step)\n");
  const auto write = [](std::ofstream& f, const std::string& path, const std::string& text) {
    f << text;
    f.close();
    if (!f) throw std::runtime_error("cannot write '" + path + "'");
    std::printf("wrote %s\n", path.c_str());
  };
  if (csv_file) write(*csv_file, csv, scale_csv(rows));
  if (json_file) write(*json_file, json, scale_json(rows, config_path));
  for (const auto& r : rows)
    if (!r.identical) {
      std::fprintf(stderr, "cvt-engine: %s with %d threads (%s) did not give the serial bits\n", r.scheduler.c_str(),
                   r.threads, r.layout.c_str());
      return kExitFailure;
    }
  return kExitOk;
}

struct RunArgs {
  std::string resume;
  long checkpoint_every = 50000;
  double flush_seconds = 10.0;
  std::string profile_json, summary_json;
  std::string method;  // --method: integrator.method
  std::string out;     // --out (empty: results.h5, or with --resume the run's own file)
  bool profile = false, quiet = false;
  bool until_steady = false;  // --until-steady: run.until_steady
  bool verify = false;        // --verify: run.verify
  std::string max_wall;       // --max-wall DURATION: run.max_wall
  bool cont = false;          // --continue: from OUT.ckpt if it exists, else from rest
};

// "1.4 min per model second" for a throughput in model seconds per wall hour.
std::string per_model_second(double model_s_per_hour) {
  if (!(model_s_per_hour > 0)) return "-";
  const double s = 3600.0 / model_s_per_hour;
  char b[64];
  if (s < 120) std::snprintf(b, sizeof b, "%.3g s", s);
  else if (s < 7200) std::snprintf(b, sizeof b, "%.3g min", s / 60);
  else std::snprintf(b, sizeof b, "%.3g h", s / 3600);
  return b;
}

// The run's output file: -o, results.h5, or without -o a resumed run's own file (GROMACS's
// mdrun -cpi: the one the checkpoint names, else the checkpoint's name without ".ckpt").
// What the run reads it never writes (exit 73): its configuration, the checkpoint it resumes
// (which only its own next checkpoint replaces), and, for a continuation into a new file,
// the run's own file, which -o would replace with the continuation alone.
std::string run_output(const std::string& config_path, const cvt::Checkpoint* ckpt, const RunArgs& ra) {
  using namespace cvt;
  std::string own;
  if (ckpt) {
    own = ckpt->output;
    if (own.empty()) {
      own = ra.resume;
      if (own.size() > 5 && own.compare(own.size() - 5, 5, ".ckpt") == 0) own.resize(own.size() - 5);
    }
  }
  const bool append = ckpt && ra.out.empty();
  const std::string out = append ? own : ra.out.empty() ? "results.h5" : ra.out;
  const std::vector<PathRole> outputs = {
      {"output file", out}, {"summary JSON", ra.summary_json}, {"profile JSON", ra.profile_json}};
  std::vector<PathRole> inputs = {{"configuration", config_path}, {"checkpoint resumed from", ra.resume}};
  if (ckpt && !append) inputs.push_back({"resumed run's own file (leave -o out to append to it)", own});
  check_distinct(inputs, outputs);
  return out;
}

// The run's header: the model, its geometry, and how it is integrated.
void print_run_header(const cvt::Config& cfg, const cvt::Model& model, const std::string& source) {
  using namespace cvt;
  std::printf("cvt-engine %s: %s\n", CVT_VERSION, source.c_str());
  std::printf("  %d links, %d coordinates, %d first-order unknowns\n", model.links, model.ndof, model.nstate);
  std::printf("  geometry: R1 = %.4f mm, R2 = %.4f mm, closure residual = %.3g m\n",
              1e3 * model.pulley[0].running_radius, 1e3 * model.pulley[1].running_radius, model.closure_residual);
  const int startup_sub = cvt::startup_substeps(cfg.integrator, cfg.integrator.step);
  std::string w;
  if (cfg.integrator.method != IntegratorMethod::rk4) {
    w = " (matrix every " + std::to_string(cfg.integrator.w_every) + " steps, its stiffness every " +
        std::to_string(cfg.integrator.w_k_every);
    const int k_every = cvt::stiffness_every(model, cfg.integrator.step, cfg.integrator.w_every, cfg.integrator.w_k_every);
    if (!cvt::adaptive_steps(cfg) && !cfg.integrator.fixed_steps && k_every < cfg.integrator.w_k_every)
      w += " (" + std::to_string(k_every) + " at this chain speed: a quarter of a pitch)";
    if (startup_sub > 1)
      w += "; " + std::to_string(startup_sub) + " ros2 sub-steps per step before t = " +
           fmt_g(cfg.integrator.startup_time) + " s";
    const int settle_sub = cvt::settle_substeps(cfg.integrator, cfg.integrator.step);
    if (settle_sub > 1)
      w += ", " + std::to_string(settle_sub) + " sub-steps per step before t = " + fmt_g(cfg.integrator.settle_time) +
           " s";
    if (!cvt::adaptive_steps(cfg) && !cfg.integrator.fixed_steps && cfg.integrator.energy_leak > 0)
      w += "; halved where the energy balance leaks more than " + fmt_g(100 * cfg.integrator.energy_leak) +
           " % of the input work";
    w += ")";
  }
  const std::string step = cvt::adaptive_steps(cfg)
                               ? "adaptive steps (tolerance " + fmt_g(cfg.integrator.tolerance) + ", first " +
                                     fmt_g(cfg.integrator.step) + " s, at most " + fmt_g(cfg.run.sample_interval) + " s)"
                               : "step = " + fmt_g(cfg.integrator.step) + " s";
  if (cvt::adaptive_steps(cfg) && startup_sub > 1)
    w = " (matrix every " + std::to_string(cfg.integrator.w_every) + " steps, its stiffness every " +
        std::to_string(cfg.integrator.w_k_every) + "; ros2 sub-steps of " + fmt_g(cfg.integrator.startup_step) +
        " s before t = " + fmt_g(cfg.integrator.startup_time) + " s)";
  std::printf("  t_end = %g s%s, %s %s%s, friction %s\n", cfg.run.t_end,
              cfg.run.until_steady ? (" (or until steady: two windows of " + fmt_g(steady_window(model)) + " s)").c_str()
                                   : "",
              to_string(cfg.integrator.method), step.c_str(), w.c_str(), to_string(cfg.friction.law));
  std::fflush(stdout);
}

int cmd_run(const std::string& config_path, std::vector<std::string> overrides, const std::string& t_end,
            const std::string& step, const ScheduleArgs& sa, const RunArgs& ra) {
  using namespace cvt;
  const StopSignals stop_signals;  // from the first instruction: a signal before the run stops it at once
  // Command-line shortcuts are overrides too, passed as typed: validated like any key and
  // recorded in the resolved TOML.
  if (!t_end.empty()) overrides.push_back("run.t_end=" + t_end);
  if (!step.empty()) overrides.push_back("integrator.step=" + step);
  if (!ra.method.empty()) overrides.push_back("integrator.method=" + ra.method);
  if (ra.until_steady) overrides.push_back("run.until_steady=true");
  if (ra.verify) overrides.push_back("run.verify=true");
  if (!ra.max_wall.empty())
    overrides.push_back("run.max_wall=" + cvt::exact_number(parse_duration("--max-wall", ra.max_wall)));
  // A resumed run takes its configuration from the checkpoint (overrides still apply:
  // --t-end to go further; changing the physics would break the continuation).
  std::optional<Checkpoint> ckpt;
  if (!ra.resume.empty()) {
    if (!config_path.empty()) throw ConfigError("CONFIG", config_path, "give either CONFIG or --resume, not both");
    if (ra.cont) throw ConfigError("--continue", "", "give either --continue (with CONFIG) or --resume, not both");
    ckpt = read_checkpoint(ra.resume);
  } else if (config_path.empty()) {
    throw ConfigError("CONFIG", "", "missing: give a TOML configuration or --resume CHECKPOINT");
  }
  std::map<std::string, std::string> shortcuts;  // the keys the shortcut options set
  if (!t_end.empty()) shortcuts["run.t_end"] = "--t-end";
  if (!step.empty()) shortcuts["integrator.step"] = "--step";
  if (!ra.method.empty()) shortcuts["integrator.method"] = "--method";
  if (ra.until_steady) shortcuts["run.until_steady"] = "--until-steady";
  if (ra.verify) shortcuts["run.verify"] = "--verify";
  if (!ra.max_wall.empty()) shortcuts["run.max_wall"] = "--max-wall";
  const Config cfg = ckpt ? parse_config(ckpt->config_toml, overrides, ra.resume, shortcuts)
                          : load_config(config_path, overrides, shortcuts);
  // --continue: the run's own checkpoint, if there is one, made by this configuration.
  const bool continued = ra.cont && (ckpt = continuation(cfg, ra.out.empty() ? "results.h5" : ra.out));
  if (continued && already_complete(*ckpt, cfg, ra.out.empty() ? "results.h5" : ra.out)) return kExitOk;
  warn_outside_envelope(cfg);
  const Model model = build_model(cfg);
  const bool append = ckpt && (ra.out.empty() || continued);
  const std::string out = continued ? ra.out.empty() ? "results.h5" : ra.out
                                    : run_output(config_path, ckpt ? &*ckpt : nullptr, ra);
  cvt::check_step_grid(cfg);  // refused (exit 78) before the header, not after it
  const bool talk = !ra.quiet;
  if (talk)
    print_run_header(cfg, model, ckpt ? (continued ? "continue " + out + ".ckpt" : "resume " + ra.resume) : config_path);
  RunOptions opt;
  opt.schedule = sa.options();
  opt.checkpoint_every = ra.checkpoint_every;
  opt.flush_seconds = ra.flush_seconds;
  opt.resume = ckpt ? &*ckpt : nullptr;
  opt.append = append;
  opt.out_path = out;
  opt.progress = talk;
  opt.profile_json = ra.profile_json;
  opt.summary_json = ra.summary_json;
  opt.started = g_command_start;
  if (ra.quiet) std::freopen("/dev/null", "w", stdout);  // the driver's own lines too
  const RunResult r = run_simulation(model, opt);
  // An interrupt is said on stderr, --quiet or not: the run did not reach t_end.
  const std::string ckpt_out = opt.checkpoint_path.empty() ? out + ".ckpt" : opt.checkpoint_path;
  if (r.stopped == "max_wall")
    std::fprintf(stderr, "cvt-engine: run stopped at t = %.9g s after %ld steps, before its wall-time limit "
                 "(run.max_wall = %s s): results up to there in %s; the same command with --continue, or "
                 "cvt-engine run --resume %s, continues it\n",
                 r.model_time, r.steps, fmt_g(cfg.run.max_wall).c_str(), out.c_str(), ckpt_out.c_str());
  else if (r.interrupted)
    std::fprintf(stderr, "cvt-engine: run interrupted by signal %d at t = %.9g s after %ld steps: results up to "
                 "there in %s; continue with: cvt-engine run --resume %s\n",
                 r.signal, r.model_time, r.steps, out.c_str(), ckpt_out.c_str());
  if (talk) {
    if (r.interrupted)
      std::printf("\nrun stopped at t = %.9g s in %s\n", r.model_time, out.c_str());
    else
      std::printf("\nrun complete: t = %.9g s in %s\n", r.model_time, out.c_str());
    std::printf("%s", format_summary(r).c_str());
    // The steps, wall time and us per step are the summary's run line: this adds the
    // wall time per model second and the schedule that gave them.
    std::printf("  throughput: %s per model second (%s, %d thread%s)\n", per_model_second(r.model_s_per_hour).c_str(),
                r.profile.scheduler.c_str(), r.profile.threads, r.profile.threads == 1 ? "" : "s");
    if (ra.profile) std::printf("\n%s", format_profile(r.profile).c_str());
  }
  return r.stopped == "max_wall" ? kExitWallLimit : r.interrupted ? kExitInterrupted : kExitOk;
}


struct ModesArgs {
  double at = 0;
  int count = 10;
  double rigid_hz = 1.0;
  bool no_jacobian = false;
  std::string json;
};

int cmd_modes(const std::string& config_path, const std::vector<std::string>& overrides, const ModesArgs& a) {
  using namespace cvt;
  const Config cfg = load_config(config_path, overrides);
  const Model model = build_model(cfg);
  const double h = cfg.integrator.step;
  std::printf("cvt-engine %s modes: %s\n", CVT_VERSION, config_path.c_str());
  std::printf("  %d links, %d coordinates, %d first-order unknowns; friction %s\n", model.links, model.ndof,
              model.nstate, to_string(cfg.friction.law));
  // The state at --at: the serial schedule from the initial state with the config's
  // step, statuses updated after every step as in a run.
  Simulation sim(model);
  const long steps = std::lround(a.at / h);
  if (steps > 0) {
    const auto t0 = std::chrono::steady_clock::now();
    const long every = std::max(1L, std::lround(cfg.run.sample_interval / h));
    for (long s = 0; s < steps; ++s) {
      sim.step(h);
      if ((s + 1) % every == 0 || s + 1 == steps) sim.check_finite();
    }
    std::printf("  ran %ld steps of %g s to t = %.9g s (%.1f s)\n", steps, h, sim.time(),
                seconds_since(t0));
  }
  std::fflush(stdout);
  ModesOptions opt;
  opt.count = a.count;
  opt.rigid_hz = a.rigid_hz;
  opt.jacobian = !a.no_jacobian;
  const ModalReport r = modal_analysis(model, sim.workspace().status, sim.time(), sim.state(), opt);
  std::printf("  rigid-body threshold |f| < %g Hz\n\n%s", a.rigid_hz, format_modal_report(r, h).c_str());
  if (r.has_jacobian) {
    // The estimate a blow-up message gives (Simulation::spectral_radius), for comparison.
    const double rho_pi = sim.spectral_radius(sim.state(), sim.time(), sim.workspace().status);
    std::printf("  (power iteration on differences, as in the blow-up message: rho ~ %.4g 1/s, 2.8/rho = %.4g s)\n",
                rho_pi, rho_pi > 0 ? 2.8 / rho_pi : 0.0);
  }
  if (!a.json.empty()) {
    std::ofstream f(a.json);
    f << modal_report_json(r, h);
    f.close();
    if (!f) throw std::runtime_error("cannot write " + a.json);
    std::printf("\nwritten: %s\n", a.json.c_str());
  }
  return kExitOk;
}

// After an unknown option: the closest options of the subcommand that was given.
void suggest_options(CLI::App& app, int argc, char** argv) {
  const CLI::App* cmd = &app;
  for (int i = 1; i < argc; ++i)
    for (const CLI::App* sub : cmd->get_subcommands({}))
      if (sub->get_name() == argv[i]) cmd = sub;
  std::vector<std::string> names;
  for (const CLI::Option* o : cmd->get_options())
    for (const std::string& n : o->get_lnames()) names.push_back("--" + n);
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    if (a.rfind("--", 0) != 0) continue;
    a = a.substr(0, a.find('='));
    if (std::find(names.begin(), names.end(), a) != names.end()) continue;
    if (const auto best = cvt::closest_name(a, names))
      std::fprintf(stderr, "%s: unknown option; did you mean '%s'?\n", a.c_str(), best->c_str());
  }
}

// A subcommand: its app (true once given on the command line) and what it runs. Each
// add_*_command declares its subcommand's options next to the state they fill.
struct Command {
  CLI::App* app;
  std::function<int()> run;
};

// cvt-engine run: simulate a configuration into HDF5 (cmd_run).
Command add_run_command(CLI::App& app) {
  struct Args {
  std::string config;
  std::vector<std::string> overrides;
  std::string t_end, step;
  RunArgs run_args;
  ScheduleArgs sched;
  };
  auto a = std::make_shared<Args>();
  auto& config = a->config;
  auto& overrides = a->overrides;
  auto& t_end = a->t_end;
  auto& step = a->step;
  auto& run_args = a->run_args;
  auto& sched = a->sched;
  auto* run = app.add_subcommand("run", "simulate a configuration and write the results to HDF5");
  run->footer("Example: cvt-engine run configs/reference-steady.toml --scheduler flowgraph --threads 2 -o results.h5");
  run->add_option("CONFIG", config, "TOML configuration (configs/reference.toml); omit with --resume");
  run->add_option("--resume", run_args.resume,
                  "continue bit-identically from a checkpoint (FILE.ckpt), appending to the run's own file "
                  "(unless --out)");
  run->add_option("--checkpoint-every", run_args.checkpoint_every,
                  "steps between checkpoints to OUT.ckpt (0: only at the end and on SIGINT/SIGTERM)")
      ->check(kNonNegative)
      ->capture_default_str();
  run->add_option("--flush-every", run_args.flush_seconds,
                  "wall seconds between flushes of the output file (what a kill -9 cannot take away)")
      ->check(kPositive)
      ->capture_default_str();
  run->add_option("--t-end", t_end, "model time to simulate [s] (run.t_end)");
  run->add_flag("--until-steady", run_args.until_steady,
                "stop once the operating point is steady or grossly slips, t_end the upper bound (run.until_steady; "
                "docs/output.md)");
  run->add_option("--max-wall", run_args.max_wall,
                  "stop cleanly, with a checkpoint, before this much wall time: seconds, 90m, 23.5h or 23:50:00 "
                  "(run.max_wall; docs/cli.md, \"On a cluster\")");
  run->add_flag("--continue", run_args.cont,
                "continue from OUT.ckpt when it exists (made by the same configuration, run.t_end and run.max_wall "
                "aside), else start from rest: the same command line resubmitted continues a run");
  run->add_flag("--verify", run_args.verify,
                "after the run, integrate the summary's window again with the step halved and print each mean's "
                "numerical error beside it (run.verify; docs/output.md, \"Numerical error\")");
  run->add_option("--step", step, "integration step [s] (integrator.step)");
  run->add_option("--method", run_args.method,
                  "rk4 | ros2 | ros34pw2 | ros34prw (integrator.method; docs/integrators.md 12, 14)");
  run->add_option("-o,--out", run_args.out, "output HDF5 file (default results.h5; with --resume: a new file "
                  "for the continuation only)")->check(kPath);
  run->add_option("--set", overrides, "override a key: section.key=value (repeatable)");
  run->add_flag("-q,--quiet", run_args.quiet, "print nothing but warnings and errors");
  run->add_flag("--profile", run_args.profile, "print the per-module profile table (always stored in /profile)");
  run->add_option("--profile-json", run_args.profile_json, "write the end-of-run profile table as JSON to FILE");
  run->add_option("--summary-json", run_args.summary_json, "write the end-of-run summary as JSON to FILE");
  add_schedule_options(run, sched);
  return {run, [a] {
    return cmd_run(a->config, a->overrides, a->t_end, a->step, a->sched, a->run_args);
  }};
}

// cvt-engine graph: the flow graph of one stage as GraphViz.
Command add_graph_command(CLI::App& app) {
  struct Args {
  std::string graph_config;
  std::vector<std::string> graph_overrides;
  ScheduleArgs graph_sched;
  bool graph_w_step = false;
  };
  auto a = std::make_shared<Args>();
  auto& graph_config = a->graph_config;
  auto& graph_overrides = a->graph_overrides;
  auto& graph_sched = a->graph_sched;
  auto* graph = app.add_subcommand("graph", "print the flow graph of one RK4 stage as GraphViz");
  graph->footer("Example: cvt-engine graph configs/reference.toml --threads 2 > graph.dot && dot -Tsvg graph.dot -o graph.svg\n"
                "         cvt-engine graph configs/reference.toml --threads 2 --w-step > w_step.dot");
  graph_sched.scheduler = "flowgraph";
  graph->add_option("CONFIG", graph_config, "TOML configuration")->required();
  graph->add_option("--set", graph_overrides, "override a key: section.key=value (repeatable)");
  graph->add_flag("--w-step", a->graph_w_step,
                  "print the W-method's whole step (stages, block-LU solves on two sweeps, rebuilds) instead of the "
                  "stage graph");
  add_schedule_options(graph, graph_sched);
  return {graph, [a] {
    return cmd_graph(a->graph_config, a->graph_overrides, a->graph_sched, a->graph_w_step);
  }};
}

// cvt-engine scale: the scaling study (engine/studies/scale.cpp).
Command add_scale_command(CLI::App& app) {
  struct Args {
  std::string scale_config, scale_out, scale_json;
  std::vector<std::string> scale_overrides, scale_layouts = {"native"};
  std::vector<std::string> scale_schedulers = {"serial", "flowgraph", "paper-omp"};
  std::vector<int> scale_threads = {1, 2};
  long scale_steps = 200;
  int scale_repeat = 5, scale_grain = 4;
  double scale_warmup = 3e-4;
  };
  auto a = std::make_shared<Args>();
  auto& scale_config = a->scale_config;
  auto& scale_out = a->scale_out;
  auto& scale_json = a->scale_json;
  auto& scale_overrides = a->scale_overrides;
  auto& scale_layouts = a->scale_layouts;
  auto& scale_schedulers = a->scale_schedulers;
  auto& scale_threads = a->scale_threads;
  auto& scale_steps = a->scale_steps;
  auto& scale_repeat = a->scale_repeat;
  auto& scale_grain = a->scale_grain;
  auto& scale_warmup = a->scale_warmup;
  auto* scale = app.add_subcommand("scale", "scaling study: time per step per scheduler, thread count and NUMA layout");
  scale->footer("Example: cvt-engine scale configs/reference.toml --threads 1,2 --out scaling.csv");
  scale->add_option("CONFIG", scale_config, "TOML configuration")->required();
  scale->add_option("--threads", scale_threads, "thread counts, comma-separated")->delimiter(',')
      ->check(CLI::Range(1, 4096))->capture_default_str();
  scale->add_option("--schedulers", scale_schedulers, "serial,flowgraph,paper-omp")->delimiter(',')
      ->check(CLI::IsMember({"serial", "flowgraph", "paper-omp"}))->capture_default_str();
  scale->add_option("--layouts", scale_layouts,
                    "NUMA layouts for the flow graph: native, or hwloc synthetic strings "
                    "(e.g. 'package:2 numa:1 core:8 pu:1'), comma-separated")
      ->delimiter(',')->capture_default_str();
  scale->add_option("--steps", scale_steps, "RK4 steps per repeat")->check(CLI::Range(1L, 100000000L))->capture_default_str();
  scale->add_option("--repeat", scale_repeat, "repeats (medians)")->check(CLI::Range(1, 100000))->capture_default_str();
  scale->add_option("--warmup", scale_warmup, "model time run first, serially [s]")->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  scale->add_option("--grain", scale_grain, "pins per task (flowgraph)")->check(CLI::Range(1, 1000000))->capture_default_str();
  scale->add_option("-o,--out", scale_out, "CSV file")->check(kPath);
  scale->add_option("--json", scale_json, "JSON file");
  scale->add_option("--set", scale_overrides, "override a key: section.key=value (repeatable)");
  return {scale, [a] {
    return cmd_scale(a->scale_config, a->scale_overrides, a->scale_threads, a->scale_schedulers, a->scale_layouts,
                     a->scale_steps, a->scale_repeat, a->scale_warmup, a->scale_grain, a->scale_out, a->scale_json);
  }};
}

// The W-methods' options of cvt-engine study integrators (docs/integrators.md 12).
void add_study_w_options(CLI::App* study_int, cvt::IntegratorStudyOptions& si, bool& si_exact_slope) {
  study_int->add_option("--w-every", si.w_every, "ROS2: rebuild its matrix every N steps (default: integrator.w_every)")
      ->check(kPositive);
  study_int->add_flag("--ros2-full-jacobian", si.ros2_full_jacobian,
                     "ROS2 with the full coloured Jacobian and a sparse LU per step instead of the friction blocks");
  study_int->add_flag("--w-exact-slope", si_exact_slope,
                      "ROS2: the exact friction slope along the sliding direction (default: the secant)");
  study_int->add_option("--w-k-every", si.w_k_every,
                        "ROS2: rebuild its stiffness blocks every N steps (default: integrator.w_k_every)")
      ->check(kPositive);
  study_int->add_flag("--w-no-stiffness", si.w_no_stiffness, "ROS2: leave the chain's stiffness out of its matrix");
  study_int->add_option("--w-fresh", si.w_fresh,
                        "W-methods: keep the matrix's friction current between rebuilds for the contacts whose "
                        "stiffness gamma h mu / m_pin moved by more than this; 0: off (default: integrator.w_fresh)")
      ->check(kNonNegative);
  study_int->add_option("--w-fresh-max", si.w_fresh_max,
                        "W-methods: at most this many contacts in that correction (default: integrator.w_fresh_max)")
      ->check(kPositive);
  study_int->add_flag("--w-status-rebuild", si.w_status_rebuild,
                      "ROS2: rebuild its whole matrix when the contact statuses change");
}

// cvt-engine study integrators: the integrator study (engine/studies/integrators.cpp).
Command add_study_command(CLI::App& app) {
  struct Args {
  std::string si_config;
  std::vector<std::string> si_overrides;
  cvt::IntegratorStudyOptions si;
  ScheduleArgs si_sched;
  bool si_no_one_step = false, si_no_curve = false, si_approx = false, si_plain_friction = false;
  std::vector<std::string> si_w_steps;
  bool si_first_accurate = false, si_one_step = false;
  bool si_exact_slope = false;
  bool si_no_cache = false;
  };
  auto a = std::make_shared<Args>();
  auto& si_config = a->si_config;
  auto& si_overrides = a->si_overrides;
  auto& si = a->si;
  auto& si_sched = a->si_sched;
  auto& si_no_one_step = a->si_no_one_step;
  auto& si_no_curve = a->si_no_curve;
  auto& si_approx = a->si_approx;
  auto& si_plain_friction = a->si_plain_friction;
  auto& si_w_steps = a->si_w_steps;
  auto& si_first_accurate = a->si_first_accurate;
  auto& si_one_step = a->si_one_step;
  auto& si_exact_slope = a->si_exact_slope;
  auto& si_no_cache = a->si_no_cache;
  auto* study = app.add_subcommand("study", "method studies");
  study->footer("Example: cvt-engine study integrators configs/reference.toml --cache study-cache --out study.csv");
  study->require_subcommand(1);
  auto* study_int = study->add_subcommand("integrators", "integrator study: by default RK4 at 1e-8 against ROS34PW2 at the configuration's step, over "
                                          "5 ms of a running chain, against RK4 at 5e-9 (docs/integrators.md): about 7 min for the "
                                          "reference model, most of it the running state and the reference, which the cache keeps "
                                          "for the next run (then about 2 min)");
  study_int->footer("Example: cvt-engine study integrators configs/reference.toml --cache study-cache --out study.csv");
  study_int->add_option("CONFIG", si_config, "TOML configuration")->required();
  study_int->add_option("--t-sample", si.t_sample, "length of the sample-curve window [s]")->capture_default_str();
  study_int->add_option("--t-warm", si.t_warm, "RK4 run to the running state [s]")->capture_default_str();
  study_int->add_option("--sample-dt", si.sample_dt, "spacing of the curve samples [s]")->capture_default_str();
  study_int->add_option("--ref-step", si.ref_step, "RK4 step of the reference curve [s]")->capture_default_str();
  study_int->add_option("--methods", si.methods,
                        "rk4,dopri5,rkc,dumka3,trapezoid,trbdf2,esdirk3,ros2,ros34pw2,ros34prw; SUNDIALS' cvode (BDF) "
                        "and arkode (ESDIRK) with their own error control at --tols, the chain's W solver their "
                        "linear solver")
      ->delimiter(',')
      ->check(CLI::IsMember({"rk4", "dopri5", "rkc", "dumka3", "trapezoid", "trbdf2", "esdirk3", "ros2", "ros34pw2",
                             "ros34prw", "cvode", "arkode"}))
      ->capture_default_str();
  study_int->add_option("--one-step-h", si.one_step_h, "steps of part (a) [s]")->delimiter(',')->capture_default_str();
  study_int->add_option("--rk4-steps", si.rk4_steps, "RK4 steps tried in (b), largest first [s]")->delimiter(',')
      ->capture_default_str();
  study_int->add_option("--w-steps,--ros2-steps", si_w_steps,
                        "W-methods' (ros2, ros34pw2, ros34prw) fixed steps tried in (b), largest first [s]; H:W:K also "
                        "sets the matrix intervals (integrator.w_every, w_k_every) of that candidate, METHOD@ before "
                        "it keeps it to one method, tol=T an adaptive candidate (default: the configuration's step)")
      ->delimiter(',');
  study_int->add_flag("--all", si.all, "(b): run every candidate (the default)");
  study_int->add_flag("--first-accurate", si_first_accurate, "(b): stop at each method's first accurate candidate");
  study_int->add_flag("--one-step", si_one_step, "run part (a), the error after one step against h (minutes)");
  study_int->add_option("--repeat", si.repeat, "run (b) in this many rounds over all its runs; each run's wall time is the median")
      ->check(CLI::Range(1, 100))->capture_default_str();
  study_int->add_option("--tols", si.tolerances, "tolerances tried in (b), loosest first (atol in units of 1 um, 1 mm/s)")
      ->delimiter(',')->capture_default_str();
  study_int->add_option("--max-dev", si.max_deviation, "accurate: deviation <= this fraction of the curve's range")
      ->capture_default_str();
  study_int->add_option("--max-wall", si.max_wall, "stop a candidate run after this many wall seconds")
      ->capture_default_str();
  study_int->add_option("--perturb", si.perturb,
                        "(b): start every run from the running state with each position q moved by EPS |q| u, u uniform "
                        "in [-1, 1) (a rounding-level change, to see how far it alone moves a curve)")
      ->check(CLI::Range(0.0, 1e-3))->capture_default_str();
  study_int->add_option("--seed", si.seed, "the seed of --perturb's u")->capture_default_str();
  study_int->add_option("--status-interval", si.status_interval,
                        "contact statuses updated every this long (0: after every accepted step)")->capture_default_str();
  study_int->add_option("--newton-max-iter", si.newton_max_iter, "Newton iterations per stage")->capture_default_str();
  add_study_w_options(study_int, si, si_exact_slope);
  study_int->add_option("--jac-theta", si.jac_theta, "new Jacobian when Newton's rate exceeds this")->capture_default_str();
  study_int->add_flag("--max-norm", si.max_norm, "error and Newton tests in the max norm (default: RMS)");
  study_int->add_flag("--newton-w", si.newton_w,
                      "implicit methods: Newton with the chain's structured matrix (the W-methods' block LU) instead of "
                      "the coloured Jacobian and a sparse LU");
  study_int->add_flag("--chain-norm", si.chain_norm,
                      "adaptive candidates: the error test per pin (the largest over the pins, shafts and load) instead "
                      "of the RMS over the state");
  study_int->add_flag("--plain-friction", si_plain_friction, "do not freeze the friction branch within a step");
  study_int->add_flag("--no-one-step", si_no_one_step, "skip part (a)");
  study_int->add_flag("--no-curve", si_no_curve, "skip part (b)");
  study_int->add_flag("--approximate-jacobian", si_approx, "leave the pins -> shaft rows out of the Jacobian");
  si.cache_dir = "study-cache";
  study_int->add_option("--cache", si.cache_dir,
                        "keep the running state and the reference curve in this folder (made if missing) and reuse "
                        "them")
      ->capture_default_str();
  study_int->add_flag("--no-cache", si_no_cache, "compute the running state and the reference anew, keep nothing");
  study_int->add_option("-o,--out", si.out_csv, "CSV file (the curves go to OUT-curves.csv)")->check(kPath);
  study_int->add_option("--set", si_overrides, "override a key: section.key=value (repeatable)");
  add_schedule_options(study_int, si_sched);
  return {study_int, [a] {
    cvt::IntegratorStudyOptions& si = a->si;
    si.one_step = a->si_one_step && !a->si_no_one_step;
    if (a->si_first_accurate) si.all = false;
    if (a->si_no_cache) si.cache_dir.clear();
    if (!si.cache_dir.empty()) std::filesystem::create_directories(si.cache_dir);
    si.curve = !a->si_no_curve;
    si.exact_dense_rows = !a->si_approx;
    si.freeze_friction = !a->si_plain_friction;
    if (a->si_exact_slope) si.w_secant = 0;
    si.schedule = a->si_sched.options();
    const cvt::Model model = cvt::build_model(cvt::load_config(a->si_config, a->si_overrides));
    if (!a->si_w_steps.empty()) si.w_steps = cvt::parse_w_candidates(a->si_w_steps);
    else  // the configuration's own step and matrix intervals
      si.w_steps = {{model.cfg.integrator.step, 0, model.cfg.integrator.w_every, model.cfg.integrator.w_k_every, "ros34pw2"}};
    if (si.w_every == 0) si.w_every = model.cfg.integrator.w_every;
    if (si.w_k_every == 0) si.w_k_every = model.cfg.integrator.w_k_every;
    return cvt::run_integrator_study(model, si);
  }};
}

// cvt-engine sweep: operating points until steady, one CSV and HDF5 row each
// (engine/studies/sweep.cpp); under mpirun or srun the points go out to the ranks.
// How a sweep runs: all its points, one (a job array's task), or the rows of the tasks.
struct SweepMode {
  long point = -1;       // --point I (or --array: $SLURM_ARRAY_TASK_ID); -1: every point
  bool array = false;
  bool gather = false;   // --gather
  std::string max_wall;  // --max-wall: run.max_wall of every point, counted from the command's start
};

// --point I / --array: the task's point, from the command line or the job array's index.
long sweep_task_point(const SweepMode& m) {
  if (!m.array) return m.point;
  if (m.point >= 0) throw cvt::ConfigError("--array", "", "give either --point I or --array, not both");
  const char* id = std::getenv("SLURM_ARRAY_TASK_ID");
  if (!id || !*id)
    throw cvt::ConfigError("--array", "", "SLURM_ARRAY_TASK_ID is not set: --array runs inside a Slurm job array "
                                          "(sbatch --array=0-N); elsewhere give --point I");
  char* end = nullptr;
  const long i = std::strtol(id, &end, 10);
  if (*end || i < 0) throw cvt::ConfigError("--array", id, "SLURM_ARRAY_TASK_ID must be a point number >= 0");
  return i;
}

// "1 point", "3 points".
std::string count_of_points(std::size_t n) { return std::to_string(n) + (n == 1 ? " point" : " points"); }

// The sweep's last line: where its table is, and how many of its points are not steady.
void print_sweep_written(const std::string& out, std::size_t points, long unsteady) {
  std::printf("wrote %s.csv and %s.h5 (%s, %ld not steady)\n", out.c_str(), out.c_str(),
              count_of_points(points).c_str(), unsteady);
}

// cvt-engine sweep --point I / --array: one point, its row into OUT.points/.
int cmd_sweep_task(const cvt::SweepOptions& o, const cvt::SweepPlan& plan, long i) {
  using namespace cvt;
  if (i >= static_cast<long>(plan.points.size()))
    throw ConfigError("--point", std::to_string(i), "the sweep's points are 0 .. " + std::to_string(plan.points.size() - 1));
  std::printf("cvt-engine %s sweep: point %ld of points 0..%zu (%s) into %s\n", CVT_VERSION, i, plan.points.size() - 1,
              plan.label(i).c_str(), task_file(o, i).c_str());
  std::fflush(stdout);
  const SweepRow r = run_sweep_task(o, plan, i);
  std::printf("  %s\n", sweep_point_line(plan, r, static_cast<long>(plan.points.size())).c_str());
  return kExitOk;
}

// cvt-engine sweep --gather: the tasks' rows into OUT.csv and OUT.h5.
int cmd_sweep_gather(const cvt::SweepOptions& o, const cvt::SweepPlan& plan) {
  using namespace cvt;
  long unsteady = 0;
  const std::vector<long> missing = gather_sweep(o, plan, &unsteady);
  if (!missing.empty()) {
    std::string list;
    for (std::size_t k = 0; k < missing.size() && k < 20; ++k) list += (k ? "," : "") + std::to_string(missing[k]);
    if (missing.size() > 20) list += ",...";
    std::fprintf(stderr, "cvt-engine: %zu of %zu points have no row in %s.points/ yet (%s): run them with --point I "
                 "(or the sweep without --point runs them here), then --gather again; the %zu rows found are in %s.csv\n",
                 missing.size(), plan.points.size(), o.out.c_str(), list.c_str(), plan.points.size() - missing.size(),
                 o.out.c_str());
    return kExitWallLimit;
  }
  print_sweep_written(o.out, plan.points.size(), unsteady);
  return kExitOk;
}

int cmd_sweep(cvt::SweepOptions o, const std::vector<std::string>& axes, const std::string& points,
              const SweepMode& mode) {
  using namespace cvt;
  const StopSignals stop_signals;  // from the first instruction, as for a run
  o.started = g_command_start;
  if (!mode.max_wall.empty())
    o.overrides.push_back("run.max_wall=" + cvt::exact_number(parse_duration("--max-wall", mode.max_wall)));
  const SweepPlan plan = sweep_plan(o, axes, points);
  const long task = sweep_task_point(mode);
  if (mode.gather && task >= 0) throw ConfigError("--gather", "", "give either --gather or --point/--array, not both");
  if (o.continuation && (task >= 0 || mode.gather))
    throw ConfigError("--continuation", "", "a continued point waits for its parent's steady state, which a job array's "
                                        "separate tasks do not share: run the sweep in one job (with mpirun for "
                                        "several nodes)");
  if (mode.gather) return cmd_sweep_gather(o, plan);
  const MpiWorld world;
  if (task >= 0 && world.size() > 1)
    throw ConfigError("--point", std::to_string(task), "a job array's task runs one point in one process, not on "
                                                       "several MPI ranks");
  if (task >= 0) try {
      return cmd_sweep_task(o, plan, task);
    } catch (const SweepInterrupted& e) {
      std::fprintf(stderr, "cvt-engine: sweep point %ld interrupted (%s): the same command continues it\n", task, e.what());
      return e.wall_limit ? kExitWallLimit : kExitInterrupted;
    }
  if (world.rank() == 0) {
    const std::optional<Checkpoint> ck = o.from.empty() ? std::nullopt : std::optional(read_checkpoint(o.from));
    for (long i = 0; i < static_cast<long>(plan.points.size()); ++i) {
      std::vector<std::string> ov = o.overrides;
      const auto own = plan.overrides(i);
      ov.insert(ov.end(), own.begin(), own.end());
      warn_outside_envelope(ck ? parse_config(ck->config_toml, ov, o.from) : load_config(o.config_path, ov),
                            "point " + std::to_string(i + 1) + " (" + plan.label(i) + "): ");
    }
    long continued = 0;
    for (long i = 0; i < static_cast<long>(plan.points.size()); ++i) continued += plan.parent(i) >= 0;
    std::printf("cvt-engine %s sweep: %s, %s over %s%s; each until steady%s\n", CVT_VERSION,
                o.from.empty() ? o.config_path.c_str() : ("from " + o.from).c_str(),
                count_of_points(plan.points.size()).c_str(), [&] {
                  std::string k;
                  for (const auto& x : plan.keys) k += (k.empty() ? "" : ", ") + x;
                  return k;
                }().c_str(),
                world.size() > 1 ? (", " + std::to_string(world.size()) + " MPI ranks").c_str() : "",
                o.continuation ? (", " + std::to_string(continued) + " continued from a neighbour's steady state").c_str()
                               : "");
    std::fflush(stdout);
  }
  long unsteady = 0;
  try {
    unsteady = world.size() > 1 ? run_sweep_mpi(o, plan, world) : run_sweep(o, plan);
  } catch (const SweepInterrupted& e) {
    std::fprintf(stderr, "cvt-engine: sweep interrupted (%s): the finished points are in %s.csv; the same command "
                 "continues\n", e.what(), o.out.c_str());
    return e.wall_limit ? kExitWallLimit : kExitInterrupted;
  }
  if (world.rank() == 0) {
    print_sweep_written(o.out, plan.points.size(), unsteady);
  }
  return kExitOk;
}

Command add_sweep_command(CLI::App& app) {
  struct Args {
    cvt::SweepOptions o;
    std::vector<std::string> axes;
    std::string points;
    ScheduleArgs sched;
    SweepMode mode;
  };
  auto a = std::make_shared<Args>();
  auto* sw = app.add_subcommand("sweep", "operating points, each run until steady, into OUT.csv and OUT.h5 (one row "
                                         "per point; with mpirun the points go out to the ranks)");
  sw->footer("Example: cvt-engine sweep configs/mini.toml --axis load.torque=5,10 --axis clamping.driving=1.1e4,1.2e4 "
             "--out sweep\n         mpirun -np 3 cvt-engine sweep ... (rank 0 hands out points and writes)");
  sw->add_option("CONFIG", a->o.config_path, "TOML configuration (the base of every point); omit with --from");
  sw->add_option("--axis", a->axes, "KEY=V1,V2,...: an axis of the full grid (repeatable; the first varies slowest)");
  sw->add_option("--points", a->points, "CSV file: a header of keys, then a row of values per point");
  sw->add_option("-o,--out", a->o.out, "OUT.csv and OUT.h5; a sweep started again with the same OUT skips the "
                                       "points OUT.csv holds")
      ->capture_default_str()->check(kPath);
  sw->add_flag("--keep-runs", a->o.keep_runs, "keep each point's run file, OUT.runs/point-NNNN.h5");
  sw->add_option("--from", a->o.from, "start every point from this checkpoint of a steady state of the same model "
                                      "(cvt-engine run CONFIG --until-steady -o base.h5 writes base.h5.ckpt); "
                                      "run.t_end then bounds each point's run beyond it");
  sw->add_flag("--continuation", a->o.continuation,
               "maps by continuation: a point that differs from others in load.torque only starts from the steady "
               "state of the nearest load among them (the middle load of each such group from rest), its load ramped "
               "over --warm-ramp (docs/studies.md, \"Maps by continuation\")");
  sw->add_option("--warm-ramp", a->o.warm_ramp, "with --from or --continuation: a changed load.torque ramps from the "
                                                "checkpoint's over this time [s] (default: the point's steady window, "
                                                "two periods of the drive line's torsion mode)")
      ->check(kNonNegative);
  sw->add_option("--set", a->o.overrides, "override a key for every point: section.key=value (repeatable)");
  sw->add_option("--point", a->mode.point, "run point I alone (0-based, the CSV's point column), its row into "
                                           "OUT.points/: a job array's task (docs/cli.md, \"On a cluster\")")
      ->check(CLI::NonNegativeNumber);
  sw->add_flag("--array", a->mode.array, "--point $SLURM_ARRAY_TASK_ID (sbatch --array=0-N)");
  sw->add_flag("--gather", a->mode.gather, "after the tasks: their rows from OUT.points/ into OUT.csv and OUT.h5");
  sw->add_option("--max-wall", a->mode.max_wall, "stop cleanly before this much wall time (run.max_wall); the same "
                                                 "command continues, the point in progress from its checkpoint");
  add_schedule_options(sw, a->sched);
  return {sw, [a] {
    a->o.schedule = a->sched.options();
    return cmd_sweep(a->o, a->axes, a->points, a->mode);
  }};
}

// cvt-engine study slip: the slip limit by bisection (engine/studies/slip.cpp).
Command add_slip_command(CLI::App& app) {
  struct Args {
    cvt::SlipStudyOptions o;
    ScheduleArgs sched;
  };
  auto a = std::make_shared<Args>();
  a->o.csv = "slip.csv";
  a->o.sweep.out = "slip";
  auto* sl = app.get_subcommand("study")->add_subcommand(
      "slip", "slip limit: for each clamping force (and ratio) the largest load torque held without gross slip, by "
              "bisection, beside 2 f0 min(F1, F2) R2 / cos(beta)");
  sl->footer("Example: cvt-engine study slip configs/reference-steady.toml --clamping 2.5e4,3.7e4 --out slip.csv "
             "--threads 2");
  sl->add_option("CONFIG", a->o.sweep.config_path, "TOML configuration")->required();
  sl->add_option("--clamping", a->o.clamping, "clamping.driving values F1 [N], comma-separated")
      ->delimiter(',')->required()->check(kPositive);
  sl->add_option("--thrust-ratio", a->o.thrust_ratio, "F1 / F2 of every point (default: the configuration's)")
      ->check(kPositive);
  sl->add_option("--ratios", a->o.ratios, "geometry.ratio values (default: the configuration's)")->delimiter(',');
  sl->add_option("--tol", a->o.tolerance, "bisection until (slips_at - slip_torque) / slip_torque <= TOL")
      ->check(CLI::Range(1e-4, 0.5))->capture_default_str();
  sl->add_option("-o,--out", a->o.csv, "CSV file")->capture_default_str()->check(kPath);
  sl->add_option("--set", a->o.sweep.overrides, "override a key: section.key=value (repeatable)");
  add_schedule_options(sl, a->sched);
  return {sl, [a] {
    a->o.sweep.schedule = a->sched.options();
    a->o.sweep.out = a->o.csv;
    std::printf("cvt-engine %s study slip: %s, F1 = ", CVT_VERSION, a->o.sweep.config_path.c_str());
    for (double f : a->o.clamping) std::printf("%s%g", f == a->o.clamping.front() ? "" : ", ", f);
    std::printf(" N; each load until steady, bisection to %g %%\n", 100 * a->o.tolerance);
    std::fflush(stdout);
    for (const auto& r : cvt::run_slip_study(a->o))
      std::printf("  F1 = %.4g N, F2 = %.4g N, ratio %.3g: holds %.4g N m, slips at %.4g N m; theory %.4g N m "
                  "(%.1f %%), %d runs, %.0f s%s%s\n",
                  r.clamping_driving, r.clamping_driven, r.ratio, r.slip_torque, r.slips_at, r.theory_torque,
                  100 * r.slip_torque / r.theory_torque, r.runs, r.wall_s, r.note.empty() ? "" : "; ", r.note.c_str());
    std::printf("wrote %s\n", a->o.csv.c_str());
    return cvt::kExitOk;
  }};
}

// cvt-engine study shift: the shift rate after a step in the thrust ratio
// (engine/studies/shift.cpp).
Command add_shift_command(CLI::App& app) {
  struct Args {
    cvt::ShiftStudyOptions o;
    ScheduleArgs sched;
  };
  auto a = std::make_shared<Args>();
  a->o.csv = "shift.csv";
  auto* sh = app.get_subcommand("study")->add_subcommand(
      "shift", "shift rate: from the steady state at each input speed, a step in the thrust ratio F1/F2; "
               "d(geometric ratio)/dt against ln(F1/F2)");
  sh->footer("Example: cvt-engine study shift configs/reference-steady.toml --thrust-ratios 1.0,1.1,1.233,1.4,1.6 "
             "--speeds 104.7,209.4 --out shift.csv --threads 2");
  sh->add_option("CONFIG", a->o.sweep.config_path, "TOML configuration")->required();
  sh->add_option("--thrust-ratios", a->o.thrust_ratios, "F1/F2 after the step (F2 kept), comma-separated")
      ->delimiter(',')->required()->check(kPositive);
  sh->add_option("--speeds", a->o.speeds, "drive.speed values [rad/s] (default: the configuration's)")
      ->delimiter(',')->check(kPositive);
  sh->add_option("--settle", a->o.settle, "after the step, left out of the fit [s]")->check(kNonNegative)
      ->capture_default_str();
  sh->add_option("--window", a->o.window, "the fit's window [s]")->check(kPositive)->capture_default_str();
  sh->add_option("--steady-bound", a->o.steady_bound, "t_end of the runs to the steady state [s]")
      ->check(kPositive)->capture_default_str();
  sh->add_option("-o,--out", a->o.csv, "CSV file")->capture_default_str()->check(kPath);
  sh->add_option("--set", a->o.sweep.overrides, "override a key: section.key=value (repeatable)");
  add_schedule_options(sh, a->sched);
  return {sh, [a] {
    a->o.sweep.schedule = a->sched.options();
    std::printf("cvt-engine %s study shift: %s; each speed until steady, then a step in F1/F2, the rate over %g s "
                "after %g s\n", CVT_VERSION, a->o.sweep.config_path.c_str(), a->o.window, a->o.settle);
    std::fflush(stdout);
    cvt::run_shift_study(a->o);
    std::printf("wrote %s\n", a->o.csv.c_str());
    return cvt::kExitOk;
  }};
}

// cvt-engine topology: NUMA nodes, cores and the pins per node.
Command add_topology_command(CLI::App& app) {
  struct Args {
  std::string topo_config;
  int topo_threads = 0;
  };
  auto a = std::make_shared<Args>();
  auto& topo_config = a->topo_config;
  auto& topo_threads = a->topo_threads;
  auto* topology = app.add_subcommand("topology", "NUMA nodes, cores, pins per node, thread and memory binding");
  topology->footer("Example: cvt-engine topology configs/reference.toml --threads 2");
  topology->add_option("CONFIG", topo_config, "TOML configuration (for the number of pins; default 84)");
  topology->add_option("--threads", topo_threads, "threads to lay out (default: all cores)");
  return {topology, [a] {
    return cmd_topology(a->topo_config, a->topo_threads);
  }};
}

// cvt-engine modes: natural frequencies and the Jacobian's spectrum at a state.
Command add_modes_command(CLI::App& app) {
  struct Args {
  std::string modes_config;
  std::vector<std::string> modes_overrides;
  ModesArgs modes_args;
  };
  auto a = std::make_shared<Args>();
  auto& modes_config = a->modes_config;
  auto& modes_overrides = a->modes_overrides;
  auto& modes_args = a->modes_args;
  auto* modes = app.add_subcommand("modes", "natural frequencies, Jacobian spectrum and stable RK4 step at a state");
  modes->footer("Example: cvt-engine modes configs/mini.toml --at 1e-3 --count 5");
  modes->add_option("CONFIG", modes_config, "TOML configuration")->required();
  modes->add_option("--at", modes_args.at, "linearize at model time T [s] (runs the model there first)")
      ->check(kNonNegative)
      ->capture_default_str();
  modes->add_option("--set", modes_overrides, "override a key: section.key=value (repeatable)");
  modes->add_option("--count", modes_args.count, "lowest and highest modes to list")
      ->check(CLI::Range(1, 1000000))
      ->capture_default_str();
  modes->add_option("--rigid-hz", modes_args.rigid_hz, "|f| below this counts as a rigid-body or mechanism mode [Hz]")
      ->check(kNonNegative)
      ->capture_default_str();
  modes->add_flag("--no-jacobian", modes_args.no_jacobian, "skip the first-order Jacobian's spectrum");
  modes->add_option("--json", modes_args.json, "also write the report as JSON to FILE");
  return {modes, [a] {
    return cmd_modes(a->modes_config, a->modes_overrides, a->modes_args);
  }};
}

}  // namespace

// SIGINT, SIGTERM or SIGHUP before a command takes them over (a run, a sweep: StopSignals)
// or in a command that does not: it says so and ends with 128 + the signal (async-signal-
// safe: write and _exit only). A run or sweep has written nothing then.
extern "C" void on_early_signal(int sig) {
  static const char msg[] = "cvt-engine: stopped by a signal before a run or sweep began (nothing of it written)\n";
  if (::write(2, msg, sizeof msg - 1) < 0) {
  }
  ::_exit(128 + sig);
}

// Installed before main, as the program's own static initialization begins; then the
// signals that the launcher (engine/cli/launcher.c) blocked while the shared libraries
// loaded are let through, and one that came meanwhile is answered here.
__attribute__((constructor)) void install_early_signals() {
  struct sigaction sa {};
  sa.sa_handler = on_early_signal;
  sigemptyset(&sa.sa_mask);
  sigset_t stops;
  sigemptyset(&stops);
  for (const int sig : {SIGINT, SIGTERM, SIGHUP}) sigaction(sig, &sa, nullptr), sigaddset(&stops, sig);
  sigprocmask(SIG_UNBLOCK, &stops, nullptr);
}

int main(int argc, char** argv) {
  // Every HDF5 file is closed by the code that opened it, in order; the library's own pass at
  // exit would close again a file whose close failed (a full disk) and crash in it.
  H5dont_atexit();
  CLI::App app{"cvt-engine: dynamics of a chain-type continuously variable transmission"};
  app.require_subcommand(1);
  app.set_version_flag("--version", std::string("cvt-engine ") + CVT_VERSION + " (commit " + CVT_COMMIT + ")");
  app.footer("Example: cvt-engine run configs/reference-steady.toml --scheduler flowgraph --threads 2\n"
             "Each subcommand has its own --help (cvt-engine run --help); docs/cli.md has them all.");
  const Command commands[] = {add_run_command(app),      add_graph_command(app),    add_scale_command(app),
                              add_study_command(app),    add_topology_command(app), add_modes_command(app),
                              add_sweep_command(app),    add_slip_command(app),
                              add_shift_command(app)};
  try {
    app.parse(argc, argv);
  } catch (const CLI::Success& e) {  // --help, --version
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    // Usage errors (unknown option, bad --scheduler, --threads 0 ...): EX_USAGE.
    app.exit(e);
    if (dynamic_cast<const CLI::ExtrasError*>(&e)) suggest_options(app, argc, argv);
    return cvt::kExitUsage;
  }
  try {
    for (const Command& c : commands)
      if (*c.app) return c.run();
  } catch (const cvt::ConfigError& e) {
    std::string text = e.what();  // one line per problem found
    for (std::size_t at = text.find('\n'); at != std::string::npos; at = text.find('\n', at + 1))
      text.insert(at + 1, "cvt-engine: ");
    std::fprintf(stderr, "cvt-engine: %s\n", text.c_str());
    return cvt::kExitConfig;
  } catch (const cvt::OutputError& e) {
    std::fprintf(stderr, "cvt-engine: %s\n", e.what());
    return cvt::kExitCantCreate;
  } catch (const cvt::BlowUpError& e) {
    std::fprintf(stderr, "cvt-engine: %s\n", e.what());
    return cvt::kExitBlowUp;
  } catch (const cvt::SweepInterrupted& e) {
    std::fprintf(stderr, "cvt-engine: interrupted: %s\n", e.what());
    return cvt::kExitInterrupted;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "cvt-engine: error: %s\n", e.what());
    return cvt::kExitFailure;
  }
  return cvt::kExitOk;
}
