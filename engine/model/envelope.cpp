// docs/envelope.md: the envelope and its warnings.
#include "engine/model/envelope.hpp"

#include <array>
#include <cmath>
#include <cstdio>
#include <mutex>
#include <vector>

#include "engine/model/geometry.hpp"

namespace cvt {
namespace {

std::string num(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.4g", v);
  return b;
}

// The end of the ratios the chain can be placed at, from the placeable ratio `inside`
// towards `outside` (which is not placeable), to 1e-4 of the ratio.
double ratio_end(ChainPathParams gp, double inside, double outside) {
  while (std::abs(outside - inside) > 1e-4 * inside) {
    gp.ratio = 0.5 * (inside + outside);
    (chain_fits(gp) ? inside : outside) = gp.ratio;
  }
  return inside;
}

// Both ends of the ratios from the placeable ratio `inside`, remembered for the last few
// chains: a run asks once for its warnings and once for its summary, and every point of a
// sweep over anything but the chain's geometry asks for the same ends (each bisection
// places the chain some thirty times).
std::array<double, 2> ratio_ends(const ChainPathParams& gp, double inside, double lo, double hi) {
  using Key = std::array<double, 8>;
  const Key key = {gp.centre_distance, static_cast<double>(gp.links), gp.plate_rest, gp.kappa,
                   gp.rocker_radius, gp.r_min, gp.r_max, inside};
  static std::mutex mutex;
  static std::vector<std::pair<Key, std::array<double, 2>>> known;  // the newest last
  {
    const std::lock_guard<std::mutex> lock(mutex);
    for (const auto& [k, ends] : known)
      if (k == key) return ends;
  }
  const std::array<double, 2> ends = {ratio_end(gp, inside, lo), ratio_end(gp, inside, hi)};
  const std::lock_guard<std::mutex> lock(mutex);
  if (known.size() == 8) known.erase(known.begin());
  known.emplace_back(key, ends);
  return ends;
}

std::string range(double lo, double hi, const char* unit) {
  return num(lo) + " to " + num(hi) + (*unit ? " " : "") + unit;
}

}  // namespace

Envelope envelope(const Config& c) {
  Envelope e;
  ChainPathParams gp = chain_path_params(c);
  // The admissible joint radii alone bound the ratio to r_min/r_max .. r_max/r_min, where
  // nothing is placeable; the chain's length and the centre distance narrow it.
  const double widest_lo = gp.r_min / gp.r_max, widest_hi = gp.r_max / gp.r_min;
  double inside = std::nan("");
  for (const double r : {1.0, c.geometry.ratio}) {
    gp.ratio = r;
    if (std::isnan(inside) && chain_fits(gp)) inside = r;
  }
  if (std::isnan(inside)) {
    e.ratio_min = e.ratio_max = inside;
  } else {
    const std::array<double, 2> ends = ratio_ends(gp, inside, widest_lo, widest_hi);
    e.ratio_min = ends[0], e.ratio_max = ends[1];
  }

  const double cos_beta = std::cos(c.sheave.cone_angle * M_PI / 180.0);
  gp.ratio = c.geometry.ratio;
  if (chain_fits(gp)) e.R2 = place_chain(gp).R2;
  e.load = std::abs(c.load.torque) + c.load.speed_coefficient * std::abs(c.drive.speed) / c.geometry.ratio;
  e.clamping = std::min(c.clamping.driving, c.clamping.driven);
  const double S = c.controller.clamping_safety;
  if (c.controller.enabled && S > 0 && e.R2 > 0)
    e.clamping = std::max(e.clamping, S * e.load * cos_beta / (2 * c.friction.f0 * e.R2));
  e.slip_limit = 2 * c.friction.f0 * e.clamping * e.R2 / cos_beta;
  return e;
}

std::vector<std::string> envelope_warnings(const Config& c) {
  const Envelope e = envelope(c);
  std::vector<std::string> w;
  const auto ratio = [&](const char* key, double r) {
    if (std::isnan(e.ratio_min) || (r >= e.ratio_min && r <= e.ratio_max)) return;
    w.push_back(std::string(key) + " = " + num(r) + " is outside the ratios the pulleys allow (" +
                range(e.ratio_min, e.ratio_max, "") + "): the chain's joints would run past the hub or the "
                "rim of a sheave, where the model has no contact");
  };
  ratio("geometry.ratio", c.geometry.ratio);
  if (c.controller.enabled) {
    if (c.controller.target_profile.empty()) ratio("controller.target_ratio", c.controller.target_ratio);
    for (const auto& p : c.controller.target_profile) ratio("controller.target_profile", p[1]);
  }
  const auto speed = [&](const std::string& key, double v) {
    if (!(v >= e.speed_min && v <= e.speed_max))
      w.push_back(key + " = " + num(v) + " rad/s is outside the envelope (" + range(e.speed_min, e.speed_max, "rad/s") +
                  "): the time step, the W matrix's rebuilds and the steady criteria are not checked at this speed");
  };
  if (c.drive.speed_profile.empty()) speed("drive.speed", c.drive.speed);
  for (const auto& p : c.drive.speed_profile) speed("drive.speed_profile", p[1]);
  if (c.friction.law == FrictionLaw::none) {
    w.push_back("friction.law = none: the chain transmits no torque by friction; the envelope's loads and "
                "friction coefficients (" + range(e.f0_min, e.f0_max, "") + ") do not apply");
    return w;
  }
  if (!(c.friction.f0 >= e.f0_min && c.friction.f0 <= e.f0_max))
    w.push_back("friction.f0 = " + num(c.friction.f0) + " is outside the envelope (" + range(e.f0_min, e.f0_max, "") +
                "): the creep, the slip limit and the efficiency are not checked at this friction coefficient");
  if (!(e.slip_limit > 0)) return w;
  const std::string limit = "the slip limit estimate 2 f0 F R2 / cos(beta) = 2 x " + num(c.friction.f0) + " x " +
                            num(1e-3 * e.clamping) + " kN x " + num(1e3 * e.R2) + " mm / cos " + num(c.sheave.cone_angle) +
                            " deg = " + num(e.slip_limit) + " N m";
  const std::string load = "load.torque = " + num(c.load.torque) + " N m" +
                           (c.load.speed_coefficient != 0 ? " (" + num(e.load) + " N m with the speed term)" : "");
  if (e.load > e.slip_limit)
    w.push_back(load + " is above " + limit + ", the envelope's heaviest load: the chain is expected to slip "
                "grossly, and no steady state is checked there");
  else if (e.load < e.light_share * e.slip_limit)
    w.push_back(load + " is below " + num(100 * e.light_share) + " % of " + limit + ", the envelope's lightest "
                "load: " + (e.load > 0 ? "the chain is clamped for " + num(e.slip_limit / e.load) + " times its load"
                                    : std::string("the chain carries no load")) +
                ", and the efficiency and the steady criteria (the drive line's torsion swing against a small load) "
                "are not checked there");
  return w;
}

}  // namespace cvt
