// run.until_steady (engine/run.cpp, docs/output.md "Until steady"): a run stops once the
// means over its last two windows agree and the summary's other criteria hold, or on gross
// slip, with t_end the bound; the summary names the criteria that held. On the mini model
// (a steady point and a slipping one) and, as a Slow test, on the reference model.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "engine/io/h5_writer.hpp"
#include "engine/run.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

RunResult run_until_steady(const std::string& config, std::vector<std::string> ov, const std::string& name) {
  ov.push_back("run.until_steady=true");
  const Model m = build_model(load_config(test::config_path(config), ov));
  const RunOptions o = test::quiet_run_options(name);
  RunResult r = run_simulation(m, o);
  // The two windows' means, read back from the file: they agree as the summary says.
  H5File f = H5File::open(o.out_path);
  const std::vector<double> t = f.read_doubles("/observables/output_torque/time"),
                            tq = f.read_doubles("/observables/output_torque/value");
  f.close();
  double a = 0, b = 0;
  long na = 0, nb = 0;
  const double w = r.steady_window, t1 = r.model_time, mid = t1 - w;
  for (std::size_t i = 0; i < t.size(); ++i)
    if (t[i] >= t1 - 2 * w - 1e-12) (t[i] < mid - 1e-12 ? (a += tq[i], ++na) : (b += tq[i], ++nb));
  if (r.stopped == "steady") {
    EXPECT_NEAR(a / na, b / nb, m.cfg.run.steady_tolerance * m.cfg.load.torque) << "the windows' means";
    EXPECT_NEAR(0.5 * (a / na + b / nb), r.output_torque, 1e-3 * m.cfg.load.torque);
  }
  test::remove_run_files(o.out_path);
  return r;
}

bool any_starts(const std::vector<std::string>& v, const std::string& head) {
  for (const auto& s : v)
    if (s.rfind(head, 0) == 0) return true;
  return false;
}

// The mini model with F1 = 11.3 kN holds its ratio under its 10 N m load: the run stops
// well before t_end, once two windows (two torsion periods each, whole meshing periods)
// fit after the ramp and agree.
TEST(UntilSteadyTest, MiniStopsWhenSteadyAndSaysWhichCriteriaHeld) {
  const RunResult r = run_until_steady("mini", {"clamping.driving=1.13e4", "run.t_end=0.05"}, "steady_mini");
  const Model m = build_model(load_config(test::config_path("mini")));
  EXPECT_EQ(r.status, "steady");
  EXPECT_EQ(r.stopped, "steady");
  EXPECT_TRUE(r.reasons.empty());
  EXPECT_EQ(r.steady_window, steady_window(m));
  EXPECT_GE(r.model_time, ramps_end(m.cfg) + 2 * r.steady_window - 1e-9);
  EXPECT_LT(r.model_time, 0.05);
  EXPECT_NEAR(r.window_start, r.model_time - 2 * r.steady_window, 2e-5);
  for (const char* c : {"no gross slip", "means over t = ", "ratio held", "torsion settled", "torque balance"})
    EXPECT_TRUE(any_starts(r.criteria, c)) << c;
  EXPECT_TRUE(r.efficiency_meaningful);
  // CVT theory: both free strands in tension, and the tight one's minus the slack one's is
  // what the driven pulley transmits, the output torque over its running radius; here
  // within 12 %: the mini's pitch spans 0.42 rad of its 19 mm radius, and a strand leaves
  // the polygon of its joints at a lever arm between R and R cos(p / R) = 0.91 R (the
  // reference model's 0.14 rad: below).
  EXPECT_GT(std::min(r.strand_upper, r.strand_lower), 0);
  const double theory = std::abs(r.output_torque) / m.pulley[1].running_radius;
  EXPECT_NEAR(std::abs(r.strand_upper - r.strand_lower), theory, 0.12 * theory)
      << "strands " << r.strand_upper << " / " << r.strand_lower << " N";
  // The window: two torsion periods (about 3.7 ms here) in whole meshing periods.
  const double t_mesh = m.cfg.chain.pitch / (m.cfg.drive.speed * m.pulley[0].running_radius);
  EXPECT_GE(r.steady_window, 2 * torsion_period(m) - 1e-12);
  EXPECT_LT(r.steady_window, 2 * torsion_period(m) + t_mesh);
  EXPECT_NEAR(std::remainder(r.steady_window / t_mesh, 1.0), 0.0, 1e-9);
}

// 40 N m on the mini model (its capacity 2 f0 F1 R1 / cos(beta) is about 35 N m): gross
// slip, named, and the run stops at the first check; the guard warned of it as it began.
TEST(UntilSteadyTest, MiniGrossSlipIsNamedAndStopsTheRun) {
  const RunResult r = run_until_steady("mini", {"load.torque=40", "run.t_end=0.05"}, "slip_mini");
  EXPECT_EQ(r.status, "slip");
  EXPECT_EQ(r.stopped, "slip");
  ASSERT_FALSE(r.reasons.empty());
  EXPECT_EQ(r.reasons.front().rfind("gross slip", 0), 0u) << r.reasons.front();
  EXPECT_GT(r.slip, 0.05);
  EXPECT_LT(r.model_time, 0.05);
  EXPECT_FALSE(r.efficiency_meaningful);
  EXPECT_TRUE(any_starts(r.warnings, "gross slip since t = ")) << (r.warnings.empty() ? "" : r.warnings.front());
}

// The torsion period against the two-inertia formula worked by hand for the reference
// model at ratio 1: J_a = 0.04, J_b = 0.05 kg m^2, k_a = k_b = 2e4 N m/rad give
// 0.002 lambda^2 - 2800 lambda + 4e8 = 0, lambda = 1.615e5 1/s^2, 15.6 ms.
TEST(UntilSteadyTest, TorsionPeriodIsTheLowestModeOfTheDriveLine) {
  const Model m = build_model(load_config(test::config_path("reference")));
  const double lambda = (2800 - std::sqrt(2800.0 * 2800 - 4 * 0.002 * 4e8)) / (2 * 0.002);
  EXPECT_NEAR(torsion_period(m), 2 * M_PI / std::sqrt(lambda), 1e-12);
  EXPECT_NEAR(torsion_period(m), 15.6e-3, 0.1e-3);
  const Model w = build_model(load_config(test::config_path("reference"), {"run.steady_window=0.01"}));
  EXPECT_EQ(steady_window(w), 0.01);
}

// The reference model at its steady operating point (configs/reference-steady.toml) from
// rest: steady before t_end = 0.3 s, its free strands' tensions apart by the output torque
// over the driven radius within 2 %.
TEST(UntilSteadyTest, SlowReferenceReachesSteady) {
  const RunResult r = run_until_steady("reference-steady", {"run.t_end=0.3"}, "steady_reference");
  EXPECT_EQ(r.status, "steady");
  EXPECT_EQ(r.stopped, "steady");
  EXPECT_LT(r.model_time, 0.3);
  EXPECT_NEAR(r.output_torque, 150.0, 3.0);
  const Model m = build_model(load_config(test::config_path("reference-steady")));
  const double theory = std::abs(r.output_torque) / m.pulley[1].running_radius;
  EXPECT_NEAR(std::abs(r.strand_upper - r.strand_lower), theory, 0.02 * theory)
      << "strands " << r.strand_upper << " / " << r.strand_lower << " N";
}

}  // namespace
}  // namespace cvt
