// The end-of-run summary's verdicts on synthetic channels (a steady operating point, a
// ramp, drift, ringing, shifting, gross slip), and the run's guards (energy balance, RK4
// step against its stability limit).
#include "engine/summary.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <functional>
#include <sstream>
#include <type_traits>
#include <variant>

#include <nlohmann/json.hpp>

#include "engine/run.hpp"
#include "engine/simulation.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

bool has_reason(const RunSummary& s, const std::string& what) {
  for (const auto& r : s.reasons)
    if (r.find(what) != std::string::npos) return true;
  return false;
}

std::string reasons(const RunSummary& s) {
  std::string out;
  for (const auto& r : s.reasons) out += "\n  " + r;
  return out;
}

// The reference model's operating point as channels: 20 ms sampled every 1e-5 s, the loads
// ramped over the config's ramp time, a meshing ripple of +-5 % on the output torque, and
// `tweak(t, sample)` to spoil it. The power the tweak adds to the output is dissipated,
// or with `stored` held in the drive line (as a swing of its inertias holds it: the stored
// energy W_in - W_out - D swings with it).
struct Synthetic {
  const Model m = test::model("reference");
  SummaryChannels ch;

  explicit Synthetic(const std::function<void(double, Sample&)>& tweak = {}, double t_end = 20e-3,
                     bool stored = false) {
    const double w1 = m.cfg.drive.speed, load = m.cfg.load.torque, ratio = 1.0, slip = 0.01;
    const double t_mesh = m.cfg.chain.pitch / (w1 * m.pulley[0].running_radius);
    double win = 0, wout = 0, wd = 0;
    for (int i = 0; i * 1e-5 <= t_end * (1 + 1e-12); ++i) {
      Sample s;
      s.t = i * 1e-5;
      const double ramp = std::min(1.0, s.t / m.cfg.ramp.time);
      s.geometric_ratio = ratio;
      s.speed_ratio = ratio / (1 - slip);
      s.input_speed = w1;
      s.output_speed = w1 / s.speed_ratio;
      s.load_torque = load * ramp;
      s.output_torque = s.load_torque * (1 + 0.05 * std::sin(2 * M_PI * s.t / t_mesh));
      s.input_torque = s.load_torque / s.speed_ratio / 0.97;
      s.clamp[0] = m.cfg.clamping.driving * ramp;
      s.clamp[1] = m.cfg.clamping.driven * ramp;
      const double pout0 = s.output_torque * s.output_speed;
      if (tweak) tweak(s.t, s);
      const double pin = s.input_torque * s.input_speed, pout = s.output_torque * s.output_speed;
      win += pin * 1e-5, wout += pout * 1e-5, wd += (pin - (stored ? pout0 : pout)) * 1e-5;
      s.work_input = win, s.work_output = wout, s.work_dissipated = wd;
      ch.push(s);
    }
  }
  RunSummary summary() const {
    RunSummary s;
    summarize(m, ch, s);
    return s;
  }
};

TEST(SummaryTest, SteadyOperatingPoint) {
  const RunSummary s = Synthetic().summary();
  EXPECT_EQ(s.status, "steady") << reasons(s);
  EXPECT_TRUE(s.efficiency_meaningful);
  EXPECT_NEAR(s.efficiency, 0.97, 0.005);
  EXPECT_NEAR(s.loss_efficiency, 0.97, 0.005);
  EXPECT_NEAR(s.slip, 0.01, 1e-9);
  EXPECT_NEAR(s.window_start, 16e-3, 1e-9) << "the window is the last 20 % of the run";
  EXPECT_NEAR(s.output_torque, 150.0, 1.0) << "the meshing ripple averages out";
  EXPECT_DOUBLE_EQ(s.clamp_driving, 25e3);
  EXPECT_NE(format_summary(s).find("efficiency               0.9"), std::string::npos) << format_summary(s);
  const std::string json = summary_json(s);
  EXPECT_NE(json.find("\"status\": \"steady\""), std::string::npos) << json;
  EXPECT_NE(json.find("\"efficiency_meaningful\": true"), std::string::npos) << json;
}

