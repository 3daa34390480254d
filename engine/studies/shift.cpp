#include "engine/studies/shift.hpp"

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include "engine/base/timing.hpp"
#include "engine/guards.hpp"
#include "engine/io/checkpoint.hpp"
#include "engine/io/h5_writer.hpp"
#include "engine/model/config.hpp"
#include "engine/run.hpp"

namespace cvt {

namespace {

RunOptions quiet_run(const SweepOptions& s, const std::string& out) {
  RunOptions r;
  r.out_path = out;
  r.progress = false;
  r.schedule = s.schedule;
  r.checkpoint_every = 0;
  r.warn = [](const std::string&) {};
  return r;
}

// The steady state at one input speed: its file's checkpoint and summary.
RunResult steady_state(const ShiftStudyOptions& o, double speed, const std::string& out) {
  std::vector<std::string> ov = o.sweep.overrides;
  if (speed > 0) ov.push_back("drive.speed=" + exact_number(speed));
  ov.push_back("run.until_steady=true");
  ov.push_back("run.t_end=" + exact_number(o.steady_bound));
  return run_simulation(build_model(load_config(o.sweep.config_path, ov)), quiet_run(o.sweep, out));
}

// From the steady state's checkpoint: F1 = thrust ratio x F2 from there on, for settle +
// window; the geometric ratio's slope over the window.
ShiftRow step(const ShiftStudyOptions& o, const Checkpoint& ck, const RunResult& base, double thrust,
              const std::string& out) {
  ShiftRow r;
  const auto t0 = WallClock::now();
  const Config c0 = parse_config(ck.config_toml, {}, "checkpoint");
  r.input_speed = c0.drive.speed;
  r.thrust_ratio = thrust, r.ln_thrust_ratio = std::log(thrust);
  r.steady_thrust_ratio = c0.clamping.driving / c0.clamping.driven;
  r.steady_status = base.status;
  const double t_end = ck.t + o.settle + o.window;
  const Config c = parse_config(ck.config_toml,
                                {"clamping.driving=" + exact_number(thrust * c0.clamping.driven), "run.until_steady=false",
                                 "run.t_end=" + exact_number(t_end)},
                                "checkpoint");
  RunOptions ro = quiet_run(o.sweep, out);
  ro.resume = &ck;
  run_simulation(build_model(c), ro);
  H5File f = H5File::open(out);
  const std::vector<double> t = f.read_doubles("/observables/geometric_ratio/time"),
                            g = f.read_doubles("/observables/geometric_ratio/value");
  f.close();
  r.shift_rate = fitted_slope(t, g, ck.t + o.settle, t_end);
  r.ratio_start = base.geometric_ratio;
  r.ratio_end = g.empty() ? 0 : g.back();
  r.wall_s = seconds_since(t0);
  return r;
}

}  // namespace

double fitted_slope(const std::vector<double>& t, const std::vector<double>& y, double t0, double t1) {
  double st = 0, sy = 0, stt = 0, sty = 0;
  long n = 0;
  for (std::size_t i = 0; i < t.size() && i < y.size(); ++i)
    if (t[i] >= t0 - 1e-12 && t[i] <= t1 + 1e-12 && y[i] > 0)
      st += t[i], sy += y[i], stt += t[i] * t[i], sty += t[i] * y[i], ++n;
  const double d = n * stt - st * st;
  return n >= 2 && d > 0 ? (n * sty - st * sy) / d : 0.0;
}

std::string shift_csv_header() {
  return "input_speed,thrust_ratio,ln_thrust_ratio,shift_rate,steady_thrust_ratio,ratio_start,ratio_end,steady_status,"
         "wall_s\n";
}

std::string shift_csv_row(const ShiftRow& r) {
  return exact_number(r.input_speed) + "," + exact_number(r.thrust_ratio) + "," + exact_number(r.ln_thrust_ratio) + "," + exact_number(r.shift_rate) + "," +
         exact_number(r.steady_thrust_ratio) + "," + exact_number(r.ratio_start) + "," + exact_number(r.ratio_end) + "," + r.steady_status + "," +
         exact_number(r.wall_s) + "\n";
}

std::vector<ShiftRow> run_shift_study(const ShiftStudyOptions& o) {
  const auto log = sweep_log(o.sweep);
  check_writable(o.csv, "CSV file", std::string(".lock").size());
  const FileLock lock(o.csv + ".lock", o.csv + " and its runs");  // one study per CSV at a time
  { std::ofstream(o.csv) << shift_csv_header(); }
  const std::string dir = o.csv + ".runs";
  std::filesystem::create_directories(dir);
  std::vector<double> speeds = o.speeds;
  if (speeds.empty()) speeds.push_back(0);
  std::vector<ShiftRow> rows;
  for (double w : speeds) {
    const auto t0 = WallClock::now();
    const std::string base_file = dir + "/steady-" + exact_number(w) + ".h5";
    const RunResult base = steady_state(o, w, base_file);
    char b[256];
    std::snprintf(b, sizeof b, "  input speed %.5g rad/s: %s at t = %.4g s, geometric ratio %.5f (%.1f s)",
                  base.drive_speed, base.status.c_str(), base.model_time, base.geometric_ratio, seconds_since(t0));
    log(b);
    const Checkpoint ck = read_checkpoint(base_file + ".ckpt");
    for (double thrust : o.thrust_ratios) {
      const ShiftRow r = step(o, ck, base, thrust, dir + "/step.h5");
      std::snprintf(b, sizeof b, "    F1/F2 %.4g (ln %+.3f): d(ratio)/dt = %+.4g 1/s, ratio %.5f -> %.5f (%.1f s)",
                    r.thrust_ratio, r.ln_thrust_ratio, r.shift_rate, r.ratio_start, r.ratio_end, r.wall_s);
      log(b);
      std::ofstream(o.csv, std::ios::app) << shift_csv_row(r);
      rows.push_back(r);
    }
  }
  std::filesystem::remove_all(dir);
  {
    std::error_code ec;
    std::filesystem::remove(o.csv + ".lock", ec);
  }
  return rows;
}

}  // namespace cvt
