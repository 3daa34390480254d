#include "engine/studies/sweep.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <sstream>
#include <stdexcept>

#include "engine/base/fingerprint.hpp"
#include "engine/base/timing.hpp"
#include "engine/guards.hpp"
#include "engine/io/checkpoint.hpp"
#include "engine/io/files.hpp"
#include "engine/io/h5_writer.hpp"
#include "engine/model/config.hpp"
#include "engine/model/model.hpp"
#include "engine/provenance.hpp"
#include "engine/run.hpp"
#include "engine/simulation.hpp"

namespace cvt {

namespace {

std::string trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r\n");
  if (b == std::string::npos) return {};
  return s.substr(b, s.find_last_not_of(" \t\r\n") - b + 1);
}

// CSV by RFC 4180: records of fields separated by commas; a field in double quotes may hold
// commas, doubled quotes, '#' and line breaks; blanks around a field are dropped. A line
// whose first non-blank character is '#' outside a quoted field is a comment, and blank lines
// are skipped. Each record comes with the line it starts on; a malformed one throws
// CsvError naming that line.
struct CsvError : std::invalid_argument {
  CsvError(int line, const std::string& why)
      : std::invalid_argument("line " + std::to_string(line) + ": " + why), line(line), why(why) {}
  int line;
  std::string why;
};

struct CsvRecord {
  int line = 0;
  std::vector<std::string> fields;
};

std::vector<CsvRecord> parse_csv(const std::string& text) {
  std::vector<CsvRecord> out;
  CsvRecord rec;
  std::string f;
  int line = 1;
  bool in_quotes = false, was_quoted = false, after_quote = false, at_start = true;
  const auto fail = [&](int at, const std::string& why) { throw CsvError(at, why); };
  const auto end_field = [&] {
    rec.fields.push_back(was_quoted ? f : trim(f));
    f.clear(), was_quoted = after_quote = false;
  };
  int quote_line = 0;
  for (std::size_t i = 0; i < text.size(); ++i) {
    const char ch = text[i];
    if (in_quotes) {
      if (ch == '"' && i + 1 < text.size() && text[i + 1] == '"') f += '"', ++i;
      else if (ch == '"') in_quotes = false, after_quote = true;
      else f += ch, line += ch == '\n';
      continue;
    }
    if (at_start) {  // a comment or a blank line, at the start of a record only
      const std::size_t b = text.find_first_not_of(" \t\r", i);
      if (b == std::string::npos) break;
      if (text[b] == '#' || text[b] == '\n') {
        const std::size_t nl = text.find('\n', b);
        if (nl == std::string::npos) break;
        i = nl, ++line;
        continue;
      }
      at_start = false, rec.line = line;
    }
    if (ch == ',' || ch == '\n') {
      end_field();
      if (ch == '\n') out.push_back(std::move(rec)), rec = {}, at_start = true, ++line;
    } else if (ch == '"') {
      if (!trim(f).empty() || was_quoted) fail(line, "a quote inside an unquoted field (quote the whole field)");
      f.clear(), in_quotes = was_quoted = true, quote_line = line;
    } else if (after_quote) {
      if (ch != ' ' && ch != '\t' && ch != '\r') fail(line, "characters after a closing quote");
    } else {
      f += ch;
    }
  }
  if (in_quotes) fail(quote_line, "a quote that is never closed");
  if (!at_start) end_field(), out.push_back(std::move(rec));
  return out;
}

// The fields of one line of CSV (an --axis list, a row of the sweep's own table).
std::vector<std::string> split_csv(const std::string& line) {
  const std::vector<CsvRecord> r = parse_csv(line);
  if (r.size() != 1) throw std::invalid_argument("not one line of CSV");
  return r.front().fields;
}

std::string csv_field(const std::string& s) {
  if (s.find_first_of(",\"\n") == std::string::npos) return s;
  std::string q = "\"";
  for (char ch : s) q += ch == '"' ? std::string("\"\"") : std::string(1, ch == '\n' ? ' ' : ch);
  return q + "\"";
}


// The result columns after the keys, each with its member.
struct Column {
  const char* name;
  double SweepRow::*field;
  const char* unit;  // SI, "1" for a ratio (OUT.h5's `unit` attributes)
};
const std::vector<Column>& result_columns() {
  static const std::vector<Column> cols = {
      {"speed_ratio", &SweepRow::speed_ratio, "1"},
      {"geometric_ratio", &SweepRow::geometric_ratio, "1"},
      {"slip", &SweepRow::slip, "1"},
      {"input_torque", &SweepRow::input_torque, "N m"},
      {"output_torque", &SweepRow::output_torque, "N m"},
      {"efficiency", &SweepRow::efficiency, "1"},
      {"loss_efficiency", &SweepRow::loss_efficiency, "1"},
      {"input_speed", &SweepRow::input_speed, "rad/s"},
      {"output_speed", &SweepRow::output_speed, "rad/s"},
      {"load_torque", &SweepRow::load_torque, "N m"},
      {"clamping_force_driving", &SweepRow::clamping_force_driving, "N"},
      {"clamping_force_driven", &SweepRow::clamping_force_driven, "N"},
      {"strand_tension_upper", &SweepRow::strand_tension_upper, "N"},
      {"strand_tension_lower", &SweepRow::strand_tension_lower, "N"},
      {"model_time", &SweepRow::model_time, "s"},
      {"steady_window", &SweepRow::steady_window, "s"},
      {"step", &SweepRow::step, "s"},
      {"energy_leak", &SweepRow::energy_leak, "1"},
  };
  return cols;
}

// The result columns that are verified means of the summary (run.verify, summary_fields()):
// each has a column <name>_numerical_error after the results, and then <name>_uncertainty.
const std::vector<std::string>& error_columns() {
  static const std::vector<std::string> cols = [] {
    std::vector<std::string> out;
    for (const auto& c : result_columns())
      for (const SummaryField& f : summary_fields())
        if (f.name == c.name && f.verify.verified) out.emplace_back(c.name);
    return out;
  }();
  return cols;
}

// The two columns of each verified mean, in this order: its numerical error and its
// statistical uncertainty, each a suffix and the row's map that holds them by mean.
struct PerMean {
  const char* suffix;
  std::map<std::string, double> SweepRow::*values;
};
constexpr std::array<PerMean, 2> kPerMean = {{{"_numerical_error", &SweepRow::numerical_error},
                                              {"_uncertainty", &SweepRow::uncertainty}}};

// A row's entry of one mean in one of those maps (NaN: none).
double row_value(const SweepRow& r, const PerMean& c, const std::string& name) {
  const auto& m = r.*c.values;
  const auto it = m.find(name);
  return it == m.end() ? std::numeric_limits<double>::quiet_NaN() : it->second;
}

const std::vector<std::string>& statuses() {
  static const std::vector<std::string> s = {"steady", "not_steady", "slip", "blow_up", "error"};
  return s;
}

// Writes text and forces it to the disk: a kill after this loses nothing of it.
void append_durably(const std::string& path, const std::string& text) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_APPEND | O_CREAT, 0644);
  if (fd < 0) throw OutputError("cannot write '" + path + "'");
  const ssize_t n = ::write(fd, text.data(), text.size());
  const bool ok = n == static_cast<ssize_t>(text.size()) && ::fsync(fd) == 0;
  ::close(fd);
  if (!ok) throw OutputError("cannot write '" + path + "'");
}