// The summary names the controller: off, the PI on F1 with its target, or the slip-safe
// clamping with its safety factor and the targets of its profile in order.
TEST(SummaryTest, NamesTheController) {
  auto controller = [](const std::vector<std::string>& ov) {
    RunSummary s;
    summarize(test::model("reference", ov), Synthetic().ch, s);
    return s.controller;
  };
  EXPECT_EQ(controller({}), "off");
  EXPECT_EQ(controller({"controller.enabled=true", "controller.target_ratio=1.1"}), "PI on F1, target speed ratio 1.1");
  EXPECT_EQ(controller({"controller.enabled=true", "controller.clamping_safety=2",
                        "controller.target_profile=[[0.06, 1.0], [0.18, 1.2], [0.24, 1.2], [0.48, 0.8]]"}),
            "slip-safe clamping (S 2), PI on ln(F1/F2), target ratio 1 -> 1.2 -> 0.8 (sheaves)");
}

TEST(SummaryTest, RunEndingInTheRampIsNotSteadyAndItsEfficiencyNotMeaningful) {
  const RunSummary s = Synthetic({}, 1.5e-3).summary();
  EXPECT_EQ(s.status, "not_steady");
  EXPECT_TRUE(has_reason(s, "load ramp")) << reasons(s);
  EXPECT_FALSE(s.efficiency_meaningful);
  EXPECT_NE(format_summary(s).find("not meaningful"), std::string::npos) << format_summary(s);
}

TEST(SummaryTest, DriftOfTheMeansIsNamed) {
  const RunSummary s = Synthetic([](double t, Sample& x) { x.output_torque *= 1 + 4.0 * std::max(0.0, t - 16e-3); })
                           .summary();  // +1.6 % of the load over the window
  EXPECT_EQ(s.status, "steady") << "a drift below the limit" << reasons(s);
  const RunSummary d =
      Synthetic([](double t, Sample& x) { x.output_torque *= 1 + 20.0 * std::max(0.0, t - 16e-3); }).summary();
  EXPECT_EQ(d.status, "not_steady");
  EXPECT_TRUE(has_reason(d, "drift of the means: output torque")) << reasons(d);
}

TEST(SummaryTest, RingingTorsionModeIsNamed) {
  // An 18 ms torsion mode swinging +-10 N m around the load.
  const RunSummary s =
      Synthetic([](double t, Sample& x) { x.output_torque += 10 * std::sin(2 * M_PI * t / 18e-3); }).summary();
  EXPECT_EQ(s.status, "not_steady");
  EXPECT_TRUE(has_reason(s, "torsion mode still ringing")) << reasons(s);
  EXPECT_FALSE(s.efficiency_meaningful);
}

// Over whole periods of the lowest torsion mode the summary judges the output torque's
// mean, not its swing: a mode ringing on at a steady amplitude (+-10 N m, 6.7 % of the load)
// leaves the mean over each period alone (steady); a second, faster mode that whole periods
// of the first do not average out scatters those means (not steady).
TEST(SummaryTest, TorsionModeIsJudgedByItsMeanOverWholePeriods) {
  const double T = torsion_period(test::model("reference"));
  const double t_end = 15 * T;  // the window, the last 20 %: about three periods
  const RunSummary ringing =
      Synthetic([T](double t, Sample& x) { x.output_torque += 10 * std::sin(2 * M_PI * t / T); }, t_end).summary();
  std::printf("torsion period %.4g s: %s\n", T, ringing.criteria.empty() ? "" : ringing.criteria.back().c_str());
  EXPECT_EQ(ringing.status, "steady") << reasons(ringing);
  bool settled = false;
  for (const auto& c : ringing.criteria) settled |= c.rfind("torsion settled: the output torque's means over ", 0) == 0;
  EXPECT_TRUE(settled);
  const RunSummary beat =
      Synthetic([T](double t, Sample& x) { x.output_torque += 20 * std::sin(2 * M_PI * t * 1.37 / T); }, t_end)
          .summary();
  EXPECT_EQ(beat.status, "not_steady");
  EXPECT_TRUE(has_reason(beat, "torsion mode not settled")) << reasons(beat);
}

