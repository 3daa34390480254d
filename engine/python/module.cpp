// The Python module's extension, cvt_engine._core (docs/python.md): the configuration, a
// run, a sweep and the slip and shift studies, each the same library call the command line
// makes, so that the same inputs give the same bits. The package engine/python/cvt_engine
// wraps it (keyword arguments, the channels as NumPy arrays, the CSV rows as dicts).
// The GIL is released while the engine runs; callbacks take it back.
#include <pybind11/functional.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cmath>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "engine/guards.hpp"
#include "engine/model/config.hpp"
#include "engine/model/model.hpp"
#include "engine/run.hpp"
#include "engine/simulation.hpp"
#include "engine/studies/shift.hpp"
#include "engine/studies/slip.hpp"
#include "engine/studies/sweep.hpp"
#include "engine/summary.hpp"

namespace py = pybind11;
using namespace cvt;

namespace {

ScheduleOptions schedule(const std::string& scheduler, int threads, int grain) {
  if (threads < 1) throw ConfigError("threads", std::to_string(threads), "must be at least 1");
  if (grain < 1) throw ConfigError("grain", std::to_string(grain), "must be at least 1");
  ScheduleOptions o;
  try {
    o.kind = parse_scheduler(scheduler);
  } catch (const std::invalid_argument&) {
    throw ConfigError("scheduler", scheduler, "must be one of serial, flowgraph, paper-omp");
  }
  o.threads = threads;
  o.grain = grain;
  return o;
}

// A Python callable as a line logger (None: silent); the GIL is taken for each call, and
// an exception it raises is kept for the caller to raise once the engine has returned.
std::function<void(const std::string&)> line_log(const py::object& log, std::optional<py::error_already_set>& error) {
  if (log.is_none()) return [](const std::string&) {};
  return [&log, &error](const std::string& line) {
    py::gil_scoped_acquire gil;
    if (error) return;
    try {
      log(line);
    } catch (py::error_already_set& e) {
      error = std::move(e);
    }
  };
}

// f() with the GIL released and the study's progress lines (o.log) sent to `log`; raises
// what `log` raised once the engine has returned.
template <class F>
auto released(SweepOptions& o, const py::object& log, F&& f) {
  std::optional<py::error_already_set> error;
  o.log = line_log(log, error);
  std::optional<decltype(f())> result;
  {
    py::gil_scoped_release nogil;
    result.emplace(f());
  }
  if (error) throw *error;
  return std::move(*result);
}

// The run: the summary as JSON text (the same as --summary-json), to be parsed by the
// package, and the signal that stopped the run (0: none).
// With `resume` (a checkpoint's path) the run continues from it, appended to `out` when
// `append` (the run's own file) or into `out` as a new file.
std::pair<std::string, int> run(const Config& cfg, const std::string& out, const std::string& scheduler, int threads, int grain,
                bool quiet, const py::object& progress, double progress_seconds, long checkpoint_every,
                const std::string& resume, bool append) {
  if (!(progress_seconds >= 0)) throw ConfigError("progress_seconds", std::to_string(progress_seconds), "must be >= 0");
  const Model model = build_model(cfg);
  std::optional<Checkpoint> ck;
  if (!resume.empty()) ck = read_checkpoint(resume);
  RunOptions opt;
  opt.resume = ck ? &*ck : nullptr;
  opt.append = ck && append;
  opt.schedule = schedule(scheduler, threads, grain);
  opt.out_path = out;
  opt.progress = !quiet && progress.is_none();
  opt.progress_seconds = progress_seconds;
  opt.checkpoint_every = checkpoint_every;
  std::optional<py::error_already_set> error;
  if (quiet) opt.warn = [](const std::string&) {};  // kept in the summary's warnings all the same
  if (!progress.is_none()) {
    opt.on_progress = [&progress, &error](const RunProgress& p) {
      py::gil_scoped_acquire gil;
      if (error) return false;
      try {
        const py::object go = progress(py::dict(py::arg("step") = p.step, py::arg("steps") = p.steps,
                                                py::arg("t") = p.t, py::arg("t_end") = p.t_end,
                                                py::arg("wall_s") = p.wall_s, py::arg("eta_s") = p.eta_s,
                                                py::arg("verifying") = p.verifying));
        if (go.is_none()) return true;
        const int truth = PyObject_IsTrue(go.ptr());  // any object's truth, as `if go:` has it
        if (truth < 0) throw py::error_already_set();
        return truth == 1;
      } catch (py::error_already_set& e) {
        error = std::move(e);
        return false;
      }
    };
  }
  RunResult r;
  {
    py::gil_scoped_release nogil;
    r = run_simulation(model, opt);
  }
  if (error) throw *error;
  return {summary_json(r), r.signal};
}

SweepOptions sweep_options(const std::string& config_path, const std::string& from,
                           const std::vector<std::string>& overrides, const std::string& out,
                           const std::string& scheduler, int threads, int grain) {
  SweepOptions o;
  o.config_path = config_path;
  o.from = from;
  o.overrides = overrides;
  o.out = out;
  o.schedule = schedule(scheduler, threads, grain);
  return o;
}

long sweep(SweepOptions o, const std::vector<std::string>& axes, const std::string& points, bool keep_runs,
           double warm_ramp, bool continuation, const py::object& log) {
  o.keep_runs = keep_runs;
  o.warm_ramp = warm_ramp;
  o.continuation = continuation;
  const SweepPlan plan = sweep_plan(o, axes, points);
  return released(o, log, [&] { return run_sweep(o, plan); });
}

py::list slip_study(SlipStudyOptions o, const py::object& log) {
  py::list out;
  for (const SlipRow& r : released(o.sweep, log, [&] { return run_slip_study(o); }))
    out.append(py::dict(py::arg("clamping_driving") = r.clamping_driving, py::arg("clamping_driven") = r.clamping_driven,
                        py::arg("ratio") = r.ratio, py::arg("theory_torque") = r.theory_torque,
                        py::arg("slip_torque") = r.slip_torque, py::arg("slips_at") = r.slips_at,
                        py::arg("runs") = r.runs, py::arg("wall_s") = r.wall_s, py::arg("note") = r.note));
  return out;
}

py::list shift_study(ShiftStudyOptions o, const py::object& log) {
  py::list out;
  for (const ShiftRow& r : released(o.sweep, log, [&] { return run_shift_study(o); }))
    out.append(py::dict(py::arg("input_speed") = r.input_speed, py::arg("thrust_ratio") = r.thrust_ratio,
                        py::arg("ln_thrust_ratio") = r.ln_thrust_ratio,
                        py::arg("steady_thrust_ratio") = r.steady_thrust_ratio, py::arg("shift_rate") = r.shift_rate,
                        py::arg("ratio_start") = r.ratio_start, py::arg("ratio_end") = r.ratio_end,
                        py::arg("steady_status") = r.steady_status, py::arg("wall_s") = r.wall_s));
  return out;
}

// A simulation stepped from Python (cvt_engine.Simulation, docs/python.md "Stepping"): the
// model from rest, advanced to a time in the configured steps, its channels read, and its
// inputs changed between advances by rewriting their profiles from the current time on
// (docs/model.md 4.6.5). Without changes its trajectory is the run's, bit for bit.
class Stepper {
 public:
  Stepper(const Config& cfg, const std::string& scheduler, int threads, int grain)
      : model_(std::make_unique<Model>(build_model(cfg))),
        sim_(std::make_unique<Simulation>(*model_, schedule(scheduler, threads, grain))),
        h_(model_->cfg.integrator.step) {
    if (adaptive_steps(model_->cfg))
      throw ConfigError("integrator.tolerance", std::to_string(model_->cfg.integrator.tolerance),
                        "a stepped simulation takes fixed steps: leave integrator.tolerance at 0");
  }
  double time() const { return sim_->time(); }
  long steps() const { return sim_->steps(); }
  double step() const { return h_; }