std::string point_file(const SweepOptions& o, long i) {
  char b[32];
  std::snprintf(b, sizeof b, "point-%04ld.h5", i);
  return o.out + ".runs/" + b;
}

// A point started from a steady state's checkpoint (point, its configuration without
// these keys): its run bounded run.t_end beyond the checkpoint, and a changed load torque
// ramped from the checkpoint's over warm_ramp (< 0: the point's steady window, two periods
// of the drive line's torsion mode, over which the half-cosine ramp leaves the mode
// about a tenth as excited as over one period: docs/studies.md, "Maps by continuation").
// The chain runs loaded already: no settling sub-steps (integrator.settle_time) after the
// checkpoint.
std::vector<std::string> warm_keys(const Checkpoint& ck, const Config& point, double warm_ramp,
                                   std::vector<std::string> ov) {
  const double from = parse_config(ck.config_toml, {}, "the checkpoint").load.torque;
  ov.push_back("run.t_end=" + exact_number(ck.t + point.run.t_end));
  ov.push_back("integrator.settle_time=" + exact_number(ck.t));
  if (point.load.torque != from) {
    const double ramp = warm_ramp >= 0 ? warm_ramp : steady_window(build_model(point));
    for (const std::string& k : {"ramp.load_from=" + exact_number(from), "ramp.load_start=" + exact_number(ck.t),
                                 "ramp.load_time=" + exact_number(ramp)})
      ov.push_back(k);
  }
  return ov;
}

// --from: every point on the checkpoint's configuration.
std::vector<std::string> warm_overrides(const Checkpoint& ck, const SweepOptions& o, const std::vector<std::string>& ov) {
  return warm_keys(ck, parse_config(ck.config_toml, ov, o.from), o.warm_ramp, ov);
}