// Where the span means scatter, the reason measures the swing itself: its period from its
// zero crossings, how many of them a span holds, and whether it holds on over the two
// windows (a self-sustained swing) or falls (a mode still decaying).
TEST(SummaryTest, AnUnsettledTorsionReasonMeasuresTheSwingsPeriodAndWhetherItHoldsOn) {
  const double T = torsion_period(test::model("reference")), t_end = 15 * T, f = 1.37 / T;
  const auto reason = [](const RunSummary& s) {
    for (const auto& r : s.reasons)
      if (r.rfind("torsion mode not settled", 0) == 0) return r;
    return std::string();
  };
  const auto period = [](const std::string& r) {
    const std::size_t at = r.find("the swing's own period, by its zero crossings, is ");
    return at == std::string::npos ? -1.0 : std::stod(r.substr(at + 50));
  };
  const RunSummary held =
      Synthetic([f](double t, Sample& x) { x.output_torque += 20 * std::sin(2 * M_PI * f * t); }, t_end).summary();
  const std::string h = reason(held);
  ASSERT_FALSE(h.empty()) << reasons(held);
  EXPECT_NEAR(period(h), 1 / f, 0.03 / f) << h;
  EXPECT_NE(h.find("self-sustained"), std::string::npos) << h;
  // Decaying by e over 2 T, +-60 N m where the window starts (12 T): the second window's
  // swing is well below the first's.
  const RunSummary decaying = Synthetic(
                                  [f, T](double t, Sample& x) {
                                    x.output_torque +=
                                        60 * std::exp(-(t - 12 * T) / (2 * T)) * std::sin(2 * M_PI * f * t);
                                  },
                                  t_end)
                                  .summary();
  const std::string d = reason(decaying);
  ASSERT_FALSE(d.empty()) << reasons(decaying);
  EXPECT_NEAR(period(d), 1 / f, 0.03 / f) << d;
  EXPECT_NE(d.find("still decaying"), std::string::npos) << d;
}

