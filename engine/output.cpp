#include "engine/output.hpp"

#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <random>
#include <type_traits>
#include <variant>

#include "engine/io/json.hpp"
#include "engine/provenance.hpp"

namespace cvt {

void write_parameters(H5File& f, const Model& m, const std::string& run_id) {
  f.set_string_attribute("/parameters", "version", CVT_VERSION);
  f.set_string_attribute("/parameters", "config", m.cfg.resolved_toml);
  f.set_string_attribute("/parameters", "run_id", run_id);
  // The initial geometry as numbers, each a scalar dataset with its unit.
  const std::pair<const char*, double> geometry[] = {{"running_radius_driving", m.pulley[0].running_radius},
                                                     {"running_radius_driven", m.pulley[1].running_radius},
                                                     {"closure_residual", m.closure_residual}};
  for (const auto& [name, value] : geometry) {
    const std::string path = std::string("/parameters/geometry/") + name;
    if (!f.exists(path)) f.write_vector(path, {value});
    f.set_string_attribute(path, "unit", "m");
  }
  write_provenance(f);
  // The layout the 3D viewer draws (docs/output.md): shaft axes, sheave faces, links.
  Json layout = {{"links", m.links},
                 {"tracked_pin", m.cfg.run.tracked_pin},
                 {"cone_angle", json_number(m.cfg.sheave.cone_angle * M_PI / 180)},
                 {"hub_radius", json_number(m.cfg.sheave.hub_radius)},
                 {"outer_radius", json_number(m.cfg.sheave.outer_radius)},
                 {"pin_length", json_number(m.cfg.pin.length)},
                 {"plate_spread", json_number(m.cfg.chain.plate_spread)},
                 {"pitch", json_number(m.cfg.chain.pitch)},
                 {"pulleys", Json::array()}};
  for (const Pulley& p : m.pulley)
    layout["pulleys"].push_back({{"centre", {json_number(p.centre.x()), json_number(p.centre.y())}},
                                 {"face_z", {json_number(p.face_z[0]), json_number(p.face_z[1])}},
                                 {"moving_side", p.moving_side},
                                 {"running_radius", json_number(p.running_radius)}});
  f.set_string_attribute("/parameters", "layout", json_inline(layout));
}

void write_profile(H5File& f, const Profiler::Report& r) {
  std::vector<std::string> names;
  std::vector<double> calls, wall, us, pct, bmin, bavg, bmax, imb;
  for (const auto& row : r.rows) {
    names.push_back(row.name);
    calls.push_back(static_cast<double>(row.calls));
    wall.push_back(row.wall_s), us.push_back(row.us_per_step), pct.push_back(row.percent);
    bmin.push_back(row.busy_min_s), bavg.push_back(row.busy_avg_s), bmax.push_back(row.busy_max_s);
    imb.push_back(row.imbalance_percent);
  }
  f.set_strings_attribute("/profile", "rows", names);  // the rows' names, in the order of the columns
  f.write_vector("/profile/calls", calls);
  f.write_vector("/profile/wall_s", wall);
  f.write_vector("/profile/us_per_step", us);
  f.write_vector("/profile/percent", pct);
  f.write_vector("/profile/busy_min_s", bmin);
  f.write_vector("/profile/busy_avg_s", bavg);
  f.write_vector("/profile/busy_max_s", bmax);
  f.write_vector("/profile/imbalance_percent", imb);
  f.set_int_attribute("/profile", "steps", r.steps);
  f.set_double_attribute("/profile", "us_per_step", r.us_per_step);
  f.set_double_attribute("/profile", "model_s_per_hour", r.model_s_per_hour);
  f.set_int_attribute("/profile", "threads", r.threads);
  f.set_int_attribute("/profile", "numa_nodes", r.numa_nodes);
  f.set_double_attribute("/profile", "wall_s", r.wall_s);
  f.set_string_attribute("/profile", "scheduler", r.scheduler);
}

std::string new_run_id() {
  std::random_device rd;
  const std::uint64_t x = (static_cast<std::uint64_t>(rd()) << 32) ^ rd() ^
                          static_cast<std::uint64_t>(std::chrono::steady_clock::now().time_since_epoch().count());
  char b[20];
  std::snprintf(b, sizeof b, "%016llx", static_cast<unsigned long long>(x));
  return b;
}

// Strings that h5py reads as str, flags and counts as integers, the rest as doubles.
void write_summary(H5File& f, const RunSummary& s) {
  f.remove("/summary");
  f.set_string_attribute("/summary", "units", summary_units_json());
  const auto& fields = summary_fields();
  for (std::size_t i = 0; i < fields.size(); ++i) {
    const SummaryField& e = fields[i];
    const std::string name(e.name);
    // A verified mean's numerical error beside it (run.verify).
    if (e.verify.verified && i < s.numerical_error.size())
      f.set_double_attribute("/summary", name + "_numerical_error", s.numerical_error[i]);
    // And its statistical uncertainty (NaN: fewer than two spans).
    if (e.verify.verified && i < s.uncertainty.size())
      f.set_double_attribute("/summary", name + "_uncertainty", s.uncertainty[i]);
    std::visit(
        [&](auto m) {
          const auto& x = s.*m;
          using T = std::decay_t<decltype(x)>;
          if constexpr (std::is_same_v<T, double>) f.set_double_attribute("/summary", name, x);
          else if constexpr (std::is_same_v<T, long>) f.set_int_attribute("/summary", name, x);
          else if constexpr (std::is_same_v<T, bool>) f.set_int_attribute("/summary", name, x ? 1 : 0);
          else if constexpr (std::is_same_v<T, std::string>) f.set_string_attribute("/summary", name, x);
          else f.set_strings_attribute("/summary", name, x);
        },
        e.member);
  }
}

FileHistory continue_file(H5File& f, const Model& m, const Checkpoint& ck, long every_sample, long every_snapshot) {
  const Config& c = m.cfg;
  const double h = c.integrator.step;
  std::string path = f.path();  // the run's file, moved to FILE.partial while it is continued
  if (path.size() > 8 && path.compare(path.size() - 8, 8, ".partial") == 0) path.resize(path.size() - 8);
  const auto refuse = [&](const std::string& why) {
    throw std::runtime_error("cannot continue " + path + " from the checkpoint: " + why +
                             "; give --out NEW to write the continuation to a new file");
  };
  std::string id;
  try {
    id = f.read_string_attribute("/parameters", "run_id");
  } catch (const H5Error&) {
    refuse("the file has no run id (it was not written by this run)");
  }
  if (id != ck.run_id) refuse("it belongs to another run (run id " + id + ", the checkpoint's " + ck.run_id + ")");
  const auto on_grid = [&](double t, long every) {
    const double k = std::round(t / h);
    return std::abs(k * h - t) <= 1e-6 * h && static_cast<long>(k) % every == 0;
  };
  const auto kept = [&](const std::vector<double>& t, long every) {
    hsize_t n = 0;
    // Rows past a write that failed (a full disk) may read as zeros: the kept rows rise.
    while (n < t.size() && t[n] <= ck.t + 1e-6 * h && (n == 0 || t[n] > t[n - 1])) ++n;
    if (n > 0 && !on_grid(t[n - 1], every) && n > 1) --n;  // an off-grid last sample (an interrupt, t_end)
    return n;
  };
  if (!f.exists("/observables/input_speed/step"))
    refuse("it has no step datasets (an older cvt-engine wrote it): give --out NEW to write the continuation to a "
           "new file");
  if (!f.exists("/observables/strand_tension_upper/value"))
    refuse("it has no strand tension channels (an older cvt-engine wrote it): give --out NEW to write the "
           "continuation to a new file");
  FileHistory hist;
  const std::vector<double> t = f.read_doubles("/observables/input_speed/time");
  hist.samples = kept(t, every_sample);
  const long last_grid = (ck.steps / every_sample) * every_sample;
  if (hist.samples == 0 || std::abs(t[hist.samples - 1] - static_cast<double>(last_grid) * h) > 1e-6 * h) {
    char b[256];
    std::snprintf(b, sizeof b, "its samples end at t = %.9g s, before the checkpoint's last sample at t = %.9g s",
                  hist.samples ? t[hist.samples - 1] : 0.0, static_cast<double>(last_grid) * h);
    refuse(b);
  }
  if (every_snapshot && f.exists("/particles/chain/position/time"))
    hist.snapshots = kept(f.read_doubles("/particles/chain/position/time"), every_snapshot);
  const auto read = [&](const char* name) {
    std::vector<double> v = f.read_doubles(std::string("/observables/") + name + "/value");
    if (v.size() < hist.samples) refuse(std::string("its channel ") + name + " is shorter than its time");
    return v;
  };
  SummaryChannels& ch = hist.channels;
  const std::size_t n = hist.samples;
  ch.t.assign(t.begin(), t.begin() + static_cast<long>(n));
  for (auto [name, to] : std::initializer_list<std::pair<const char*, std::vector<double>*>>{
           {"input_speed", &ch.input_speed},
           {"output_speed", &ch.output_speed},
           {"input_torque", &ch.input_torque},
           {"output_torque", &ch.output_torque},
           {"load_torque", &ch.load_torque},
           {"speed_ratio", &ch.speed_ratio},
           {"geometric_ratio", &ch.geometric_ratio},
           {"clamping_force_driving", &ch.clamp_driving},
           {"clamping_force_driven", &ch.clamp_driven},
           {"strand_tension_upper", &ch.strand_upper},
           {"strand_tension_lower", &ch.strand_lower},
           {"work_input", &ch.work_input},
           {"work_output", &ch.work_output},
           {"work_dissipated", &ch.work_dissipated},
           {"work_clamping", &ch.work_clamping}}) {
    const std::vector<double> v = read(name);
    to->assign(v.begin(), v.begin() + static_cast<long>(n));
  }
  const std::vector<double> sheave = read("sheave_position");
  for (std::size_t i = 0; i < n; ++i) ch.sheave_driving.push_back(sheave[2 * i]), ch.sheave_driven.push_back(sheave[2 * i + 1]);
  for (std::size_t i = 0; i < n; ++i)
    if (ch.t[i] >= ck.t - c.run.efficiency_window - 1e-6 * h) {
      Sample s;
      s.t = ch.t[i], s.work_input = ch.work_input[i], s.work_output = ch.work_output[i];
      hist.tail.push_back(s);
    }
  return hist;
}

}  // namespace cvt