// With continuation: the final checkpoint of point i's parent, if the parent ended steady
// (its run's verdict; a parent that slipped, blew up or never settled leaves the point
// from rest).
std::optional<Checkpoint> steady_parent(const SweepOptions& o, const SweepPlan& plan, long i) {
  const long p = plan.parent(i);
  if (p < 0) return std::nullopt;
  const std::string path = point_file(o, p) + ".ckpt";
  if (!std::filesystem::exists(path)) return std::nullopt;
  Checkpoint c = read_checkpoint(path);
  if (c.stopped != "steady") return std::nullopt;
  return c;
}

}  // namespace

SweepAxis parse_axis(const std::string& text) {
  const auto eq = text.find('=');
  if (eq == std::string::npos || eq == 0 || eq + 1 == text.size())
    throw ConfigError("--axis", "'" + text + "'", "expected KEY=V1,V2,... (section.key=values)");
  SweepAxis a;
  a.key = trim(text.substr(0, eq));
  std::vector<std::string> values;
  try {
    values = split_csv(text.substr(eq + 1));
  } catch (const std::invalid_argument& e) {
    throw ConfigError("--axis", "'" + text + "'", e.what());
  }
  for (const std::string& v : values) {
    if (trim(v).empty()) throw ConfigError("--axis", "'" + text + "'", "an empty value");
    a.values.push_back(trim(v));
  }
  return a;
}

SweepPlan SweepPlan::grid(const std::vector<SweepAxis>& axes) {
  SweepPlan p;
  for (const auto& a : axes) {
    if (std::find(p.keys.begin(), p.keys.end(), a.key) != p.keys.end())
      throw ConfigError("--axis", a.key, "given twice");
    p.keys.push_back(a.key);
  }
  p.points.push_back({});
  for (const auto& a : axes) {
    std::vector<std::vector<std::string>> next;
    for (const auto& pt : p.points)
      for (const auto& v : a.values) {
        next.push_back(pt);
        next.back().push_back(v);
      }
    p.points = std::move(next);
  }
  if (axes.empty()) p.points.clear();
  p.origins.assign(p.points.size(), "--axis");
  return p;
}

SweepPlan SweepPlan::from_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ConfigError::unreadable(path, "no such file");
  std::stringstream text;
  text << in.rdbuf();
  if (in.bad()) throw ConfigError::unreadable(path, "read error");
  std::vector<CsvRecord> records;
  try {
    records = parse_csv(text.str());
  } catch (const CsvError& e) {
    throw ConfigError(path, "line " + std::to_string(e.line), e.why);
  }
  SweepPlan p;
  for (const CsvRecord& r : records) {
    const std::string where = "line " + std::to_string(r.line);
    if (p.keys.empty()) {
      for (const std::string& k : r.fields) {
        if (k.empty()) throw ConfigError(path, where, "an empty key in the header");
        if (std::find(p.keys.begin(), p.keys.end(), k) != p.keys.end())
          throw ConfigError(path, where, "the key '" + k + "' is given twice");
        p.keys.push_back(k);
      }
      continue;
    }
    if (r.fields.size() != p.keys.size())
      throw ConfigError(path, where,
                        std::to_string(r.fields.size()) + " values for " + std::to_string(p.keys.size()) + " keys");
    for (std::size_t k = 0; k < r.fields.size(); ++k)
      if (r.fields[k].empty()) throw ConfigError(path, where, "no value for " + p.keys[k]);
    p.points.push_back(r.fields);
    p.origins.push_back(path + " " + where);
  }
  if (p.keys.empty()) throw ConfigError(path, "", "no header line of keys");
  return p;
}