// Every verified mean carries its statistical uncertainty, the standard error of its means
// over the window's whole torsion spans: none for a steady signal, one that follows
// sd / sqrt(n) for a swing the spans miss. The losses' is a criterion: input and output
// torque swinging by +-1 % of the load at a frequency the spans miss (1.37 times the
// torsion mode's) leave 1 - dissipated / input work uncertain by more than 0.1 points; and
// energy stored across the window's ends (the dissipated work short of input minus output
// work by a swinging store) parts the power ratio from it.
TEST(SummaryTest, EveryMeanCarriesItsStatisticalUncertaintyOverWholeSpans) {
  const Model m = test::model("reference");
  const double W = steady_window(m), T = torsion_period(m);
  const double t_end = ramps_end(m.cfg) + 2 * W + 1e-3;
  const auto summary = [&](const Synthetic& x) {
    RunSummary s;
    summarize(m, x.ch, s, SteadyCriteria{}, t_end - 2 * W);
    return s;
  };
  const RunSummary still = summary(Synthetic({}, t_end));
  EXPECT_EQ(still.status, "steady") << reasons(still);
  EXPECT_EQ(still.uncertainty_spans, 4);
  EXPECT_NEAR(still.uncertainty_span, 0.5 * W, 1e-12);
  EXPECT_LT(uncertainty(still, "efficiency"), 1e-5) << "the meshing ripple, whole periods of which each span holds";
  EXPECT_LT(uncertainty(still, "slip"), 1e-12);
  EXPECT_TRUE(std::isnan(uncertainty(still, "model_time"))) << "not a verified mean";

  const auto swing = [T](double a) {
    return [T, a](double t, Sample& x) {
      x.input_torque *= 1 + a * std::sin(2 * M_PI * t * 1.37 / T);
      x.output_torque *= 1 - a * std::sin(2 * M_PI * t * 1.37 / T);
    };
  };
  const Synthetic swung(swing(0.01), t_end);
  const RunSummary s = summary(swung);
  // The spans' own means, as the summary takes them: the last four whole spans.
  const std::size_t n = swung.ch.size(), k = static_cast<std::size_t>(std::floor(0.5 * W / 1e-5 * (1 + 1e-9)));
  std::vector<double> eff;
  for (std::size_t p = 0; p < 4; ++p) {
    double pin = 0, pout = 0;
    for (std::size_t i = n - (4 - p) * k; i < n - (3 - p) * k; ++i)
      pin += swung.ch.input_torque[i] * swung.ch.input_speed[i], pout += swung.ch.output_torque[i] * swung.ch.output_speed[i];
    eff.push_back(pout / pin);
  }
  double avg = 0, var = 0;
  for (double e : eff) avg += e / 4;
  for (double e : eff) var += (e - avg) * (e - avg) / 3;
  EXPECT_NEAR(uncertainty(s, "efficiency"), std::sqrt(var / 4), 1e-9);
  EXPECT_GT(uncertainty(s, "loss_efficiency"), 1e-3);
  EXPECT_EQ(s.status, "not_steady");
  EXPECT_TRUE(has_reason(s, "efficiency not settled: the power ratio")) << reasons(s);
  EXPECT_NE(format_summary(s).find("(statistical uncertainty, the standard error of the means over 4 whole spans"),
            std::string::npos)
      << format_summary(s);
  const nlohmann::json j = nlohmann::json::parse(summary_json(s));
  EXPECT_EQ(j.at("efficiency_uncertainty").get<double>(), uncertainty(s, "efficiency"));
  EXPECT_EQ(j.at("units").at("efficiency_uncertainty"), "1");
  // A tenth of the swing passes.
  const RunSummary small = summary(Synthetic(swing(0.001), t_end));
  EXPECT_LT(uncertainty(small, "efficiency"), 1e-3);
  EXPECT_FALSE(has_reason(small, "efficiency not settled")) << reasons(small);
  // A store of +-8 J swinging at the same frequency: no effect on the powers, but the
  // dissipated work misses what it holds at the window's ends.
  Synthetic stored({}, t_end);
  for (std::size_t i = 0; i < stored.ch.size(); ++i)
    stored.ch.work_dissipated[i] -= 8 * std::sin(2 * M_PI * stored.ch.t[i] * 1.37 / T);
  const RunSummary e = summary(stored);
  EXPECT_GT(std::abs(e.efficiency - e.loss_efficiency), 1e-3) << "the store's swing across the window's ends";
  EXPECT_NEAR(e.efficiency, still.efficiency, 1e-12);
  EXPECT_EQ(e.status, "not_steady");
  EXPECT_TRUE(has_reason(e, "efficiency not settled: the power ratio")) << reasons(e);
  bool held = false;
  for (const auto& c : still.criteria) held |= c.rfind("efficiency settled: the power ratio", 0) == 0;
  EXPECT_TRUE(held);
  // A clamping that takes 1 % of the input work out (a ratio controller whose force follows
  // its sheave's motion): the power ratio lies 0.01 below 1 - dissipated / input work, and
  // the energy balance, which counts the clamping's work, still holds it.
  Synthetic clamped({}, t_end);
  for (std::size_t i = 0; i < clamped.ch.size(); ++i) {
    clamped.ch.work_clamping[i] = -0.01 * clamped.ch.work_input[i];
    clamped.ch.work_dissipated[i] -= 0.01 * clamped.ch.work_input[i];
  }
  const RunSummary cl = summary(clamped);
  EXPECT_NEAR(cl.efficiency, still.efficiency, 1e-12);
  EXPECT_NEAR(cl.loss_efficiency - still.loss_efficiency, 0.01, 1e-9);
  EXPECT_GT(cl.loss_efficiency - cl.efficiency, 0.009);
  EXPECT_EQ(cl.status, still.status) << reasons(cl);
  EXPECT_FALSE(has_reason(cl, "efficiency not settled")) << reasons(cl);
  // A window of fewer than two spans has none.
  RunSummary short_window;
  summarize(m, swung.ch, short_window, SteadyCriteria{}, t_end - 0.6 * W);
  EXPECT_EQ(short_window.uncertainty_spans, 0);
  EXPECT_TRUE(std::isnan(uncertainty(short_window, "efficiency")));
  EXPECT_TRUE(nlohmann::json::parse(summary_json(short_window)).at("efficiency_uncertainty").is_null());
}

