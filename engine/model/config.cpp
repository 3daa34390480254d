// Configuration loading: TOML (toml++ v3) -> Config, with overrides and full validation.
//
// One schema table below lists every key once (section, key, type, unit, range); parsing,
// type checks, range checks and the resolved TOML output are all driven by it, so a key
// cannot be known to one of them and forgotten by another.
#include "engine/model/config.hpp"

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <sstream>
#include <string_view>

#include <toml++/toml.h>

namespace cvt {

const char* to_string(FrictionLaw law) {
  switch (law) {
    case FrictionLaw::nonsmooth: return "nonsmooth";
    case FrictionLaw::smooth: return "smooth";
    case FrictionLaw::none: return "none";
  }
  return "?";
}

const char* to_string(IntegratorMethod method) {
  switch (method) {
    case IntegratorMethod::rk4: return "rk4";
    case IntegratorMethod::ros2: return "ros2";
    case IntegratorMethod::ros34pw2: return "ros34pw2";
    case IntegratorMethod::ros34prw: return "ros34prw";
  }
  return "?";
}

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

enum class Kind { real, integer, boolean, method, law, profile };

// Bounds of a numeric key: lo <(=) value <(=) hi.
struct Range {
  double lo = -kInf;
  bool lo_open = false;  // true: value must be > lo; false: >= lo
  double hi = kInf;
  bool hi_open = false;  // true: value must be < hi; false: <= hi
};

constexpr Range positive{0.0, true, kInf, false};
constexpr Range nonneg{0.0, false, kInf, false};
constexpr Range above_one{1.0, true, kInf, false};

struct KeyDef {
  const char* section;
  const char* key;
  Kind kind;
  const char* unit;  // "" for dimensionless / not applicable
  void* (*ref)(Config&);
  Range range;
};

#define CVT_KEY(sec, name, kind, unit, range)                                    \
  KeyDef {                                                                       \
    #sec, #name, Kind::kind, unit, [](Config& c) -> void* { return &c.sec.name; }, range \
  }

// Every key, in the order the resolved TOML prints them.
const std::vector<KeyDef>& schema() {
  static const std::vector<KeyDef> defs = {
      CVT_KEY(geometry, centre_distance, real, "m", positive),
      CVT_KEY(geometry, ratio, real, "1", positive),
      CVT_KEY(chain, links, integer, "", (Range{3, false, 10000, false})),
      CVT_KEY(chain, pitch, real, "m", positive),
      CVT_KEY(chain, plates_per_link, integer, "", (Range{1, false, 64, false})),
      CVT_KEY(chain, plate_mass, real, "kg", positive),
      CVT_KEY(chain, plate_stiffness, real, "N/m", positive),
      CVT_KEY(chain, plate_damping, real, "N s/m", nonneg),
      CVT_KEY(chain, plate_spread, real, "m", nonneg),
      CVT_KEY(chain, link_inertia, real, "kg m^2", positive),
      CVT_KEY(chain, pack_stiffness, real, "N/m", positive),
      CVT_KEY(chain, pack_damping, real, "N s/m", nonneg),

      CVT_KEY(pin, length, real, "m", positive),
      CVT_KEY(pin, ea, real, "N", positive),
      CVT_KEY(pin, ei, real, "N m^2", positive),
      CVT_KEY(pin, mass, real, "kg", positive),
      CVT_KEY(pin, damping_time, real, "s", nonneg),
      CVT_KEY(pin, tilt_stiffness, real, "N m/rad", nonneg),

      CVT_KEY(rocker, stations, integer, "", (Range{1, false, 16, false})),
      CVT_KEY(rocker, radius, real, "m", positive),
      CVT_KEY(rocker, half_distance, real, "m", positive),
      CVT_KEY(rocker, stiffness, real, "N/m^1.5", positive),
      CVT_KEY(rocker, damping, real, "N s/m", nonneg),
      CVT_KEY(rocker, keeper_stiffness, real, "N/m", nonneg),

      CVT_KEY(pulley_contact, end_radius, real, "m", positive),
      CVT_KEY(pulley_contact, stiffness, real, "N/m^1.5", positive),
      CVT_KEY(pulley_contact, damping, real, "N s/m", nonneg),

      CVT_KEY(friction, law, law, "", Range{}),
      CVT_KEY(friction, f0, real, "1", positive),
      CVT_KEY(friction, v0, real, "m/s", positive),

      CVT_KEY(sheave, cone_angle, real, "deg", (Range{0, true, 45, true})),
      CVT_KEY(sheave, outer_radius, real, "m", positive),
      CVT_KEY(sheave, hub_radius, real, "m", positive),

      CVT_KEY(shaft, mass, real, "kg", positive),
      CVT_KEY(shaft, polar_inertia, real, "kg m^2", positive),
      CVT_KEY(shaft, tilt_inertia, real, "kg m^2", positive),
      CVT_KEY(shaft, sheave_mass, real, "kg", positive),

      CVT_KEY(bearing, half_span, real, "m", positive),
      CVT_KEY(bearing, k1, real, "N/m", positive),
      CVT_KEY(bearing, k3, real, "N/m^3", nonneg),
      CVT_KEY(bearing, radial_damping, real, "N s/m", nonneg),
      CVT_KEY(bearing, axial_stiffness, real, "N/m", positive),
      CVT_KEY(bearing, axial_damping, real, "N s/m", nonneg),

      CVT_KEY(drive, speed, real, "rad/s", nonneg),
      CVT_KEY(drive, speed_profile, profile, "s, rad/s", positive),
      CVT_KEY(drive, stiffness, real, "N m/rad", nonneg),
      CVT_KEY(drive, damping, real, "N m s/rad", nonneg),

      CVT_KEY(load, torque, real, "N m", nonneg),
      CVT_KEY(load, torque_profile, profile, "s, N m", nonneg),
      CVT_KEY(load, inertia, real, "kg m^2", positive),
      CVT_KEY(load, speed_coefficient, real, "N m s/rad", nonneg),
      CVT_KEY(load, stiffness, real, "N m/rad", nonneg),
      CVT_KEY(load, damping, real, "N m s/rad", nonneg),

      CVT_KEY(clamping, driving, real, "N", positive),
      CVT_KEY(clamping, driven, real, "N", positive),
      CVT_KEY(clamping, driving_profile, profile, "s, N", positive),
      CVT_KEY(clamping, driven_profile, profile, "s, N", positive),
      CVT_KEY(clamping, sheave_damping, real, "N s/m", nonneg),

      CVT_KEY(controller, enabled, boolean, "", Range{}),
      CVT_KEY(controller, target_ratio, real, "1", positive),
      CVT_KEY(controller, target_profile, profile, "s, 1", positive),
      CVT_KEY(controller, kp, real, "N", nonneg),
      CVT_KEY(controller, ki, real, "N/s", nonneg),
      CVT_KEY(controller, clamping_safety, real, "1", nonneg),
      CVT_KEY(controller, shift_kp, real, "1", nonneg),
      CVT_KEY(controller, shift_ki, real, "1/s", nonneg),
      CVT_KEY(controller, thrust_limit, real, "1", above_one),
      CVT_KEY(controller, gain_speed, real, "rad/s", nonneg),

      CVT_KEY(ramp, time, real, "s", nonneg),
      CVT_KEY(ramp, load_time, real, "s", nonneg),
      CVT_KEY(ramp, load_start, real, "s", nonneg),
      CVT_KEY(ramp, load_from, real, "N m", nonneg),
      CVT_KEY(damping, scale, real, "1", nonneg),

      CVT_KEY(integrator, method, method, "", Range{}),
      CVT_KEY(integrator, step, real, "s", positive),
      CVT_KEY(integrator, w_every, integer, "", (Range{1, false, 1000000, false})),
      CVT_KEY(integrator, w_k_every, integer, "", (Range{1, false, 1000000, false})),
      CVT_KEY(integrator, w_secant, boolean, "", Range{}),
      CVT_KEY(integrator, w_analytic_stiffness, boolean, "", Range{}),
      CVT_KEY(integrator, w_segments, integer, "", (Range{0, false, 1000, false})),
      CVT_KEY(integrator, w_fresh, real, "1", nonneg),
      CVT_KEY(integrator, w_fresh_max, integer, "", (Range{1, false, 1000, false})),
      CVT_KEY(integrator, w_shafts, boolean, "", Range{}),
      CVT_KEY(integrator, startup_time, real, "s", nonneg),
      CVT_KEY(integrator, startup_step, real, "s", positive),
      CVT_KEY(integrator, settle_time, real, "s", nonneg),
      CVT_KEY(integrator, settle_step, real, "s", positive),
      CVT_KEY(integrator, tolerance, real, "1", nonneg),
      CVT_KEY(integrator, fixed_steps, boolean, "", Range{}),
      CVT_KEY(integrator, energy_leak, real, "1", nonneg),

      CVT_KEY(run, t_end, real, "s", positive),
      CVT_KEY(run, sample_interval, real, "s", positive),
      CVT_KEY(run, snapshot_interval, real, "s", nonneg),
      CVT_KEY(run, tracked_pin, integer, "", nonneg),
      CVT_KEY(run, tracked_link, integer, "", nonneg),
      CVT_KEY(run, efficiency_window, real, "s", positive),
      CVT_KEY(run, until_steady, boolean, "", Range{}),
      CVT_KEY(run, steady_window, real, "s", nonneg),
      CVT_KEY(run, steady_tolerance, real, "1", (Range{0, true, 1, true})),
      CVT_KEY(run, verify, boolean, "", Range{}),
      CVT_KEY(run, max_wall, real, "s", nonneg),
  };
  return defs;
}

#undef CVT_KEY

const std::vector<std::string>& section_names() {
  static const std::vector<std::string> names = [] {
    std::vector<std::string> out;
    for (const auto& d : schema())
      if (out.empty() || out.back() != d.section) out.emplace_back(d.section);
    return out;
  }();
  return names;
}

const KeyDef* find_key(std::string_view section, std::string_view key) {
  for (const auto& d : schema())
    if (section == d.section && key == d.key) return &d;
  return nullptr;
}

bool is_section(std::string_view name) {
  const auto& s = section_names();
  return std::find(s.begin(), s.end(), name) != s.end();
}

const std::vector<std::string>& law_names() {
  static const std::vector<std::string> names = {"nonsmooth", "smooth", "none"};
  return names;
}
constexpr IntegratorMethod kMethods[] = {IntegratorMethod::rk4, IntegratorMethod::ros2, IntegratorMethod::ros34pw2,
                                         IntegratorMethod::ros34prw};
const std::vector<std::string>& method_names() {
  static const std::vector<std::string> names = [] {
    std::vector<std::string> out;
    for (IntegratorMethod m : kMethods) out.emplace_back(to_string(m));
    return out;
  }();
  return names;
}

// ---- formatting -------------------------------------------------------------------------

// Shortest round-trip representation that always reads back as a TOML float:
// "84.0", "0.16", "1e8", "2.5e-7".
std::string format_double(double v) {
  if (std::isnan(v)) return "nan";
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  char buf[64];
  auto res = std::to_chars(buf, buf + sizeof buf, v);
  std::string s(buf, res.ptr);
  const auto e = s.find('e');
  if (e != std::string::npos) {
    // Tidy the exponent: "e+08" -> "e8", "e-07" -> "e-7".
    std::string mant = s.substr(0, e);
    std::string exp = s.substr(e + 1);
    bool neg = false;
    if (!exp.empty() && (exp[0] == '+' || exp[0] == '-')) {
      neg = exp[0] == '-';
      exp.erase(0, 1);
    }
    while (exp.size() > 1 && exp[0] == '0') exp.erase(0, 1);
    return mant + "e" + (neg ? "-" : "") + exp;
  }
  if (s.find('.') == std::string::npos) s += ".0";
  return s;
}

std::string quote(std::string_view s) {
  std::string out = "\"";
  for (char ch : s) {
    const auto c = static_cast<unsigned char>(ch);
    switch (ch) {
      case '"': out += "\\\""; break;
      case '\\': out += "\\\\"; break;
      case '\n': out += "\\n"; break;
      case '\t': out += "\\t"; break;
      case '\r': out += "\\r"; break;
      default:
        if (c < 0x20 || c == 0x7f) {
          char buf[8];
          std::snprintf(buf, sizeof buf, "\\u%04X", c);
          out += buf;
        } else {
          out += ch;
        }
    }
  }
  return out + "\"";
}

const char* type_name(const toml::node& n) {
  switch (n.type()) {
    case toml::node_type::table: return "a table";
    case toml::node_type::array: return "an array";
    case toml::node_type::string: return "a string";
    case toml::node_type::integer: return "an integer";
    case toml::node_type::floating_point: return "a floating-point number";
    case toml::node_type::boolean: return "a boolean";
    case toml::node_type::date: return "a date";
    case toml::node_type::time: return "a time";
    case toml::node_type::date_time: return "a date-time";
    default: return "nothing";
  }
}

// A node's value as TOML would write it.
std::string node_text(const toml::node& n) {
  if (auto v = n.as_floating_point()) return format_double(v->get());
  if (auto v = n.as_integer()) return std::to_string(v->get());
  if (auto v = n.as_boolean()) return v->get() ? "true" : "false";
  if (auto v = n.as_string()) return quote(v->get());
  if (auto t = n.as_table()) return t->empty() ? "{}" : "{...}";
  if (auto a = n.as_array()) {
    std::ostringstream os;
    os << *a;
    return os.str();
  }
  std::ostringstream os;
  n.visit([&](const auto& x) { os << x; });
  return os.str();
}

// ---- did-you-mean -----------------------------------------------------------------------

// Optimal string alignment distance (Levenshtein plus adjacent transpositions).
std::size_t edit_distance(std::string_view a, std::string_view b) {
  const std::size_t n = a.size(), m = b.size();
  std::vector<std::vector<std::size_t>> d(n + 1, std::vector<std::size_t>(m + 1));
  for (std::size_t i = 0; i <= n; ++i) d[i][0] = i;
  for (std::size_t j = 0; j <= m; ++j) d[0][j] = j;
  for (std::size_t i = 1; i <= n; ++i)
    for (std::size_t j = 1; j <= m; ++j) {
      const std::size_t cost = a[i - 1] == b[j - 1] ? 0 : 1;
      d[i][j] = std::min({d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + cost});
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1])
        d[i][j] = std::min(d[i][j], d[i - 2][j - 2] + 1);
    }
  return d[n][m];
}

}  // namespace