SweepPlan sweep_plan(const SweepOptions& o, const std::vector<std::string>& axes, const std::string& points) {
  if (o.config_path.empty() == o.from.empty())
    throw ConfigError("CONFIG", o.config_path, "give either CONFIG or --from CHECKPOINT (whose configuration is the base)");
  if (axes.empty() == points.empty())
    throw ConfigError("--axis", "", "give the points: one or more --axis KEY=V1,V2,... or --points FILE, not both");
  std::vector<SweepAxis> ax;
  for (const auto& a : axes) ax.push_back(parse_axis(a));
  SweepPlan plan = points.empty() ? SweepPlan::grid(ax) : SweepPlan::from_file(points);
  if (plan.points.empty()) throw ConfigError("--points", points, "no points");
  if (o.continuation && !o.from.empty())
    throw ConfigError("--continuation", "", "continues each point from a neighbour's steady state, and --from starts every "
                                        "point from one checkpoint: give one of the two");
  const std::optional<Checkpoint> ck = o.from.empty() ? std::nullopt : std::optional(read_checkpoint(o.from));
  std::vector<std::string> resolved;
  std::vector<double> loads;
  for (long i = 0; i < static_cast<long>(plan.points.size()); ++i) {
    std::vector<std::string> ov = o.overrides;
    const auto own = plan.overrides(i);
    ov.insert(ov.end(), own.begin(), own.end());
    try {
      const Config c = ck ? parse_config(ck->config_toml, ov, o.from) : load_config(o.config_path, ov);
      resolved.push_back(continuation_toml(c.resolved_toml, false));
      loads.push_back(c.load.torque);
    } catch (const ConfigError& e) {  // named with the point's line
      throw ConfigError(e.key(), e.value(), e.reason() + " (point " + std::to_string(i + 1) + ", " +
                                                plan.origins[static_cast<std::size_t>(i)] + ")");
    }
  }
  if (o.continuation) plan.parents = continuation_parents(plan, loads, &plan.order);
  // A continued point's row is the configuration and the point it continues from: a CSV of
  // the same points from rest is another sweep.
  for (long i = 0; i < static_cast<long>(plan.points.size()); ++i)
    plan.fingerprints.push_back(fingerprint(resolved[static_cast<std::size_t>(i)] +
                                            (o.continuation ? "\n# continued from point " + std::to_string(plan.parent(i))
                                                            : std::string())));
  return plan;
}

std::vector<long> continuation_parents(const SweepPlan& plan, const std::vector<double>& loads,
                                       std::vector<long>* order) {
  const long n = static_cast<long>(plan.points.size());
  const auto load_key = std::find(plan.keys.begin(), plan.keys.end(), "load.torque");
  const auto group_of = [&](long i) {  // the point's values but its load's
    std::vector<std::string> g = plan.points[static_cast<std::size_t>(i)];
    if (load_key != plan.keys.end()) g.erase(g.begin() + (load_key - plan.keys.begin()));
    return g;
  };
  std::vector<long> parent(static_cast<std::size_t>(n), -1), depth(static_cast<std::size_t>(n), 0);
  std::vector<bool> seen(static_cast<std::size_t>(n), false);
  const auto L = [&](long i) { return loads[static_cast<std::size_t>(i)]; };
  for (long first = 0; first < n; ++first) {
    if (seen[static_cast<std::size_t>(first)]) continue;
    std::vector<long> g;  // the group, in point order
    for (long i = first; i < n; ++i)
      if (!seen[static_cast<std::size_t>(i)] && group_of(i) == group_of(first)) g.push_back(i), seen[static_cast<std::size_t>(i)] = true;
    std::vector<long> by_load = g;
    std::stable_sort(by_load.begin(), by_load.end(), [&](long a, long b) { return L(a) < L(b); });
    const long root = by_load[(by_load.size() - 1) / 2];
    // Prim: the point nearest in load to the tree joins it, below its nearest member.
    std::vector<long> tree = {root}, rest;
    for (long i : g)
      if (i != root) rest.push_back(i);
    while (!rest.empty()) {
      std::size_t best = 0;
      long to = -1;
      double d_best = std::numeric_limits<double>::infinity();
      for (std::size_t k = 0; k < rest.size(); ++k)
        for (long t : tree) {
          const double d = std::abs(L(rest[k]) - L(t));
          if (d < d_best) d_best = d, best = k, to = t;  // ties: the lower index, the earlier member
        }
      const long i = rest[best];
      parent[static_cast<std::size_t>(i)] = to, depth[static_cast<std::size_t>(i)] = depth[static_cast<std::size_t>(to)] + 1;
      tree.push_back(i), rest.erase(rest.begin() + static_cast<long>(best));
    }
  }
  order->resize(static_cast<std::size_t>(n));
  for (long i = 0; i < n; ++i) (*order)[static_cast<std::size_t>(i)] = i;
  std::stable_sort(order->begin(), order->end(),
                   [&](long a, long b) { return depth[static_cast<std::size_t>(a)] < depth[static_cast<std::size_t>(b)]; });
  return parent;
}

std::vector<std::string> SweepPlan::overrides(long i) const {
  std::vector<std::string> o;
  for (std::size_t k = 0; k < keys.size(); ++k) o.push_back(keys[k] + "=" + points[static_cast<std::size_t>(i)][k]);
  return o;
}

std::string SweepPlan::label(long i) const {
  std::string s;
  for (const std::string& o : overrides(i)) s += (s.empty() ? "" : ", ") + o;
  return s;
}

std::string sweep_csv_header(const SweepPlan& plan) {
  std::string s;
  for (const auto& k : plan.keys) s += csv_field(k) + ",";
  s += "status";
  for (const auto& c : result_columns()) s += std::string(",") + c.name;
  for (const PerMean& c : kPerMean)
    for (const auto& e : error_columns()) s += "," + e + c.suffix;
  return s + ",point,from_point,reason,wall_s,config\n";
}

