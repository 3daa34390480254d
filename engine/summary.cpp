#include "engine/summary.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "engine/io/json.hpp"
#include "engine/run.hpp"
#include "engine/simulation.hpp"

namespace cvt {

void SummaryChannels::push(const Sample& s) {
  t.push_back(s.t);
  input_speed.push_back(s.input_speed);
  output_speed.push_back(s.output_speed);
  input_torque.push_back(s.input_torque);
  output_torque.push_back(s.output_torque);
  load_torque.push_back(s.load_torque);
  speed_ratio.push_back(s.speed_ratio);
  geometric_ratio.push_back(s.geometric_ratio);
  clamp_driving.push_back(s.clamp[0]);
  clamp_driven.push_back(s.clamp[1]);
  sheave_driving.push_back(s.sheave_position[0]);
  sheave_driven.push_back(s.sheave_position[1]);
  work_input.push_back(s.work_input);
  work_output.push_back(s.work_output);
  work_dissipated.push_back(s.work_dissipated);
}

namespace {

double mean(const std::vector<double>& v, std::size_t a, std::size_t b) {
  double s = 0;
  for (std::size_t i = a; i < b; ++i) s += v[i];
  return b > a ? s / static_cast<double>(b - a) : 0.0;
}

// The mean of the defined entries (> 0 and finite): the geometric ratio is 0 while no pin
// touches a sheave (the start from rest).
double mean_defined(const std::vector<double>& v, std::size_t a, std::size_t b) {
  double s = 0;
  std::size_t k = 0;
  for (std::size_t i = a; i < b; ++i)
    if (v[i] > 0 && std::isfinite(v[i])) s += v[i], ++k;
  return k ? s / static_cast<double>(k) : 0.0;
}

std::string fmt(const char* f, double a, double b = 0, double c = 0, double d = 0) {
  char buf[512];
  std::snprintf(buf, sizeof buf, f, a, b, c, d);
  return buf;
}

}  // namespace

void summarize(const Model& m, const SummaryChannels& ch, RunSummary& s, const SteadyCriteria& c) {
  const Config& cfg = m.cfg;
  s.drive_speed = cfg.drive.speed;
  s.load_torque_nominal = cfg.load.torque;
  s.clamp_driving_nominal = cfg.clamping.driving;
  s.clamp_driven_nominal = cfg.clamping.driven;
  s.ratio_target = cfg.geometry.ratio;
  s.method = to_string(cfg.integrator.method);
  s.step = cfg.integrator.step;
  s.controller = cfg.controller.enabled ? fmt("PI on F1, target speed ratio %.4g", cfg.controller.target_ratio) : "off";
  s.reasons.clear();
  const std::size_t n = ch.size();
  if (n == 0) return;
  // The window: the last window_fraction of the run, not before the ramp has ended.
  const double t0 = ch.t.front(), t1 = ch.t.back();
  const double ramp_end = cfg.ramp.time;
  double w0 = t1 - c.window_fraction * (t1 - t0);
  const bool ramping = w0 < ramp_end;
  if (ramping && ramp_end < t1) w0 = std::max(w0, ramp_end);
  std::size_t a = static_cast<std::size_t>(std::lower_bound(ch.t.begin(), ch.t.end(), w0) - ch.t.begin());
  if (a + 2 > n) a = n >= 2 ? n - 2 : 0;
  const std::size_t b = n, mid = (a + b) / 2;
  s.window_start = ch.t[a], s.window_end = t1;
  s.speed_ratio = mean(ch.speed_ratio, a, b);
  s.geometric_ratio = mean_defined(ch.geometric_ratio, a, b);
  s.slip = s.speed_ratio != 0 && s.geometric_ratio > 0 ? 1.0 - s.geometric_ratio / s.speed_ratio : 0.0;
  s.input_speed = mean(ch.input_speed, a, b);
  s.output_speed = mean(ch.output_speed, a, b);
  s.input_torque = mean(ch.input_torque, a, b);
  s.output_torque = mean(ch.output_torque, a, b);
  s.load_torque = mean(ch.load_torque, a, b);
  s.clamp_driving = mean(ch.clamp_driving, a, b);
  s.clamp_driven = mean(ch.clamp_driven, a, b);
  s.sheave_driving = mean(ch.sheave_driving, a, b);
  s.sheave_driven = mean(ch.sheave_driven, a, b);
  double pin = 0, pout = 0;
  for (std::size_t i = a; i < b; ++i)
    pin += ch.input_torque[i] * ch.input_speed[i], pout += ch.output_torque[i] * ch.output_speed[i];
  s.efficiency = pin != 0 ? pout / pin : 0.0;
  // 1 - D / W_in over the window: unlike the ratio of mean powers it does not see energy
  // swinging in and out of the torsion springs and inertias.
  const double win = ch.work_input[b - 1] - ch.work_input[a];
  s.loss_efficiency = win > 0 ? 1.0 - (ch.work_dissipated[b - 1] - ch.work_dissipated[a]) / win : 0.0;

  // Verdicts. Torques are judged against the load (or the output torque without a load).
  const double torque_scale = std::max({std::abs(s.load_torque), std::abs(s.output_torque), 1e-6});
  std::vector<std::string> slip, unsteady;
  if (ramping)
    unsteady.push_back(fmt("load ramp: the loads and clamping forces ramp up until t = %.4g s, and the run "
                           "ends at %.4g s",
                           ramp_end, t1));
  if (std::abs(s.slip) > c.gross_slip)
    slip.push_back(fmt("gross slip: speed ratio %.4f against geometric ratio %.4f (slip %.1f %%)", s.speed_ratio,
                       s.geometric_ratio, 100 * s.slip));
  // The slow swing of the output torque: a moving average over one meshing period (the time
  // a link takes to pass, pitch / (omega_in R1)) removes the polygon ripple and leaves the
  // torsion modes of shafts and load.
  const double dt = (t1 - t0) / static_cast<double>(std::max<std::size_t>(1, n - 1));
  const double v_chain = std::abs(s.input_speed) * m.pulley[0].running_radius;
  const double t_mesh = v_chain > 0 ? cfg.chain.pitch / v_chain : 0;
  const std::size_t k = t_mesh > 0 && dt > 0 ? std::max<std::size_t>(1, std::lround(t_mesh / dt)) : 1;
  // A window shorter than two meshing periods says nothing about drift, shift or ringing.
  const bool short_window = b - a < 2 * k;
  if (short_window)
    unsteady.push_back(fmt("window too short: %.3g s holds fewer than two meshing periods (%.3g s)",
                           s.window_end - s.window_start, t_mesh));
  const double w_a = mean(ch.output_speed, a, mid), w_b = mean(ch.output_speed, mid, b);
  if (!short_window && s.output_speed != 0 && (w_b - w_a) / std::abs(s.output_speed) < -c.falling)
    slip.push_back(fmt("output speed falling: %.2f -> %.2f rad/s across the window", w_a, w_b));
  // Drift of the means between the window's two halves.
  const auto drift = [&](const char* name, const char* unit, const std::vector<double>& v, double scale) {
    const double x = mean(v, a, mid), y = mean(v, mid, b);
    if (std::abs(y - x) > c.drift * scale) {
      char buf[256];
      std::snprintf(buf, sizeof buf, "drift of the means: %s %.4g -> %.4g%s%s over the window's halves (limit %.2g %%)",
                    name, x, y, *unit ? " " : "", unit, 100 * c.drift);
      unsteady.push_back(buf);
    }
  };
  if (!short_window) drift("output torque", "N m", ch.output_torque, torque_scale);
  if (!short_window) drift("input torque", "N m", ch.input_torque, torque_scale);
  if (!short_window) drift("speed ratio", "", ch.speed_ratio, std::abs(s.speed_ratio));
  // A shift: the geometric ratio moving (the clamping forces do not hold this ratio at this
  // load), reported as a rate.
  {
    const double x = mean_defined(ch.geometric_ratio, a, mid), y = mean_defined(ch.geometric_ratio, mid, b);
    const double dt_halves = 0.5 * (s.window_end - s.window_start);
    if (!short_window && x > 0 && y > 0 && dt_halves > 0 && std::abs(y - x) / std::abs(s.geometric_ratio) / dt_halves > c.shift)
      unsteady.push_back(fmt("shifting: the geometric ratio moves %.5f -> %.5f over the window's halves (%+.2g %% per "
                             "10 ms; limit %.2g): the clamping forces do not hold this ratio at this load",
                             x, y, 100 * (y - x) / s.geometric_ratio / dt_halves * 0.01, c.shift));
  }
  if (!short_window) {
    double lo = 1e300, hi = -1e300, run = 0;
    for (std::size_t i = a; i < b; ++i) {
      run += ch.output_torque[i];
      if (i >= a + k) run -= ch.output_torque[i - k];
      if (i + 1 >= a + k) lo = std::min(lo, run / k), hi = std::max(hi, run / k);
    }
    const double swing = 0.5 * (hi - lo);
    if (swing > c.ringing * torque_scale)
      unsteady.push_back(fmt("torsion mode still ringing: the output torque swings +-%.3g N m (%.1f %% of the "
                             "load) with the meshing ripple removed",
                             swing, 100 * swing / torque_scale));
  }
  if (!short_window && std::abs(s.load_torque) > 0 &&
      std::abs(s.output_torque - s.load_torque) > c.balance * torque_scale)
    unsteady.push_back(fmt("torque balance: mean output torque %.4g N m against the load's %.4g N m (%.1f %%)",
                           s.output_torque, s.load_torque, 100 * (s.output_torque / s.load_torque - 1)));
  s.status = !slip.empty() ? "slip" : unsteady.empty() ? "steady" : "not_steady";
  s.reasons = slip;
  s.reasons.insert(s.reasons.end(), unsteady.begin(), unsteady.end());
  s.efficiency_meaningful = s.status == "steady" && s.efficiency >= 0 && s.efficiency <= 1;
}

std::string format_summary(const RunSummary& s) {
  std::ostringstream os;
  char b[512];
  const auto line = [&](const char* f, auto... x) {
    std::snprintf(b, sizeof b, f, x...);
    os << b;
  };
  line("  operating point: input speed %.4g rad/s, load %.4g N m, clamping %.4g / %.4g kN, ratio %.4g;\n",
       s.drive_speed, s.load_torque_nominal, 1e-3 * s.clamp_driving_nominal, 1e-3 * s.clamp_driven_nominal,
       s.ratio_target);
  line("                   %s, step %.4g s, controller %s\n", s.method.c_str(), s.step, s.controller.c_str());
  line("  status: %s\n", s.status == "not_steady" ? "not yet steady" : s.status.c_str());
  for (const auto& r : s.reasons) line("    - %s\n", r.c_str());
  line("  means over t = %.5g .. %.5g s:\n", s.window_start, s.window_end);
  line("    speed ratio              %.5f   (geometric ratio %.5f, slip %+.2f %%)\n", s.speed_ratio, s.geometric_ratio,
       100 * s.slip);
  line("    input / output speed     %.3f / %.3f rad/s\n", s.input_speed, s.output_speed);
  line("    input / output torque    %.3f / %.3f N m   (load %.3f N m)\n", s.input_torque, s.output_torque,
       s.load_torque);
  line("    clamping forces          %.4g / %.4g kN   (sheaves at %.4f / %.4f mm)\n", 1e-3 * s.clamp_driving,
       1e-3 * s.clamp_driven, 1e3 * s.sheave_driving, 1e3 * s.sheave_driven);
  const bool outside = !(s.efficiency >= 0 && s.efficiency <= 1);
  if (s.efficiency_meaningful && !outside)
    line("    efficiency               %.4f   (mean output / input power; 1 - dissipated/input work %.4f)\n",
         s.efficiency, s.loss_efficiency);
  else
    line("    efficiency               not meaningful (%s: the power ratio is %.4g%s; 1 - dissipated/input work "
         "%.4f)\n",
         s.status == "steady" ? "outside [0, 1]" : "the run is not steady", s.efficiency,
         outside ? ", outside [0, 1]" : "", s.loss_efficiency);
  line("  energy balance residual    %.4g J (%.3g %% of the energy turned over, %.4g J)\n", s.energy_residual,
       100 * s.residual_fraction, s.energy_turnover);
  for (const auto& w : s.warnings) line("  warning: %s\n", w.c_str());
  return os.str();
}

std::string summary_json(const RunSummary& s) {
  std::ostringstream os;
  os.precision(17);
  const auto str = [&](const char* k, const std::string& v) { os << "  \"" << k << "\": \"" << json_escape(v) << "\",\n"; };
  const auto num = [&](const char* k, double v) {
    os << "  \"" << k << "\": ";
    if (std::isfinite(v)) os << v;
    else os << "null";
    os << ",\n";
  };
  const auto list = [&](const char* k, const std::vector<std::string>& v) {
    os << "  \"" << k << "\": [";
    for (std::size_t i = 0; i < v.size(); ++i) os << (i ? ", " : "") << "\"" << json_escape(v[i]) << "\"";
    os << "],\n";
  };
  os << "{\n";
  str("status", s.status);
  list("reasons", s.reasons);
  list("warnings", s.warnings);
  os << "  \"efficiency_meaningful\": " << (s.efficiency_meaningful ? "true" : "false") << ",\n";
  os << "  \"interrupted\": " << (s.interrupted ? "true" : "false") << ",\n";
  str("method", s.method);
  str("controller", s.controller);
  num("step", s.step);
  num("drive_speed", s.drive_speed);
  num("load_torque_nominal", s.load_torque_nominal);
  num("clamping_force_driving_nominal", s.clamp_driving_nominal);
  num("clamping_force_driven_nominal", s.clamp_driven_nominal);
  num("ratio_target", s.ratio_target);
  num("window_start", s.window_start);
  num("window_end", s.window_end);
  num("speed_ratio", s.speed_ratio);
  num("geometric_ratio", s.geometric_ratio);
  num("slip", s.slip);
  num("input_speed", s.input_speed);
  num("output_speed", s.output_speed);
  num("input_torque", s.input_torque);
  num("output_torque", s.output_torque);
  num("load_torque", s.load_torque);
  num("clamping_force_driving", s.clamp_driving);
  num("clamping_force_driven", s.clamp_driven);
  num("sheave_position_driving", s.sheave_driving);
  num("sheave_position_driven", s.sheave_driven);
  num("efficiency", s.efficiency);
  num("loss_efficiency", s.loss_efficiency);
  num("energy_residual", s.energy_residual);
  num("energy_turnover", s.energy_turnover);
  num("residual_fraction", s.residual_fraction);
  num("t_start", s.t_start);
  num("model_time", s.model_time);
  num("steps", static_cast<double>(s.steps));
  num("wall_s", s.wall_s);
  num("us_per_step", s.us_per_step);
  os << "  \"model_s_per_hour\": " << (std::isfinite(s.model_s_per_hour) ? s.model_s_per_hour : 0.0) << "\n}\n";
  return os.str();
}

}  // namespace cvt
