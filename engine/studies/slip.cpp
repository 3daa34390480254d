#include "engine/studies/slip.hpp"

#include <cmath>
#include <stdexcept>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include "engine/base/timing.hpp"
#include "engine/guards.hpp"
#include "engine/model/config.hpp"
#include "engine/model/model.hpp"

namespace cvt {

namespace {

struct SlipProbeFailed : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// One load torque at one clamping force and ratio, run until steady: held (no gross slip)
// or not. A blow-up that followed gross slip (the run names it: the chain thrown off the
// sheaves by a load the clamping does not hold) is a slip; any other blow-up or error says
// nothing about the slip limit and stops the row (SlipProbeFailed).
struct Probe {
  const SlipStudyOptions& o;
  double f1, f2;
  std::string ratio;
  SlipRow& row;
  bool holds(double torque) {
    SweepPlan p;
    p.keys = {"clamping.driving", "clamping.driven", "load.torque"};
    p.points = {{exact_number(f1), exact_number(f2), exact_number(torque)}};
    if (!ratio.empty()) p.keys.push_back("geometry.ratio"), p.points[0].push_back(ratio);
    const SweepRow r = run_sweep_point(o.sweep, p, 0);
    ++row.runs;
    const bool held = r.status == "steady" || r.status == "not_steady";
    char b[200];
    std::snprintf(b, sizeof b, "    F1 = %.4g N, load %.5g N m: %s (slip %+.2f %%, t = %.4g s, %.1f s)", f1, torque,
                  r.status.c_str(), 100 * r.slip, r.model_time, r.wall_s);
    sweep_log(o.sweep)(b);
    if (r.status == "blow_up" && r.reason.find("It followed gross slip") != std::string::npos) {
      row.note = "blow_up after gross slip at " + exact_number(torque) + " N m: a slip";
    } else if (r.status == "blow_up" || r.status == "error") {
      throw SlipProbeFailed(r.status + " at " + exact_number(torque) + " N m, not after gross slip: " + r.reason);
    }
    return held;
  }
};

}  // namespace

double slip_theory_torque(const std::string& config_path, const std::vector<std::string>& overrides) {
  const Model m = build_model(load_config(config_path, overrides));
  const Config& c = m.cfg;
  return 2 * c.friction.f0 * std::min(c.clamping.driving, c.clamping.driven) * m.pulley[1].running_radius /
         std::cos(c.sheave.cone_angle * M_PI / 180);
}

std::string slip_csv_header() {
  return "clamping_force_driving,clamping_force_driven,ratio,slip_torque,theory_torque,slip_over_theory,slips_at,runs,"
         "note,wall_s\n";
}

std::string slip_csv_row(const SlipRow& r) {
  return exact_number(r.clamping_driving) + "," + exact_number(r.clamping_driven) + "," + exact_number(r.ratio) + "," + exact_number(r.slip_torque) + "," +
         exact_number(r.theory_torque) + "," + exact_number(r.theory_torque > 0 ? r.slip_torque / r.theory_torque : 0) + "," +
         exact_number(r.slips_at) + "," + std::to_string(r.runs) + "," + r.note + "," + exact_number(r.wall_s) + "\n";
}

// For each ratio and clamping force: a bracket around the theory (widened until its lower
// end holds and its upper end slips), then bisection to the tolerance.
std::vector<SlipRow> run_slip_study(const SlipStudyOptions& o) {
  const Config base = load_config(o.sweep.config_path, o.sweep.overrides);
  const double thrust = o.thrust_ratio > 0 ? o.thrust_ratio : base.clamping.driving / base.clamping.driven;
  std::vector<std::string> ratios = o.ratios;
  if (ratios.empty()) ratios.push_back("");
  check_writable(o.csv, "CSV file", std::string(".lock").size());
  const FileLock lock(o.csv + ".lock", o.csv + " and its runs");  // one study per CSV at a time
  { std::ofstream(o.csv) << slip_csv_header(); }
  std::filesystem::create_directories(o.sweep.out + ".runs");
  std::vector<SlipRow> rows;
  for (const std::string& ratio : ratios)
    for (double f1 : o.clamping) {
      SlipRow row;
      const auto t0 = WallClock::now();
      row.clamping_driving = f1, row.clamping_driven = f1 / thrust;
      std::vector<std::string> ov = o.sweep.overrides;
      ov.push_back("clamping.driving=" + exact_number(f1));
      ov.push_back("clamping.driven=" + exact_number(row.clamping_driven));
      if (!ratio.empty()) ov.push_back("geometry.ratio=" + ratio);
      row.ratio = load_config(o.sweep.config_path, ov).geometry.ratio;
      row.theory_torque = slip_theory_torque(o.sweep.config_path, ov);
      Probe probe{o, f1, row.clamping_driven, ratio, row};
      double lo = 0.7 * row.theory_torque, hi = 1.3 * row.theory_torque;
      bool lo_holds = false, hi_slips = false;
      try {
        lo_holds = probe.holds(lo);
        for (int k = 0; k < 4 && !lo_holds; ++k) hi = lo, hi_slips = true, lo *= 0.6, lo_holds = probe.holds(lo);
        for (int k = 0; k < 4 && lo_holds && !hi_slips; ++k) {
          hi_slips = !probe.holds(hi);
          if (!hi_slips) lo = hi, hi *= 1.4;
        }
        if (!lo_holds || !hi_slips) {
          row.note = !lo_holds ? "slips at every load tried" : "holds every load tried";
          lo = lo_holds ? lo : 0, hi = lo_holds ? 0 : hi;
        }
        while (lo_holds && hi_slips && hi - lo > o.tolerance * lo) {
          const double mid = 0.5 * (lo + hi);
          (probe.holds(mid) ? lo : hi) = mid;
        }
      } catch (const SlipProbeFailed& e) {
        // The bracket so far (0 where an end is not known yet), and why it stopped.
        row.note = std::string("stopped: ") + e.what();
        for (char& ch : row.note)
          if (ch == ',' || ch == '\n' || ch == '"') ch = ';';  // one CSV cell
        lo = lo_holds ? lo : 0, hi = hi_slips ? hi : 0;
      }
      row.slip_torque = lo, row.slips_at = hi;
      row.wall_s = seconds_since(t0);
      std::ofstream(o.csv, std::ios::app) << slip_csv_row(row);
      rows.push_back(row);
    }
  std::error_code ec;
  std::filesystem::remove(o.sweep.out + ".runs", ec);
  {
    std::error_code ec;
    std::filesystem::remove(o.csv + ".lock", ec);
  }
  return rows;
}

}  // namespace cvt
