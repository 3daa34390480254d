// The scaling study: the Amdahl fit recovers a known serial fraction,
// and a small study measures every combination from the same state, ends in the serial
// bits, and writes its CSV and JSON.
#include <gtest/gtest.h>

#include <cmath>
#include <sstream>

#include <nlohmann/json.hpp>

#include "engine/studies/scale.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

TEST(ScaleTest, AmdahlFitRecoversAKnownSerialFraction) {
  for (double f : {0.0, 0.05, 0.3, 1.0}) {
    std::vector<int> p = {1, 2, 4, 8, 16};
    std::vector<double> s;
    for (int n : p) s.push_back(1.0 / (f + (1.0 - f) / n));
    EXPECT_NEAR(fit_amdahl(p, s), f, 1e-12) << f;
  }
  // Noisy speedups: the fit lies between the fractions each point implies alone.
  const std::vector<int> p = {2, 4};
  const std::vector<double> s = {1.6, 2.4};  // f = 0.25 and 0.222...
  const double f = fit_amdahl(p, s);
  EXPECT_GT(f, 2.0 / 9.0 - 1e-12);
  EXPECT_LT(f, 0.25 + 1e-12);
}

TEST(ScaleTest, SmallStudyOnTheMiniModel) {
  const Model m = test::model("mini");
  ScaleOptions o;
  o.threads = {1, 2};
  o.layouts = {"native", "package:2 numa:1 core:1 pu:1"};
  o.steps = 5;
  o.repeat = 2;
  o.warmup = 2e-6;
  std::vector<std::string> told;
  const auto rows = run_scaling_study(m, o, [&](const std::string& s) { told.push_back(s); });
  // serial; flowgraph x {1, 2} threads x 2 layouts; paper-omp x {1, 2}.
  ASSERT_EQ(rows.size(), 7u);
  EXPECT_EQ(rows[0].scheduler, "serial");
  EXPECT_DOUBLE_EQ(rows[0].speedup, 1.0);
  int synthetic = 0;
  for (const ScaleRow& r : rows) {
    EXPECT_TRUE(r.identical) << r.scheduler << " " << r.threads << " " << r.layout;
    EXPECT_GT(r.us_per_step, 0.0);
    EXPECT_GT(r.chain_us, 0.0);
    EXPECT_NEAR(r.efficiency, r.speedup / r.threads, 1e-12);
    EXPECT_GE(r.amdahl_serial_fraction, 0.0);
    EXPECT_LE(r.amdahl_serial_fraction, 1.0);
    if (r.scheduler == "paper-omp") EXPECT_GT(r.zero_gather_us, 0.0);  // its thread-local buffers
    else EXPECT_EQ(r.zero_gather_us, 0.0);
    synthetic += r.layout != "native";
  }
  EXPECT_EQ(synthetic, 2);
  EXPECT_EQ(told.size(), 1u + 2u * 7u);  // the warm-up, then each combination per repeat
  const std::string csv = scale_csv(rows);
  std::istringstream in(csv);
  std::string line;
  int lines = 0;
  std::getline(in, line);
  EXPECT_EQ(line.rfind("scheduler,layout,threads,steps,repeat,us_per_step,speedup,efficiency,chain_us,", 0), 0u);
  while (std::getline(in, line)) ++lines;
  EXPECT_EQ(lines, 7);
  const nlohmann::json j = nlohmann::json::parse(scale_json(rows, "mini"));
  EXPECT_EQ(j.at("config").get<std::string>(), "mini");
  ASSERT_EQ(j.at("rows").size(), rows.size());
  for (std::size_t i = 0; i < rows.size(); ++i) {
    EXPECT_EQ(j.at("rows")[i].at("threads").get<int>(), rows[i].threads);
    EXPECT_TRUE(j.at("rows")[i].contains("amdahl_serial_fraction"));
  }
}

}  // namespace
}  // namespace cvt
