// Inputs that change in time (docs/config.md, "Inputs that change in time"): profiles of the
// drive speed, the load torque and the clamping forces, validated like every key and read
// from the configuration or a CSV file; the drive's angle is its speed's integral; a
// constant profile gives the constant key's bits; the energy balance closes while the
// inputs change.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include "engine/guards.hpp"
#include "engine/model/config.hpp"
#include "engine/model/model.hpp"
#include "engine/simulation.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

namespace fs = std::filesystem;

TEST(ProfileTest, ValueRateAndIntegralAgree) {
  const Config::Profile p = {{1e-3, 50.0}, {3e-3, 150.0}, {3e-3, 100.0}, {6e-3, 250.0}};
  EXPECT_EQ(profile_value(p, 0.0), 50.0);  // held before the first point
  EXPECT_DOUBLE_EQ(profile_value(p, 2e-3), 100.0);
  EXPECT_EQ(profile_value(p, 3e-3), 100.0);  // a step: the later point from its time on
  EXPECT_EQ(profile_value(p, 1.0), 250.0);   // held after the last
  EXPECT_DOUBLE_EQ(profile_rate(p, 2e-3), 5e4);
  EXPECT_EQ(profile_rate(p, 0.5e-3), 0.0);
  EXPECT_EQ(profile_rate(p, 7e-3), 0.0);
  // The integral's derivative is the value (central differences away from the points), and
  // its value at the points sums the trapezoids.
  for (double t : {0.5e-3, 1.5e-3, 2.7e-3, 4e-3, 5.9e-3, 8e-3}) {
    const double d = 1e-8;
    EXPECT_NEAR((profile_integral(p, t + d) - profile_integral(p, t - d)) / (2 * d), profile_value(p, t), 1e-5) << t;
  }
  EXPECT_DOUBLE_EQ(profile_integral(p, 6e-3), 50.0 * 1e-3 + 0.5 * (50 + 150) * 2e-3 + 0.5 * (100 + 250) * 3e-3);
}

TEST(ProfileTest, ProfilesAreValidatedLikeEveryKey) {
  const auto error = [](const std::string& set) {
    try {
      load_config(test::config_path("mini"), {set});
    } catch (const ConfigError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_NE(error("drive.speed_profile=[[0, 50], [1e-3, -5]]").find("the value must be positive"), std::string::npos);
  EXPECT_NE(error("load.torque_profile=[[2e-3, 5], [1e-3, 6]]").find("the times must not decrease"), std::string::npos);
  EXPECT_NE(error("clamping.driving_profile=[[0, 1e3], [0, 2e3]]").find("the times must increase"), std::string::npos);
  EXPECT_NE(error("load.torque_profile=[[0, 5, 6]]").find("[time, value] pair"), std::string::npos);
  EXPECT_NE(error("drive.speed_profile=[[-1, 5]]").find("the time must not be negative"), std::string::npos);
  EXPECT_NE(error("drive.speed_profile=\"no-such-file.csv\"").find("cannot read the profile file"), std::string::npos);
  EXPECT_EQ(error("load.torque_profile=[[0, 5], [1e-3, 5], [1e-3, 8]]"), "");  // a step of the load
}

TEST(ProfileTest, ACsvFileIsTheSameProfileAsTheArray) {
  const fs::path dir = fs::temp_directory_path() / ("cvt_profile_test_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  {
    std::ofstream f(dir / "speed.csv");
    f << "# a launch\r\ntime, speed\r\n0, 50\r\n\r\n2e-3, 50\r\n0.012, 209.4\r\n";
  }
  const std::string toml = "[drive]\nspeed_profile = \"speed.csv\"\n";
  {
    std::ofstream f(dir / "c.toml");
    f << toml;
  }
  const Config from_file = load_config((dir / "c.toml").string());
  const Config from_array = parse_config("[drive]\nspeed_profile = [[0, 50], [2e-3, 50], [0.012, 209.4]]\n");
  EXPECT_EQ(from_file.drive.speed_profile, from_array.drive.speed_profile);
  EXPECT_EQ(from_file.resolved_toml, from_array.resolved_toml) << "the resolved TOML holds the numbers";
  {
    std::ofstream f(dir / "speed.csv");
    f << "time, speed\n0, 50\n1e-3, fast\n";
  }
  try {
    load_config((dir / "c.toml").string());
    ADD_FAILURE() << "a bad line was read";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("speed.csv line 3"), std::string::npos) << e.what();
  }
  fs::remove_all(dir);
}

// A speed profile that holds drive.speed from t = 0 gives the constant key's bits.
TEST(ProfileTest, AConstantProfileGivesTheConstantKeysBits) {
  const Model a = build_model(load_config(test::config_path("mini"), {"run.t_end=2e-4"}));
  const Model b = build_model(load_config(test::config_path("mini"), {"run.t_end=2e-4", "drive.speed_profile=[[0, 209.4]]"}));
  Simulation sa(a), sb(b);
  for (int i = 0; i < 240; ++i) sa.step(a.cfg.integrator.step), sb.step(b.cfg.integrator.step);
  EXPECT_TRUE(sa.state() == sb.state());
}

// The launch (configs/launch.toml) through its clamping ramp and into its speed ramp: the
// inputs follow their profiles and the energy balance closes (the drive's work is its
// torque times its prescribed speed, the clamping's the forces' rates times the sheaves'
// positions).
TEST(ProfileTest, TheEnergyBalanceClosesWhileTheInputsChange) {
  const Model m = build_model(load_config(test::config_path("launch"), {"run.t_end=8e-3"}));
  Simulation sim(m);
  const double h = m.cfg.integrator.step;
  double worst = 0;
  for (long n = 1; n * h <= 8e-3 + 1e-12; ++n) {
    sim.step(h);
    if (n % 600 == 0) {
      const Sample s = sim.sample();
      worst = std::max(worst, std::abs(s.energy_residual) / energy_turnover(s));
      EXPECT_NEAR(s.load_torque, profile_value(m.cfg.load.torque_profile, s.t), 1e-9) << s.t;
      EXPECT_NEAR(s.clamp[0], profile_value(m.cfg.clamping.driving_profile, s.t), 1e-6) << s.t;
    }
  }
  const Sample s = sim.sample();
  EXPECT_GT(s.input_speed, 60.0) << "the drive sped up";
  EXPECT_LT(worst, 2e-3) << "the energy balance's residual, as a share of the energy turned over";
}

}  // namespace
}  // namespace cvt