  // Steps to t (to the step grid: t a multiple of the step within 1e-6 of it), the GIL
  // released; BlowUpError on a blow-up, as a run.
  void advance(double t) {
    const double k = std::round(t / h_);
    if (!std::isfinite(t) || std::abs(k * h_ - t) > 1e-6 * h_)
      throw ConfigError("t", std::to_string(t), "must be a multiple of the step " + std::to_string(h_) + " s");
    const long n = static_cast<long>(k);
    if (n < sim_->steps())
      throw ConfigError("t", std::to_string(t), "is before the simulation's time " + std::to_string(sim_->time()) + " s");
    py::gil_scoped_release nogil;
    const long every = std::max(1L, std::lround(model_->cfg.run.sample_interval / h_));
    for (long i = sim_->steps() + 1; i <= n; ++i) {
      sim_->step(h_);
      if (i % every == 0 || i == n) sim_->check_finite();
    }
  }

  py::dict channels() {
    const Sample s = sim_->sample(h_);
    return py::dict(py::arg("time") = s.t, py::arg("step") = s.step, py::arg("input_speed") = s.input_speed,
                    py::arg("output_speed") = s.output_speed, py::arg("load_speed") = s.load_speed,
                    py::arg("input_torque") = s.input_torque, py::arg("output_torque") = s.output_torque,
                    py::arg("load_torque") = s.load_torque, py::arg("speed_ratio") = s.speed_ratio,
                    py::arg("geometric_ratio") = s.geometric_ratio, py::arg("efficiency") = s.efficiency,
                    py::arg("clamping_force_driving") = s.clamp[0], py::arg("clamping_force_driven") = s.clamp[1],
                    py::arg("sheave_position") = std::vector<double>(s.sheave_position, s.sheave_position + 2),
                    py::arg("link_tension") = s.link_tension,
                    py::arg("strand_tension_upper") = s.strand_tension[0],
                    py::arg("strand_tension_lower") = s.strand_tension[1], py::arg("power_input") = s.power_input,
                    py::arg("power_output") = s.power_output, py::arg("work_input") = s.work_input,
                    py::arg("work_output") = s.work_output, py::arg("energy_residual") = s.energy_residual);
  }

