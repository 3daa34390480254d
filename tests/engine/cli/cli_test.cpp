// The cvt-engine command line, run as a real process: bad input exits with status 78
// (EX_CONFIG), names the key, the value and the reason on stderr, and leaves no output file
// behind; a good run exits 0, prints its summary and renames FILE.partial to FILE.
#include <gtest/gtest.h>
#include <hdf5.h>
#include <signal.h>
#include <fcntl.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <chrono>
#include <thread>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "engine/guards.hpp"
#include "engine/io/checkpoint.hpp"
#include "engine/io/h5_writer.hpp"
#include "engine/model/config.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

namespace fs = std::filesystem;

using test::shell_quote;

std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::string source_config(const std::string& name) {
  return std::string(CVT_SOURCE_DIR) + "/configs/" + name + ".toml";
}

// Rows of a 1-D dataset of an HDF5 file (with SWMR read access if asked); -1 when the file
// or the dataset does not open.
long h5_rows(const fs::path& file, const char* dataset, bool swmr = false) {
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY | (swmr ? H5F_ACC_SWMR_READ : 0), H5P_DEFAULT);
  if (f < 0) return -1;
  long n = -1;
  const hid_t d = H5Dopen2(f, dataset, H5P_DEFAULT);
  if (d >= 0) {
    const hid_t sp = H5Dget_space(d);
    hsize_t dims = 0;
    H5Sget_simple_extent_dims(sp, &dims, nullptr);
    n = static_cast<long>(dims);
    H5Sclose(sp);
    H5Dclose(d);
  }
  H5Fclose(f);
  return n;
}

struct RunResult {
  int exit_code = -1;
  std::string out, err;
};

class CliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    static std::atomic<int> counter{0};
    std::random_device rd;
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::temp_directory_path() /
           ("cvt_cli_test_" + std::string(info->name()) + "_" + std::to_string(::getpid()) + "_" +
            std::to_string(counter++) + "_" + std::to_string(rd()));
    fs::create_directories(dir_);
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }

  // Runs `cvt-engine ARGS` with the temp directory as working directory; stdout and stderr
  // go to files there.
  RunResult run(const std::vector<std::string>& args) {
    std::string cmd = "cd ";
    cmd += shell_quote(dir_.string());
    cmd += " && exec ";
    cmd += shell_quote(CVT_ENGINE_EXE);
    for (const auto& a : args) {
      cmd += ' ';
      cmd += shell_quote(a);
    }
    cmd += " >";
    cmd += shell_quote((dir_ / "stdout.txt").string());
    cmd += " 2>";
    cmd += shell_quote((dir_ / "stderr.txt").string());
    const int status = std::system(cmd.c_str());
    RunResult r;
    if (status != -1 && WIFEXITED(status)) r.exit_code = WEXITSTATUS(status);
    r.out = read_text(dir_ / "stdout.txt");
    r.err = read_text(dir_ / "stderr.txt");
    return r;
  }

  // Starts `cvt-engine ARGS` in the temp directory without waiting (stdout and stderr to
  // files there); returns its pid.
  // max_file_bytes > 0: files it writes may not grow past it (RLIMIT_FSIZE, SIGXFSZ ignored),
  // so that a write fails as on a full disk.
  // Returns once the child has become cvt-engine (execv done: a close-on-exec pipe closes).
  pid_t start(const std::vector<std::string>& args, rlim_t max_file_bytes = 0) {
    int exec_seen[2];
    if (pipe2(exec_seen, O_CLOEXEC) != 0) return -1;
    const pid_t pid = fork();
    if (pid != 0) {
      ::close(exec_seen[1]);
      char c;
      while (pid > 0 && ::read(exec_seen[0], &c, 1) < 0 && errno == EINTR) {
      }
      ::close(exec_seen[0]);
      return pid;
    }
    ::close(exec_seen[0]);
    std::vector<char*> argv = {const_cast<char*>(CVT_ENGINE_EXE)};
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    if (max_file_bytes > 0) {
      const rlimit limit{max_file_bytes, max_file_bytes};
      if (setrlimit(RLIMIT_FSIZE, &limit) != 0 || signal(SIGXFSZ, SIG_IGN) == SIG_ERR) _exit(127);
    }
    if (chdir(dir_.c_str()) != 0) _exit(127);
    if (!freopen("stdout.txt", "w", stdout) || !freopen("stderr.txt", "w", stderr)) _exit(127);
    execv(CVT_ENGINE_EXE, argv.data());
    _exit(127);
  }

  // Bad input: status 78, stderr names key, value and reason, no FILE nor FILE.partial.
  void expect_config_error(std::vector<std::string> args, const std::string& key, const std::string& value,
                           const std::string& reason) {
    const std::string out = "out.h5";
    args.push_back("--quiet");
    args.push_back("--out");
    args.push_back(out);
    std::string shown;
    for (const auto& a : args) shown += " " + a;
    SCOPED_TRACE("cvt-engine" + shown);
    const RunResult r = run(args);
    EXPECT_EQ(r.exit_code, 78) << "stderr: " << r.err << "\nstdout: " << r.out;
    EXPECT_NE(r.err.find("configuration error"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find(key), std::string::npos) << "key '" << key << "' not named: " << r.err;
    if (!value.empty()) {
      EXPECT_NE(r.err.find(value), std::string::npos) << "value '" << value << "' not named: " << r.err;
    }
    EXPECT_NE(r.err.find(reason), std::string::npos) << "reason '" << reason << "' not given: " << r.err;
    EXPECT_FALSE(fs::exists(dir_ / out)) << "output file left behind";
    EXPECT_FALSE(fs::exists(dir_ / (out + ".partial"))) << "partial output file left behind";
    EXPECT_FALSE(fs::exists(dir_ / "results.h5")) << "default output file written";
  }

  fs::path dir_;
};

const std::string kMini = source_config("mini");
const std::string kReference = source_config("reference");

TEST_F(CliTest, UnknownKey) {
  expect_config_error({"run", kMini, "--set", "chain.linkz=3"}, "chain.linkz", "3", "unknown key");
}

TEST_F(CliTest, UnknownKeySuggestsKnownKey) {
  const RunResult r = run({"run", kMini, "--quiet", "--out", "out.h5", "--set", "chain.linkz=3"});
  EXPECT_EQ(r.exit_code, 78);
  EXPECT_NE(r.err.find("chain.links"), std::string::npos) << r.err;
}

TEST_F(CliTest, WrongTypeFromSet) {
  expect_config_error({"run", kMini, "--set", "chain.links=abc"}, "chain.links", "abc", "wrong type");
}

TEST_F(CliTest, WrongTypeInFile) {
  const fs::path cfg = dir_ / "bad_links.toml";
  {
    std::ofstream f(cfg);
    f << "[chain]\nlinks = 3.5\n";
  }
  expect_config_error({"run", cfg.string()}, "chain.links", "3.5", "wrong type");
  const std::string err = read_text(dir_ / "stderr.txt");
  EXPECT_NE(err.find("integer"), std::string::npos) << err;
  EXPECT_NE(err.find("line 2"), std::string::npos) << err;
}