std::string sweep_csv_row(const SweepRow& r) {
  std::string s;
  for (const auto& v : r.values) s += csv_field(v) + ",";
  s += r.status;
  // Appended one by one (+= only: GCC 12 warns falsely, -Wrestrict, on "," + a string here).
  for (const auto& c : result_columns()) s += ',', s += exact_number(r.*c.field);
  for (const PerMean& c : kPerMean)
    for (const auto& e : error_columns()) s += ',', s += exact_number(row_value(r, c, e));
  for (const std::string& f : {std::to_string(r.point), std::to_string(r.from_point), csv_field(r.reason),
                               exact_number(r.wall_s), r.config}) {
    s += ',';
    s += f;
  }
  s += '\n';
  return s;
}

SweepRow parse_sweep_csv_row(const std::string& line, const SweepPlan& plan) {
  const std::vector<std::string> f = split_csv(line);
  const std::size_t nk = plan.keys.size(), nr = result_columns().size() + kPerMean.size() * error_columns().size();
  if (f.size() != nk + 1 + nr + 5) throw std::runtime_error("a row of " + std::to_string(f.size()) + " fields");
  SweepRow r;
  r.values.assign(f.begin(), f.begin() + static_cast<long>(nk));
  r.status = f[nk];
  if (std::find(statuses().begin(), statuses().end(), r.status) == statuses().end())
    throw std::runtime_error("unknown status '" + r.status + "'");
  std::size_t at = nk + 1;
  for (const auto& c : result_columns()) r.*c.field = std::stod(f[at++]);
  for (const PerMean& c : kPerMean)
    for (const auto& e : error_columns())
      if (const double x = std::stod(f[at++]); !std::isnan(x)) (r.*c.values)[e] = x;
  r.point = std::stol(f[at++]);
  r.from_point = std::stol(f[at++]);
  r.reason = f[at++];
  r.wall_s = std::stod(f[at++]);
  r.config = f[at];
  return r;
}

namespace {

// The checkpoint of a point's run that a signal or run.max_wall stopped, if it ran this
// configuration; nullopt otherwise (the point runs from its start).
std::optional<Checkpoint> stopped_point(const std::string& path, const Config& cfg) {
  if (!std::filesystem::exists(path)) return std::nullopt;
  try {
    Checkpoint c = read_checkpoint(path);
    if ((c.stopped == "signal" || c.stopped == "max_wall" || c.stopped == "callback") &&
        continuation_toml(c.config_toml, false) == continuation_toml(cfg.resolved_toml, false))
      return c;
  } catch (const std::exception&) {
  }
  return std::nullopt;
}

}  // namespace