// The candidate the word begins (when only one does: "ros34pw" -> "ros34pw2"; none when
// several do: "ros34" begins ros34pw2 and ros34prw), else the closest candidate within edit
// distance 2, if any.
std::optional<std::string> closest_name(std::string_view word, const std::vector<std::string>& candidates) {
  if (word.size() >= 3) {
    std::optional<std::string> prefix;
    int count = 0;
    for (const auto& c : candidates)
      if (c.size() > word.size() && c.compare(0, word.size(), word) == 0) prefix = c, ++count;
    if (count == 1) return prefix;
    if (count > 1) return std::nullopt;
  }
  std::optional<std::string> best;
  std::size_t best_d = 3;
  for (const auto& c : candidates) {
    const std::size_t dist = edit_distance(word, c);
    if (dist < best_d) {
      best_d = dist;
      best = c;
    }
  }
  return best;
}

namespace {

std::vector<std::string> keys_of(std::string_view section) {
  std::vector<std::string> out;
  for (const auto& d : schema())
    if (section == d.section) out.emplace_back(d.key);
  return out;
}

std::vector<std::string> qualified_names() {
  std::vector<std::string> out;
  for (const auto& d : schema()) out.push_back(std::string(d.section) + "." + d.key);
  return out;
}

// Sections that hold a key of exactly this name.
std::vector<std::string> sections_with_key(std::string_view key) {
  std::vector<std::string> out;
  for (const auto& d : schema())
    if (key == d.key) out.emplace_back(std::string(d.section) + "." + d.key);
  return out;
}

std::string suggestion_text(const std::vector<std::string>& names) {
  if (names.empty()) return "";
  std::string s = "; did you mean ";
  for (std::size_t i = 0; i < names.size(); ++i) {
    if (i) s += i + 1 == names.size() ? " or " : ", ";
    s += "'" + names[i] + "'";
  }
  return s + "?";
}

// Reason for an unknown `key` inside `section` (section may itself be unknown).
std::string unknown_key_reason(const std::string& section, const std::string& key) {
  if (is_section(section)) {
    if (auto k = closest_name(key, keys_of(section))) return "unknown key" + suggestion_text({section + "." + *k});
    return "unknown key" + suggestion_text(sections_with_key(key));
  }
  std::string reason = "unknown key (there is no section [" + section + "])";
  if (auto s = closest_name(section, section_names())) {
    if (find_key(*s, key)) return reason + suggestion_text({*s + "." + key});
    if (auto k = closest_name(key, keys_of(*s))) return reason + suggestion_text({*s + "." + *k});
    return reason + suggestion_text({"[" + *s + "]"});
  }
  if (auto q = closest_name(section + "." + key, qualified_names())) return reason + suggestion_text({*q});
  return reason + suggestion_text(sections_with_key(key));
}

// ---- validation -------------------------------------------------------------------------

class Validator {
 public:
  Validator(const std::string& origin, const std::map<std::string, std::string>& override_text,
            const std::map<std::string, std::string>& shortcuts)
      : origin_(origin), override_text_(override_text), shortcuts_(shortcuts) {}

