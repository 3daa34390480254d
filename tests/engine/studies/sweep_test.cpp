// cvt-engine sweep (engine/studies/sweep.cpp, sweep_mpi.cpp): the grid and the points file,
// the CSV read back to the same bits, a restart that skips the finished points and drops
// a torn line, every fate of a point a row; and, on the mini model, the serial sweep
// against mpirun -np 3 and against a sweep killed with kill -9 and started again.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

#include "engine/guards.hpp"
#include "engine/io/checkpoint.hpp"
#include "engine/model/config.hpp"
#include "engine/studies/sweep.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

namespace fs = std::filesystem;

std::string read_text(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

std::vector<std::string> lines(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string l; std::getline(in, l);) out.push_back(l);
  return out;
}

// The CSV without its column wall_s (the only one that differs between runs).
std::string without_wall(const std::string& csv) {
  std::string out;
  for (const auto& l : lines(csv)) {  // wall_s is the last field but config
    const auto config = l.rfind(','), wall = l.rfind(',', config - 1);
    out += l.substr(0, wall) + l.substr(config) + "\n";
  }
  return out;
}

class SweepDir : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::temp_directory_path() / ("cvt_sweep_test_" + std::string(info->name()) + "_" + std::to_string(getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  // `sh -c CMD` in the test's folder; its exit status.
  int sh(const std::string& cmd) {
    const int st = std::system(("cd " + test::shell_quote(dir_.string()) + " && " + cmd).c_str());
    return st != -1 && WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  }
  fs::path dir_;
};

TEST(SweepPlanTest, GridIsTheFullProductFirstAxisSlowest) {
  const SweepPlan p = SweepPlan::grid({parse_axis("load.torque=50,100"), parse_axis("clamping.driving = 3e4, 3.5e4,4e4")});
  ASSERT_EQ(p.keys, (std::vector<std::string>{"load.torque", "clamping.driving"}));
  ASSERT_EQ(p.points.size(), 6u);
  EXPECT_EQ(p.points[0], (std::vector<std::string>{"50", "3e4"}));
  EXPECT_EQ(p.points[2], (std::vector<std::string>{"50", "4e4"}));
  EXPECT_EQ(p.points[3], (std::vector<std::string>{"100", "3e4"}));
  EXPECT_EQ(p.overrides(4), (std::vector<std::string>{"load.torque=100", "clamping.driving=3.5e4"}));
  EXPECT_EQ(p.label(5), "load.torque=100, clamping.driving=4e4");
  EXPECT_THROW(parse_axis("load.torque"), ConfigError);
  EXPECT_THROW(parse_axis("load.torque=1,,2"), ConfigError);
  EXPECT_THROW(SweepPlan::grid({parse_axis("load.torque=1"), parse_axis("load.torque=2")}), ConfigError);
}

// The continuation tree: points that agree but for load.torque form a group; its middle
// load (the lower middle) runs from rest, every other point continues from the nearest load
// in the tree; no point continues across groups; the order puts every parent first.
TEST(SweepPlanTest, ContinuationGrowsEachGroupFromItsMiddleLoadToTheNearest) {
  const SweepPlan p = SweepPlan::grid({parse_axis("geometry.ratio=0.8,1.2"), parse_axis("load.torque=200,50,100,150,25")});
  std::vector<double> loads;
  for (const auto& v : p.points) loads.push_back(std::stod(v[1]));
  std::vector<long> order;
  const std::vector<long> parent = continuation_parents(p, loads, &order);
  // Group ratio 0.8 is points 0..4 (loads 200, 50, 100, 150, 25): root 100 (point 2);
  // 50 and 150 from 100, 25 from 50, 200 from 150.
  EXPECT_EQ(parent, (std::vector<long>{3, 2, -1, 2, 1, 8, 7, -1, 7, 6}));
  ASSERT_EQ(order.size(), 10u);
  std::vector<int> rank(10);
  for (int k = 0; k < 10; ++k) rank[static_cast<std::size_t>(order[static_cast<std::size_t>(k)])] = k;
  for (long i = 0; i < 10; ++i) {
    if (parent[static_cast<std::size_t>(i)] < 0) continue;
    EXPECT_LT(rank[static_cast<std::size_t>(parent[static_cast<std::size_t>(i)])], rank[static_cast<std::size_t>(i)]);
    EXPECT_EQ(p.points[static_cast<std::size_t>(parent[static_cast<std::size_t>(i)])][0], p.points[static_cast<std::size_t>(i)][0]);
  }
  EXPECT_EQ(order[0], 2);  // the roots first, in point order
  EXPECT_EQ(order[1], 7);
  // Without a load axis every point is its own group: all from rest.
  const SweepPlan q = SweepPlan::grid({parse_axis("geometry.ratio=0.8,1.2")});
  EXPECT_EQ(continuation_parents(q, {150, 150}, &order), (std::vector<long>{-1, -1}));
}

TEST_F(SweepDir, PointsFileHasAHeaderOfKeysAndARowPerPoint) {
  std::ofstream(dir_ / "points.csv") << "# operating points\nload.torque, friction.law\n50, smooth\n\n100,\"none\"\n";
  const SweepPlan p = SweepPlan::from_file((dir_ / "points.csv").string());
  EXPECT_EQ(p.keys, (std::vector<std::string>{"load.torque", "friction.law"}));
  ASSERT_EQ(p.points.size(), 2u);
  EXPECT_EQ(p.points[1], (std::vector<std::string>{"100", "none"}));
  EXPECT_EQ(p.origins[1], (dir_ / "points.csv").string() + " line 5");
  std::ofstream(dir_ / "bad.csv") << "load.torque,clamping.driving\n50\n";
  EXPECT_THROW(SweepPlan::from_file((dir_ / "bad.csv").string()), ConfigError);
  EXPECT_THROW(SweepPlan::from_file((dir_ / "missing.csv").string()), ConfigError);
}

// Points files by RFC 4180: quoted fields hold commas, doubled quotes, '#' and line breaks;
// comments only where a line starts; CRLF ends lines too. Every malformed file is a
// ConfigError that names the line.
TEST_F(SweepDir, PointsFilesAreReadByRfc4180) {
  std::ofstream(dir_ / "good.csv") << "  # comment\r\n\"load.torque\" , friction.law\r\n"
                                      "50,\"a#b, \"\"c\"\"\"\r\n   # another\n60,\"two\nlines\"\n70,x";
  const SweepPlan p = SweepPlan::from_file((dir_ / "good.csv").string());
  EXPECT_EQ(p.keys, (std::vector<std::string>{"load.torque", "friction.law"}));
  ASSERT_EQ(p.points.size(), 3u);
  EXPECT_EQ(p.points[0], (std::vector<std::string>{"50", "a#b, \"c\""}));
  EXPECT_EQ(p.points[1], (std::vector<std::string>{"60", "two\nlines"}));
  EXPECT_EQ(p.points[2], (std::vector<std::string>{"70", "x"}));
  EXPECT_EQ(p.origins[2], (dir_ / "good.csv").string() + " line 7");  // after a field of two lines
  const std::vector<std::pair<std::string, std::string>> bad = {
      {"k.a,k.b\n1,2\n3,\"4\n5,6\n", "line 3: a quote that is never closed"},
      {"k.a,k.b\n1,\"2\"x\n", "line 2: characters after a closing quote"},
      {"k.a,k.b\n1,2\"x\"\n", "line 2: a quote inside an unquoted field"},
      {"k.a,k.a\n1,2\n", "line 1: the key 'k.a' is given twice"},
      {"k.a,k.b\n1,2\n\n3\n", "line 4: 1 values for 2 keys"},
      {"k.a,k.b\n1,2 # a comment after values\n7,8,9\n", "line 3: 3 values for 2 keys"},
      {"k.a,k.b\n1,\n", "line 2: no value for k.b"},
      {"k.a,,k.b\n", "line 1: an empty key"}};
  for (const auto& [text, says] : bad) {
    SCOPED_TRACE(text);
    std::ofstream(dir_ / "bad.csv") << text;
    try {
      SweepPlan::from_file((dir_ / "bad.csv").string());
      ADD_FAILURE() << "accepted";
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find(says), std::string::npos) << e.what();
    }
  }
}