// run.until_steady judges the last two steady windows, and longer pairs (2, 4, ... times)
// where those do not settle: a swing whose period whole torsion spans miss (a mode at 1.37
// times the estimated frequency, +-20 N m) moves the means of spans of W / 2 by more than
// 0.5 % of the load, and those of longer spans by less, in proportion to their length. A
// steady point is decided by W itself; a trend no window passes.
TEST(SummaryTest, UntilSteadyJudgesLongerWindowsWhereTheSteadyWindowDoesNotSettle) {
  const Model m = test::model("reference");
  const double W = steady_window(m), T = torsion_period(m);
  const double t_end = ramps_end(m.cfg) + 2 * W * (1 << kSteadyWindowDoublings) + 1e-3;
  const auto beat = [T](double t, Sample& x) { x.output_torque += 20 * std::sin(2 * M_PI * t * 1.37 / T); };
  const Synthetic swinging(beat, t_end);
  RunSummary s;
  const double w = until_steady_verdict(m, swinging.ch, SteadyCriteria{}, s);
  EXPECT_GT(w, 1.5 * W) << "the steady window's pair does not settle this swing";
  EXPECT_LE(w, W * (1 << kSteadyWindowDoublings) * (1 + 1e-9));
  EXPECT_EQ(s.status, "steady") << reasons(s);
  EXPECT_NEAR(s.window_end - s.window_start, 2 * w, 2e-5);
  RunSummary at_w;
  summarize(m, swinging.ch, at_w, SteadyCriteria{}, t_end - 2 * W);
  EXPECT_TRUE(has_reason(at_w, "torsion mode not settled")) << reasons(at_w);

  RunSummary plain;
  EXPECT_DOUBLE_EQ(until_steady_verdict(m, Synthetic({}, t_end).ch, SteadyCriteria{}, plain), W);
  EXPECT_EQ(plain.status, "steady") << reasons(plain);
  bool four = false;  // the pair of steady windows holds four whole spans, two per window
  for (const auto& c : plain.criteria) four |= c.rfind("torsion settled: the output torque's means over 4 spans", 0) == 0;
  EXPECT_TRUE(four);

  RunSummary trend;
  const Synthetic drifting([&](double t, Sample& x) { beat(t, x); x.output_torque *= std::exp(2 * t); }, t_end);
  EXPECT_EQ(until_steady_verdict(m, drifting.ch, SteadyCriteria{}, trend), 0.0);
  EXPECT_EQ(trend.status, "not_steady");
  EXPECT_TRUE(has_reason(trend, "drift of the means: output torque")) << reasons(trend);
  EXPECT_NEAR(trend.window_end - trend.window_start, 2 * W, 2e-5) << "the reasons are the steady window's";
}

// A self-sustained swing (a limit cycle of the drive line) at a period that the torsion
// mode's estimate misses scatters the means of spans of W / 2 and of the doublings that fit;
// windows of whole periods of it, between upward crossings of the stored energy's swing,
// settle: the verdict takes them and says so. A decaying swing gets no such windows: it
// must ring down.
TEST(SummaryTest, UntilSteadyJudgesWholePeriodsOfASelfSustainedSwing) {
  const Model m = test::model("reference");
  const double W = steady_window(m), T = torsion_period(m), P = T / 1.37;
  const double t_end = ramps_end(m.cfg) + 4 * W + 1e-3;  // the pairs of W and 2 W fit, no longer
  RunSummary s;
  const Synthetic held([P](double t, Sample& x) { x.output_torque += 60 * std::sin(2 * M_PI * t / P); }, t_end,
                       true);
  RunSummary at_2w;
  summarize(m, held.ch, at_2w, SteadyCriteria{}, t_end - 4 * W, W);
  EXPECT_EQ(at_2w.status, "not_steady") << "the doubled pair does not settle it";
  std::vector<double> bounds;
  const double w = until_steady_verdict(m, held.ch, SteadyCriteria{}, s, &bounds);
  ASSERT_GT(w, 0) << reasons(s);
  EXPECT_EQ(s.status, "steady") << reasons(s);
  ASSERT_EQ(bounds.size(), 5u);
  for (std::size_t i = 1; i < bounds.size(); ++i) {
    const double periods = (bounds[i] - bounds[i - 1]) / P;  // each span whole periods, to a sample
    EXPECT_GE(periods, 0.99);
    EXPECT_NEAR(periods, std::round(periods), 1.5e-5 / P) << i;
  }
  EXPECT_NEAR(s.window_start, bounds.front(), 1e-9);
  EXPECT_LE(bounds.back(), t_end);
  EXPECT_NEAR(w, 0.5 * (s.window_end - s.window_start), 1e-12);
  bool said = false;
  for (const auto& c : s.criteria) said |= c.rfind("windows of whole periods of the drive line's self-sustained swing", 0) == 0;
  EXPECT_TRUE(said);
  // The same window summarized again from its bounds gives the same verdict and means.
  RunSummary again;
  summarize(m, held.ch, again, SteadyCriteria{}, bounds);
  EXPECT_EQ(again.status, "steady");
  EXPECT_EQ(again.output_torque, s.output_torque);
  EXPECT_EQ(again.efficiency, s.efficiency);

  RunSummary d;
  const double t_a = t_end - 4 * W;
  const Synthetic decaying(
      [P, T, t_a](double t, Sample& x) { x.output_torque += 60 * std::exp(-(t - t_a) / (2 * T)) * std::sin(2 * M_PI * t / P); },
      t_end);
  EXPECT_EQ(until_steady_verdict(m, decaying.ch, SteadyCriteria{}, d), 0.0) << "a decaying swing rings down first";
  EXPECT_EQ(d.status, "not_steady");
}