// The point's configuration (the base, --set, the point's keys, run.until_steady), run into
// its own file; the row from its summary.
SweepRow run_sweep_point(const SweepOptions& o, const SweepPlan& plan, long i) {
  SweepRow r;
  r.point = i;
  r.values = plan.points[static_cast<std::size_t>(i)];
  const auto t0 = WallClock::now();
  const std::string path = point_file(o, i);
  if (static_cast<std::size_t>(i) < plan.fingerprints.size()) r.config = plan.fingerprints[static_cast<std::size_t>(i)];
  try {
    std::vector<std::string> ov = o.overrides;
    const std::vector<std::string> own = plan.overrides(i);
    ov.insert(ov.end(), own.begin(), own.end());
    ov.push_back("run.until_steady=true");
    std::optional<Checkpoint> ck;
    if (!o.from.empty()) {
      ck = read_checkpoint(o.from), ov = warm_overrides(*ck, o, ov);
    } else if ((ck = steady_parent(o, plan, i))) {
      r.from_point = plan.parent(i);
      ov = warm_keys(*ck, load_config(o.config_path, ov), o.warm_ramp, ov);
    }
    const Model m = build_model(!o.from.empty() ? parse_config(ck->config_toml, ov, o.from) : load_config(o.config_path, ov));
    // A point that a signal or run.max_wall stopped continues from its own checkpoint.
    std::optional<Checkpoint> mine = stopped_point(path + ".ckpt", m.cfg);
    RunOptions ro;
    ro.resume = mine ? &*mine : ck ? &*ck : nullptr;
    ro.append = mine.has_value();
    ro.out_path = path;
    ro.progress = false;
    ro.schedule = o.schedule;
    ro.checkpoint_every = 0;
    ro.started = o.started;
    ro.warn = [](const std::string&) {};
    const RunResult s = run_simulation(m, ro);
    if (s.interrupted)
      throw SweepInterrupted("point " + std::to_string(i + 1) + (s.stopped == "max_wall"
                                                                      ? " stopped before the wall-time limit (run.max_wall)"
                                                                      : " stopped by signal " + std::to_string(s.signal)),
                             s.stopped == "max_wall");
    r.status = s.status;
    for (const auto& x : s.reasons) r.reason += (r.reason.empty() ? "" : "; ") + x;
    if (!s.unverified.empty()) r.reason += (r.reason.empty() ? "" : "; ") + ("not verified: " + s.unverified);
    r.speed_ratio = s.speed_ratio, r.geometric_ratio = s.geometric_ratio, r.slip = s.slip;
    r.input_torque = s.input_torque, r.output_torque = s.output_torque, r.efficiency = s.efficiency;
    r.loss_efficiency = s.loss_efficiency;
    r.input_speed = s.input_speed, r.output_speed = s.output_speed, r.load_torque = s.load_torque;
    r.clamping_force_driving = s.clamp_driving, r.clamping_force_driven = s.clamp_driven;
    r.strand_tension_upper = s.strand_upper, r.strand_tension_lower = s.strand_lower;
    r.model_time = s.model_time, r.steady_window = s.steady_window;
    r.step = s.step, r.energy_leak = s.energy_leak;
    if (s.verify_step > 0)
      for (const auto& e : error_columns()) r.numerical_error[e] = numerical_error(s, e);
    for (const auto& e : error_columns())
      if (const double u = uncertainty(s, e); !std::isnan(u)) r.uncertainty[e] = u;
  } catch (const SweepInterrupted&) {
    throw;
  } catch (const OutputError& e) {
    // A full disk or a held file ends the sweep (exit 73): every later point would fail
    // alike. The finished points are in its table, from which it continues.
    std::error_code ec;
    for (const std::string& f : {path, path + ".ckpt", path + ".partial"}) std::filesystem::remove(f, ec);
    const auto* w = dynamic_cast<const WriteFailed*>(&e);
    if (!w) throw;
    throw OutputError("point " + std::to_string(i + 1) + ": " + w->cause() + "; the finished points are in " + o.out +
                      ".csv: free space and give the same sweep command again to continue");
  } catch (const BlowUpError& e) {
    r.status = "blow_up", r.reason = e.what();
    // The run file goes unless kept: so does the sentence that points to it.
    if (const auto at = r.reason.find(". Every sample before the blow-up is in"); at != std::string::npos && !o.keep_runs)
      r.reason.resize(at);
  } catch (const std::exception& e) {
    r.status = "error", r.reason = e.what();
  }
  r.wall_s = seconds_since(t0);
  if (!o.keep_runs) {
    // With continuation a steady point's checkpoint stays for the points that continue from
    // it, until the sweep ends (close_sweep).
    const bool parent = o.continuation && r.status == "steady";
    std::error_code ec;
    for (const std::string& f : {path, path + ".ckpt", path + ".partial"})
      if (!parent || f != path + ".ckpt") std::filesystem::remove(f, ec);
  }
  return r;
}

SweepLedger::SweepLedger(const SweepOptions& o, const SweepPlan& plan)
    : o_(o), plan_(plan), csv_(o.out + ".csv"), done_(plan.points.size(), false) {
  // One writer per sweep: a lock the kernel lets go of when the process ends, kill -9
  // included.
  check_writable(csv_, "CSV file", std::string(".lock").size());
  lock_.emplace(csv_ + ".lock", csv_);
  const std::string header = sweep_csv_header(plan);
  std::ifstream in(csv_);
  std::string line, kept = header;
  if (in && std::getline(in, line)) {
    if (line + "\n" != header)
      throw ConfigError(csv_, "", "holds another sweep (its header is not this sweep's): give another --out, "
                                  "or remove it");
    // Complete lines only: a kill may have torn the last one.
    std::stringstream rest;
    rest << in.rdbuf();
    const std::string text = rest.str();
    std::size_t at = 0;
    for (std::size_t nl; (nl = text.find('\n', at)) != std::string::npos; at = nl + 1) {
      SweepRow r;
      try {
        r = parse_sweep_csv_row(text.substr(at, nl - at), plan);
      } catch (const std::exception&) {
        continue;
      }
      if (r.point < 0 || r.point >= static_cast<long>(done_.size()) ||
          r.values != plan.points[static_cast<std::size_t>(r.point)])
        throw ConfigError(csv_, "point " + std::to_string(r.point),
                          "holds another sweep (other values): give another --out, or remove it");
      if (static_cast<std::size_t>(r.point) < plan.fingerprints.size() &&
          r.config != plan.fingerprints[static_cast<std::size_t>(r.point)])
        throw ConfigError(csv_, "point " + std::to_string(r.point),
                          "holds another sweep (its row ran another configuration: another CONFIG, --from or --set "
                          "than this sweep's): give another --out, or remove it");
      if (done_[static_cast<std::size_t>(r.point)]) continue;
      done_[static_cast<std::size_t>(r.point)] = true;
      rows_.push_back(r);
      kept += text.substr(at, nl - at + 1);
    }
  }
  in.close();
  // The file again from its whole rows (the torn line gone), under a temporary name.
  const std::string tmp = csv_ + ".tmp";
  std::filesystem::remove(tmp);
  append_durably(tmp, kept);
  std::filesystem::rename(tmp, csv_);
}

