// run.verify (engine/run.cpp, docs/output.md "Numerical error"): the summary's window
// integrated again from the state at its start with a finer step, each mean's change its
// numerical error. On the mini model over 5 ms (the window: its last millisecond).
#include <gtest/gtest.h>
#include <hdf5.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <fstream>
#include <sstream>

#include "engine/io/checkpoint.hpp"
#include "engine/io/h5_writer.hpp"
#include "engine/io/json.hpp"
#include "engine/run.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

struct Verified {
  RunResult r;
  Json json;
  std::vector<double> output_torque;  // the file's series
  bool has_error_attribute = false;   // /summary holds efficiency_numerical_error
  double efficiency_error_attribute = 0;
};

// The mini model to 5 ms with the given overrides; refine: RunOptions::verify_refine;
// on_progress: called at every step.
Verified run_mini(std::vector<std::string> ov, int refine, const std::string& name,
                  std::function<bool(const RunProgress&)> on_progress = {}) {
  ov.insert(ov.begin(), "run.t_end=5e-3");
  const Model m = build_model(load_config(test::config_path("mini"), ov));
  RunOptions o = test::quiet_run_options(name);
  o.verify_refine = refine;
  if (on_progress) o.on_progress = std::move(on_progress), o.progress_seconds = 0;
  o.summary_json = o.out_path + ".json";
  Verified v;
  v.r = run_simulation(m, o);
  std::ifstream js(o.summary_json);
  std::stringstream ss;
  ss << js.rdbuf();
  v.json = Json::parse(ss.str());
  {
    H5File f = H5File::open(o.out_path);
    v.output_torque = f.read_doubles("/observables/output_torque/value");
  }
  const hid_t f = H5Fopen(o.out_path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  if (H5Aexists_by_name(f, "/summary", "efficiency_numerical_error", H5P_DEFAULT) > 0) {
    const hid_t a = H5Aopen_by_name(f, "/summary", "efficiency_numerical_error", H5P_DEFAULT, H5P_DEFAULT);
    H5Aread(a, H5T_NATIVE_DOUBLE, &v.efficiency_error_attribute);
    H5Aclose(a);
    v.has_error_attribute = true;
  }
  H5Fclose(f);
  test::remove_run_files(o.out_path);
  std::filesystem::remove(o.summary_json);
  return v;
}

// The verified means of the summary's table, with their values.
std::vector<std::pair<std::string, double>> means(const RunSummary& s) {
  std::vector<std::pair<std::string, double>> out;
  for (const SummaryField& f : summary_fields())
    if (f.verify.verified) out.emplace_back(std::string(f.name), s.*std::get<double RunSummary::*>(f.member));
  return out;
}

// The torques' and clamping forces' errors relative to their means, summed, plus the
// efficiency's: one figure of how far a run's means are from the finer step's.
double error_figure(const RunSummary& s) {
  double e = numerical_error(s, "efficiency");
  for (const char* n : {"input_torque", "output_torque", "clamping_force_driving", "clamping_force_driven"})
    for (const auto& [name, x] : means(s))
      if (name == n) e += numerical_error(s, n) / std::abs(x);
  return e;
}

class VerifyTest : public ::testing::Test {
 protected:
  // The runs the tests share: verified with the step halved, the same run unverified, and
  // verified with twice the mini model's step.
  static void SetUpTestSuite() {
    halved_ = new Verified(run_mini({"run.verify=true"}, 2, "verify_halved"));
    plain_ = new Verified(run_mini({}, 2, "verify_plain"));
  }
  static void TearDownTestSuite() {
    delete halved_, delete plain_;
    halved_ = plain_ = nullptr;
  }
  static inline Verified* halved_ = nullptr;
  static inline Verified* plain_ = nullptr;
};

// A verification whose steps are the run's own repeats the run from the kept state bit for
// bit: every error is exactly 0.
TEST_F(VerifyTest, RepeatingTheRunsOwnStepGivesErrorsOfExactlyZero) {
  const Verified v = run_mini({"run.verify=true"}, 1, "verify_same");
  ASSERT_EQ(v.r.numerical_error.size(), summary_fields().size());
  EXPECT_EQ(v.r.verify_step, v.r.step);
  for (const auto& [name, x] : means(v.r)) EXPECT_EQ(numerical_error(v.r, name), 0.0) << name << " " << x;
  for (const auto& w : v.r.warnings) EXPECT_EQ(w.find("run.verify"), std::string::npos) << w;
}

// With the step halved the errors are those of a real integration: not 0, well below the
// means' own size, and within the goals at the mini model's tuned step; the run's own means
// and file are the same bits as without the verification.
TEST_F(VerifyTest, HalvedStepGivesSmallErrorsAndLeavesTheRunsNumbers) {
  const RunResult& r = halved_->r;
  ASSERT_EQ(r.numerical_error.size(), summary_fields().size());
  EXPECT_EQ(r.verify_step, 0.5 * r.step);
  EXPECT_GT(r.verify_wall_s, 0);
  for (const auto& [name, x] : means(r)) {
    const double e = numerical_error(r, name);
    EXPECT_TRUE(std::isfinite(e)) << name;
    EXPECT_GE(e, 0) << name;
  }
  // (The mini model's clamping forces and load torque are prescribed: their errors are 0.)
  for (const char* n : {"input_torque", "output_torque", "speed_ratio", "efficiency", "strand_tension_upper",
                        "strand_tension_lower"}) {
    const double e = numerical_error(r, n);
    for (const auto& [name, x] : means(r))
      if (name == n) {
        EXPECT_GT(e, 0) << n;
        EXPECT_LT(e, 0.05 * std::abs(x)) << n;
      }
  }
  EXPECT_LT(numerical_error(r, "efficiency"), 0.05);
  // The run's means: the same bits as the unverified run's; so is its file.
  for (const auto& [name, x] : means(r)) {
    for (const auto& [name0, x0] : means(plain_->r))
      if (name == name0) {
        EXPECT_EQ(x, x0) << name;
      }
  }
  EXPECT_EQ(halved_->output_torque, plain_->output_torque);
  EXPECT_EQ(plain_->r.verify_step, 0);
  EXPECT_TRUE(plain_->r.numerical_error.empty());
  EXPECT_TRUE(std::isnan(numerical_error(plain_->r, "efficiency")));
}

// The JSON and /summary carry each verified mean's error beside it, only when verified.
TEST_F(VerifyTest, JsonAndSummaryGroupCarryTheErrors) {
  const Json& j = halved_->json;
  for (const auto& [name, x] : means(halved_->r)) {
    const std::string key = name + "_numerical_error";
    ASSERT_TRUE(j.contains(key)) << key;
    EXPECT_EQ(j[key].get<double>(), numerical_error(halved_->r, name)) << key;
    EXPECT_FALSE(plain_->json.contains(key)) << key;
  }
  // Beside its mean: the next key.
  std::string before;
  for (auto it = j.begin(); it != j.end(); ++it) {
    if (it.key() == "efficiency_numerical_error") {
      EXPECT_EQ(before, "efficiency");
    }
    before = it.key();
  }
  EXPECT_EQ(j["verify_step"].get<double>(), halved_->r.verify_step);
  ASSERT_TRUE(halved_->has_error_attribute);
  EXPECT_EQ(halved_->efficiency_error_attribute, numerical_error(halved_->r, "efficiency"));
  EXPECT_FALSE(plain_->has_error_attribute);
  // The text: "+- e" beside the verified means only.
  EXPECT_NE(format_summary(halved_->r).find(" +- "), std::string::npos);
  EXPECT_EQ(format_summary(plain_->r).find(" +- "), std::string::npos);
}

// A coarser step errs more: twice the mini model's step gives a larger error figure than
// its own step.
TEST_F(VerifyTest, CoarserStepHasTheLargerError) {
  const Verified coarse = run_mini({"run.verify=true", "integrator.step=1.6666666666666667e-6"}, 2, "verify_coarse");
  ASSERT_EQ(coarse.r.numerical_error.size(), summary_fields().size());
  EXPECT_GT(error_figure(coarse.r), error_figure(halved_->r));
}

// The second integration reports its progress: after the run's calls, the callback's calls
// marked verifying count its own steps up to its total, at model times within the run's;
// a false return there stops it, leaving the means unverified (a warning says why) and the
// run's own means and end as they were.
TEST_F(VerifyTest, VerificationReportsItsProgressAndStopsWhenAsked) {
  std::vector<RunProgress> seen;
  const Verified v = run_mini({"run.verify=true"}, 2, "verify_progress", [&seen](const RunProgress& p) {
    seen.push_back(p);
    return true;
  });
  EXPECT_EQ(v.r.numerical_error.size(), summary_fields().size());
  const auto first = std::find_if(seen.begin(), seen.end(), [](const RunProgress& p) { return p.verifying; });
  ASSERT_NE(first, seen.begin());
  ASSERT_NE(first, seen.end());
  EXPECT_TRUE(std::all_of(first, seen.end(), [](const RunProgress& p) { return p.verifying; }));
  long before = 0;
  for (auto p = first; p != seen.end(); ++p) {
    EXPECT_GT(p->step, before);
    EXPECT_LE(p->step, p->steps);
    EXPECT_EQ(p->steps, first->steps);
    EXPECT_LE(p->t, p->t_end * (1 + 1e-12));
    EXPECT_EQ(p->t_end, v.r.model_time);
    before = p->step;
  }
  EXPECT_EQ(seen.back().step, first->steps);

  const Verified stopped = run_mini({"run.verify=true"}, 2, "verify_stopped", [](const RunProgress& p) {
    return !p.verifying;
  });
  EXPECT_TRUE(stopped.r.numerical_error.empty());
  EXPECT_EQ(stopped.r.stopped, plain_->r.stopped);
  EXPECT_EQ(stopped.r.model_time, plain_->r.model_time);
  for (const auto& [name, x] : means(stopped.r))
    for (const auto& [name0, x0] : means(plain_->r))
      if (name == name0) {
        EXPECT_EQ(x, x0) << name;
      }
  EXPECT_TRUE(std::any_of(stopped.r.warnings.begin(), stopped.r.warnings.end(), [](const std::string& w) {
    return w.find("run.verify: the means are not verified: stopped by the progress callback") != std::string::npos;
  }));
}

// A run cut short inside its window (the callback stops it at 4.5 ms; the window starts at
// about 4 ms) keeps the window's state in its checkpoint: continued in place, it verifies
// with the same errors as the uninterrupted run. A continuation under another configuration
// takes none of those states, and says why its means are not verified.
TEST_F(VerifyTest, ContinuationVerifiesAWindowThatStartsBeforeIt) {
  const Model m = build_model(load_config(test::config_path("mini"), {"run.t_end=5e-3", "run.verify=true"}));
  RunOptions o = test::quiet_run_options("verify_cut");
  o.progress_seconds = 0;
  o.on_progress = [](const RunProgress& p) { return p.t < 4.5e-3; };
  const RunResult cut = run_simulation(m, o);
  ASSERT_TRUE(cut.interrupted);
  const Checkpoint ck = read_checkpoint(o.out_path + ".ckpt");
  ASSERT_FALSE(ck.verify_states.empty());
  EXPECT_LT(ck.verify_states.front().t, halved_->r.window_start);
  for (const Checkpoint& k : ck.verify_states) {
    EXPECT_LT(k.t, ck.t);
    EXPECT_EQ(k.state.size(), ck.state.size());
  }

  RunOptions on = test::quiet_run_options("verify_cut");
  on.resume = &ck, on.append = true;
  const RunResult r = run_simulation(m, on);
  EXPECT_TRUE(r.unverified.empty()) << r.unverified;
  ASSERT_EQ(r.numerical_error.size(), summary_fields().size());
  EXPECT_EQ(r.window_start, halved_->r.window_start);
  for (const auto& [name, x] : means(r)) EXPECT_EQ(numerical_error(r, name), numerical_error(halved_->r, name)) << name;
  test::remove_run_files(on.out_path);

  // The same continuation from a checkpoint without the states (an ended run's), and from
  // one that another configuration wrote: nothing verified, and the reason said.
  const std::string other = build_model(load_config(test::config_path("mini"), {"run.t_end=5e-3", "run.verify=true",
                                                                               "load.torque=8"})).cfg.resolved_toml;
  for (bool another_config : {false, true}) {
    ASSERT_TRUE(run_simulation(m, o).interrupted);
    Checkpoint c = read_checkpoint(o.out_path + ".ckpt");
    if (another_config)
      c.config_toml = other;
    else
      c.verify_states.clear();
    RunOptions again = test::quiet_run_options("verify_cut");
    again.resume = &c, again.append = true;
    const RunResult u = run_simulation(m, again);
    EXPECT_TRUE(u.numerical_error.empty());
    EXPECT_NE(u.unverified.find("no state was kept at or before the window's start"), std::string::npos) << u.unverified;
    EXPECT_EQ(u.efficiency, r.efficiency);
    test::remove_run_files(again.out_path);
  }
  test::remove_run_files(o.out_path);
}

// A checkpoint carries the kept states through its file: the same numbers read back.
TEST(VerifyStatesTest, CheckpointFileKeepsTheVerificationStates) {
  Checkpoint c;
  c.config_toml = "x = 1\n";
  c.state = Eigen::VectorXd::LinSpaced(7, 0.5, 3.5);
  c.rocker = {1, 0, 2}, c.pulley = {0, 1};
  c.t = 2e-3, c.steps = 800;
  for (int i = 0; i < 3; ++i) {
    Checkpoint k;
    k.state = Eigen::VectorXd::Constant(7, 0.25 * i);
    k.rocker = {std::uint8_t(i), 1, 0}, k.pulley = {1, std::uint8_t(i)};
    k.t = 1e-3 * (0.25 * i), k.t0 = 0, k.steps = 100 * i, k.energy0 = 1.5 + i;
    k.halvings = i, k.halved_at = i ? 1e-4 : -1, k.leak = 0.01 * i, k.leak_from = 40 * i;
    c.verify_states.push_back(k);
  }
  const std::string path = (std::filesystem::temp_directory_path() / "verify_states_test.ckpt").string();
  write_checkpoint(path, c);
  const Checkpoint b = read_checkpoint(path);
  std::filesystem::remove(path);
  EXPECT_EQ(b.state, c.state);
  ASSERT_EQ(b.verify_states.size(), 3u);
  for (std::size_t i = 0; i < 3; ++i) {
    const Checkpoint &x = b.verify_states[i], &y = c.verify_states[i];
    EXPECT_EQ(x.state, y.state);
    EXPECT_EQ(x.rocker, y.rocker);
    EXPECT_EQ(x.pulley, y.pulley);
    EXPECT_EQ(x.t, y.t);
    EXPECT_EQ(x.steps, y.steps);
    EXPECT_EQ(x.energy0, y.energy0);
    EXPECT_EQ(x.halvings, y.halvings);
    EXPECT_EQ(x.halved_at, y.halved_at);
    EXPECT_EQ(x.leak, y.leak);
    EXPECT_EQ(x.leak_from, y.leak_from);
  }
}

// A mean whose error passes its goal is a reason; the status stays what the verdicts say.
TEST(VerifyGoalTest, ErrorPastItsGoalIsAReasonAndKeepsTheStatus) {
  RunSummary s, tight;
  s.status = "steady";
  s.efficiency = 0.95, tight.efficiency = 0.9485;        // 0.0015 > 0.001
  s.output_torque = 10.0, tight.output_torque = 10.04;   // 0.4 % < 0.5 %
  s.input_torque = 10.0, tight.input_torque = 10.06;     // 0.6 % > 0.5 %
  s.slip = 0.0100, tight.slip = 0.0104;                  // 0.04 % points < 0.05
  set_numerical_errors(s, tight, 1e-7);
  EXPECT_EQ(s.status, "steady");
  ASSERT_EQ(s.reasons.size(), 2u);
  EXPECT_EQ(s.reasons[0].rfind("numerical error of input_torque", 0), 0u) << s.reasons[0];
  EXPECT_EQ(s.reasons[1].rfind("numerical error of efficiency 0.0015 > 0.001", 0), 0u) << s.reasons[1];
  EXPECT_NEAR(numerical_error(s, "slip"), 4e-4, 1e-12);
  EXPECT_EQ(s.verify_step, 1e-7);
}

}  // namespace
}  // namespace cvt