  [[noreturn]] void fail(const std::string& qkey, const toml::node* node, const std::string& reason) const {
    std::string value = node ? node_text(*node) : std::string();
    std::string where;
    if (auto it = override_text_.find(qkey); it != override_text_.end()) {
      value = it->second;
      auto sc = shortcuts_.find(qkey);
      if (sc == shortcuts_.end()) sc = shortcuts_.find("*");
      where = " (from " + (sc != shortcuts_.end() ? sc->second : std::string("--set")) + ")";
    } else if (node && node->source().begin.line > 0) {
      where = " (" + origin_ + " line " + std::to_string(node->source().begin.line) + ")";
    }
    throw ConfigError(qkey, value, reason + where);
  }

  // Runs `f`, keeping its ConfigError to report with the others (every problem of the
  // input at once).
  template <class F>
  void collect(F&& f) {
    try {
      f();
    } catch (const ConfigError& e) {
      errors_.push_back(e);
    }
  }
  // Throws the first error found, with the others as further lines.
  void throw_collected() const {
    if (errors_.empty()) return;
    std::vector<std::string> more;
    for (std::size_t i = 1; i < errors_.size(); ++i)
      more.push_back(errors_[i].key() + (errors_[i].value().empty() ? "" : " = " + errors_[i].value()) + ": " +
                     errors_[i].reason());
    const ConfigError& e = errors_.front();
    throw ConfigError(e.key(), e.value(), e.reason(), more);
  }