// A swing whose period and amplitude wander: the windows between crossings of the stored
// energy's swing hold the same energy at their ends, so the power ratio meets the energy
// balance; a pair of the same spans in periods of the swing's mean length, ending where the
// channels end, does not: its ends lie at another phase, and the swing's energy between
// them shows in the power ratio.
TEST(SummaryTest, WholePeriodWindowsOfAWanderingSwingEndWhereTheStoredEnergyStarted) {
  const Model m = test::model("reference");
  const double W = steady_window(m), T = torsion_period(m), P = T / 1.37;
  const double t_end = ramps_end(m.cfg) + 4 * W + 1e-3;
  double phase = 0, t_last = 0;
  const Synthetic held(
      [&](double t, Sample& x) {
        phase += 2 * M_PI / P * (1 + 0.06 * std::sin(2 * M_PI * t / (5.3 * P))) * (t - t_last), t_last = t;
        x.output_torque += 60 * (1 + 0.1 * std::sin(2 * M_PI * t / (3.7 * P))) * std::sin(phase);
      },
      t_end, true);
  RunSummary s;
  std::vector<double> bounds;
  ASSERT_GT(until_steady_verdict(m, held.ch, SteadyCriteria{}, s, &bounds), 0) << reasons(s);
  EXPECT_EQ(s.status, "steady") << reasons(s);
  ASSERT_EQ(bounds.size(), 5u);
  const double per = std::round((bounds[1] - bounds[0]) / P), span = per * P;
  RunSummary fixed;
  summarize(m, held.ch, fixed, SteadyCriteria{}, t_end - 4 * span, span);
  EXPECT_EQ(fixed.status, "not_steady");
  EXPECT_TRUE(has_reason(fixed, "efficiency not settled")) << reasons(fixed);
  EXPECT_GT(std::abs(fixed.efficiency - fixed.loss_efficiency), 10 * std::abs(s.efficiency - s.loss_efficiency));
}

TEST(SummaryTest, ShiftingRatioIsNamedWithItsRate) {
  const RunSummary s = Synthetic([](double t, Sample& x) {
                         x.geometric_ratio *= 1 + 0.4 * t;  // +0.4 % per 10 ms
                         x.speed_ratio = x.geometric_ratio / 0.99;
                       }).summary();
  EXPECT_EQ(s.status, "not_steady");
  EXPECT_TRUE(has_reason(s, "shifting")) << reasons(s);
  EXPECT_TRUE(has_reason(s, "+0.4 % per 10 ms")) << reasons(s);
}

// A shift towards underdrive lowers the output speed with the creep unchanged: no slip.
TEST(SummaryTest, OutputSpeedFallingWithTheRatioIsAShiftNotASlip) {
  const RunSummary s = Synthetic([](double t, Sample& x) {
                         const double f = 1 + 0.6 * t;  // the ratio grows by 0.6 % per 10 ms
                         x.geometric_ratio *= f;
                         x.speed_ratio *= f;
                         x.output_speed /= f;
                       }).summary();
  EXPECT_EQ(s.status, "not_steady") << reasons(s);
  EXPECT_TRUE(has_reason(s, "shifting")) << reasons(s);
  EXPECT_FALSE(has_reason(s, "slip growing")) << reasons(s);
}

TEST(SummaryTest, GrossSlipIsReportedAsSlip) {
  // The chain slips on the driven pulley: the output speed falls while the load holds.
  const RunSummary s = Synthetic([](double t, Sample& x) {
                         const double f = 1 + 20 * std::max(0.0, t - 10e-3);
                         x.speed_ratio *= f;
                         x.output_speed /= f;
                       }).summary();
  EXPECT_EQ(s.status, "slip");
  EXPECT_TRUE(has_reason(s, "gross slip")) << reasons(s);
  EXPECT_TRUE(has_reason(s, "slip growing")) << reasons(s);
  EXPECT_GT(s.slip, 0.05);
  EXPECT_FALSE(s.efficiency_meaningful);
}

