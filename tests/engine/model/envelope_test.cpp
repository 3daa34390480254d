// The envelope (engine/model/envelope.cpp, docs/envelope.md): every shipped configuration
// and every point of the envelope study lies inside it; each key outside it gives one
// warning that names the key, the value and the range; the ratio range is where the chain
// can be placed; and a run outside is warned about, not refused.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "engine/model/envelope.hpp"
#include "engine/model/model.hpp"
#include "engine/studies/sweep.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

namespace fs = std::filesystem;

Config config(const std::string& name, const std::vector<std::string>& overrides = {}) {
  return load_config(test::config_path(name), overrides);
}

// The one warning of `c`, which must name `key` and every text of `names`.
void expect_one_warning(const Config& c, const std::string& key, const std::vector<std::string>& names) {
  const auto w = envelope_warnings(c);
  ASSERT_EQ(w.size(), 1u) << key << ": " << (w.empty() ? "no warning" : w[0] + (w.size() > 1 ? " | " + w[1] : ""));
  EXPECT_EQ(w[0].rfind(key + " = ", 0), 0u) << w[0];
  for (const auto& n : names) EXPECT_NE(w[0].find(n), std::string::npos) << "'" << n << "' not in: " << w[0];
}

TEST(EnvelopeTest, EveryShippedConfigurationLiesInsideIt) {
  int configs = 0;
  for (const auto& f : fs::directory_iterator(std::string(CVT_SOURCE_DIR) + "/configs")) {
    if (f.path().extension() != ".toml") continue;
    ++configs;
    const auto w = envelope_warnings(load_config(f.path().string()));
    EXPECT_TRUE(w.empty()) << f.path().filename() << ": " << (w.empty() ? "" : w[0]);
  }
  EXPECT_GE(configs, 6);
}

// Each point of the two points files is the model's base configuration with the point's keys.
TEST(EnvelopeTest, EveryPointOfTheEnvelopeStudyLiesInsideIt) {
  for (const char* model : {"reference", "mini"}) {
    const std::string dir = std::string(CVT_SOURCE_DIR) + "/configs/";
    const SweepPlan plan = SweepPlan::from_file(dir + "envelope-" + model + ".csv");
    const std::string base = std::string(model) == "mini" ? "mini" : "reference-steady";
    for (long i = 0; i < static_cast<long>(plan.points.size()); ++i) {
      const auto w = envelope_warnings(config(base, plan.overrides(i)));
      EXPECT_TRUE(w.empty()) << model << " point " << i + 1 << " (" << plan.label(i) << "): " << (w.empty() ? "" : w[0]);
    }
  }
}

// The shipped 50-point map (configs/map-reference.csv) with its recipe's keys: every point
// inside the envelope; 5 ratios x 2 speeds x 5 loads; with --continuation one point per ratio and
// speed from rest (its 100 N m), the other 40 continued, each from a load of its own ratio
// and speed.
TEST(EnvelopeTest, TheShippedMapLiesInsideItAndContinuesAlongTheLoads) {
  const SweepPlan plan = SweepPlan::from_file(std::string(CVT_SOURCE_DIR) + "/configs/map-reference.csv");
  ASSERT_EQ(plan.points.size(), 50u);
  const std::vector<std::string> recipe = {"controller.enabled=true", "controller.clamping_safety=2",
                                           "controller.shift_kp=100", "controller.shift_ki=1000",
                                           "clamping.driving=12.3e3", "clamping.driven=1e4"};
  std::vector<double> loads;
  for (long i = 0; i < 50; ++i) {
    std::vector<std::string> ov = recipe;
    for (const auto& o : plan.overrides(i)) ov.push_back(o);
    const Config c = config("reference-steady", ov);
    const auto w = envelope_warnings(c);
    EXPECT_TRUE(w.empty()) << "point " << i + 1 << " (" << plan.label(i) << "): " << (w.empty() ? "" : w[0]);
    loads.push_back(c.load.torque);
  }
  std::vector<long> order;
  const std::vector<long> parent = continuation_parents(plan, loads, &order);
  long roots = 0;
  for (long i = 0; i < 50; ++i) {
    const long p = parent[static_cast<std::size_t>(i)];
    if (p < 0) {
      ++roots;
      EXPECT_EQ(loads[static_cast<std::size_t>(i)], 100.0) << "point " << i + 1;
      continue;
    }
    EXPECT_EQ(plan.points[static_cast<std::size_t>(p)][0], plan.points[static_cast<std::size_t>(i)][0]);
    EXPECT_EQ(plan.points[static_cast<std::size_t>(p)][2], plan.points[static_cast<std::size_t>(i)][2]);
  }
  EXPECT_EQ(roots, 10);
}