  // Collects every unknown section and key.
  void check_unknown(const toml::table& root) {
    for (const auto& [k, node] : root) {
      const std::string section(k.str());
      if (!node.is_table()) {
        // A plain key at top level: no such thing in the schema.
        std::string reason = "unknown key (keys must sit inside a [section])";
        auto where = sections_with_key(section);
        if (where.empty())
          if (auto s = closest_name(section, section_names())) where = {"[" + *s + "]"};
        collect([&] { fail(section, &node, reason + suggestion_text(where)); });
        continue;
      }
      const auto& tbl = *node.as_table();
      if (!is_section(section)) {
        // Named as a section, with the sections it may have meant (by its name, or by
        // the keys it holds) and its keys.
        std::string reason = "unknown section";
        std::vector<std::string> keys;
        for (const auto& [k2, n2] : tbl) keys.emplace_back(k2.str());
        // From --set: named by the override's key, as the user wrote it.
        bool from_set = false;
        for (const auto& [k2, n2] : tbl)
          if (override_text_.count(section + "." + std::string(k2.str()))) {
            const std::string key(k2.str());
            collect([&] { fail(section + "." + key, &n2, unknown_key_reason(section, key)); });
            from_set = true;
          }
        if (from_set) continue;
        if (auto s = closest_name(section, section_names())) reason += suggestion_text({"[" + *s + "]"});
        else if (!keys.empty() && !sections_with_key(keys.front()).empty())
          reason += suggestion_text(sections_with_key(keys.front()));
        if (!keys.empty()) {
          reason += " (it holds ";
          for (std::size_t i = 0; i < keys.size(); ++i) reason += (i ? ", " : "") + keys[i];
          reason += ")";
        }
        collect([&] { fail("[" + section + "]", nullptr, reason + where_is(node)); });
        continue;
      }
      for (const auto& [k2, n2] : tbl) {
        const std::string key(k2.str());
        if (!find_key(section, key))
          collect([&] { fail(section + "." + key, &n2, unknown_key_reason(section, key)); });
      }
    }
  }

  // " (FILE line N)" for a node of the file; "" without a line, or for an override.
  std::string where_is(const toml::node& n) const {
    const auto line = n.source().begin.line;
    if (line == 0 || (n.source().path && *n.source().path == "--set")) return "";
    return " (" + origin_ + " line " + std::to_string(line) + ")";
  }

