// The end-of-run profile: its rows add up to the run's wall time, count
// what was called, are the same in the table, the JSON and the file's /profile group, and
// timing a run does not change its bits.
#include <gtest/gtest.h>

#include <hdf5.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>

#include "engine/run.hpp"
#include "engine/simulation.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

namespace fs = std::filesystem;

const std::vector<std::string> kRows = {"chain forces",     "pulley contact",  "other forces",  "inertia decomposition",
                                        "accelerations",    "integrator update", "contact status", "W stiffness",
                                        "W assembly",       "W factorization", "W solves",      "scheduling",
                                        "output",           "rest",            "total"};

class ProfileTest : public ::testing::TestWithParam<SchedulerKind> {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("cvt_profile_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

TEST_P(ProfileTest, RowsAddUpAndAgreeWithTheFileAndTheJson) {
  const Model m = test::model("mini", {"run.t_end=5e-6", "run.sample_interval=5e-7"});
  RunOptions o;
  o.out_path = (dir_ / "run.h5").string();
  o.profile_json = (dir_ / "profile.json").string();
  o.progress = false;
  o.schedule.kind = GetParam();
  o.schedule.threads = GetParam() == SchedulerKind::serial ? 1 : 2;
  const RunResult r = run_simulation(m, o);
  const Profiler::Report& p = r.profile;
  const long steps = std::lround(5e-6 / m.cfg.integrator.step);
  EXPECT_EQ(p.steps, steps);
  EXPECT_EQ(p.threads, o.schedule.threads);
  ASSERT_EQ(p.rows.size(), kRows.size());
  double sum = 0;
  for (std::size_t i = 0; i < kRows.size(); ++i) {
    const auto& row = p.rows[i];
    EXPECT_EQ(row.name, kRows[i]);
    EXPECT_LE(row.busy_min_s, row.busy_avg_s * (1 + 1e-12)) << row.name;
    EXPECT_LE(row.busy_avg_s, row.busy_max_s * (1 + 1e-12)) << row.name;
    EXPECT_GE(row.wall_s, 0.0) << row.name;
    if (row.name != "total") sum += row.wall_s;
  }
  // Four RHS per RK4 step, one status update per step, one sample per 5e-7 s plus the first.
  EXPECT_EQ(p.rows[0].calls, 4 * steps);
  EXPECT_EQ(p.rows[5].calls, 4 * steps);
  EXPECT_EQ(p.rows[6].calls, steps);
  for (int i = 7; i <= 10; ++i) EXPECT_EQ(p.rows[i].calls, 0) << p.rows[i].name << " in an RK4 run";
  EXPECT_GE(p.rows[12].calls, 11);
  EXPECT_NEAR(sum, p.rows.back().wall_s, 1e-9 * p.rows.back().wall_s);
  // The kernels did run: the chain forces are the largest module.
  EXPECT_GT(p.rows[0].wall_s, 0.0);
  EXPECT_GT(p.rows[0].wall_s, p.rows[2].wall_s);

  // The same rows in the file's /profile group ...
  const hid_t f = H5Fopen(o.out_path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const hid_t d = H5Dopen2(f, "/profile/wall_s", H5P_DEFAULT);
  ASSERT_GE(d, 0);
  std::vector<double> wall(kRows.size() + 1, -1);
  const hid_t space = H5Dget_space(d);
  EXPECT_EQ(H5Sget_simple_extent_npoints(space), static_cast<hssize_t>(kRows.size()));
  H5Sclose(space);
  H5Dread(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, wall.data());
  for (std::size_t i = 0; i < kRows.size(); ++i) EXPECT_EQ(wall[i], p.rows[i].wall_s);
  H5Dclose(d);
  const hid_t g = H5Gopen2(f, "/profile", H5P_DEFAULT);
  const hid_t a = H5Aopen(g, "steps", H5P_DEFAULT);
  double s = 0;
  H5Aread(a, H5T_NATIVE_DOUBLE, &s);
  EXPECT_EQ(s, static_cast<double>(steps));
  H5Aclose(a), H5Gclose(g), H5Fclose(f);
  // ... and in the JSON, every figure to its last bit.
  std::ifstream js(o.profile_json);
  const nlohmann::json j = nlohmann::json::parse(js);
  EXPECT_EQ(j.at("header").at("steps").get<long>(), steps);
  EXPECT_EQ(j.at("header").at("threads").get<int>(), p.threads);
  EXPECT_EQ(j.at("header").at("scheduler").get<std::string>(), p.scheduler);
  EXPECT_EQ(j.at("header").at("us_per_step").get<double>(), p.us_per_step);
  ASSERT_EQ(j.at("rows").size(), kRows.size());
  for (std::size_t i = 0; i < kRows.size(); ++i) {
    const auto& row = j.at("rows")[i];
    EXPECT_EQ(row.at("name").get<std::string>(), kRows[i]);
    EXPECT_EQ(row.at("calls").get<long>(), p.rows[i].calls) << kRows[i];
    EXPECT_EQ(row.at("wall_s").get<double>(), p.rows[i].wall_s) << kRows[i];
    EXPECT_EQ(row.at("busy_max_s").get<double>(), p.rows[i].busy_max_s) << kRows[i];
  }
}

// Names with quotes, backslashes and control characters come back from the JSON as they
// went in; a non-finite figure is null.
TEST(ProfileJson, ParsesWithAnyNames) {
  Profiler::Report r;
  r.steps = 3;
  r.scheduler = "flow \"graph\" \\ \t";
  r.us_per_step = 1.0 / 3.0;
  r.model_s_per_hour = std::nan("");
  Profiler::Row row;
  row.name = "chain \"forces\"\n\x01 \u00e9";
  row.calls = 12;
  row.wall_s = 0.1 + 0.2;
  r.rows = {row, row};
  const nlohmann::json j = nlohmann::json::parse(profile_json(r));
  EXPECT_EQ(j.at("header").at("scheduler").get<std::string>(), r.scheduler);
  EXPECT_EQ(j.at("header").at("us_per_step").get<double>(), r.us_per_step);
  EXPECT_TRUE(j.at("header").at("model_s_per_hour").is_null());
  ASSERT_EQ(j.at("rows").size(), 2u);
  EXPECT_EQ(j.at("rows")[1].at("name").get<std::string>(), row.name);
  EXPECT_EQ(j.at("rows")[1].at("wall_s").get<double>(), row.wall_s);
}

// A W-method's linear algebra has rows of its own (not "scheduling"), every step counts
// as an integrator update, and the table shows the W rows only for a W-method.
TEST(ProfileWMethod, NamesTheMatrixWork) {
  const Model m = test::model("mini", {"integrator.method=ros34pw2", "integrator.step=2e-7", "run.t_end=4e-6",
                                       "run.sample_interval=1e-6", "integrator.startup_time=0"});
  const fs::path dir = fs::temp_directory_path() / ("cvt_profile_w_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  RunOptions o;
  o.out_path = (dir / "run.h5").string();
  o.progress = false;
  o.schedule.threads = 1;
  const RunResult r = run_simulation(m, o);
  fs::remove_all(dir);
  const Profiler::Report& p = r.profile;
  ASSERT_EQ(p.rows.size(), kRows.size());
  EXPECT_EQ(p.steps, 20);
  EXPECT_EQ(p.rows[5].calls, 20) << "integrator update";
  EXPECT_GE(p.rows[7].calls, 1) << "W stiffness";
  EXPECT_GE(p.rows[8].calls, 1) << "W assembly";
  EXPECT_GE(p.rows[9].calls, 1) << "W factorization";
  EXPECT_GE(p.rows[10].calls, 20) << "W solves";
  EXPECT_GT(p.rows[9].wall_s, 0.0);
  const std::string table = format_profile(p);
  EXPECT_NE(table.find("W factorization"), std::string::npos) << table;
  Profiler::Report rk4 = p;
  for (auto& row : rk4.rows)
    if (row.name.rfind("W ", 0) == 0) row.calls = 0;
  EXPECT_EQ(format_profile(rk4).find("W factorization"), std::string::npos);
}

TEST_P(ProfileTest, TimingDoesNotChangeTheBits) {
  const Model m = test::model("mini");
  ScheduleOptions o;
  o.kind = GetParam();
  o.threads = GetParam() == SchedulerKind::serial ? 1 : 2;
  Simulation plain(m, o), timed(m, o);
  timed.enable_profiling();
  for (int i = 0; i < 200; ++i) plain.step(m.cfg.integrator.step), timed.step(m.cfg.integrator.step);
  ASSERT_EQ(plain.state().size(), timed.state().size());
  EXPECT_EQ(std::memcmp(plain.state().data(), timed.state().data(), sizeof(double) * plain.state().size()), 0);
  EXPECT_EQ(timed.profiler()->steps(), 200);
}

INSTANTIATE_TEST_SUITE_P(Schedules, ProfileTest,
                         ::testing::Values(SchedulerKind::serial, SchedulerKind::flowgraph, SchedulerKind::paper_omp),
                         [](const auto& i) {
                           std::string n = scheduler_name(i.param);
                           for (char& c : n)
                             if (c == '-') c = '_';
                           return n;
                         });

}  // namespace
}  // namespace cvt