// The study spreads over the envelope: both ends of the ratios, light and heavy loads, low
// and high speeds, on each model.
TEST(EnvelopeTest, TheEnvelopeStudySpreadsOverBothModelsRatiosLoadsAndSpeeds) {
  long points = 0;
  for (const char* model : {"reference", "mini"}) {
    const SweepPlan plan = SweepPlan::from_file(std::string(CVT_SOURCE_DIR) + "/configs/envelope-" + model + ".csv");
    const std::string base = std::string(model) == "mini" ? "mini" : "reference-steady";
    const Envelope whole = envelope(config(base));
    bool low_ratio = false, high_ratio = false, light = false, heavy = false, slow = false, fast = false;
    for (long i = 0; i < static_cast<long>(plan.points.size()); ++i) {
      const Config c = config(base, plan.overrides(i));
      const Envelope e = envelope(c);
      const double share = e.load / e.slip_limit;
      // Near an end: at least three quarters of the way from 1 to it (in ln of the ratio).
      low_ratio |= std::log(c.geometry.ratio) <= 0.75 * std::log(whole.ratio_min);
      high_ratio |= std::log(c.geometry.ratio) >= 0.75 * std::log(whole.ratio_max);
      light |= share < 0.15;
      heavy |= share > 0.4;
      slow |= c.drive.speed <= 100;
      fast |= c.drive.speed >= 500;
      EXPECT_EQ(c.controller.target_ratio, c.geometry.ratio) << model << " point " << i + 1;
    }
    EXPECT_TRUE(low_ratio && high_ratio) << model << ": ratios near both ends of " << whole.ratio_min << " .. "
                                         << whole.ratio_max;
    EXPECT_TRUE(light && heavy) << model;
    EXPECT_TRUE(slow && fast) << model;
    points += static_cast<long>(plan.points.size());
  }
  EXPECT_GE(points, 24);
}

// The ratio range is where the chain can be placed: just inside each end the model builds,
// just outside it is refused.
TEST(EnvelopeTest, TheRatioRangeIsWhereTheChainCanBePlaced) {
  for (const char* name : {"reference", "mini"}) {
    const Envelope e = envelope(config(name));
    ASSERT_LT(e.ratio_min, 1.0) << name;
    ASSERT_GT(e.ratio_max, 1.0) << name;
    for (const double r : {e.ratio_min * 1.001, e.ratio_max * 0.999})
      EXPECT_NO_THROW(build_model(config(name, {"geometry.ratio=" + std::to_string(r)}))) << name << " at " << r;
    for (const double r : {e.ratio_min * 0.999, e.ratio_max * 1.001})
      EXPECT_THROW(build_model(config(name, {"geometry.ratio=" + std::to_string(r)})), ConfigError)
          << name << " at " << r;
  }
}

// The ratio ends are remembered per chain: asked in turn for two chains and for a chain
// whose centre distance differs, each gets its own ends, the same as when asked first.
TEST(EnvelopeTest, EachChainKeepsItsOwnRatioRange) {
  const Envelope ref = envelope(config("reference")), mini = envelope(config("mini"));
  const Envelope wide = envelope(config("reference", {"geometry.centre_distance=0.165"}));
  EXPECT_NE(ref.ratio_min, mini.ratio_min);
  EXPECT_NE(ref.ratio_min, wide.ratio_min);
  for (int round = 0; round < 2; ++round) {
    EXPECT_EQ(envelope(config("reference")).ratio_min, ref.ratio_min);
    EXPECT_EQ(envelope(config("reference")).ratio_max, ref.ratio_max);
    EXPECT_EQ(envelope(config("mini")).ratio_max, mini.ratio_max);
    EXPECT_EQ(envelope(config("reference", {"geometry.centre_distance=0.165"})).ratio_max, wide.ratio_max);
    // The load, the speed and the ratio itself do not change the chain's range.
    EXPECT_EQ(envelope(config("reference", {"load.torque=20", "geometry.ratio=1.2"})).ratio_min, ref.ratio_min);
  }
}