  void read_key(const KeyDef& d, const toml::node& n, Config& cfg) const {
    const std::string qkey = std::string(d.section) + "." + d.key;
    auto type_error = [&](const char* expected) {
      fail(qkey, &n, std::string("wrong type: expected ") + expected + ", got " + type_name(n));
    };
    switch (d.kind) {
      case Kind::real: {
        double v = 0.0;
        if (auto f = n.as_floating_point()) v = f->get();
        else if (auto i = n.as_integer()) v = static_cast<double>(i->get());
        else type_error("a floating-point number");
        if (!std::isfinite(v)) fail(qkey, &n, "must be a finite number");
        check_range(qkey, n, v, d.range);
        *static_cast<double*>(d.ref(cfg)) = v;
        break;
      }
      case Kind::integer: {
        auto i = n.as_integer();
        if (!i) type_error("an integer");
        const std::int64_t v = i->get();
        check_range(qkey, n, static_cast<double>(v), d.range);
        if (v < std::numeric_limits<int>::min() || v > std::numeric_limits<int>::max())
          fail(qkey, &n, "out of range for an integer");
        *static_cast<int*>(d.ref(cfg)) = static_cast<int>(v);
        break;
      }
      case Kind::boolean: {
        auto b = n.as_boolean();
        if (!b) type_error("a boolean (true or false)");
        *static_cast<bool*>(d.ref(cfg)) = b->get();
        break;
      }
      case Kind::method: {
        auto s = n.as_string();
        if (!s) type_error("a string");
        const std::string v = s->get();
        check_name(qkey, n, v, method_names(), "integrator method");
        auto& method = *static_cast<IntegratorMethod*>(d.ref(cfg));
        for (IntegratorMethod m : kMethods)
          if (v == to_string(m)) method = m;
        break;
      }
      case Kind::law: {
        auto s = n.as_string();
        if (!s) type_error("a string");
        const std::string v = s->get();
        check_name(qkey, n, v, law_names(), "friction law");
        auto& law = *static_cast<FrictionLaw*>(d.ref(cfg));
        law = v == "nonsmooth" ? FrictionLaw::nonsmooth : v == "smooth" ? FrictionLaw::smooth : FrictionLaw::none;
        break;
      }
      case Kind::profile:
        read_profile(qkey, n, *static_cast<std::vector<std::array<double, 2>>*>(d.ref(cfg)), d);
        break;
    }
  }

  // An array of [time, value] pairs, or the name of a CSV file of them (relative to the
  // configuration's folder): finite numbers, times >= 0 and non-decreasing (increasing for
  // a clamping force, whose work needs its rate), values in the key's range.
  void read_profile(const std::string& qkey, const toml::node& n, std::vector<std::array<double, 2>>& out,
                    const KeyDef& d) const {
    const std::string what = std::string_view(d.key) == "target_profile" ? "ratio" : "value";
    out.clear();
    if (const auto s = n.as_string()) {
      out = profile_file(qkey, n, s->get());
    } else {
      const auto* a = n.as_array();
      if (!a)
        fail(qkey, &n, "wrong type: expected an array of [time, " + what + "] pairs or a CSV file's name, got " +
                           std::string(type_name(n)));
      for (const toml::node& e : *a) {
        const auto* pair = e.as_array();
        std::array<double, 2> p{};
        if (!pair || pair->size() != 2) fail(qkey, &n, "each point must be a [time, " + what + "] pair of two numbers");
        for (int k = 0; k < 2; ++k) {
          const toml::node& x = *pair->get(static_cast<std::size_t>(k));
          if (auto f = x.as_floating_point()) p[k] = f->get();
          else if (auto i = x.as_integer()) p[k] = static_cast<double>(i->get());
          else fail(qkey, &n, "each point must be a [time, " + what + "] pair of two numbers, got " + type_name(x));
        }
        out.push_back(p);
      }
    }
    const bool strict = std::string_view(d.section) == "clamping";
    for (std::size_t i = 0; i < out.size(); ++i) {
      const auto& p = out[i];
      const std::string at = "point " + std::to_string(i + 1) + " [" + format_double(p[0]) + ", " + format_double(p[1]) + "]: ";
      if (!std::isfinite(p[0]) || !std::isfinite(p[1])) fail(qkey, &n, at + "must hold finite numbers");
      if (p[0] < 0) fail(qkey, &n, at + "the time must not be negative");
      if (i > 0 && (strict ? p[0] <= out[i - 1][0] : p[0] < out[i - 1][0]))
        fail(qkey, &n, at + (strict ? "the times must increase (a clamping force has a rate)" : "the times must not decrease"));
      const bool lo_ok = d.range.lo_open ? p[1] > d.range.lo : p[1] >= d.range.lo;
      if (!lo_ok) fail(qkey, &n, at + "the " + what + (d.range.lo_open ? " must be positive (> 0)" : " must not be negative (>= 0)"));
    }
  }

  // The points of a CSV file: "time, value" per line, a first line of names allowed, lines
  // starting with '#' and blank ones skipped.
  std::vector<std::array<double, 2>> profile_file(const std::string& qkey, const toml::node& n,
                                                  const std::string& name) const {
    std::filesystem::path path(name);
    if (path.is_relative() && std::filesystem::is_regular_file(origin_))
      path = std::filesystem::path(origin_).parent_path() / path;
    std::ifstream in(path);
    if (!in) fail(qkey, &n, "cannot read the profile file " + path.string());
    std::vector<std::array<double, 2>> out;
    std::string line;
    bool header = false;
    for (int number = 1; std::getline(in, line); ++number) {
      if (!line.empty() && line.back() == '\r') line.pop_back();
      const auto first = line.find_first_not_of(" \t");
      if (first == std::string::npos || line[first] == '#') continue;
      const auto comma = line.find(',');
      std::array<double, 2> p{};
      bool ok = comma != std::string::npos;
      for (int k = 0; ok && k < 2; ++k) {
        const std::string field = k == 0 ? line.substr(0, comma) : line.substr(comma + 1);
        char* end = nullptr;
        p[k] = std::strtod(field.c_str(), &end);
        ok = end != field.c_str() && std::string(end).find_first_not_of(" \t") == std::string::npos;
      }
      if (!ok && out.empty() && !header) {
        header = true;  // the first line may name the columns
        continue;
      }
      if (!ok) fail(qkey, &n, path.string() + " line " + std::to_string(number) + ": expected \"time, value\", got \"" + line + "\"");
      out.push_back(p);
    }
    if (out.empty()) fail(qkey, &n, "the profile file " + path.string() + " holds no points");
    return out;
  }