// A points file that cannot run is refused with exit 78 before the first point (nothing
// written): its malformed rows, and a value that is no value of its key, named with its line.
TEST_F(SweepDir, ABadPointsFileIsRefusedBeforeTheFirstPoint) {
  const std::string mini = test::shell_quote(std::string(CVT_SOURCE_DIR) + "/configs/mini.toml");
  const std::vector<std::pair<std::string, std::string>> bad = {
      {"geometry.ratio,load.torque\n0.9,\"1\n", "line 2: a quote that is never closed"},
      {"geometry.ratio,geometry.ratio\n0.9,1\n", "given twice"},
      {"geometry.ratio\n0.9 # a comment after the value\n", "a '#' outside quotes"},
      {"geometry.ratio\n0.9\n\"abc\"\n", "(point 2, points.csv line 3)"}};
  for (const auto& [text, says] : bad) {
    SCOPED_TRACE(text);
    std::ofstream(dir_ / "points.csv") << text;
    EXPECT_EQ(sh(test::shell_quote(CVT_ENGINE_EXE) + " sweep " + mini +
                 " --points points.csv --set run.t_end=1e-5 -o out 2>err.txt >/dev/null"),
              78);
    std::ifstream in(dir_ / "err.txt");
    const std::string err((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    EXPECT_NE(err.find(says), std::string::npos) << err;
    for (const char* f : {"out.csv", "out.h5", "out.h5.partial", "out.runs", "out.csv.lock"})
      EXPECT_FALSE(fs::exists(dir_ / f)) << f;
  }
}

TEST(SweepCsvTest, ARowReadsBackToTheSameBits) {
  const SweepPlan p = SweepPlan::grid({parse_axis("load.torque=150"), parse_axis("friction.law=smooth")});
  SweepRow r;
  r.point = 0;
  r.values = p.points[0];
  r.status = "blow_up";
  r.reason = "a reason, with \"quotes\", commas";
  r.speed_ratio = 1.0 / 3.0, r.slip = -2.5e-17, r.efficiency = 0.1 + 0.2, r.wall_s = 12.345678901234567;
  r.model_time = 0.1;
  const std::string line = sweep_csv_row(r);
  ASSERT_EQ(line.back(), '\n');
  const SweepRow b = parse_sweep_csv_row(line.substr(0, line.size() - 1), p);
  EXPECT_EQ(b.values, r.values);
  EXPECT_EQ(b.status, r.status);
  EXPECT_EQ(b.reason, r.reason);
  EXPECT_EQ(b.speed_ratio, r.speed_ratio);
  EXPECT_EQ(b.slip, r.slip);
  EXPECT_EQ(b.efficiency, r.efficiency);
  EXPECT_EQ(b.wall_s, r.wall_s);
  EXPECT_EQ(sweep_csv_row(b), line);
  // The header: the keys under their exact names, then status and the results.
  const std::string h = sweep_csv_header(p);
  EXPECT_EQ(h.rfind("load.torque,friction.law,status,speed_ratio,geometric_ratio,slip,input_torque,output_torque,"
                    "efficiency,loss_efficiency,input_speed,",
                    0),
            0u)
      << h;
  for (const char* c : {"clamping_force_driving", "clamping_force_driven", "wall_s"})
    EXPECT_NE(h.find(c), std::string::npos) << c;
  EXPECT_THROW(parse_sweep_csv_row("150,smooth,weird,1", p), std::runtime_error);
}

// A point's log line keeps its status and results however long its label is (a points
// file of eleven keys makes a label of over 240 characters).
TEST(SweepLogTest, APointLineKeepsItsStatusBehindALongLabel) {
  std::vector<SweepAxis> axes;
  for (const char* k : {"geometry.ratio=0.8", "controller.target_ratio=0.8", "drive.speed=300", "load.torque=4",
                        "clamping.driving=3e3", "clamping.driven=3e3", "controller.clamping_safety=3",
                        "controller.enabled=true", "controller.shift_kp=100", "controller.shift_ki=1000",
                        "friction.f0=0.06"})
    axes.push_back(parse_axis(k));
  const SweepPlan p = SweepPlan::grid(axes);
  ASSERT_GT(p.label(0).size(), 240u);
  SweepRow r;
  r.point = 0, r.values = p.points[0], r.status = "steady";
  r.speed_ratio = 0.8059, r.slip = 0.0058, r.efficiency = 0.82, r.model_time = 0.027, r.wall_s = 74.8;
  const std::string line = sweep_point_line(p, r, 2);
  EXPECT_NE(line.find(p.label(0) + ": steady, speed ratio 0.8059, slip +0.58 %, efficiency 0.8200, t = 0.027 s, 74.8 s"),
            std::string::npos)
      << line;
}

// run.verify's errors: a column <mean>_numerical_error for each verified mean among the
// results, and one <mean>_uncertainty (the statistical uncertainty, after all the errors),
// read back to the same bits; a point not verified reads back without errors.
TEST(SweepCsvTest, VerifiedMeansHaveErrorColumnsThatReadBack) {
  const SweepPlan p = SweepPlan::grid({parse_axis("load.torque=150")});
  const std::string h = sweep_csv_header(p);
  for (const char* c : {"speed_ratio", "slip", "input_torque", "output_torque", "efficiency", "clamping_force_driving",
                        "clamping_force_driven"})
    EXPECT_NE(h.find(std::string(",") + c + "_numerical_error,"), std::string::npos) << c << " in " << h;
  EXPECT_EQ(h.find("model_time_numerical_error"), std::string::npos) << h;
  EXPECT_LT(h.find("clamping_force_driven_numerical_error,"), h.find("speed_ratio_uncertainty,")) << h;
  EXPECT_NE(h.find(",efficiency_uncertainty,"), std::string::npos) << h;
  SweepRow r;
  r.point = 0, r.values = p.points[0], r.status = "steady";
  r.numerical_error["efficiency"] = 1.0 / 3.0 * 1e-4;
  r.numerical_error["slip"] = 2.5e-17;
  r.uncertainty["efficiency"] = 2.0 / 3.0 * 1e-3;
  const std::string line = sweep_csv_row(r);
  const SweepRow b = parse_sweep_csv_row(line.substr(0, line.size() - 1), p);
  EXPECT_EQ(b.uncertainty.at("efficiency"), r.uncertainty.at("efficiency"));
  EXPECT_EQ(b.uncertainty.count("slip"), 0u);
  EXPECT_EQ(b.numerical_error.at("efficiency"), r.numerical_error.at("efficiency"));
  EXPECT_EQ(b.numerical_error.at("slip"), r.numerical_error.at("slip"));
  EXPECT_EQ(b.numerical_error.count("output_torque"), 0u);
  EXPECT_EQ(sweep_csv_row(b), line);
  SweepRow plain;
  plain.point = 0, plain.values = p.points[0], plain.status = "steady";
  const std::string pl = sweep_csv_row(plain);
  EXPECT_TRUE(parse_sweep_csv_row(pl.substr(0, pl.size() - 1), p).numerical_error.empty());
}

// A restart keeps the whole rows, drops a torn last line, and refuses a CSV of another sweep.
TEST_F(SweepDir, LedgerKeepsWholeRowsDropsATornLineRefusesAnotherSweep) {
  const SweepPlan p = SweepPlan::grid({parse_axis("load.torque=5,10,15")});
  SweepOptions o;
  o.out = (dir_ / "s").string();
  {
    SweepLedger l(o, p);
    EXPECT_EQ(l.finished(), 0);
    SweepRow r;
    r.point = 1, r.values = p.points[1], r.status = "steady", r.efficiency = 0.93;
    l.add(r);
    // A second sweep on the same files while this one runs: refused.
    EXPECT_THROW(SweepLedger(o, p), OutputError);
  }
  std::ofstream(o.out + ".csv", std::ios::app) << "5,steady,1.0,0.9";  // torn: no newline
  {
    SweepLedger l(o, p);
    EXPECT_EQ(l.finished(), 1);
    EXPECT_TRUE(l.done(1));
    EXPECT_FALSE(l.done(0));
    EXPECT_EQ(l.rows()[0].efficiency, 0.93);
  }
  EXPECT_EQ(lines(read_text(o.out + ".csv")).size(), 2u);  // header and the whole row
  const SweepPlan other = SweepPlan::grid({parse_axis("load.torque=6,10,15")});
  EXPECT_THROW(SweepLedger(o, SweepPlan::grid({parse_axis("clamping.driving=1e4")})), ConfigError);
  std::ofstream(o.out + ".csv", std::ios::app) << "";
  {
    // Point 1 with another value than this plan's.
    const SweepPlan moved = SweepPlan::grid({parse_axis("load.torque=5,11,15")});
    EXPECT_THROW(SweepLedger(o, moved), ConfigError);
  }
  (void)other;
}

// A restart compares each finished row's whole resolved configuration, not only its axes:
// the same axes on another model, or with another --set, are another sweep.
TEST_F(SweepDir, ARestartWithAnotherConfigurationIsAnotherSweep) {
  SweepOptions o;
  o.out = (dir_ / "s").string();
  o.config_path = test::config_path("mini");
  const SweepPlan a = sweep_plan(o, {"load.torque=5,10"}, "");
  ASSERT_EQ(a.fingerprints.size(), 2u);
  EXPECT_NE(a.fingerprints[0], a.fingerprints[1]);
  {
    SweepLedger l(o, a);
    SweepRow r;
    r.point = 0, r.values = a.points[0], r.status = "steady", r.config = a.fingerprints[0];
    l.add(r);
  }
  EXPECT_EQ(SweepLedger(o, sweep_plan(o, {"load.torque=5,10"}, "")).finished(), 1);  // the same sweep goes on
  o.config_path = test::config_path("reference");
  EXPECT_THROW(SweepLedger(o, sweep_plan(o, {"load.torque=5,10"}, "")), ConfigError);
  o.config_path = test::config_path("mini");
  o.overrides = {"friction.f0=0.1"};
  try {
    SweepLedger(o, sweep_plan(o, {"load.torque=5,10"}, ""));
    ADD_FAILURE() << "another --set was taken for the same sweep";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("ran another configuration"), std::string::npos) << e.what();
  }
}

// The mini model, 4 points: one runs to t_end (short windows), one blows up (a step far
// too large, taken as fixed steps, which no gross estimate retakes in pieces), one cannot be built (a ratio the pulleys do not allow); each a row, the sweep
// goes on. Serial, then mpirun -np 3, then mpirun killed with kill -9 and started again:
// the same CSV (but wall_s), cell by cell.
TEST_F(SweepDir, MiniSerialMpiAndKilledGiveTheSameCsv) {
  const std::string exe = test::shell_quote(CVT_ENGINE_EXE);
  const std::string args = " sweep " + test::shell_quote(test::config_path("mini")) +
                           " --axis integrator.step=8.333333333333333e-7,1e-5 --axis geometry.ratio=1.0,3.5"
                           " --set run.t_end=0.008 --set run.steady_window=2e-3 --set clamping.driving=1.13e4"
                           " --set integrator.fixed_steps=true";
  ASSERT_EQ(sh(exe + args + " --out serial > serial.log 2>&1"), 0) << read_text(dir_ / "serial.log");
  const std::string serial = read_text(dir_ / "serial.csv");
  const auto rows = lines(serial);
  ASSERT_EQ(rows.size(), 5u) << serial;
  EXPECT_EQ(rows[1].substr(0, rows[1].find(',', rows[1].find(',') + 1)), "8.333333333333333e-7,1.0");
  // Not yet settled at t_end = 8 ms: the row says so and why (tests/engine/until_steady_test.cpp
  // runs the same point to steady).
  EXPECT_NE(rows[1].find(",not_steady,"), std::string::npos) << rows[1];
  EXPECT_NE(rows[1].find(",0.0080000000000000002,"), std::string::npos) << rows[1];
  // Not verified (run.verify off): its error columns nan, then its uncertainties (a window of
  // four spans: finite), then the point's index.
  EXPECT_NE(rows[1].find(",nan,nan,"), std::string::npos) << rows[1];
  const SweepRow r1 = parse_sweep_csv_row(
      rows[1], SweepPlan::grid({parse_axis("integrator.step=8.333333333333333e-7,1e-5"), parse_axis("geometry.ratio=1.0,3.5")}));
  EXPECT_TRUE(r1.numerical_error.empty());
  EXPECT_GT(r1.uncertainty.at("efficiency"), 0.0) << rows[1];
  EXPECT_EQ(r1.point, 0);
  EXPECT_NE(rows[2].find(",error,"), std::string::npos) << rows[2];
  EXPECT_NE(rows[2].find("impossible ratio"), std::string::npos) << rows[2];
  EXPECT_NE(rows[3].find(",blow_up,"), std::string::npos) << rows[3];
  EXPECT_NE(rows[4].find(",error,"), std::string::npos) << rows[4];
  EXPECT_TRUE(fs::exists(dir_ / "serial.h5"));
  EXPECT_FALSE(fs::exists(dir_ / "serial.runs"));  // not kept

  // Started again: every point is in the CSV, none runs.
  ASSERT_EQ(sh(exe + args + " --out serial > again.log 2>&1"), 0);
  EXPECT_NE(read_text(dir_ / "again.log").find("4 of 4 points already in"), std::string::npos);
  EXPECT_EQ(read_text(dir_ / "serial.csv"), serial);

#ifdef CVT_WITH_MPI
  if (sh("command -v mpirun > /dev/null") != 0) GTEST_SKIP() << "no mpirun";
  const std::string mpirun = "OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 exec mpirun --oversubscribe -np 3 ";
  ASSERT_EQ(sh(mpirun + exe + args + " --out mpi > mpi.log 2>&1"), 0) << read_text(dir_ / "mpi.log");
  EXPECT_EQ(without_wall(read_text(dir_ / "mpi.csv")), without_wall(serial));
  EXPECT_NE(read_text(dir_ / "mpi.log").find("[rank 2]"), std::string::npos) << read_text(dir_ / "mpi.log");

  // Killed with kill -9 once the first point is in, then the same command again.
  const pid_t pid = fork();
  if (pid == 0) {
    setpgid(0, 0);
    const std::string cmd = "cd " + test::shell_quote(dir_.string()) + " && " + mpirun + exe + args +
                            " --out killed > killed.log 2>&1";
    execl("/bin/sh", "sh", "-c", cmd.c_str(), static_cast<char*>(nullptr));
    _exit(127);
  }
  const auto t0 = std::chrono::steady_clock::now();
  while (lines(read_text(dir_ / "killed.csv")).size() < 2 &&
         std::chrono::steady_clock::now() - t0 < std::chrono::seconds(120))
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  ASSERT_EQ(kill(pid, SIGKILL), 0);  // the shell exec'd mpirun: this is mpirun
  waitpid(pid, nullptr, 0);
  const std::size_t before = lines(read_text(dir_ / "killed.csv")).size();
  EXPECT_GE(before, 2u);
  EXPECT_LT(before, 5u);  // killed before the end
  // Its ranks go with it; the lock lets the restart in once they have.
  for (int i = 0; i < 200 && sh("exec 9>killed.csv.lock && flock -n 9") != 0; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  ASSERT_EQ(sh(mpirun + exe + args + " --out killed > restart.log 2>&1"), 0) << read_text(dir_ / "restart.log");
  EXPECT_EQ(without_wall(read_text(dir_ / "killed.csv")), without_wall(serial)) << read_text(dir_ / "restart.log");
  EXPECT_NE(read_text(dir_ / "restart.log").find("points already in"), std::string::npos)
      << read_text(dir_ / "restart.log");
#endif
}

// A sweep as a job array: each point alone (--point I, or --array with the index Slurm
// gives), then --gather, gives the CSV of the sweep run in one process; --gather before every
// point has a row names the missing ones (exit 75), and a row of another configuration is
// refused.
TEST_F(SweepDir, AJobArrayOfPointsGivesTheSweepsCsv) {
  const std::string exe = test::shell_quote(CVT_ENGINE_EXE);
  const std::string args = " sweep " + test::shell_quote(test::config_path("mini")) +
                           " --axis load.torque=5,10,12 --set run.t_end=0.002 --set run.steady_window=5e-4";
  ASSERT_EQ(sh(exe + args + " --out whole > whole.log 2>&1"), 0) << read_text(dir_ / "whole.log");
  ASSERT_EQ(sh(exe + args + " --out arr --point 2 > p2.log 2>&1"), 0) << read_text(dir_ / "p2.log");
  EXPECT_TRUE(fs::exists(dir_ / "arr.points" / "point-0002.csv"));
  EXPECT_FALSE(fs::exists(dir_ / "arr.csv")) << "a task writes its own row only";
  ASSERT_EQ(sh(exe + args + " --out arr --gather > g1.log 2>&1"), 75) << read_text(dir_ / "g1.log");
  EXPECT_NE(read_text(dir_ / "g1.log").find("2 of 3 points have no row in arr.points/ yet (0,1)"), std::string::npos)
      << read_text(dir_ / "g1.log");
  ASSERT_EQ(sh("SLURM_ARRAY_TASK_ID=0 " + exe + args + " --out arr --array > p0.log 2>&1"), 0)
      << read_text(dir_ / "p0.log");
  EXPECT_EQ(sh(exe + args + " --out arr --array > noid.log 2>&1"), 78);
  EXPECT_NE(read_text(dir_ / "noid.log").find("SLURM_ARRAY_TASK_ID is not set"), std::string::npos);
  EXPECT_EQ(sh(exe + args + " --out arr --point 3 > out.log 2>&1"), 78);
  EXPECT_NE(read_text(dir_ / "out.log").find("the sweep's points are 0 .. 2"), std::string::npos)
      << read_text(dir_ / "out.log");
  // Point 1 run with another --set: its row is refused by the gather of this sweep.
  ASSERT_EQ(sh(exe + args + " --set damping.scale=2 --out arr --point 1 > p1x.log 2>&1"), 0);
  EXPECT_EQ(sh(exe + args + " --out arr --gather > g2.log 2>&1"), 78);
  EXPECT_NE(read_text(dir_ / "g2.log").find("its point ran another configuration"), std::string::npos)
      << read_text(dir_ / "g2.log");
  fs::remove(dir_ / "arr.points" / "point-0001.csv");
  ASSERT_EQ(sh(exe + args + " --out arr --point 1 > p1.log 2>&1"), 0);
  ASSERT_EQ(sh(exe + args + " --out arr --gather > g3.log 2>&1"), 0) << read_text(dir_ / "g3.log");
  EXPECT_EQ(without_wall(read_text(dir_ / "arr.csv")), without_wall(read_text(dir_ / "whole.csv")));
  EXPECT_TRUE(fs::exists(dir_ / "arr.h5"));
  EXPECT_FALSE(fs::exists(dir_ / "arr.points"));
}

// run.max_wall in a sweep: the point in progress stops with its checkpoint (exit 75), and the
// same command, given again until it ends, continues it: the CSV of an uninterrupted sweep;
// the same under mpirun -np 3.
TEST_F(SweepDir, ASweepStoppedByMaxWallContinuesItsPoint) {
  const std::string exe = test::shell_quote(CVT_ENGINE_EXE);
  const std::string args = " sweep " + test::shell_quote(test::config_path("mini")) +
                           " --axis load.torque=5,10 --set run.t_end=0.005 --set run.steady_window=1e-3";
  ASSERT_EQ(sh(exe + args + " --out whole > whole.log 2>&1"), 0) << read_text(dir_ / "whole.log");
  std::vector<int> codes;
  for (int k = 0; k < 40 && (codes.empty() || codes.back() == 75); ++k)
    codes.push_back(sh(exe + args + " --out job --max-wall 4 >> job.log 2>&1"));
  const std::string log = read_text(dir_ / "job.log");
  ASSERT_EQ(codes.back(), 0) << log;
  ASSERT_GE(codes.size(), 2u) << "never stopped by --max-wall: the case is not tested\n" << log;
  EXPECT_NE(log.find("stopped before the wall-time limit (run.max_wall)"), std::string::npos) << log;
  EXPECT_EQ(without_wall(read_text(dir_ / "job.csv")), without_wall(read_text(dir_ / "whole.csv")));
#ifdef CVT_WITH_MPI
  // Under mpirun: the rank whose point reaches the limit says so, rank 0 hands out no more
  // points and every rank ends (exit 75, no abort); the same command continues.
  if (sh("command -v mpirun > /dev/null") != 0) GTEST_SKIP() << "no mpirun";
  const std::string mpirun = "OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 mpirun --oversubscribe -np 3 ";
  codes.clear();
  for (int k = 0; k < 40 && (codes.empty() || codes.back() == 75); ++k)
    codes.push_back(sh(mpirun + exe + args + " --out mjob --max-wall 4 >> mjob.log 2>&1"));
  const std::string mlog = read_text(dir_ / "mjob.log");
  ASSERT_EQ(codes.back(), 0) << mlog;
  ASSERT_GE(codes.size(), 2u) << "never stopped by --max-wall: the case is not tested\n" << mlog;
  EXPECT_NE(mlog.find("stopped before the wall-time limit (run.max_wall)  [rank "), std::string::npos) << mlog;
  EXPECT_EQ(mlog.find("MPI_ABORT"), std::string::npos) << mlog;
  EXPECT_EQ(without_wall(read_text(dir_ / "mjob.csv")), without_wall(read_text(dir_ / "whole.csv")));
#endif
}

// Points started from a steady state's checkpoint (sweep --from): the point at the
// checkpoint's own load is steady once two windows of its own samples agree; a changed load ramps
// over --warm-ramp first; mpirun -np 3 gives the serial CSV.
TEST_F(SweepDir, WarmStartFromASteadyState) {
  const std::string exe = test::shell_quote(CVT_ENGINE_EXE);
  ASSERT_EQ(sh(exe + " run " + test::shell_quote(test::config_path("mini")) +
               " --until-steady --t-end 0.05 --set clamping.driving=1.13e4 --set run.steady_window=4e-3"
               " -o base.h5 -q > base.log 2>&1"),
            0)
      << read_text(dir_ / "base.log");
  const Checkpoint ck = read_checkpoint((dir_ / "base.h5.ckpt").string());
  ASSERT_LT(ck.t, 0.05);  // it stopped steady
  const std::string args = " sweep --from base.h5.ckpt --axis load.torque=10,10.5 --set run.t_end=0.02 --warm-ramp 2e-3";
  ASSERT_EQ(sh(exe + args + " --out warm > warm.log 2>&1"), 0) << read_text(dir_ / "warm.log");
  const auto rows = lines(read_text(dir_ / "warm.csv"));
  ASSERT_EQ(rows.size(), 3u);
  SweepPlan plan = SweepPlan::grid({parse_axis("load.torque=10,10.5")});
  const SweepRow same = parse_sweep_csv_row(rows[1], plan), moved = parse_sweep_csv_row(rows[2], plan);
  EXPECT_EQ(same.status, "steady") << same.reason;
  EXPECT_GE(same.model_time, ck.t + 2 * 4e-3 - 1e-9);  // two windows of its own samples
  EXPECT_LT(same.model_time, ck.t + 0.02);
  EXPECT_EQ(moved.status, "steady") << moved.reason;
  EXPECT_GE(moved.model_time, ck.t + 2e-3 + 2 * 4e-3 - 1e-9);  // the load's ramp, then two windows
  EXPECT_NEAR(moved.load_torque, 10.5, 1e-9);
  EXPECT_GT(moved.output_torque, same.output_torque);
#ifdef CVT_WITH_MPI
  if (sh("command -v mpirun > /dev/null") != 0) GTEST_SKIP() << "no mpirun";
  ASSERT_EQ(sh("OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 mpirun --oversubscribe -np 3 " + exe + args +
               " --out warm-mpi > mpi.log 2>&1"),
            0)
      << read_text(dir_ / "mpi.log");
  EXPECT_EQ(without_wall(read_text(dir_ / "warm-mpi.csv")), without_wall(read_text(dir_ / "warm.csv")));
#endif
}

// Maps by continuation (sweep --continuation): the middle load runs from rest, the others start
// from the steady state of the nearest load (from_point), ramp their load and need two windows
// of their own after the ramp; a continued point lands on the point from rest within the
// ratio's spread under fixed clamping; mpirun -np 3 hands a point out only after its parent
// and gives the serial CSV; --continuation with --from or a job array's task is refused.
TEST_F(SweepDir, ContinuedPointsStartFromTheNearestLoadsSteadyState) {
  const std::string exe = test::shell_quote(CVT_ENGINE_EXE);
  const std::string base = " sweep " + test::shell_quote(test::config_path("mini")) +
                           " --set clamping.driving=1.13e4 --set run.steady_window=4e-3 --set run.t_end=0.05";
  const std::string args = base + " --axis load.torque=9,10,11 --continuation --warm-ramp 2e-3";
  ASSERT_EQ(sh(exe + args + " --out cont > cont.log 2>&1"), 0) << read_text(dir_ / "cont.log");
  const std::string csv = read_text(dir_ / "cont.csv");
  EXPECT_FALSE(fs::exists(dir_ / "cont.runs")) << "the parents' checkpoints go with the sweep's end";
  const SweepPlan plan = SweepPlan::grid({parse_axis("load.torque=9,10,11")});
  const auto rows = lines(csv);
  ASSERT_EQ(rows.size(), 4u) << csv;
  const SweepRow lo = parse_sweep_csv_row(rows[1], plan), mid = parse_sweep_csv_row(rows[2], plan),
                 hi = parse_sweep_csv_row(rows[3], plan);
  EXPECT_EQ(mid.from_point, -1);
  EXPECT_EQ(lo.from_point, 1);
  EXPECT_EQ(hi.from_point, 1);
  for (const SweepRow* r : {&lo, &mid, &hi}) EXPECT_EQ(r->status, "steady") << r->reason;
  for (const SweepRow* r : {&lo, &hi}) {
    EXPECT_GE(r->model_time, mid.model_time + 2e-3 + 2 * 4e-3 - 1e-9);  // the ramp, then two windows
    EXPECT_NEAR(r->output_torque, r->load_torque, 0.02 * r->load_torque);  // the torque balance
  }
  EXPECT_NEAR(lo.load_torque, 9, 1e-9);
  EXPECT_NEAR(hi.load_torque, 11, 1e-9);
  EXPECT_NE(read_text(dir_ / "cont.log").find("from point 2"), std::string::npos) << read_text(dir_ / "cont.log");
  // The point at 9 N m from rest: the same operating point, up to where the ratio settles
  // under fixed clamping forces (it depends on the path).
  ASSERT_EQ(sh(exe + base + " --axis load.torque=9 --out rest > rest.log 2>&1"), 0) << read_text(dir_ / "rest.log");
  const SweepRow rest = parse_sweep_csv_row(lines(read_text(dir_ / "rest.csv"))[1], SweepPlan::grid({parse_axis("load.torque=9")}));
  EXPECT_EQ(rest.from_point, -1);
  EXPECT_NEAR(lo.efficiency, rest.efficiency, 0.005);
  EXPECT_NEAR(lo.speed_ratio, rest.speed_ratio, 0.005);
  EXPECT_EQ(sh(exe + args + " --from cont.csv --out x > from.log 2>&1"), 78);
  EXPECT_EQ(sh(exe + args + " --point 0 --out x > task.log 2>&1"), 78);
  EXPECT_NE(read_text(dir_ / "task.log").find("job array"), std::string::npos) << read_text(dir_ / "task.log");
#ifdef CVT_WITH_MPI
  if (sh("command -v mpirun > /dev/null") != 0) GTEST_SKIP() << "no mpirun";
  ASSERT_EQ(sh("OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 mpirun --oversubscribe -np 3 " + exe + args +
               " --out cont-mpi > mpi.log 2>&1"),
            0)
      << read_text(dir_ / "mpi.log");
  EXPECT_EQ(without_wall(read_text(dir_ / "cont-mpi.csv")), without_wall(csv));
#endif
}

}  // namespace
}  // namespace cvt