  std::vector<double> state() const {
    const Eigen::VectorXd& y = sim_->state();
    return std::vector<double>(y.data(), y.data() + y.size());
  }

  // An input from now on: "drive_speed" [rad/s] and "load_torque" [N m] step to the value
  // at the current time; "clamping_driving" and "clamping_driven" [N] go linearly to it over
  // `over` seconds (> 0: a clamping force's rate enters the energy balance).
  void set_input(const std::string& name, double value, double over) {
    Config& c = model_->cfg;
    const double t = sim_->time();
    if (!std::isfinite(value)) throw ConfigError(name, std::to_string(value), "must be a finite number");
    if (name == "drive_speed") {
      if (!(value > 0)) throw ConfigError(name, std::to_string(value), "must be positive (> 0)");
      // The angle is the speed's integral: the past is kept, the new speed holds from t.
      Config::Profile& p = c.drive.speed_profile;
      const double now = drive_speed(c, t);
      if (p.empty()) p = {{0.0, c.drive.speed}};
      while (!p.empty() && p.back()[0] > t) p.pop_back();
      p.push_back({t, now});
      p.push_back({t, value});
    } else if (name == "load_torque") {
      if (!(value >= 0)) throw ConfigError(name, std::to_string(value), "must not be negative (>= 0)");
      c.load.torque_profile = {{t, ramped_load_torque(c, t)}, {t, value}};
    } else if (name == "clamping_driving" || name == "clamping_driven") {
      if (!(value > 0)) throw ConfigError(name, std::to_string(value), "must be positive (> 0)");
      if (!(over > 0)) throw ConfigError("over", std::to_string(over), "must be positive (> 0)");
      double F[2], Fd[2];
      clamping_schedule(*model_, t, F, Fd);
      const int k = name == "clamping_driving" ? 0 : 1;
      (k == 0 ? c.clamping.driving_profile : c.clamping.driven_profile) = {{t, F[k]}, {t + over, value}};
    } else {
      throw ConfigError("name", name, "must be one of drive_speed, load_torque, clamping_driving, clamping_driven");
    }
  }

 private:
  std::unique_ptr<Model> model_;  // owned: the inputs are changed in its configuration
  std::unique_ptr<Simulation> sim_;
  double h_;
};

py::dict model_info(const Config& cfg) {
  const Model m = build_model(cfg);
  return py::dict(py::arg("links") = m.links, py::arg("coordinates") = m.ndof, py::arg("unknowns") = m.nstate,
                  py::arg("running_radius_driving") = m.pulley[0].running_radius,
                  py::arg("running_radius_driven") = m.pulley[1].running_radius,
                  py::arg("closure_residual") = m.closure_residual);
}

void register_errors(py::module_& m) {
  // ConfigError carries the key, the value and the reason; the others their message.
  static py::exception<ConfigError> config_error(m, "ConfigError", PyExc_ValueError);
  static py::exception<BlowUpError> blow_up(m, "BlowUpError", PyExc_RuntimeError);
  static py::exception<OutputError> output_error(m, "OutputError", PyExc_OSError);
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const ConfigError& e) {
      py::object err = py::reinterpret_borrow<py::object>(config_error.ptr())(e.what());
      err.attr("key") = e.key();
      err.attr("value") = e.value();
      err.attr("reason") = e.reason();
      PyErr_SetObject(config_error.ptr(), err.ptr());
    } catch (const BlowUpError& e) {
      blow_up(e.what());
    } catch (const OutputError& e) {
      output_error(e.what());
    } catch (const SweepInterrupted& e) {
      PyErr_SetString(PyExc_KeyboardInterrupt, e.what());  // the finished points are in OUT.csv
    }
  });
}

}  // namespace