  void check_name(const std::string& qkey, const toml::node& n, const std::string& v,
                  const std::vector<std::string>& accepted, const char* what) const {
    if (std::find(accepted.begin(), accepted.end(), v) != accepted.end()) return;
    std::string reason = std::string("unknown ") + what + "; accepted: ";
    for (std::size_t i = 0; i < accepted.size(); ++i) reason += (i ? ", " : "") + quote(accepted[i]);
    if (auto c = closest_name(v, accepted)) reason += suggestion_text({*c});
    fail(qkey, &n, reason);
  }

  void check_range(const std::string& qkey, const toml::node& n, double v, const Range& r) const {
    const bool lo_ok = r.lo_open ? v > r.lo : v >= r.lo;
    const bool hi_ok = r.hi_open ? v < r.hi : v <= r.hi;
    if (lo_ok && hi_ok) return;
    auto num = [](double x) {
      std::string s = format_double(x);
      if (s.size() > 2 && s.compare(s.size() - 2, 2, ".0") == 0) s.resize(s.size() - 2);
      return s;
    };
    std::string reason;
    if (std::isinf(r.hi)) {
      if (r.lo == 0.0 && r.lo_open) reason = "must be positive (> 0)";
      else if (r.lo == 0.0) reason = "must not be negative (>= 0)";
      else reason = std::string("must be ") + (r.lo_open ? "> " : ">= ") + num(r.lo);
    } else {
      reason = std::string("must be in ") + (r.lo_open ? "(" : "[") + num(r.lo) + ", " + num(r.hi) +
               (r.hi_open ? ")" : "]");
    }
    fail(qkey, &n, reason);
  }

  // Checks that tie several keys together; run after every key was read.
  void check_relations(const toml::table& root, const Config& c) const {
    const auto num = format_double;
    // Names the key; its value is the one written (file or --set) or else the default.
    auto fail_rel = [&](const char* section, const char* key, const std::string& value, const std::string& reason) {
      const std::string qkey = std::string(section) + "." + key;
      if (const toml::node* n = root.at_path(qkey).node()) fail(qkey, n, reason);
      throw ConfigError(qkey, value, reason + " (default value)");
    };

    if (!(c.sheave.hub_radius < c.sheave.outer_radius))
      fail_rel("sheave", "hub_radius", num(c.sheave.hub_radius),
               "must be < sheave.outer_radius = " + num(c.sheave.outer_radius));
    if (!(c.rocker.radius > c.rocker.half_distance / 2))
      fail_rel("rocker", "radius", num(c.rocker.radius),
               "must be > rocker.half_distance / 2 = " + num(c.rocker.half_distance / 2));
    if (!(c.chain.plate_spread < c.pin.length))
      fail_rel("chain", "plate_spread", num(c.chain.plate_spread), "must be < pin.length = " + num(c.pin.length));
    if (!(c.run.t_end >= c.integrator.step))
      fail_rel("run", "t_end", num(c.run.t_end), "must be >= integrator.step = " + num(c.integrator.step));
    if (!(c.run.sample_interval >= c.integrator.step))
      fail_rel("run", "sample_interval", num(c.run.sample_interval),
               "must be >= integrator.step = " + num(c.integrator.step));
    if (c.run.snapshot_interval != 0.0 && !(c.run.snapshot_interval >= c.integrator.step))
      fail_rel("run", "snapshot_interval", num(c.run.snapshot_interval),
               "must be 0 (off) or >= integrator.step = " + num(c.integrator.step));
    // A run must be able to count its steps (docs/cli.md, "The run's contract"): at most 2^52
    // (the clock's times stay exact), and sub-steps that a step can finish. (That the step
    // divides the intervals, check_step_grid.)
    const double grid = grid_step(c);
    if (!(c.run.t_end / grid <= kMaxRunSteps))
      fail_rel("run", "t_end", num(c.run.t_end),
               "is " + num(c.run.t_end / grid) + " steps of " + num(grid) + " s, more than a run can count (2^52)");
    if (c.integrator.method != IntegratorMethod::rk4) {
      const auto subs = [&](const char* key, double sub, bool on) {
        if (!on || c.integrator.step / sub <= kMaxSubsteps) return;
        char n[32];
        std::snprintf(n, sizeof n, "%.0f", std::ceil(c.integrator.step / sub));
        fail_rel("integrator", key, num(sub),
                 std::string("gives ") + n + " sub-steps per step of integrator.step = " + num(c.integrator.step) +
                     " s, more than " + std::to_string(kMaxSubsteps) + ": a step could not finish");
      };
      subs("startup_step", c.integrator.startup_step, c.integrator.startup_time > 0);
      subs("settle_step", c.integrator.settle_step, c.integrator.settle_time != 0);
    }
    if (c.integrator.w_segments != 0 && (c.integrator.w_segments < 3 || 2 * c.integrator.w_segments > c.chain.links))
      fail_rel("integrator", "w_segments", std::to_string(c.integrator.w_segments),
               "must be 0 (the block LU's two sweeps) or from 3 to half of chain.links = " +
                   std::to_string(c.chain.links) + " (each segment holds a separator and at least one link)");
    if (c.integrator.w_k_every % c.integrator.w_every != 0)
      fail_rel("integrator", "w_k_every", std::to_string(c.integrator.w_k_every),
               "must be a multiple of integrator.w_every = " + std::to_string(c.integrator.w_every) +
                   " (the stiffness is taken when the matrix is rebuilt)");
    if (c.controller.clamping_safety > 0 && (c.controller.kp > 0 || c.controller.ki > 0))
      fail_rel("controller", c.controller.kp > 0 ? "kp" : "ki", num(c.controller.kp > 0 ? c.controller.kp : c.controller.ki),
               "kp and ki act on F1 alone (controller.clamping_safety = 0); with clamping_safety > 0 the PI "
               "sets ln(F1/F2): give controller.shift_kp and controller.shift_ki instead");
    if (c.controller.clamping_safety == 0 && (c.controller.shift_kp > 0 || c.controller.shift_ki > 0))
      fail_rel("controller", c.controller.shift_kp > 0 ? "shift_kp" : "shift_ki",
               num(c.controller.shift_kp > 0 ? c.controller.shift_kp : c.controller.shift_ki),
               "acts only with the slip-safe clamping: give controller.clamping_safety > 0 (or use kp and ki)");
    const std::string links_range = "must be in [0, chain.links) = [0, " + std::to_string(c.chain.links) + ")";
    if (c.run.tracked_pin >= c.chain.links) fail_rel("run", "tracked_pin", std::to_string(c.run.tracked_pin), links_range);
    if (c.run.tracked_link >= c.chain.links) fail_rel("run", "tracked_link", std::to_string(c.run.tracked_link), links_range);
  }