void SweepLedger::add(const SweepRow& r) {
  if (done_[static_cast<std::size_t>(r.point)]) return;
  append_durably(csv_, sweep_csv_row(r));
  done_[static_cast<std::size_t>(r.point)] = true;
  rows_.push_back(r);
}

void SweepLedger::finish(const std::string& config_text) const {
  std::vector<SweepRow> rows = rows_;
  std::sort(rows.begin(), rows.end(), [](const SweepRow& a, const SweepRow& b) { return a.point < b.point; });
  std::string text = sweep_csv_header(plan_);
  for (const auto& r : rows) text += sweep_csv_row(r);
  const std::string tmp = csv_ + ".tmp";
  std::filesystem::remove(tmp);
  append_durably(tmp, text);
  std::filesystem::rename(tmp, csv_);
  // OUT.h5: /points/KEY (values as written), /results/COLUMN, the base configuration.
  const std::string h5 = o_.out + ".h5", h5tmp = h5 + ".partial";
  H5File f = H5File::create(h5tmp);
  for (std::size_t k = 0; k < plan_.keys.size(); ++k) {
    std::vector<std::string> v;
    for (const auto& r : rows) v.push_back(r.values[k]);
    f.write_strings("/points/" + plan_.keys[k], v);
  }
  std::vector<double> idx, from, wall;
  std::vector<std::string> st, why;
  for (const auto& r : rows)
    idx.push_back(static_cast<double>(r.point)), from.push_back(static_cast<double>(r.from_point)),
        wall.push_back(r.wall_s), st.push_back(r.status), why.push_back(r.reason);
  f.write_vector("/results/point", idx);
  f.write_vector("/results/from_point", from);
  f.write_strings("/results/status", st);
  f.write_strings("/results/reason", why);
  std::map<std::string, std::string> units;
  for (const auto& c : result_columns()) {
    std::vector<double> v;
    for (const auto& r : rows) v.push_back(r.*c.field);
    f.write_vector(std::string("/results/") + c.name, v);
    f.set_string_attribute(std::string("/results/") + c.name, "unit", c.unit);
    units[c.name] = c.unit;
  }
  for (const PerMean& c : kPerMean)
    for (const auto& e : error_columns()) {
      std::vector<double> v;
      for (const auto& r : rows) v.push_back(row_value(r, c, e));
      f.write_vector("/results/" + e + c.suffix, v);
      f.set_string_attribute("/results/" + e + c.suffix, "unit", units[e]);
    }
  f.write_vector("/results/wall_s", wall);
  f.set_string_attribute("/results/wall_s", "unit", "s");
  write_provenance(f);
  f.write_string("/config", config_text);
  f.set_strings_attribute("/points", "keys", plan_.keys);
  f.close();
  std::filesystem::rename(h5tmp, h5);
  std::error_code ec;
  std::filesystem::remove(csv_ + ".lock", ec);
}

std::string exact_number(double x) {
  char b[40];
  std::snprintf(b, sizeof b, "%.17g", x);
  return b;
}

std::function<void(const std::string&)> sweep_log(const SweepOptions& o) {
  if (o.log) return o.log;
  return [](const std::string& s) { std::printf("%s\n", s.c_str()), std::fflush(stdout); };
}

std::string sweep_config_text(const SweepOptions& o) {
  if (!o.from.empty()) return read_checkpoint(o.from).config_toml;
  std::ifstream in(o.config_path);
  std::stringstream cfg;
  cfg << in.rdbuf();
  return cfg.str();
}

std::string sweep_point_line(const SweepPlan& plan, const SweepRow& r, long total) {
  // The label and status as strings: a point of many keys has a label longer than any buffer.
  std::string s = "point " + std::to_string(r.point + 1) + "/" + std::to_string(total) + "  ";
  s += plan.label(r.point);
  s += ": ";
  s += r.status;
  char b[256];
  if (r.status == "blow_up" || r.status == "error") s += " (" + r.reason.substr(0, 160) + ")";
  else {
    std::snprintf(b, sizeof b, ", speed ratio %.4f, slip %+.2f %%, efficiency %.4f, t = %.4g s", r.speed_ratio,
                  100 * r.slip, r.efficiency, r.model_time);
    s += b;
  }
  if (r.from_point >= 0) s += ", from point " + std::to_string(r.from_point + 1);
  std::snprintf(b, sizeof b, ", %.1f s", r.wall_s);
  return s + b;
}