TEST(SummaryTest, EfficiencyOutsideZeroOneIsNeverPrintedAsAValue) {
  // Power flowing back (output torque against the motion): the ratio is negative.
  Synthetic syn;
  RunSummary s = syn.summary();
  s.efficiency = -1.5;
  const std::string text = format_summary(s);
  EXPECT_NE(text.find("not meaningful (outside [0, 1]"), std::string::npos) << text;
}

TEST(SummaryTest, StartFromRestWithoutContactsHasNoRatioVerdicts) {
  // The geometric ratio is 0 while no pin touches a sheave: no slip, no shift.
  Synthetic syn({}, 30e-5);
  for (std::size_t i = 0; i < syn.ch.size(); ++i)
    if (i % 3 == 0) syn.ch.geometric_ratio[i] = 0;
  const RunSummary s = syn.summary();
  EXPECT_NE(s.status, "slip") << reasons(s);
  EXPECT_FALSE(has_reason(s, "shifting")) << reasons(s);
  EXPECT_NEAR(s.geometric_ratio, 1.0, 1e-12);
}

TEST(GuardTest, EnergyResidualWarnsOnceItPassesItsShareOfTheTurnover) {
  EnergyGuard g;
  Sample s;
  s.t = 1e-3;
  s.work_input = 4, s.work_output = 3, s.work_dissipated = 1;  // 8 J turned over
  s.energy_residual = 2;
  EXPECT_EQ(g.check(s), "") << "judged before the turnover reaches 10 J";
  s.work_input = 40, s.work_output = 30, s.work_dissipated = 10;  // 80 J
  s.energy_residual = 3.9;
  EXPECT_EQ(g.check(s), "") << "4.9 % of the turnover";
  s.energy_residual = -4.1;
  const std::string w = g.check(s);
  EXPECT_NE(w.find("5.1 % of the energy turned over"), std::string::npos) << w;
  EXPECT_NE(w.find("reduce integrator.step"), std::string::npos) << w;
  EXPECT_EQ(g.check(s), "") << "warned twice";
  EnergyGuard nan;
  s.energy_residual = std::nan("");
  EXPECT_NE(nan.check(s), "") << "a non-finite residual passes silently";
}

TEST(GuardTest, Rk4StepAboveItsStabilityLimitWarnsWithTheStableStep) {
  EXPECT_EQ(rk4_stability_warning(1e-8, 2.5e8, 0), "");  // 2.8 / 2.5e8 = 1.12e-8
  const std::string w = rk4_stability_warning(1e-7, 2.5e8, 0);
  EXPECT_NE(w.find("above its stability limit of about 1.12e-08 s"), std::string::npos) << w;
  EXPECT_NE(w.find("--step 5.6e-09 or less"), std::string::npos) << w;
  EXPECT_EQ(rk4_stability_warning(1e-7, 0, 0), "") << "no estimate, no warning";
}

// A summary in which every entry differs from every other and from its default: numbers
// with all 17 digits, strings with quotes, backslashes, control characters and non-ASCII.
RunSummary busy_summary() {
  RunSummary s;
  int k = 0;
  for (const SummaryField& f : summary_fields())
    std::visit(
        [&](auto m) {
          auto& x = s.*m;
          using T = std::decay_t<decltype(x)>;
          ++k;
          if constexpr (std::is_same_v<T, double>) x = (k + 0.1234567890123456) / 7.0;
          else if constexpr (std::is_same_v<T, long>) x = 1000 + k;
          else if constexpr (std::is_same_v<T, bool>) x = true;
          else if constexpr (std::is_same_v<T, std::string>) x = std::string(f.name) + " \"quoted\" C:\\dir";
          else x = {std::string(f.name) + " line\nnext\ttab \x01\x1f \u00e9\u00fc \u4e2d\u6587 \\ \"q\"", "second"};
        },
        f.member);
  s.status = "steady", s.stopped = "steady";  // the values the text has lines for
  s.efficiency = 0.9;
  return s;
}

