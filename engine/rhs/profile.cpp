#include "engine/rhs/profile.hpp"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <sstream>

#include "engine/io/json.hpp"

namespace cvt {

namespace {

double clock_s() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

const char* const kSectionNames[kSections] = {"chain forces",        "pulley contact",    "other forces",
                                              "inertia decomposition", "accelerations",     "integrator update",
                                              "contact status",      "W stiffness",       "W assembly",
                                              "W factorization",     "W solves"};


}  // namespace

Profiler::Profiler(int workers) : workers_(std::max(1, workers)), slots_(static_cast<std::size_t>(workers_)) { reset(); }

void Profiler::reset() {
  for (Slot& s : slots_) s.busy.fill(0);
  calls_.fill(0);
  master_.fill(0);
  rhs_wall_ = 0;
  step_ticks_ = output_ticks_ = ahead_ticks_ = 0;
  steps_ = output_calls_ = 0;
  tick0_ = ticks();
  clock0_ = clock_s();
}

double Profiler::seconds_per_tick() const {
  const double dt = clock_s() - clock0_;
  const std::uint64_t dn = ticks() - tick0_;
  return dn > 0 && dt > 0 ? dt / static_cast<double>(dn) : 1e-9;
}

Profiler::Report Profiler::report(double total_wall_s, double model_time, int numa_nodes,
                                  const std::string& scheduler) const {
  const double spt = seconds_per_tick();
  Report r;
  r.steps = steps_;
  r.wall_s = total_wall_s;
  r.us_per_step = steps_ > 0 ? 1e6 * total_wall_s / steps_ : 0;
  r.model_s_per_hour = total_wall_s > 0 ? model_time * 3600.0 / total_wall_s : 0;
  r.threads = workers_;
  r.numa_nodes = numa_nodes;
  r.scheduler = scheduler;
  const double W = static_cast<double>(workers_);
  const auto finish = [&](Row& row) {
    row.us_per_step = steps_ > 0 ? 1e6 * row.wall_s / steps_ : 0;
    row.percent = total_wall_s > 0 ? 100.0 * row.wall_s / total_wall_s : 0;
    row.imbalance_percent = row.busy_avg_s > 0 ? 100.0 * (row.busy_max_s / row.busy_avg_s - 1.0) : 0;
    r.rows.push_back(row);
  };
  const double step_s = static_cast<double>(step_ticks_) * spt;
  std::vector<double> busy_total(static_cast<std::size_t>(workers_), 0.0);
  double sections_s = 0;
  for (int k = 0; k < kSections; ++k) {
    Row row;
    row.name = kSectionNames[k];
    row.calls = calls_[k];
    double lo = 1e300, hi = 0, sum = 0;
    for (int w = 0; w < workers_; ++w) {
      const double b = static_cast<double>(slots_[static_cast<std::size_t>(w)].busy[k]) * spt;
      busy_total[static_cast<std::size_t>(w)] += b;
      lo = std::min(lo, b), hi = std::max(hi, b), sum += b;
    }
    // Work timed on the master alone (the W-methods' matrix work and step updates) is
    // serial: every thread spends it in this section, the others waiting for it.
    const double master = static_cast<double>(master_[k]) * spt;
    row.busy_min_s = lo + master, row.busy_max_s = hi + master, row.busy_avg_s = sum / W + master;
    row.wall_s = row.busy_avg_s;
    sections_s += row.wall_s;
    finish(row);
  }
  const double master_s = static_cast<double>(master_total()) * spt;
  // Scheduling: per worker, the time inside steps that it did not spend in a timed chunk
  // (waiting for work, wake-up, task spawning, the graph's own bookkeeping).
  Row sched;
  sched.name = "scheduling";
  sched.calls = steps_;
  double lo = 1e300, hi = 0, sum = 0;
  for (double b : busy_total) {
    const double idle = std::max(0.0, step_s - b - master_s);
    lo = std::min(lo, idle), hi = std::max(hi, idle), sum += idle;
  }
  sched.busy_min_s = lo, sched.busy_max_s = hi, sched.busy_avg_s = sum / W;
  sched.wall_s = sched.busy_avg_s;
  finish(sched);
  Row out;
  out.name = "output";
  out.calls = output_calls_;
  out.wall_s = out.busy_min_s = out.busy_avg_s = out.busy_max_s = static_cast<double>(output_ticks_) * spt;
  finish(out);
  Row rest;
  rest.name = "rest";
  rest.calls = 0;
  rest.wall_s = std::max(0.0, total_wall_s - sections_s - sched.wall_s - out.wall_s);
  rest.busy_min_s = rest.busy_avg_s = rest.busy_max_s = rest.wall_s;
  finish(rest);
  Row total;
  total.name = "total";
  total.calls = steps_;
  total.wall_s = total.busy_min_s = total.busy_avg_s = total.busy_max_s = total_wall_s;
  finish(total);
  return r;
}

std::string format_profile(const Profiler::Report& r) {
  std::ostringstream os;
  char line[256];
  std::snprintf(line, sizeof line,
                "Profile: %ld steps, %.1f us/step, %.4f model s per wall hour, %d thread%s, %d NUMA node%s (%s)\n",
                r.steps, r.us_per_step, r.model_s_per_hour, r.threads, r.threads == 1 ? "" : "s", r.numa_nodes,
                r.numa_nodes == 1 ? "" : "s", r.scheduler.c_str());
  os << line;
  std::snprintf(line, sizeof line, "%-22s %10s %10s %9s %7s %10s %10s %10s %7s\n", "section", "calls", "wall s",
                "us/step", "%", "busy min", "busy avg", "busy max", "imbal%");
  os << line << std::string(103, '-') << '\n';
  const bool w_method = std::any_of(r.rows.begin(), r.rows.end(), [](const Profiler::Row& row) {
    return row.name.rfind("W ", 0) == 0 && row.calls > 0;
  });
  for (const auto& row : r.rows) {
    if (!w_method && row.name.rfind("W ", 0) == 0) continue;  // an explicit method's table
    if (row.name == "total") os << std::string(103, '-') << '\n';
    std::snprintf(line, sizeof line, "%-22s %10ld %10.3f %9.2f %7.1f %10.3f %10.3f %10.3f %7.1f\n", row.name.c_str(),
                  row.calls, row.wall_s, row.us_per_step, row.percent, row.busy_min_s, row.busy_avg_s, row.busy_max_s,
                  row.imbalance_percent);
    os << line;
  }
  os << "(wall s of a section: its busy time averaged over the threads, so that the rows add up to the total;\n"
        " W rows: the W-method's linear algebra, wall time on the master; scheduling: time inside steps outside\n"
        " every timed part; imbalance: max / avg busy - 1)\n";
  return os.str();
}

std::string profile_json(const Profiler::Report& r) {
  Json j = {{"header",
             {{"steps", r.steps},
              {"us_per_step", json_number(r.us_per_step)},
              {"model_s_per_hour", json_number(r.model_s_per_hour)},
              {"threads", r.threads},
              {"numa_nodes", r.numa_nodes},
              {"scheduler", r.scheduler},
              {"wall_s", json_number(r.wall_s)}}},
            {"rows", Json::array()}};
  for (const auto& row : r.rows)
    j["rows"].push_back({{"name", row.name},
                         {"calls", row.calls},
                         {"wall_s", json_number(row.wall_s)},
                         {"us_per_step", json_number(row.us_per_step)},
                         {"percent", json_number(row.percent)},
                         {"busy_min_s", json_number(row.busy_min_s)},
                         {"busy_avg_s", json_number(row.busy_avg_s)},
                         {"busy_max_s", json_number(row.busy_max_s)},
                         {"imbalance_percent", json_number(row.imbalance_percent)}});
  return json_text(j);
}

}  // namespace cvt