long run_sweep(const SweepOptions& o, const SweepPlan& plan) {
  SweepLedger ledger(o, plan);
  const long total = static_cast<long>(plan.points.size());
  const auto log = sweep_log(o);
  log_resumed(o, ledger);
  std::filesystem::create_directories(o.out + ".runs");
  for (long k = 0; k < total; ++k) {
    const long i = plan.at(k);  // with continuation, every point after its parent
    if (ledger.done(i)) continue;
    const SweepRow r = run_sweep_point(o, plan, i);
    ledger.add(r);
    log("  " + sweep_point_line(plan, r, total));
  }
  return close_sweep(o, ledger);
}

void log_resumed(const SweepOptions& o, const SweepLedger& ledger) {
  if (ledger.finished() > 0)
    sweep_log(o)("  " + std::to_string(ledger.finished()) + " of " + std::to_string(ledger.points()) +
                 " points already in " + o.out + ".csv: skipped");
}

long close_sweep(const SweepOptions& o, const SweepLedger& ledger) {
  ledger.finish(sweep_config_text(o));
  if (!o.keep_runs) {
    std::error_code ec;
    if (o.continuation)  // the parents' checkpoints
      for (long i = 0; i < ledger.points(); ++i) std::filesystem::remove(point_file(o, i) + ".ckpt", ec);
    std::filesystem::remove(o.out + ".runs", ec);  // only if empty
  }
  long unsteady = 0;
  for (const auto& r : ledger.rows()) unsteady += r.status != "steady";
  return unsteady;
}

std::string task_file(const SweepOptions& o, long i) {
  char b[32];
  std::snprintf(b, sizeof b, "point-%04ld.csv", i);
  return o.out + ".points/" + b;
}

SweepRow run_sweep_task(const SweepOptions& o, const SweepPlan& plan, long i) {
  const long total = static_cast<long>(plan.points.size());
  if (i < 0 || i >= total)
    throw ConfigError("--point", std::to_string(i), "the sweep's points are 0 .. " + std::to_string(total - 1));
  const std::string file = task_file(o, i);
  for (const std::string& d : {o.out + ".runs", o.out + ".points"}) {
    std::error_code ec;
    std::filesystem::create_directories(d, ec);  // a failure is named by check_writable
  }
  check_writable(file, "point's row", std::string(".tmp").size());
  const SweepRow r = run_sweep_point(o, plan, i);
  const std::string text = sweep_csv_header(plan) + sweep_csv_row(r);
  replace_file(file, text.data(), text.size());
  return r;
}

std::vector<long> gather_sweep(const SweepOptions& o, const SweepPlan& plan, long* unsteady) {
  SweepLedger ledger(o, plan);
  std::vector<long> missing;
  const long total = static_cast<long>(plan.points.size());
  for (long i = 0; i < total; ++i) {
    if (ledger.done(i)) continue;
    std::ifstream in(task_file(o, i));
    std::string header, line;
    if (!in || !std::getline(in, header) || !std::getline(in, line)) {
      missing.push_back(i);
      continue;
    }
    const auto refuse = [&](const std::string& why) {
      return ConfigError(task_file(o, i), "", why + ": it belongs to another sweep; give another --out, or remove it");
    };
    if (header + "\n" != sweep_csv_header(plan)) throw refuse("its header is not this sweep's");
    SweepRow r;
    try {
      r = parse_sweep_csv_row(line, plan);
    } catch (const std::exception& e) {
      throw refuse(std::string("its row does not read (") + e.what() + ")");
    }
    if (r.point != i || r.values != plan.points[static_cast<std::size_t>(i)]) throw refuse("its point is not point " + std::to_string(i));
    if (static_cast<std::size_t>(i) < plan.fingerprints.size() && r.config != plan.fingerprints[static_cast<std::size_t>(i)])
      throw refuse("its point ran another configuration");
    ledger.add(r);
  }
  if (!missing.empty()) return missing;
  *unsteady = close_sweep(o, ledger);
  std::error_code ec;
  for (long i = 0; i < total; ++i) std::filesystem::remove(task_file(o, i), ec);
  std::filesystem::remove(o.out + ".points", ec);  // only if empty
  return missing;
}

}  // namespace cvt