// The JSON is what a real parser reads back: every string exactly, every number to its
// last bit, the keys those of the table in its order.
TEST(SummaryTest, JsonParsesAndGivesBackEveryEntryOfTheTable) {
  RunSummary s = busy_summary();
  s.warnings.push_back(std::string("nul \0 inside", 12) + ", delete \x7f, bell \a");
  const nlohmann::json j = nlohmann::json::parse(summary_json(s));
  ASSERT_TRUE(j.is_object());
  EXPECT_EQ(j.size(), summary_fields().size() + 1) << "keys beyond the table and its units";
  // The units: every entry of the table that has one, and none that has none.
  ASSERT_TRUE(j.contains("units") && j.at("units").is_object());
  for (const SummaryField& f : summary_fields()) {
    const std::string name(f.name);
    if (f.unit.empty()) EXPECT_FALSE(j.at("units").contains(name)) << name;
    else EXPECT_EQ(j.at("units").value(name, ""), std::string(f.unit)) << name;
  }
  for (const SummaryField& f : summary_fields()) {
    const std::string name(f.name);
    ASSERT_TRUE(j.contains(name)) << name;
    std::visit(
        [&](auto m) {
          const auto& x = s.*m;
          using T = std::decay_t<decltype(x)>;
          const auto& v = j.at(name);
          if constexpr (std::is_same_v<T, double>) {
            ASSERT_TRUE(v.is_number_float()) << name;
            EXPECT_EQ(v.get<double>(), x) << name;
          } else if constexpr (std::is_same_v<T, long>) {
            ASSERT_TRUE(v.is_number_integer()) << name;
            EXPECT_EQ(v.get<long>(), x) << name;
          } else if constexpr (std::is_same_v<T, bool>) {
            ASSERT_TRUE(v.is_boolean()) << name;
            EXPECT_EQ(v.get<bool>(), x) << name;
          } else {
            EXPECT_EQ(v.get<T>(), x) << name;
          }
        },
        f.member);
  }
  const nlohmann::ordered_json ordered = nlohmann::ordered_json::parse(summary_json(s));
  std::size_t i = 0;
  for (auto it = ordered.begin(); it != ordered.end() && i < summary_fields().size(); ++it)
    EXPECT_EQ(it.key(), summary_fields()[i++].name) << "the JSON's keys in the order of the table";
}

TEST(SummaryTest, JsonWritesNonFiniteNumbersAsNull) {
  RunSummary s;
  s.efficiency = std::nan("");
  s.model_s_per_hour = HUGE_VAL;
  const nlohmann::json j = nlohmann::json::parse(summary_json(s));
  EXPECT_TRUE(j.at("efficiency").is_null());
  EXPECT_TRUE(j.at("model_s_per_hour").is_null());
  EXPECT_TRUE(j.at("slip").is_number());
}

// Each entry of the table shows in the text: changing it alone changes the text.
TEST(SummaryTest, TextShowsEveryEntryOfTheTable) {
  const RunSummary base = busy_summary();
  const std::string text = format_summary(base);
  for (const SummaryField& f : summary_fields()) {
    RunSummary s = base;
    std::visit(
        [&](auto m) {
          auto& x = s.*m;
          using T = std::decay_t<decltype(x)>;
          if constexpr (std::is_same_v<T, double>) x = 3.5 * x + 1.75;
          else if constexpr (std::is_same_v<T, long>) x += 7;
          else if constexpr (std::is_same_v<T, bool>) x = !x;
          else if constexpr (std::is_same_v<T, std::string>) x += "-changed";
          else x.push_back("an added line");
        },
        f.member);
    EXPECT_NE(format_summary(s), text) << f.name << " does not show in the text:\n" << text;
  }
}

// docs/output.md names every entry of the table in its /summary section.
TEST(SummaryTest, OutputDocumentationNamesEveryEntry) {
  std::ifstream in(std::string(CVT_SOURCE_DIR) + "/docs/output.md");
  ASSERT_TRUE(in) << "docs/output.md";
  std::stringstream doc;
  doc << in.rdbuf();
  const std::string text = doc.str();
  const std::size_t a = text.find("\n## /summary"), b = text.find("\n## ", a + 1);
  ASSERT_NE(a, std::string::npos) << "docs/output.md has no /summary section";
  const std::string section = text.substr(a, b == std::string::npos ? std::string::npos : b - a);
  for (const SummaryField& f : summary_fields()) {
    std::string quoted = "`";  // built with += (GCC 12's false -Wrestrict on "x" + std::string)
    quoted += f.name;
    quoted += '`';
    EXPECT_NE(section.find(quoted), std::string::npos)
        << "docs/output.md, /summary, does not name `" << f.name << "`";
  }
}

}  // namespace
}  // namespace cvt