TEST_F(CliTest, NegativePitch) {
  expect_config_error({"run", kMini, "--set", "chain.pitch=-0.008"}, "chain.pitch", "-0.008", "must be positive");
}

// A pitch that leaves the joints no radius on the pulleys is the pitch's fault, not the ratio's.
TEST_F(CliTest, PitchTooLongForThePulleys) {
  for (const char* p : {"1e10", "0.03"})
    expect_config_error({"run", kMini, "--set", std::string("chain.pitch=") + p}, "chain.pitch", "",
                        "too long for the pulleys");
  EXPECT_EQ(read_text(dir_ / "stderr.txt").find("geometry.ratio"), std::string::npos);
}

// --version names the commit the binary was built from: 12 hex digits of one that exists in
// the source tree's history ("-dirty" when tracked files differed), or "unknown" outside git.
TEST_F(CliTest, VersionNamesTheCommit) {
  const RunResult r = run({"--version"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::string prefix = std::string("cvt-engine ") + CVT_VERSION + " (commit ";
  ASSERT_EQ(r.out.rfind(prefix, 0), 0u) << r.out;
  const std::string commit = r.out.substr(prefix.size(), r.out.find(')') - prefix.size());
  if (commit == "unknown") return;
  const std::string hash = commit.substr(0, 12);
  ASSERT_EQ(hash.find_first_not_of("0123456789abcdef"), std::string::npos) << commit;
  ASSERT_EQ(hash.size(), 12u) << commit;
  EXPECT_TRUE(commit.size() == 12 || commit.substr(12) == "-dirty") << commit;
  const std::string git = "git -C " + shell_quote(CVT_SOURCE_DIR) + " cat-file -e " + hash + "^{commit} 2>/dev/null";
  EXPECT_EQ(std::system(git.c_str()), 0) << hash << " is no commit of " << CVT_SOURCE_DIR;
}

TEST_F(CliTest, ZeroAxialRigidity) {
  expect_config_error({"run", kMini, "--set", "pin.ea=0"}, "pin.ea", "0", "must be positive");
}

TEST_F(CliTest, ChainTooShort) {
  expect_config_error({"run", kReference, "--set", "chain.links=40"}, "chain.links", "40", "too short");
}

TEST_F(CliTest, ChainTooLong) {
  expect_config_error({"run", kReference, "--set", "chain.links=200"}, "chain.links", "200", "too long");
}

TEST_F(CliTest, ImpossibleRatio) {
  expect_config_error({"run", kMini, "--set", "geometry.ratio=10"}, "geometry.ratio", "10", "impossible ratio");
}

TEST_F(CliTest, BadFrictionLaw) {
  expect_config_error({"run", kMini, "--set", "friction.law=dry"}, "friction.law", "dry", "unknown friction law");
}

TEST_F(CliTest, ZeroStep) {
  // --t-end keeps the run short should --step 0 be ignored instead of rejected.
  expect_config_error({"run", kMini, "--t-end", "2e-6", "--step", "0"}, "integrator.step", "0", "must be positive");
}

TEST_F(CliTest, NegativeStep) {
  expect_config_error({"run", kMini, "--t-end", "2e-6", "--step", "-1e-8"}, "integrator.step", "-1e-",
                      "must be positive");
}

TEST_F(CliTest, UnknownMethod) {
  expect_config_error({"run", kMini, "--t-end", "2e-6", "--method", "euler"}, "integrator.method", "euler",
                      "unknown integrator method");
}

TEST_F(CliTest, ZeroWEvery) {
  expect_config_error({"run", kMini, "--t-end", "2e-6", "--set", "integrator.w_every=0"}, "integrator.w_every", "0",
                      "");
}

TEST_F(CliTest, StiffnessIntervalNotAMultipleOfWEvery) {
  expect_config_error({"run", kMini, "--t-end", "2e-6", "--set", "integrator.w_every=4", "--set",
                       "integrator.w_k_every=6"},
                      "integrator.w_k_every", "6", "must be a multiple of integrator.w_every = 4");
}

TEST_F(CliTest, BlockLUSegmentsOutsideTheirRange) {
  // The mini chain has 30 links: from 3 to 15 segments.
  for (const char* s : {"2", "16"})
    expect_config_error({"run", kMini, "--t-end", "2e-6", "--set", std::string("integrator.w_segments=") + s},
                        "integrator.w_segments", s, "must be 0 (the block LU's two sweeps) or from 3 to half of chain.links = 30");
}

TEST_F(CliTest, Ros2RunWritesOutputAndNamesTheMethod) {
  const RunResult r = run({"run", kMini, "--t-end", "2e-6", "--step", "1e-7", "--method", "ros2", "--set",
                           "integrator.w_every=4", "--out", "ros2.h5"});
  ASSERT_EQ(r.exit_code, 0) << "stderr: " << r.err << "\nstdout: " << r.out;
  EXPECT_NE(r.out.find("ros2 step = 1e-07 s (matrix every 4 steps, its stiffness every 16; 2 ros2 sub-steps per "
                       "step before t = 0.0001 s; halved where the energy balance leaks more than 0.1 % of the input "
                       "work)"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find(", 20 steps (mean 1e-07 s"), std::string::npos) << r.out;
  EXPECT_TRUE(fs::exists(dir_ / "ros2.h5"));
}

TEST_F(CliTest, Ros34pw2RunNamesTheMethod) {
  const RunResult r = run({"run", kMini, "--t-end", "2e-6", "--step", "2e-7", "--method", "ros34pw2", "--out",
                           "ros34.h5"});
  ASSERT_EQ(r.exit_code, 0) << "stderr: " << r.err << "\nstdout: " << r.out;
  EXPECT_NE(r.out.find("ros34pw2 step = 2e-07 s (matrix every 4 steps"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find(", 10 steps (mean 2e-07 s"), std::string::npos) << r.out;
  EXPECT_TRUE(fs::exists(dir_ / "ros34.h5"));
}

TEST_F(CliTest, MissingConfigFile) {
  const std::string missing = (dir_ / "no_such_config.toml").string();
  expect_config_error({"run", missing}, "cannot read the configuration file", missing, "no such file");
}

TEST_F(CliTest, MalformedSet) {
  expect_config_error({"run", kMini, "--set", "chain.links40"}, "chain.links40", "", "malformed override");
}

// A step that does not divide the sample interval or t_end is refused before the run, with
// both keys named and a step that fits.
TEST_F(CliTest, StepThatDoesNotDivideTheSampleIntervalIsRefused) {
  const RunResult r = run({"run", kMini, "--method", "ros34pw2", "--step", "3e-7", "--t-end", "1e-4", "-o", "g.h5"});
  EXPECT_EQ(r.exit_code, 78) << r.err;
  for (const char* what : {"integrator.step = 3e-07", "does not divide run.sample_interval = 1e-05 s",
                           "e.g. --step 2.94117647"})
    EXPECT_NE(r.err.find(what), std::string::npos) << what << " missing: " << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "g.h5"));
  EXPECT_FALSE(fs::exists(dir_ / "g.h5.partial"));
  const RunResult t = run({"run", kMini, "--t-end", "1.0000001e-4", "-o", "g.h5"});
  EXPECT_EQ(t.exit_code, 78) << t.err;
  EXPECT_NE(t.err.find("does not divide run.t_end = 0.00010000001 s"), std::string::npos) << t.err;
  EXPECT_NE(t.err.find("run.t_end a multiple of run.sample_interval"), std::string::npos) << t.err;
}

// Samples fall on exact multiples of the step, and the run ends at t_end.
TEST_F(CliTest, SampleTimesAreExactMultiplesOfTheStep) {
  const RunResult r = run({"run", kMini, "--method", "rk4", "--step", "3e-8", "--t-end", "3e-6", "--set",
                           "run.sample_interval=3e-7", "--set", "run.snapshot_interval=0", "-q", "-o", "t.h5"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::vector<double> t = H5File::open((dir_ / "t.h5").string()).read_doubles("/observables/input_speed/time");
  ASSERT_EQ(t.size(), 11u);
  for (std::size_t i = 0; i < t.size(); ++i) EXPECT_EQ(t[i], static_cast<double>(10 * i) * 3e-8) << i;
}

// An output folder that does not exist is refused before the run is set up: exit 73, in
// plain words, and nothing written.
TEST_F(CliTest, OutputFolderThatDoesNotExistIsRefusedFirst) {
  const RunResult r = run({"run", kMini, "--t-end", "2.5e-5", "-o", "no/such/dir/r.h5"});
  EXPECT_EQ(r.exit_code, 73) << r.err;
  EXPECT_NE(r.err.find("cannot write the output file 'no/such/dir/r.h5': the folder 'no/such/dir' does not exist"),
            std::string::npos)
      << r.err;
  EXPECT_EQ(r.err.find("H5F"), std::string::npos) << r.err;
  EXPECT_EQ(r.out.find("schedule"), std::string::npos) << "the run was set up first:\n" << r.out;
}

// RK4 with a step past its stability estimate warns with the estimated stable step (on
// stderr and in the file's /summary), before it blows up or not.
TEST_F(CliTest, Rk4StepPastItsStabilityLimitWarns) {
  const RunResult r = run({"run", kMini, "--method", "rk4", "--step", "1e-7", "--t-end", "2e-6", "--set",
                           "run.sample_interval=1e-6", "--set", "ramp.time=0", "-q", "-o", "w.h5", "--summary-json",
                           "w.json"});
  EXPECT_TRUE(r.exit_code == 0 || r.exit_code == 70) << r.err;
  EXPECT_NE(r.err.find("cvt-engine: warning: RK4's step 1e-07 s is above its stability limit"), std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("--step "), std::string::npos) << r.err;
  EXPECT_EQ(r.out, "") << "--quiet printed on stdout";
  if (r.exit_code == 0) {
    const std::string json = read_text(dir_ / "w.json");
    EXPECT_NE(json.find("above its stability limit"), std::string::npos) << json;
  }
}

// --quiet prints nothing on stdout; the run still writes its file.
TEST_F(CliTest, QuietIsQuiet) {
  const RunResult r = run({"run", kMini, "--t-end", "2.5e-5", "--quiet", "-o", "q.h5"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.out, "");
  EXPECT_EQ(r.err, "");
  EXPECT_TRUE(fs::exists(dir_ / "q.h5"));
}

// --profile prints the profile table; without it there is one throughput line.
TEST_F(CliTest, ProfileTableOnlyWithProfile) {
  const RunResult plain = run({"run", kMini, "--t-end", "2.5e-5", "-o", "p.h5"});
  ASSERT_EQ(plain.exit_code, 0) << plain.err;
  EXPECT_EQ(plain.out.find("W factorization"), std::string::npos) << plain.out;
  EXPECT_NE(plain.out.find("throughput: "), std::string::npos) << plain.out;
  const RunResult prof = run({"run", kMini, "--t-end", "2.5e-5", "-o", "p.h5", "--profile"});
  ASSERT_EQ(prof.exit_code, 0) << prof.err;
  for (const char* row : {"W stiffness", "W assembly", "W factorization", "W solves", "chain forces", "total"})
    EXPECT_NE(prof.out.find(row), std::string::npos) << row << " missing:\n" << prof.out;
}

TEST_F(CliTest, GoodRunWritesOutputAndSummary) {
  // The config's own method and step (ROS34PW2), 30 steps.
  const std::string out = "good.h5";
  const RunResult r = run({"run", kMini, "--t-end", "2.5e-5", "-o", out, "--summary-json", "s.json"});
  ASSERT_EQ(r.exit_code, 0) << "stderr: " << r.err << "\nstdout: " << r.out;
  for (const char* word : {"run complete", "operating point", "ros34pw2, step 8.333e-07 s", "status: ",
                           "means over t = ", "speed ratio", "efficiency", "energy balance residual",
                           "30 steps (mean 8.333e-07 s", "throughput: ", "per model second"})
    EXPECT_NE(r.out.find(word), std::string::npos) << "'" << word << "' missing from stdout:\n" << r.out;
  EXPECT_EQ(r.out.find("scheduling"), std::string::npos) << "the profile table without --profile:\n" << r.out;
  const std::string json = read_text(dir_ / "s.json");
  for (const char* key : {"\"status\": ", "\"reasons\": [", "\"efficiency_meaningful\": false", "\"speed_ratio\": "})
    EXPECT_NE(json.find(key), std::string::npos) << key << " missing from --summary-json:\n" << json;
  EXPECT_TRUE(fs::exists(dir_ / out));
  EXPECT_GT(fs::file_size(dir_ / out), 0u);
  EXPECT_FALSE(fs::exists(dir_ / (out + ".partial")));
}

// Nothing the run reads is written (exit 73, the file byte for byte as it was): its
// configuration, the checkpoint it resumes, the resumed run's own file under -o; no two
// outputs are one file; an output that exists as a FIFO or a link is refused, not replaced.
TEST_F(CliTest, OutputsThatAreInputsOrNotRegularFilesAreRefused) {
  fs::copy_file(kMini, dir_ / "self.toml");
  const std::string config = read_text(dir_ / "self.toml");
  ASSERT_EQ(::mkfifo((dir_ / "ff").c_str(), 0600), 0);
  fs::create_symlink("x.h5", dir_ / "lnk.h5");
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      {{"-o", "self.toml"}, "the output file 'self.toml' is the configuration"},
      {{"-o", "a.h5", "--summary-json", "self.toml"}, "the summary JSON 'self.toml' is the configuration"},
      {{"-o", "a.h5", "--profile-json", "a.h5"}, "is also the output file"},
      {{"-o", "ff"}, "not a regular file (a FIFO)"},
      {{"-o", "lnk.h5"}, "not a regular file (a link)"},
  };
  for (const auto& [args, what] : cases) {
    std::vector<std::string> a = {"run", "self.toml", "--t-end", "1e-5", "--quiet"};
    a.insert(a.end(), args.begin(), args.end());
    const RunResult r = run(a);
    EXPECT_EQ(r.exit_code, 73) << r.err;
    EXPECT_NE(r.err.find(what), std::string::npos) << what << " missing: " << r.err;
  }
  EXPECT_EQ(read_text(dir_ / "self.toml"), config);
  EXPECT_TRUE(fs::is_fifo(dir_ / "ff"));
  EXPECT_TRUE(fs::is_symlink(dir_ / "lnk.h5"));
  EXPECT_FALSE(fs::exists(dir_ / "a.h5"));
  const RunResult usage = run({"run", "self.toml", "-o", ""});
  EXPECT_EQ(usage.exit_code, 64) << usage.err;
  EXPECT_FALSE(fs::exists(dir_ / "results.h5"));

  ASSERT_EQ(run({"run", "self.toml", "--t-end", "2e-5", "--quiet", "-o", "p.h5", "--checkpoint-every", "0"}).exit_code, 0);
  const std::string file = read_text(dir_ / "p.h5"), ckpt = read_text(dir_ / "p.h5.ckpt");
  const RunResult own = run({"run", "--resume", "p.h5.ckpt", "-o", "p.h5", "--t-end", "4e-5", "--quiet"});
  EXPECT_EQ(own.exit_code, 73) << own.err;
  EXPECT_NE(own.err.find("leave -o out to append to it"), std::string::npos) << own.err;
  const RunResult onto = run({"run", "--resume", "p.h5.ckpt", "--summary-json", "p.h5.ckpt", "--t-end", "4e-5"});
  EXPECT_EQ(onto.exit_code, 73) << onto.err;
  EXPECT_NE(onto.err.find("is the checkpoint resumed from"), std::string::npos) << onto.err;
  EXPECT_EQ(read_text(dir_ / "p.h5"), file);
  EXPECT_EQ(read_text(dir_ / "p.h5.ckpt"), ckpt);
}

// One writer per file: while another process holds FILE.lock, a run onto FILE is refused
// (exit 73) before it writes anything; once it is let go of, the run goes and removes it.
TEST_F(CliTest, ASecondWriterOfTheSameFileIsRefused) {
  {
    const FileLock held((dir_ / "same.h5.lock").string(), "same.h5");
    const RunResult second = run({"run", kMini, "--t-end", "1e-5", "--quiet", "-o", "same.h5"});
    EXPECT_EQ(second.exit_code, 73) << second.err;
    EXPECT_NE(second.err.find("another cvt-engine is writing 'same.h5'"), std::string::npos) << second.err;
    EXPECT_FALSE(fs::exists(dir_ / "same.h5.partial"));
    EXPECT_FALSE(fs::exists(dir_ / "same.h5"));
  }
  const RunResult first = run({"run", kMini, "--t-end", "1e-5", "--quiet", "-o", "same.h5"});
  EXPECT_EQ(first.exit_code, 0) << first.err;
  EXPECT_TRUE(fs::exists(dir_ / "same.h5"));
  EXPECT_FALSE(fs::exists(dir_ / "same.h5.lock"));
  // The summary JSON too: two runs into other files but one JSON.
  {
    const FileLock held((dir_ / "s.json.lock").string(), "s.json");
    const RunResult other = run({"run", kMini, "--t-end", "1e-5", "--quiet", "-o", "o.h5", "--summary-json", "s.json"});
    EXPECT_EQ(other.exit_code, 73) << other.err;
    EXPECT_NE(other.err.find("another cvt-engine is writing 's.json'"), std::string::npos) << other.err;
    EXPECT_FALSE(fs::exists(dir_ / "o.h5.partial"));
  }
  EXPECT_EQ(run({"run", kMini, "--t-end", "1e-5", "--quiet", "-o", "o.h5", "--summary-json", "s.json"}).exit_code, 0);
  EXPECT_TRUE(fs::exists(dir_ / "s.json"));
  EXPECT_FALSE(fs::exists(dir_ / "s.json.lock"));
}

// A name too long for the files made beside it (FILE.partial, FILE.ckpt.tmp) is refused with
// exit 73 before the run, naming the limit; a lock file that cannot be made is not "another
// writer".
TEST_F(CliTest, ANameTooLongForItsCompanionsIsRefusedFirst) {
  const long name_max = pathconf(dir_.c_str(), _PC_NAME_MAX);
  ASSERT_GT(name_max, 20);
  const std::string too_long = std::string(static_cast<std::size_t>(name_max) - 6, 'a') + ".h5";
  const RunResult r = run({"run", kMini, "--t-end", "1e-5", "--quiet", "-o", too_long});
  EXPECT_EQ(r.exit_code, 73) << r.err;
  EXPECT_NE(r.err.find("past the file system's limit of " + std::to_string(name_max)), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("another cvt-engine"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / too_long));
  const std::string fits = std::string(static_cast<std::size_t>(name_max) - 12, 'b') + ".h5";
  EXPECT_EQ(run({"run", kMini, "--t-end", "1e-5", "--quiet", "-o", fits}).exit_code, 0);
}

// A refused continuation leaves every file byte for byte as it was, under its name: the
// run's own file when it is empty, not HDF5, truncated, or another run's; the checkpoint.
TEST_F(CliTest, ARefusedResumeLeavesTheFilesAsTheyWere) {
  ASSERT_EQ(run({"run", kMini, "--t-end", "2e-5", "--quiet", "-o", "p.h5", "--checkpoint-every", "0"}).exit_code, 0);
  ASSERT_EQ(run({"run", kMini, "--t-end", "2e-5", "--quiet", "-o", "other.h5"}).exit_code, 0);
  const std::string good = read_text(dir_ / "p.h5"), ckpt = read_text(dir_ / "p.h5.ckpt");
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"empty", ""}, {"not HDF5", std::string(5000, 'x')}, {"truncated", good.substr(0, 3000)},
      {"another run's", read_text(dir_ / "other.h5")}};
  for (const auto& [what, bytes] : cases) {
    SCOPED_TRACE(what);
    {
      std::ofstream f(dir_ / "p.h5", std::ios::binary | std::ios::trunc);
      f << bytes;
    }
    const RunResult r = run({"run", "--resume", "p.h5.ckpt", "--t-end", "4e-5", "--quiet"});
    EXPECT_EQ(r.exit_code, 1) << r.err;
    EXPECT_NE(r.err.find("cannot continue"), std::string::npos) << r.err;
    EXPECT_EQ(read_text(dir_ / "p.h5"), bytes) << "the refused file was changed";
    EXPECT_EQ(read_text(dir_ / "p.h5.ckpt"), ckpt) << "the checkpoint was changed";
    EXPECT_FALSE(fs::exists(dir_ / "p.h5.partial"));
  }
}

// Every dataset under group of two files, read as doubles (the observables and the chain's
// particles: what a continuation must reproduce bit for bit).
std::vector<std::vector<double>> h5_group_doubles(const fs::path& file, const std::string& group) {
  std::vector<std::vector<double>> out;
  H5File f = H5File::open(file.string());
  struct Walk {
    static herr_t visit(hid_t g, const char* name, const H5O_info_t* info, void* data) {
      if (info->type != H5O_TYPE_DATASET) return 0;
      auto* out = static_cast<std::vector<std::vector<double>>*>(data);
      const hid_t d = H5Dopen2(g, name, H5P_DEFAULT);
      const hid_t sp = H5Dget_space(d);
      std::vector<double> v(static_cast<std::size_t>(H5Sget_simple_extent_npoints(sp)));
      if (!v.empty()) H5Dread(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, v.data());
      out->push_back(std::move(v));
      H5Sclose(sp);
      H5Dclose(d);
      return 0;
    }
  };
  f.close();
  const hid_t fid = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  if (fid < 0) return out;
  const hid_t g = H5Gopen2(fid, group.c_str(), H5P_DEFAULT);
  H5Ovisit(g, H5_INDEX_NAME, H5_ITER_INC, &Walk::visit, &out);
  H5Gclose(g);
  H5Fclose(fid);
  return out;
}

// The continuation's observables and particles are those of the uninterrupted run.
void expect_same_run(const fs::path& a, const fs::path& b) {
  for (const char* group : {"/observables", "/particles"}) {
    const auto x = h5_group_doubles(a, group), y = h5_group_doubles(b, group);
    ASSERT_FALSE(x.empty()) << group;
    ASSERT_EQ(x.size(), y.size()) << group;
    for (std::size_t i = 0; i < x.size(); ++i) EXPECT_TRUE(x[i] == y[i]) << group << ": dataset " << i << " differs";
  }
}

// A run killed with kill -9 leaves its file marked as open for writing; its continuation
// clears that mark itself (no h5clear) and gives the uninterrupted run's bits.
TEST_F(CliTest, AContinuationAfterKill9NeedsNoH5clear) {
  const std::vector<std::string> args = {"run", kMini, "--t-end", "0.006", "--checkpoint-every", "128",
                                         "--flush-every", "0.1", "--quiet"};
  auto killed = args;
  for (const char* a : {"-o", "k.h5"}) killed.push_back(a);
  const pid_t pid = start(killed);
  ASSERT_NE(pid, -1);
  // Up to 2 minutes for the first checkpoint: a loaded machine or a sanitizer build is slow.
  for (int i = 0; i < 4800 && !fs::exists(dir_ / "k.h5.ckpt"); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(25));
  std::this_thread::sleep_for(std::chrono::milliseconds(600));
  ASSERT_EQ(kill(pid, SIGKILL), 0);
  int status = 0;
  waitpid(pid, &status, 0);
  ASSERT_TRUE(fs::exists(dir_ / "k.h5.partial"));
  ASSERT_TRUE(fs::exists(dir_ / "k.h5.ckpt")) << "killed before its first checkpoint";
  EXPECT_EQ(h5_rows(dir_ / "k.h5.partial", "/observables/input_speed/time"), -1)
      << "the killed run's file opens without clearing: the case is not tested";
  const RunResult resumed = run({"run", "--resume", "k.h5.ckpt", "--quiet"});
  ASSERT_EQ(resumed.exit_code, 0) << resumed.err;
  EXPECT_FALSE(fs::exists(dir_ / "k.h5.partial"));
  auto whole = args;
  for (const char* a : {"-o", "whole.h5"}) whole.push_back(a);
  ASSERT_EQ(run(whole).exit_code, 0);
  expect_same_run(dir_ / "k.h5", dir_ / "whole.h5");
}

// A write that fails as on a full disk (the file size limit of the process) ends the run with
// exit 73, no crash, a message naming the reason and the way on, and a whole checkpoint,
// from which the run, once there is room, continues to the uninterrupted run's bits.
TEST_F(CliTest, AFullDiskEndsWithExit73AndAWholeCheckpoint) {
  const std::vector<std::string> args = {"run", kMini, "--t-end", "0.004", "--checkpoint-every", "128",
                                         "--flush-every", "0.1", "--quiet"};
  auto limited = args;
  for (const char* a : {"-o", "full.h5"}) limited.push_back(a);
  const pid_t pid = start(limited, 1500 * 1024);
  ASSERT_NE(pid, -1);
  int status = 0;
  ASSERT_EQ(waitpid(pid, &status, 0), pid);
  const std::string err = read_text(dir_ / "stderr.txt");
  ASSERT_TRUE(WIFEXITED(status)) << "ended by signal " << WTERMSIG(status) << ": " << err;
  EXPECT_EQ(WEXITSTATUS(status), 73) << err;
  for (const char* what : {"writing the run's output failed at t = ", "File too large", "is whole",
                           "cvt-engine run --resume full.h5.ckpt"})
    EXPECT_NE(err.find(what), std::string::npos) << what << " missing: " << err;
  EXPECT_FALSE(fs::exists(dir_ / "full.h5.ckpt.tmp"));
  const RunResult resumed = run({"run", "--resume", "full.h5.ckpt", "--quiet"});
  ASSERT_EQ(resumed.exit_code, 0) << resumed.err;
  auto whole = args;
  for (const char* a : {"-o", "whole.h5"}) whole.push_back(a);
  ASSERT_EQ(run(whole).exit_code, 0);
  expect_same_run(dir_ / "full.h5", dir_ / "whole.h5");
}

// A cluster job: --max-wall stops the run with its checkpoint (exit 75), and the same command
// line with --continue, resubmitted until it ends, gives the uninterrupted run's bits; once
// complete it runs nothing; another configuration, or a malformed wall time, is refused.
TEST_F(CliTest, AJobStoppedByMaxWallContinuesWhenResubmitted) {
  const std::vector<std::string> job = {"run", kMini, "--t-end", "0.02", "-o", "job.h5", "--max-wall", "2",
                                        "--continue", "--quiet"};
  std::vector<int> codes;
  std::string err;
  for (int k = 0; k < 60 && (codes.empty() || codes.back() == 75); ++k) {
    const RunResult r = run(job);
    codes.push_back(r.exit_code);
    err += r.err;
  }
  ASSERT_EQ(codes.back(), 0) << err;
  ASSERT_GE(codes.size(), 2u) << "never stopped by --max-wall: the case is not tested";
  EXPECT_NE(err.find("before its wall-time limit (run.max_wall = 2 s)"), std::string::npos) << err;
  EXPECT_NE(err.find("the same command with --continue"), std::string::npos) << err;
  ASSERT_EQ(run({"run", kMini, "--t-end", "0.02", "-o", "whole.h5", "--quiet"}).exit_code, 0);
  expect_same_run(dir_ / "job.h5", dir_ / "whole.h5");

  const auto bytes = read_text(dir_ / "job.h5");
  const RunResult again = run({"run", kMini, "--t-end", "0.02", "-o", "job.h5", "--max-wall", "2", "--continue"});
  EXPECT_EQ(again.exit_code, 0) << again.err;
  EXPECT_NE(again.out.find("job.h5 is complete (stopped: t_end"), std::string::npos) << again.out;
  EXPECT_EQ(read_text(dir_ / "job.h5"), bytes) << "a complete run was run again";

  const RunResult other = run({"run", kMini, "--t-end", "0.03", "--set", "load.torque=12", "-o", "job.h5", "--continue"});
  EXPECT_EQ(other.exit_code, 78) << other.err;
  EXPECT_NE(other.err.find("made by another configuration ([load] torque = 10.0 there, torque = 12.0 here)"),
            std::string::npos) << other.err;
  for (const char* bad : {"2:61", "0", "1h30", "abc", "1-x:00", "nan"})
    expect_config_error({"run", kMini, "--max-wall", bad}, "--max-wall", bad, "a wall time");
}

TEST(CliDuration, WallTimesAreReadAsJobSchedulersWriteThem) {
  // What --max-wall accepts, through the key it sets (run.max_wall in the resolved TOML).
  for (const auto& [text, seconds] : std::vector<std::pair<std::string, double>>{
           {"3600", 3600}, {"90m", 5400}, {"23.5h", 84600}, {"45s", 45}, {"23:50:00", 85800}, {"1-00:00:00", 86400},
           {"10:30", 37800}}) {
    const fs::path dir = fs::temp_directory_path() / ("cvt_cli_duration_" + std::to_string(getpid()));
    fs::create_directories(dir);
    const std::string cmd = "cd " + shell_quote(dir.string()) + " && " + shell_quote(CVT_ENGINE_EXE) + " run " +
                            shell_quote(kMini) + " --t-end 1e-5 -q -o d.h5 --max-wall " + text + " > /dev/null 2>&1";
    ASSERT_EQ(std::system(cmd.c_str()), 0) << text;
    const Config c = parse_config(read_checkpoint((dir / "d.h5.ckpt").string()).config_toml);
    EXPECT_EQ(c.run.max_wall, seconds) << text;
    fs::remove_all(dir);
  }
}

// A numerical failure (a matrix singular at every retake from a sound state) is reported like
// a blow-up: exit 70, the time and what to change, every good sample kept under FILE.
TEST_F(CliTest, ANumericalFailureIsReportedLikeABlowUp) {
  const RunResult r = run({"run", kMini, "--set", "drive.speed=1e30", "--t-end", "1e-4", "--quiet", "-o", "n.h5"});
  EXPECT_EQ(r.exit_code, 70) << r.err;
  for (const char* what : {"numerical failure", "singular at t = 0 s", "Every sample before the blow-up is in n.h5"})
    EXPECT_NE(r.err.find(what), std::string::npos) << what << " missing: " << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "n.h5.partial"));
  EXPECT_GE(h5_rows(dir_ / "n.h5", "/observables/input_speed/time"), 1) << "the kept file does not open";
}