 private:
  const std::string& origin_;
  const std::map<std::string, std::string>& override_text_;
  const std::map<std::string, std::string>& shortcuts_;
  std::vector<ConfigError> errors_;
};

// ---- overrides --------------------------------------------------------------------------

std::string trim(std::string_view s) {
  const auto b = s.find_first_not_of(" \t\r\n");
  if (b == std::string_view::npos) return {};
  const auto e = s.find_last_not_of(" \t\r\n");
  return std::string(s.substr(b, e - b + 1));
}

// Parses `text` as one TOML value; nullopt if it is not one.
std::optional<toml::table> parse_value(const std::string& text, std::string* error) {
  try {
    toml::table t = toml::parse("v = " + text + "\n", std::string_view{"--set"});
    if (t.size() != 1 || !t.contains("v")) {
      if (error) *error = "not a single TOML value";
      return std::nullopt;
    }
    return t;
  } catch (const toml::parse_error& e) {
    if (error) *error = std::string(e.description());
    return std::nullopt;
  }
}

// Whether a '#' outside TOML's strings would make the rest of `text` a comment (which TOML
// drops silently: --set geometry.ratio=0.9#x would read 0.9).
bool has_comment(const std::string& text) {
  char in = 0;  // the quote of the string we are in
  for (std::size_t i = 0; i < text.size(); ++i) {
    const char ch = text[i];
    if (in) {
      if (ch == '\\' && in == '"') ++i;
      else if (ch == in) in = 0;
    } else if (ch == '"' || ch == '\'') {
      in = ch;
    } else if (ch == '#') {
      return true;
    }
  }
  return false;
}

void apply_override(toml::table& root, const std::string& raw, std::map<std::string, std::string>& override_text) {
  // A malformed override is named as the option and its text, quoted (it may be empty).
  if (raw.find('=') == std::string::npos)
    throw ConfigError("--set", "'" + raw + "'", "malformed override: expected section.key=value (no '=')");
  const auto eq = raw.find('=');
  const std::string qkey = trim(std::string_view(raw).substr(0, eq));
  const std::string value = trim(std::string_view(raw).substr(eq + 1));
  const auto dot = qkey.find('.');
  if (dot == std::string::npos || dot == 0 || dot + 1 == qkey.size())
    throw ConfigError("--set", "'" + raw + "'", "malformed override: expected section.key=value (key must be section.key)");
  if (value.empty())
    throw ConfigError("--set", "'" + raw + "'", "malformed override: expected section.key=value (empty value)");
  const std::string section = qkey.substr(0, dot);
  const std::string key = qkey.substr(dot + 1);
  if (has_comment(value))
    throw ConfigError(qkey, value, "a '#' outside quotes, where TOML would drop the rest as a comment (quote a string)");
  std::string error;
  auto parsed = parse_value(value, &error);
  // A bare word is taken as a string (friction.law=smooth). For a numeric key this makes
  // the type check report "expected a number, got a string" with the value as written.
  if (!parsed) parsed = parse_value(quote(value), nullptr);
  if (!parsed) throw ConfigError(qkey, value, "not a valid TOML value: " + error);
  toml::node* v = parsed->get("v");

  toml::node* sec = root.get(section);
  if (!sec) {
    root.insert(section, toml::table{});
    sec = root.get(section);
  }
  override_text[qkey] = value;
  if (!sec->is_table()) return;  // reported as an unknown top-level key by validation
  auto& tbl = *sec->as_table();
  v->visit([&](auto& x) { tbl.insert_or_assign(key, std::move(x)); });
}

// ---- resolved TOML ----------------------------------------------------------------------

// [[t, r], ...] as TOML writes it.
std::string profile_text(const std::vector<std::array<double, 2>>& p) {
  std::string out = "[";
  for (std::size_t i = 0; i < p.size(); ++i)
    out += (i ? ", [" : "[") + format_double(p[i][0]) + ", " + format_double(p[i][1]) + "]";
  return out + "]";
}

std::string resolved_toml(Config& cfg) {
  std::ostringstream os;
  os << "# cvt-engine resolved configuration: every key, defaults filled in (SI units)\n";
  std::string section;
  for (const auto& d : schema()) {
    if (section != d.section) {
      section = d.section;
      os << (section == section_names().front() ? "" : "\n") << "[" << section << "]\n";
    }
    os << d.key << " = ";
    switch (d.kind) {
      case Kind::real: os << format_double(*static_cast<double*>(d.ref(cfg))); break;
      case Kind::integer: os << *static_cast<int*>(d.ref(cfg)); break;
      case Kind::boolean: os << (*static_cast<bool*>(d.ref(cfg)) ? "true" : "false"); break;
      case Kind::method: os << quote(to_string(*static_cast<IntegratorMethod*>(d.ref(cfg)))); break;
      case Kind::law: os << quote(to_string(*static_cast<FrictionLaw*>(d.ref(cfg)))); break;
      case Kind::profile: os << profile_text(*static_cast<std::vector<std::array<double, 2>>*>(d.ref(cfg))); break;
    }
    if (*d.unit) os << "  # [" << d.unit << "]";
    os << "\n";
  }
  return os.str();
}

// Files (and checkpoints) written before integrator.startup_step replaced
// integrator.startup_substeps = n (sub-steps of step / n) still load: the key becomes
// startup_step = step / n, unless startup_step is given too.
void migrate_startup_substeps(toml::table& root) {
  toml::table* in = root.get_as<toml::table>("integrator");
  if (!in || !in->contains("startup_substeps")) return;
  const auto n = in->get("startup_substeps")->value<std::int64_t>();
  if (!n || *n < 1) return;  // left for the validator to name
  double step = Config{}.integrator.step;
  if (const toml::node* s = in->get("step"))
    if (auto v = s->value<double>()) step = *v;
  in->erase("startup_substeps");
  if (!in->contains("startup_step")) in->insert("startup_step", step / static_cast<double>(*n));
}

}  // namespace