PYBIND11_MODULE(_core, m) {
  m.doc() = "cvt-engine's extension; use the package cvt_engine (docs/python.md)";
  m.attr("version") = CVT_VERSION;
  register_errors(m);
  py::class_<Config>(m, "Config", "a validated configuration (load_config, parse_config)")
      .def_property_readonly("toml", [](const Config& c) { return c.resolved_toml; },
                             "the resolved TOML: every key with its value");
  m.def("load_config", &load_config, py::arg("path"), py::arg("overrides"),
        py::arg("shortcuts") = std::map<std::string, std::string>{});
  m.def("parse_config", &parse_config, py::arg("text"), py::arg("overrides"), py::arg("origin"),
        py::arg("shortcuts") = std::map<std::string, std::string>{});
  m.def("model_info", &model_info, py::arg("config"));
  py::class_<Stepper>(m, "Stepper", "a simulation stepped from Python (use cvt_engine.Simulation)")
      .def(py::init<const Config&, const std::string&, int, int>(), py::arg("config"), py::arg("scheduler"),
           py::arg("threads"), py::arg("grain"))
      .def_property_readonly("time", &Stepper::time)
      .def_property_readonly("steps", &Stepper::steps)
      .def_property_readonly("step", &Stepper::step)
      .def("advance", &Stepper::advance, py::arg("t"))
      .def("channels", &Stepper::channels)
      .def("state", &Stepper::state)
      .def("set_input", &Stepper::set_input, py::arg("name"), py::arg("value"), py::arg("over"));
  m.def("run", &run, py::arg("config"), py::arg("out"), py::arg("scheduler"), py::arg("threads"), py::arg("grain"),
        py::arg("quiet"), py::arg("progress"), py::arg("progress_seconds"), py::arg("checkpoint_every"),
        py::arg("resume") = std::string(), py::arg("append") = false);
  // A checkpoint's configuration (its overrides applied) and the run's own file it names.
  m.def("checkpoint_config",
        [](const std::string& path, const std::vector<std::string>& overrides,
           const std::map<std::string, std::string>& shortcuts) {
          const Checkpoint ck = read_checkpoint(path);
          std::string own = ck.output;
          if (own.empty()) own = path.size() > 5 && path.ends_with(".ckpt") ? path.substr(0, path.size() - 5) : path;
          return std::make_pair(parse_config(ck.config_toml, overrides, path, shortcuts), own);
        },
        py::arg("path"), py::arg("overrides"), py::arg("shortcuts"));
  m.def("sweep",
        [](const std::string& config, const std::string& from, const std::vector<std::string>& overrides,
           const std::vector<std::string>& axes, const std::string& points, const std::string& out, bool keep_runs,
           double warm_ramp, bool continuation, const std::string& scheduler, int threads, int grain,
           const py::object& log) {
          return sweep(sweep_options(config, from, overrides, out, scheduler, threads, grain), axes, points,
                       keep_runs, warm_ramp, continuation, log);
        },
        py::arg("config"), py::arg("from_checkpoint"), py::arg("overrides"), py::arg("axes"), py::arg("points"),
        py::arg("out"), py::arg("keep_runs"), py::arg("warm_ramp"), py::arg("continuation"), py::arg("scheduler"),
        py::arg("threads"), py::arg("grain"), py::arg("log"));
  m.def("study_slip",
        [](const std::string& config, const std::vector<std::string>& overrides, const std::vector<double>& clamping,
           double thrust_ratio, const std::vector<std::string>& ratios, double tolerance, const std::string& csv,
           const std::string& scheduler, int threads, int grain, const py::object& log) {
          SlipStudyOptions o;
          o.sweep = sweep_options(config, "", overrides, csv, scheduler, threads, grain);
          o.clamping = clamping;
          o.thrust_ratio = thrust_ratio;
          o.ratios = ratios;
          o.tolerance = tolerance;
          o.csv = csv;
          return slip_study(o, log);
        },
        py::arg("config"), py::arg("overrides"), py::arg("clamping"), py::arg("thrust_ratio"), py::arg("ratios"),
        py::arg("tolerance"), py::arg("csv"), py::arg("scheduler"), py::arg("threads"), py::arg("grain"),
        py::arg("log"));
  m.def("study_shift",
        [](const std::string& config, const std::vector<std::string>& overrides,
           const std::vector<double>& thrust_ratios, const std::vector<double>& speeds, double settle, double window,
           double steady_bound, const std::string& csv, const std::string& scheduler, int threads, int grain,
           const py::object& log) {
          ShiftStudyOptions o;
          o.sweep = sweep_options(config, "", overrides, csv, scheduler, threads, grain);
          o.thrust_ratios = thrust_ratios;
          o.speeds = speeds;
          o.settle = settle;
          o.window = window;
          o.steady_bound = steady_bound;
          o.csv = csv;
          return shift_study(o, log);
        },
        py::arg("config"), py::arg("overrides"), py::arg("thrust_ratios"), py::arg("speeds"), py::arg("settle"),
        py::arg("window"), py::arg("steady_bound"), py::arg("csv"), py::arg("scheduler"), py::arg("threads"),
        py::arg("grain"), py::arg("log"));
}