// The run's contract (docs/cli.md): a configuration that cannot be read is an error, never
// an empty one (which would run the defaults); a FIFO is refused, not waited on.
TEST_F(CliTest, AnUnreadableConfigurationIsAnErrorNotTheDefaults) {
  const RunResult mem = run({"run", "/proc/self/mem", "-o", "m.h5"});
  EXPECT_EQ(mem.exit_code, 78) << mem.err;
  EXPECT_NE(mem.err.find("cannot read the configuration file"), std::string::npos) << mem.err;
  EXPECT_FALSE(fs::exists(dir_ / "m.h5"));
  ASSERT_EQ(::mkfifo((dir_ / "fifo.toml").c_str(), 0600), 0);
  const RunResult fifo = run({"run", "fifo.toml", "-o", "f.h5"});
  EXPECT_EQ(fifo.exit_code, 78) << fifo.err;
  EXPECT_NE(fifo.err.find("not a regular file"), std::string::npos) << fifo.err;
}

// Ranges that make a run impossible are refused before its first line: more steps than a
// run can count, sub-steps a step could not finish, a step that divides the sample interval
// only to 1e-8, a tolerance at the end of its open range; a value of megabytes is named,
// not echoed.
TEST_F(CliTest, RangesThatMakeARunImpossibleAreRefused) {
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      {{"--set", "run.t_end=1e13"}, "run.t_end = 1e13: is 1.2e19 steps"},
      {{"--set", "run.t_end=1e300"}, "more than a run can count"},
      {{"--set", "integrator.startup_step=1e-15"}, "integrator.startup_step = 1e-15: gives 833333334 sub-steps"},
      {{"--set", "integrator.settle_step=1e-15"}, "a step could not finish"},
      {{"--step", "3.3333333e-6"}, "does not divide run.sample_interval = 1e-05 s (3.00000003 steps)"},
      {{"--set", "run.steady_tolerance=1"}, "must be in (0, 1)"},
      {{"--set", "run.out=\"" + std::string(100000, 'x') + "\""}, "... (100002 characters)"},
  };
  for (const auto& [args, what] : cases) {
    std::vector<std::string> a = {"run", kMini, "-o", "r.h5"};
    a.insert(a.end(), args.begin(), args.end());
    const RunResult r = run(a);
    EXPECT_EQ(r.exit_code, 78) << args[1].substr(0, 60) << ": " << r.err.substr(0, 400);
    EXPECT_NE(r.err.find(what), std::string::npos) << what << " missing: " << r.err.substr(0, 400);
    EXPECT_LT(r.err.size(), 2000u) << "the message echoes the value";
    EXPECT_EQ(r.out.find("cvt-engine 0"), std::string::npos) << "refused after the run's header";
    EXPECT_FALSE(fs::exists(dir_ / "r.h5"));
    EXPECT_FALSE(fs::exists(dir_ / "r.h5.partial"));
  }
}