Config parse_config(const std::string& toml_text, const std::vector<std::string>& overrides,
                    const std::string& origin, const std::map<std::string, std::string>& shortcuts) {
  toml::table root;
  try {
    root = toml::parse(std::string_view{toml_text}, std::string_view{origin});
  } catch (const toml::parse_error& e) {
    const auto& src = e.source();
    throw ConfigError("<file>", origin,
                      "TOML parse error at line " + std::to_string(src.begin.line) + ", column " +
                          std::to_string(src.begin.column) + ": " + std::string(e.description()));
  }

  std::map<std::string, std::string> override_text;
  for (const auto& o : overrides) apply_override(root, o, override_text);

  migrate_startup_substeps(root);
  Validator val(origin, override_text, shortcuts);
  val.check_unknown(root);

  Config cfg;
  for (const auto& d : schema()) {
    const toml::table* sec = root.get_as<toml::table>(d.section);
    if (!sec) continue;
    if (const toml::node* n = sec->get(d.key)) val.collect([&] { val.read_key(d, *n, cfg); });
  }
  val.throw_collected();
  if (cfg.ramp.load_time < 0) cfg.ramp.load_time = cfg.ramp.time;  // not given: the clamping's ramp
  if (cfg.integrator.settle_time < 0)  // not given: until both ramps have ended (ramps_end)
    cfg.integrator.settle_time = std::max(cfg.ramp.time, cfg.ramp.load_start + cfg.ramp.load_time);
  // The slip-safe clamping changes the clamping forces with the state: a W-method's
  // stiffness rebuilt seldom falls behind them (docs/studies.md, "The ratio controller"), so
  // with it the stiffness is rebuilt every 16 steps at most (a multiple of w_every).
  if (cfg.controller.enabled && cfg.controller.clamping_safety > 0 && cfg.integrator.w_every > 0 &&
      cfg.integrator.w_k_every > kSlipSafeStiffnessEvery)
    cfg.integrator.w_k_every =
        std::max(cfg.integrator.w_every, kSlipSafeStiffnessEvery / cfg.integrator.w_every * cfg.integrator.w_every);
  val.check_relations(root, cfg);

  cfg.resolved_toml = resolved_toml(cfg);
  return cfg;
}

std::string continuation_toml(const std::string& resolved_toml, bool any_t_end) {
  std::vector<std::string> fixed = {"run.max_wall=0"};
  if (any_t_end) fixed.push_back("run.t_end=1");
  return parse_config(resolved_toml, fixed, "the resolved configuration").resolved_toml;
}

Config load_config(const std::string& path, const std::vector<std::string>& overrides,
                   const std::map<std::string, std::string>& shortcuts) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) throw ConfigError::unreadable(path, "it is a folder");
  if (!std::filesystem::exists(path, ec)) throw ConfigError::unreadable(path, "no such file");
  // A FIFO or a device would block or never end: a configuration is a regular file, of a
  // configuration's size; a read error is an error, never an empty (default) configuration.
  if (!std::filesystem::is_regular_file(path, ec)) throw ConfigError::unreadable(path, "not a regular file");
  constexpr std::size_t kMaxConfigBytes = 64u << 20;
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) throw ConfigError::unreadable(path, std::strerror(errno));
  std::string text;
  char buf[1 << 16];
  std::size_t n = 0;
  while (text.size() <= kMaxConfigBytes && (n = std::fread(buf, 1, sizeof buf, f)) > 0) text.append(buf, n);
  const int err = std::ferror(f) ? errno : 0;
  std::fclose(f);
  if (err) throw ConfigError::unreadable(path, std::string("read error: ") + std::strerror(err));
  if (text.size() > kMaxConfigBytes) throw ConfigError::unreadable(path, "larger than 64 MiB: not a configuration");
  return parse_config(text, overrides, path, shortcuts);
}

}  // namespace cvt