// The slip limit estimate is the Coulomb capacity 2 f0 F R2 / cos(beta): it grows with f0
// and with the smaller clamping force; with the slip-safe controller it is S times the
// load wherever that exceeds what the least force holds.
TEST(EnvelopeTest, TheSlipLimitIsTheCoulombCapacityOfTheSmallerForce) {
  const Envelope e = envelope(config("reference"));
  const Model m = build_model(config("reference"));
  EXPECT_DOUBLE_EQ(e.R2, m.pulley[1].running_radius);
  EXPECT_DOUBLE_EQ(e.clamping, std::min(m.cfg.clamping.driving, m.cfg.clamping.driven));
  EXPECT_NEAR(e.slip_limit, 2 * m.cfg.friction.f0 * e.clamping * e.R2 / m.cos_beta, 1e-9 * e.slip_limit);
  const Envelope twice_f0 = envelope(config("reference", {"friction.f0=0.1"}));
  EXPECT_NEAR(twice_f0.slip_limit / e.slip_limit, 0.1 / 0.09, 1e-12);
  const Envelope other_force = envelope(config("reference", {"clamping.driven=20e3"}));
  EXPECT_NEAR(other_force.slip_limit / e.slip_limit, 20.0 / 25.0, 1e-12);
  const Envelope ctrl = envelope(config("reference-shift"));
  EXPECT_NEAR(ctrl.slip_limit, 2.0 * ctrl.load, 1e-9 * ctrl.slip_limit);  // S = 2
  const Envelope floor = envelope(config("reference-shift", {"load.torque=20"}));
  EXPECT_DOUBLE_EQ(floor.clamping, 10e3);
}

TEST(EnvelopeTest, EachKeyOutsideGivesItsWarning) {
  expect_one_warning(config("reference", {"drive.speed=40"}), "drive.speed", {"40", "50 to 600 rad/s"});
  expect_one_warning(config("reference", {"drive.speed=700"}), "drive.speed", {"700", "50 to 600 rad/s"});
  expect_one_warning(config("mini", {"friction.f0=0.04"}), "friction.f0", {"0.04", "0.05 to 0.12"});
  expect_one_warning(config("mini", {"friction.f0=0.13"}), "friction.f0", {"0.13", "0.05 to 0.12"});
  const Envelope ref = envelope(config("reference"));
  expect_one_warning(config("reference", {"load.torque=" + std::to_string(1.05 * ref.slip_limit)}), "load.torque",
                     {"above the slip limit", "slip grossly"});
  expect_one_warning(config("reference", {"load.torque=" + std::to_string(0.09 * ref.slip_limit)}), "load.torque",
                     {"below 10 %", "lightest"});
  expect_one_warning(config("reference", {"load.torque=0"}), "load.torque", {"no load"});
  // The build refuses these ratios; the envelope names them too.
  expect_one_warning(config("reference", {"geometry.ratio=" + std::to_string(1.01 * ref.ratio_max)}),
                     "geometry.ratio", {"ratios the pulleys allow"});
  expect_one_warning(config("reference-shift", {"controller.target_profile=[[0.1, 1.0], [0.2, 0.3]]"}),
                     "controller.target_profile", {"0.3"});
  expect_one_warning(config("reference", {"controller.enabled=true", "controller.target_ratio=3"}),
                     "controller.target_ratio", {"3"});
  expect_one_warning(config("reference", {"friction.law=none"}), "friction.law", {"no torque"});
}

// Just inside each bound gives no warning: the bounds are where the text says.
TEST(EnvelopeTest, JustInsideEachBoundGivesNoWarning) {
  const Envelope ref = envelope(config("reference"));
  for (const std::string& o :
       {std::string("drive.speed=50"), std::string("drive.speed=600"),
        "load.torque=" + std::to_string(0.99 * ref.slip_limit), "load.torque=" + std::to_string(0.11 * ref.slip_limit)}) {
    const auto w = envelope_warnings(config("reference", {o}));
    EXPECT_TRUE(w.empty()) << o << ": " << (w.empty() ? "" : w[0]);
  }
  // The mini's load lies within the slip limits of both ends of f0 (the reference's 150 N m
  // is above the limit at f0 = 0.05).
  for (const std::string o : {"friction.f0=0.05", "friction.f0=0.12"}) {
    const auto w = envelope_warnings(config("mini", {o}));
    EXPECT_TRUE(w.empty()) << o << ": " << (w.empty() ? "" : w[0]);
  }
}

