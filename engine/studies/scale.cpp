#include "engine/base/timing.hpp"
#include "engine/studies/scale.hpp"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <memory>
#include <sstream>

#include "engine/io/json.hpp"
#include "engine/simulation.hpp"
#include "numa/topology.hpp"

namespace cvt {

namespace {

// Sets HWLOC_SYNTHETIC for the lifetime of the object (the topology is read when a
// flow-graph schedule is built).
class LayoutScope {
 public:
  explicit LayoutScope(const std::string& layout) {
    if (const char* old = std::getenv("HWLOC_SYNTHETIC")) had_ = true, old_ = old;
    if (layout == "native") unsetenv("HWLOC_SYNTHETIC");
    else setenv("HWLOC_SYNTHETIC", layout.c_str(), 1);
  }
  ~LayoutScope() {
    if (had_) setenv("HWLOC_SYNTHETIC", old_.c_str(), 1);
    else unsetenv("HWLOC_SYNTHETIC");
  }

 private:
  bool had_ = false;
  std::string old_;
};

struct Combo {
  ScaleRow row;
  std::unique_ptr<Simulation> sim;
  std::vector<double> us, chain, pulley, zero_gather, compute;
};

double row_busy_max(const Profiler::Report& r, const char* name) {
  for (const auto& row : r.rows)
    if (row.name == name) return row.busy_max_s;
  return 0;
}

}  // namespace

double fit_amdahl(const std::vector<int>& threads, const std::vector<double>& speedup) {
  double num = 0, den = 0;
  for (std::size_t i = 0; i < threads.size(); ++i) {
    const double p = threads[i];
    if (p <= 1 || speedup[i] <= 0) continue;
    const double x = 1.0 - 1.0 / p;
    num += (1.0 / speedup[i] - 1.0 / p) * x;
    den += x * x;
  }
  return den > 0 ? std::clamp(num / den, 0.0, 1.0) : 0.0;
}

std::vector<ScaleRow> run_scaling_study(const Model& m, const ScaleOptions& o,
                                        const std::function<void(const std::string&)>& progress) {
  if (o.steps < 1 || o.repeat < 1) throw std::invalid_argument("--steps and --repeat must be >= 1");
  const double h = m.cfg.integrator.step;
  // Bad layouts are refused before anything runs.
  for (const std::string& l : o.layouts)
    if (l != "native") {
      LayoutScope scope(l);
      (void)numa::discover_topology();
    }
  // The running state every combination starts from.
  Simulation warm(m);
  const long warm_steps = std::lround(o.warmup / h);
  for (long n = 0; n < warm_steps; ++n) warm.step(h);
  if (progress) progress("warmed up: " + std::to_string(warm_steps) + " serial steps to t = " + std::to_string(warm.time()) + " s");

  std::vector<Combo> combos;
  const auto add = [&](SchedulerKind kind, int threads, const std::string& layout) {
    for (const Combo& c : combos)
      if (c.row.scheduler == scheduler_name(kind) && c.row.threads == threads && c.row.layout == layout) return;
    Combo c;
    c.row.scheduler = scheduler_name(kind);
    c.row.layout = layout;
    c.row.threads = threads;
    c.row.steps = o.steps;
    c.row.repeat = o.repeat;
    ScheduleOptions so;
    so.kind = kind;
    so.threads = threads;
    so.grain = o.grain;
    {
      LayoutScope scope(layout);
      c.sim = std::make_unique<Simulation>(m, so);
    }
    c.sim->mutable_state() = warm.state();
    c.sim->workspace().status = warm.workspace().status;
    c.sim->set_clock(warm.time(), warm.steps());
    c.sim->enable_profiling();
    combos.push_back(std::move(c));
  };
  add(SchedulerKind::serial, 1, "native");  // the baseline, always
  for (SchedulerKind k : o.schedulers)
    for (int t : o.threads) {
      if (k == SchedulerKind::serial) {
        add(k, 1, "native");
        continue;
      }
      if (k == SchedulerKind::flowgraph)
        for (const std::string& l : o.layouts) add(k, t, l);
      else
        add(k, t, "native");
    }
  for (Combo& c : combos)
    for (int i = 0; i < 10; ++i) c.sim->step(h);  // warm caches and thread pools
  // Interleaved repeats: every combination meets the machine in the same moods.
  for (int r = 0; r < o.repeat; ++r)
    for (Combo& c : combos) {
      Simulation& s = *c.sim;
      Profiler& p = *s.profiler();
      p.reset();
      const ScheduleCounters k0 = s.schedule().counters();
      const auto t0 = std::chrono::steady_clock::now();
      for (long n = 0; n < o.steps; ++n) s.step(h);
      const double wall = seconds_since(t0);
      const ScheduleCounters k1 = s.schedule().counters();
      const Profiler::Report rep = p.report(wall, o.steps * h, s.schedule().numa_nodes(), c.row.scheduler);
      const double per = 1e6 / static_cast<double>(o.steps);
      c.us.push_back(wall * per);
      c.chain.push_back(row_busy_max(rep, "chain forces") * per);
      c.pulley.push_back(row_busy_max(rep, "pulley contact") * per);
      const double T = c.row.threads;
      if (k1.compute_s > k0.compute_s) {
        c.zero_gather.push_back(((k1.zero_s - k0.zero_s) + (k1.gather_s - k0.gather_s)) / T * per);
        c.compute.push_back((k1.compute_s - k0.compute_s) / T * per);
      } else {
        double busy = 0;
        for (const auto& row : rep.rows)
          if (row.name == "chain forces" || row.name == "pulley contact") busy += row.busy_avg_s;
        c.zero_gather.push_back(0);
        c.compute.push_back(busy * per);
      }
      if (progress) {
        char line[200];
        std::snprintf(line, sizeof line, "repeat %d/%d  %-10s %2d threads  %-12s %8.1f us/step", r + 1, o.repeat,
                      c.row.scheduler.c_str(), c.row.threads, c.row.layout.c_str(), c.us.back());
        progress(line);
      }
    }
  const Combo& base = combos.front();
  const double base_us = median(base.us), base_chain = median(base.chain), base_pulley = median(base.pulley);
  std::vector<ScaleRow> rows;
  for (Combo& c : combos) {
    ScaleRow r = c.row;
    r.us_per_step = median(c.us);
    r.speedup = base_us / r.us_per_step;
    r.efficiency = r.speedup / r.threads;
    r.chain_us = median(c.chain);
    r.pulley_us = median(c.pulley);
    r.chain_speedup = r.chain_us > 0 ? base_chain / r.chain_us : 0;
    r.pulley_speedup = r.pulley_us > 0 ? base_pulley / r.pulley_us : 0;
    r.zero_gather_us = median(c.zero_gather);
    r.compute_us = median(c.compute);
    // Every combination advanced the same number of steps from the same state.
    r.identical = c.sim->state().size() == base.sim->state().size() &&
                  std::memcmp(c.sim->state().data(), base.sim->state().data(),
                              sizeof(double) * static_cast<std::size_t>(c.sim->state().size())) == 0;
    rows.push_back(r);
  }
  std::map<std::string, std::pair<std::vector<int>, std::vector<double>>> curves;
  for (const ScaleRow& r : rows) {
    auto& cv = curves[r.scheduler + "|" + r.layout];
    cv.first.push_back(r.threads);
    cv.second.push_back(r.speedup);
  }
  for (ScaleRow& r : rows) {
    const auto& cv = curves[r.scheduler + "|" + r.layout];
    r.amdahl_serial_fraction = r.scheduler == "serial" ? 1.0 : fit_amdahl(cv.first, cv.second);
  }
  return rows;
}

std::string scale_csv(const std::vector<ScaleRow>& rows) {
  std::ostringstream os;
  os.precision(9);
  os << "scheduler,layout,threads,steps,repeat,us_per_step,speedup,efficiency,chain_us,chain_speedup,pulley_us,"
        "pulley_speedup,zero_gather_us,compute_us,amdahl_serial_fraction,identical\n";
  for (const ScaleRow& r : rows)
    os << r.scheduler << ",\"" << r.layout << "\"," << r.threads << ',' << r.steps << ',' << r.repeat << ','
       << r.us_per_step << ',' << r.speedup << ',' << r.efficiency << ',' << r.chain_us << ',' << r.chain_speedup << ','
       << r.pulley_us << ',' << r.pulley_speedup << ',' << r.zero_gather_us << ',' << r.compute_us << ','
       << r.amdahl_serial_fraction << ',' << (r.identical ? 1 : 0) << '\n';
  return os.str();
}

std::string scale_json(const std::vector<ScaleRow>& rows, const std::string& config) {
  // Nine significant digits, as the table's figures are measured.
  const auto num = [](double x) { return json_number(x, 9); };
  Json j = {{"config", config}, {"rows", Json::array()}};
  for (const ScaleRow& r : rows)
    j["rows"].push_back({{"scheduler", r.scheduler},
                         {"layout", r.layout},
                         {"threads", r.threads},
                         {"steps", r.steps},
                         {"repeat", r.repeat},
                         {"us_per_step", num(r.us_per_step)},
                         {"speedup", num(r.speedup)},
                         {"efficiency", num(r.efficiency)},
                         {"chain_us", num(r.chain_us)},
                         {"chain_speedup", num(r.chain_speedup)},
                         {"pulley_us", num(r.pulley_us)},
                         {"pulley_speedup", num(r.pulley_speedup)},
                         {"zero_gather_us", num(r.zero_gather_us)},
                         {"compute_us", num(r.compute_us)},
                         {"amdahl_serial_fraction", num(r.amdahl_serial_fraction)},
                         {"identical", r.identical}});
  return json_text(j);
}

std::string scale_table(const std::vector<ScaleRow>& rows) {
  std::ostringstream os;
  char line[300];
  std::snprintf(line, sizeof line, "%-10s %-12s %7s %10s %8s %6s %9s %7s %9s %7s %10s %10s %7s %5s\n", "scheduler",
                "layout", "threads", "us/step", "speedup", "eff", "chain us", "x", "pulley us", "x", "zero+gath",
                "compute", "amdahl", "same");
  os << line;
  for (const ScaleRow& r : rows) {
    std::snprintf(line, sizeof line, "%-10s %-12.12s %7d %10.1f %8.3f %6.2f %9.1f %7.2f %9.1f %7.2f %10.2f %10.1f %7.3f %5s\n",
                  r.scheduler.c_str(), r.layout.c_str(), r.threads, r.us_per_step, r.speedup, r.efficiency, r.chain_us,
                  r.chain_speedup, r.pulley_us, r.pulley_speedup, r.zero_gather_us, r.compute_us,
                  r.amdahl_serial_fraction, r.identical ? "yes" : "NO");
    os << line;
  }
  return os.str();
}

}  // namespace cvt