// Command-line numbers are finite (CLI11's own checks let nan through), and a thread count
// above the machine's is capped with a warning: the run ends, with the bits of any count.
TEST_F(CliTest, NonFiniteNumbersAreRefusedAndThreadsAreCapped) {
  for (const char* v : {"nan", "inf", "0", "-1"}) {
    const RunResult r = run({"run", kMini, "--flush-every", v, "-o", "n.h5"});
    EXPECT_EQ(r.exit_code, 64) << v << ": " << r.err;
    EXPECT_NE(r.err.find("must be a finite number > 0"), std::string::npos) << r.err;
    EXPECT_LT(r.err.size(), 400u) << r.err;
  }
  const RunResult many = run({"run", kMini, "--t-end", "2.5e-6", "--threads", "4096", "--quiet", "-o", "t.h5"});
  EXPECT_EQ(many.exit_code, 0) << many.err;
  EXPECT_NE(many.err.find("--threads 4096 is more than the"), std::string::npos) << many.err;
  EXPECT_TRUE(fs::exists(dir_ / "t.h5"));
}

}  // namespace
}  // namespace cvt

namespace cvt {
namespace {

// Usage errors (an option's value outside its set or range) exit with 64 and write nothing.
TEST_F(CliTest, BadSchedulerIsAUsageError) {
  for (const std::vector<std::string>& extra :
       {std::vector<std::string>{"--scheduler", "openmp"}, {"--threads", "0"}, {"--grain", "-1"}}) {
    std::vector<std::string> args = {"run", kMini, "--quiet", "--out", "out.h5"};
    args.insert(args.end(), extra.begin(), extra.end());
    const RunResult r = run(args);
    EXPECT_EQ(r.exit_code, 64) << extra[0] << ": " << r.err;
    EXPECT_NE(r.err.find(extra[0]), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(dir_ / "out.h5"));
  }
}

// Threads without a scheduler run on the flow graph; the serial schedule with more than one
// thread is a contradiction, refused before anything runs.
TEST_F(CliTest, ThreadsAloneRunOnTheFlowGraphAndSerialRefusesThem) {
  const RunResult two = run({"run", kMini, "--t-end", "2.5e-6", "-o", "two.h5", "--threads", "2"});
  ASSERT_EQ(two.exit_code, 0) << two.err;
  EXPECT_NE(two.out.find("schedule: flowgraph (2 threads"), std::string::npos) << two.out;
  const RunResult one = run({"run", kMini, "--t-end", "2.5e-6", "-o", "one.h5"});
  ASSERT_EQ(one.exit_code, 0) << one.err;
  EXPECT_NE(one.out.find("schedule: serial (1 thread)"), std::string::npos) << one.out;
  const RunResult bad = run({"run", kMini, "--quiet", "-o", "bad.h5", "--scheduler", "serial", "--threads", "2"});
  EXPECT_EQ(bad.exit_code, 64) << bad.err;
  EXPECT_NE(bad.err.find("--scheduler serial runs on one thread"), std::string::npos) << bad.err;
  EXPECT_FALSE(fs::exists(dir_ / "bad.h5"));
}

TEST_F(CliTest, GraphPrintsTheStageAsGraphViz) {
  const RunResult r = run({"graph", kReference, "--threads", "2"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* node : {"digraph", "chain_forces", "pulley_contact", "other_forces", "inertia_decomposition",
                           "gather", "accelerations"})
    EXPECT_NE(r.out.find(node), std::string::npos) << node << " missing:\n" << r.out;
}

// --w-step: the W-method's whole step around the stage graph: its four stages, each an
// evaluation and a solve on the block LU's two sweeps, the rebuilds, and for adaptive steps
// the error test; refused for RK4.
TEST_F(CliTest, GraphDrawsTheWStep) {
  const RunResult r = run({"graph", kReference, "--threads", "2", "--w-step"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* node : {"digraph w_step", "evaluation 4", "solve4", "top sweep (thread 0) | bottom sweep (thread 1)",
                           "every 8 steps (stiffness every 32)", "stage sums"})
    EXPECT_NE(r.out.find(node), std::string::npos) << node << " missing:\n" << r.out;
  EXPECT_EQ(r.out.find("error norm"), std::string::npos);
  const RunResult a = run({"graph", kReference, "--w-step", "--set", "integrator.tolerance=3"});
  ASSERT_EQ(a.exit_code, 0) << a.err;
  EXPECT_NE(a.out.find("error norm per pin"), std::string::npos) << a.out;
  EXPECT_NE(a.out.find("top sweep, then bottom sweep"), std::string::npos) << a.out;
  const RunResult k = run({"graph", kReference, "--w-step", "--set", "integrator.method=rk4"});
  EXPECT_NE(k.exit_code, 0);
  EXPECT_NE(k.err.find("--w-step draws a W-method's step"), std::string::npos) << k.err;
}

TEST_F(CliTest, TopologyReportsNodesPinsAndBinding) {
  const RunResult r = run({"topology", kReference, "--threads", "2"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* what : {"NUMA nodes", "[0, 84)", "thread binding", "memory binding"})
    EXPECT_NE(r.out.find(what), std::string::npos) << what << " missing:\n" << r.out;
}

// SIGINT or SIGTERM during a run: the step finishes, the file is closed and kept under
// its final name with every sample so far, the summary says so, and the exit code is 130.
class CliSignalTest : public CliTest, public ::testing::WithParamInterface<int> {};

TEST_P(CliSignalTest, StopsCleanlyAndKeepsTheFile) {
  const int sig = GetParam();
  const pid_t pid = start({"run", kMini, "--method", "rk4", "--step", "1e-8", "--t-end", "1.0", "--out", "sig.h5",
                           "--quiet"});
  ASSERT_NE(pid, -1);
  // Let it run: the file exists from the start; wait a little longer for some samples.
  for (int i = 0; i < 200 && !fs::exists(dir_ / "sig.h5.partial"); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  std::this_thread::sleep_for(std::chrono::milliseconds(1500));
  ASSERT_EQ(kill(pid, sig), 0);
  int status = 0;
  ASSERT_EQ(waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFEXITED(status)) << "killed instead of stopping";
  EXPECT_EQ(WEXITSTATUS(status), 130);
  const std::string err = read_text(dir_ / "stderr.txt");
  EXPECT_NE(err.find("run interrupted by signal " + std::to_string(sig)), std::string::npos) << err;
  EXPECT_NE(err.find("--resume sig.h5.ckpt"), std::string::npos) << err;
  EXPECT_EQ(read_text(dir_ / "stdout.txt"), "") << "--quiet printed on stdout";
  EXPECT_FALSE(fs::exists(dir_ / "sig.h5.partial"));
  EXPECT_TRUE(fs::exists(dir_ / "sig.h5.ckpt")) << "no checkpoint written at the stop";
  ASSERT_TRUE(fs::exists(dir_ / "sig.h5"));
  const long n = h5_rows(dir_ / "sig.h5", "/observables/input_speed/time");
  std::printf("signal %d: exit %d, %ld samples kept\n", sig, WEXITSTATUS(status), n);
  EXPECT_GT(n, 1) << "the kept file does not open, or holds no samples";
}

INSTANTIATE_TEST_SUITE_P(Signals, CliSignalTest, ::testing::Values(SIGINT, SIGTERM, SIGHUP));

// A signal at any moment from the start leaves a readable file or none, never a torn
// FILE.partial, and always a message: before the run begins the process ends with 128 + the
// signal (the launcher blocks the signals from its first instruction, so one that comes
// while the engine's shared libraries load waits for its handlers); once it has begun, the
// run stops at its next stop point with exit 130 and keeps its file.
TEST_P(CliSignalTest, AtAnyMomentLeavesAReadableFileOrNone) {
  const int sig = GetParam();
  // Until the static launcher's first instruction has run (microseconds of start-up, but the
  // process may wait for a core on a busy machine) a signal ends it by its default action, as
  // for any program; from 10 ms on (the engine's shared libraries load for about 20 ms)
  // there is always a message.
  for (const int ms : {0, 1, 3, 10, 15, 20, 25, 30, 45, 60, 90, 150}) {
    SCOPED_TRACE("signal " + std::to_string(sig) + " after " + std::to_string(ms) + " ms");
    for (const char* f : {"e.h5", "e.h5.partial", "e.h5.ckpt"}) fs::remove(dir_ / f);
    const pid_t pid = start({"run", kMini, "--t-end", "0.01", "--out", "e.h5", "--quiet"});
    ASSERT_NE(pid, -1);
    std::this_thread::sleep_for(std::chrono::milliseconds(ms));
    ASSERT_EQ(kill(pid, sig), 0);
    int status = 0;
    ASSERT_EQ(waitpid(pid, &status, 0), pid);
    EXPECT_FALSE(fs::exists(dir_ / "e.h5.partial")) << "a torn file left behind";
    if (fs::exists(dir_ / "e.h5")) {
      ASSERT_TRUE(WIFEXITED(status));
      EXPECT_TRUE(WEXITSTATUS(status) == 130 || WEXITSTATUS(status) == 0) << WEXITSTATUS(status);
      EXPECT_GT(h5_rows(dir_ / "e.h5", "/observables/input_speed/time"), 0) << "the kept file does not open";
    } else if (ms < 10 && WIFSIGNALED(status)) {
      EXPECT_EQ(WTERMSIG(status), sig);
    } else {
      ASSERT_TRUE(WIFEXITED(status)) << "ended by the signal's default action, with no message";
      EXPECT_EQ(WEXITSTATUS(status), 128 + sig);
      EXPECT_NE(read_text(dir_ / "stderr.txt").find("stopped by a signal before a run or sweep began"),
                std::string::npos);
    }
  }
}

// Slow steps (here some 3333 settling sub-steps each, about half a second): a stop is taken
// within a second of the signal, not at the next matrix rebuild 16 steps on.
TEST_P(CliSignalTest, AStopIsTakenWithinASecondEvenWhenStepsAreSlow) {
  const int sig = GetParam();
  const pid_t pid = start({"run", kMini, "--set", "integrator.startup_time=0", "--set", "integrator.settle_step=2.5e-10",
                           "--set", "integrator.settle_time=1", "--t-end", "0.001", "--out", "slow.h5", "--quiet"});
  ASSERT_NE(pid, -1);
  std::this_thread::sleep_for(std::chrono::milliseconds(2500));
  ASSERT_EQ(kill(pid, sig), 0);
  int status = 0;
  ASSERT_EQ(waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 130) << read_text(dir_ / "stderr.txt");
  const hid_t f = H5Fopen((dir_ / "slow.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  long steps = -1;
  const hid_t a = H5Aopen_by_name(f, "/summary", "steps", H5P_DEFAULT, H5P_DEFAULT);
  H5Aread(a, H5T_NATIVE_LONG, &steps);
  H5Aclose(a);
  H5Fclose(f);
  std::printf("signal %d: stopped after %ld slow steps\n", sig, steps);
  EXPECT_GT(steps, 0);
  EXPECT_LT(steps, 16) << "waited for the matrix rebuild";
}

// The output file can be read while the run writes it (SWMR), and after kill -9 it still
// opens and holds every sample up to the last flush.
TEST_F(CliTest, FileIsReadableWhileWritingAndSurvivesKill9) {
  const pid_t pid = start({"run", kMini, "--method", "rk4", "--step", "1e-8", "--t-end", "1.0", "--out", "live.h5",
                           "--quiet", "--flush-every", "0.2"});
  ASSERT_NE(pid, -1);
  const auto rows = [&] { return h5_rows(dir_ / "live.h5.partial", "/observables/input_speed/time", true); };
  // Polled, not timed: a sanitizer build on a loaded machine writes its first rows late.
  const auto rows_above = [&](long n) {
    long r = rows();
    for (int i = 0; i < 1200 && r <= n; ++i) {
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
      r = rows();
    }
    return r;
  };
  const long first = rows_above(0);
  const long second = rows_above(first);
  ASSERT_EQ(kill(pid, SIGKILL), 0);
  int status = 0;
  waitpid(pid, &status, 0);
  const long after = rows();
  std::printf("rows while running: %ld then %ld; after kill -9: %ld\n", first, second, after);
  EXPECT_GT(first, 0) << "not readable while the run writes it";
  EXPECT_GT(second, first) << "a reader does not see the file grow";
  EXPECT_GE(after, second) << "kill -9 lost flushed samples or the file no longer opens";
}

// A step far above the stable RK4 step blows the run up: exit 70, a message naming time,
// step, the coordinate and the stable step estimated from the Jacobian's spectral radius
// (below the step that failed), and a file with every good sample.
TEST_F(CliTest, BlowUpIsExplainedAndKeepsTheGoodSamples) {
  const RunResult r =
      run({"run", kMini, "--method", "rk4", "--step", "1e-5", "--t-end", "1e-3", "--out", "bu.h5", "--quiet"});
  EXPECT_EQ(r.exit_code, 70) << r.err;
  for (const char* what : {"numerical blow-up at t = ", "(step ", "joint", "replayed from t = ", "first bad state",
                           "largest acceleration", "pin ", "dominate", "spectral radius", "stable for h up to about",
                           "reduce integrator.step", "bu.h5"})
    EXPECT_NE(r.err.find(what), std::string::npos) << what << " missing: " << r.err;
  EXPECT_TRUE(r.err.find("is not finite") != std::string::npos || r.err.find("absurd penetration") != std::string::npos)
      << r.err;
  double h_stable = 0;
  const auto at = r.err.find("stable for h up to about ");
  ASSERT_NE(at, std::string::npos);
  h_stable = std::atof(r.err.c_str() + at + std::strlen("stable for h up to about "));
  EXPECT_GT(h_stable, 0.0);
  EXPECT_LT(h_stable, 1e-5);
  ASSERT_TRUE(fs::exists(dir_ / "bu.h5"));
  EXPECT_FALSE(fs::exists(dir_ / "bu.h5.partial"));
  const hid_t f = H5Fopen((dir_ / "bu.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const hid_t d = H5Dopen2(f, "/observables/input_speed/value", H5P_DEFAULT);
  const hid_t sp = H5Dget_space(d);
  hsize_t n = 0;
  H5Sget_simple_extent_dims(sp, &n, nullptr);
  std::vector<double> v(n);
  H5Dread(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, v.data());
  EXPECT_GE(n, 1u);
  for (double x : v) EXPECT_TRUE(std::isfinite(x)) << "a bad sample was kept";
  std::printf("blow-up: %llu good samples kept; estimated stable step %.3g s\n", static_cast<unsigned long long>(n), h_stable);
  H5Sclose(sp);
  H5Dclose(d);
  H5Fclose(f);
}

// `scale` refuses a bad layout or an unwritable output before it runs anything, and
// writes its CSV and JSON otherwise.
TEST_F(CliTest, ScaleChecksItsInputsFirstAndWritesItsFiles) {
  const RunResult bad_layout = run({"scale", kMini, "--layouts", "garbage", "--steps", "2", "--repeat", "1"});
  EXPECT_EQ(bad_layout.exit_code, 1) << bad_layout.err;
  EXPECT_NE(bad_layout.err.find("hwloc rejects this synthetic description"), std::string::npos) << bad_layout.err;
  EXPECT_EQ(bad_layout.err.find("warmed up"), std::string::npos) << "ran before checking the layout";
  const RunResult bad_out = run({"scale", kMini, "--steps", "2", "--repeat", "1", "--out", "no/such/dir/s.csv"});
  EXPECT_EQ(bad_out.exit_code, 1) << bad_out.err;
  EXPECT_NE(bad_out.err.find("cannot write"), std::string::npos) << bad_out.err;
  const RunResult usage = run({"scale", kMini, "--schedulers", "foo"});
  EXPECT_EQ(usage.exit_code, 64) << usage.err;
  const RunResult ok = run({"scale", kMini, "--threads", "1,2", "--steps", "3", "--repeat", "1", "--warmup", "1e-6",
                            "--out", "s.csv", "--json", "s.json"});
  EXPECT_EQ(ok.exit_code, 0) << ok.err;
  EXPECT_TRUE(fs::exists(dir_ / "s.csv"));
  EXPECT_TRUE(fs::exists(dir_ / "s.json"));
}

}  // namespace
}  // namespace cvt