// A run outside the envelope runs to its end, the warning on stderr first.
TEST(EnvelopeTest, ARunOutsideIsWarnedAboutNotRefused) {
  const fs::path dir = fs::temp_directory_path() / ("cvt_envelope_test_" + std::to_string(getpid()));
  fs::create_directories(dir);
  const std::string cmd = "cd " + test::shell_quote(dir.string()) + " && " + test::shell_quote(CVT_ENGINE_EXE) +
                          " run " + test::shell_quote(test::config_path("mini")) +
                          " --set drive.speed=700 --t-end 2e-5 --quiet --out out.h5 2>stderr.txt";
  const int status = std::system(cmd.c_str());
  std::ifstream in(dir / "stderr.txt");
  std::stringstream err;
  err << in.rdbuf();
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << err.str();
  EXPECT_NE(err.str().find("cvt-engine: warning: drive.speed = 700 rad/s is outside the envelope"), std::string::npos)
      << err.str();
  EXPECT_TRUE(fs::exists(dir / "out.h5"));
  fs::remove_all(dir);
}

// Three of the mini's envelope points (ratio 1, light and slow; ratio 1, heavy and fast;
// the high end of the ratios, heavy and slow), through the sweep from rest: each ends
// steady or in gross slip, none not steady, blown up or in error.
TEST(EnvelopeTest, SlowMiniPointsAreSteadyOrSlip) {
  const fs::path dir = fs::temp_directory_path() / ("cvt_envelope_slow_" + std::to_string(getpid()));
  fs::create_directories(dir);
  std::ifstream in(std::string(CVT_SOURCE_DIR) + "/configs/envelope-mini.csv");
  std::vector<std::string> rows;
  std::string header;
  for (std::string l; std::getline(in, l);) {
    if (l.empty() || l[0] == '#') continue;
    if (header.empty()) header = l;
    else rows.push_back(l);
  }
  ASSERT_EQ(rows.size(), 12u);
  const auto starts = [](const std::string& row, const std::string& head) { return row.rfind(head, 0) == 0; };
  std::vector<std::string> chosen;
  for (const auto& r : rows)
    if (starts(r, "1.0,1.0,60,1.5,") || starts(r, "1.0,1.0,550,10,") || starts(r, "1.55,1.55,60,10,")) chosen.push_back(r);
  ASSERT_EQ(chosen.size(), 3u);
  {
    std::ofstream out(dir / "points.csv");
    out << header << "\n";
    for (const auto& r : chosen) out << r << "\n";
  }
  const std::string cmd = "cd " + test::shell_quote(dir.string()) + " && " + test::shell_quote(CVT_ENGINE_EXE) +
                          " sweep " + test::shell_quote(test::config_path("mini")) +
                          " --points points.csv --set run.t_end=0.2 --out sub --threads 2 >stdout.txt 2>stderr.txt";
  const int status = std::system(cmd.c_str());
  std::ifstream log(dir / "stdout.txt"), csv(dir / "sub.csv");
  std::stringstream text;
  text << log.rdbuf();
  ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << text.str();
  std::string head;
  std::getline(csv, head);
  // The status column's index in the header.
  int column = 0;
  for (std::size_t at = 0, next; (next = head.find(',', at)) != std::string::npos && head.substr(at, next - at) != "status";
       at = next + 1)
    ++column;
  int points = 0;
  for (std::string l; std::getline(csv, l);) {
    std::stringstream cells(l);
    std::string cell;
    for (int k = 0; k <= column; ++k) std::getline(cells, cell, ',');
    EXPECT_TRUE(cell == "steady" || cell == "slip") << "point " << points + 1 << ": " << l;
    ++points;
  }
  EXPECT_EQ(points, 3) << text.str();
  std::printf("%s", text.str().c_str());
  fs::remove_all(dir);
}

}  // namespace
}  // namespace cvt
