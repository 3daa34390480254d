// Bad input never crashes: mutated configuration files and random
// --set strings go through the loader and the model builder. Every outcome must be either
// a model with a finite initial state or a ConfigError that names a key and a reason;
// any other exception, a crash or a hang is a failure. Deterministic seeds: a failure
// prints the mutant so that it can be replayed.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <sys/wait.h>

#include "engine/model/config.hpp"
#include "engine/model/model.hpp"
#include "engine/io/h5_writer.hpp"
#include "engine/studies/sweep.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

namespace fs = std::filesystem;

std::string read_text(const std::string& path) {
  std::ifstream f(path);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

// Outcome of one input: "" when acceptable, else what went wrong.
std::string check(const std::string& path, const std::vector<std::string>& sets, bool* was_error = nullptr) {
  try {
    const Model m = build_model(load_config(path, sets));
    for (int i = 0; i < m.nstate; ++i)
      if (!std::isfinite(m.y0[i])) return "accepted, but the initial state has a non-finite entry " + std::to_string(i);
    return "";
  } catch (const ConfigError& e) {
    if (was_error) *was_error = true;
    if (e.key().empty() || e.reason().empty()) return std::string("ConfigError without key or reason: ") + e.what();
    return "";
  } catch (const std::exception& e) {
    return std::string("not a ConfigError: ") + e.what();
  }
}

const char* kValues[] = {"0", "-1", "1e308", "-1e308", "1e-308", "nan", "inf", "-inf", "99999999999999999999",
                         "\"text\"", "[1, 2]", "{ a = 1 }", "true", "1979-05-27", "0x10", "''", "\"\"", "",
                         "1.5", "3", "-0.0", "1e400"};

class ConfigFuzzTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("cvt_fuzz_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
    base_ = read_text(test::config_path("mini"));
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
  std::string base_;
};

TEST_F(ConfigFuzzTest, MutatedFilesGiveAModelOrAClearError) {
  std::mt19937_64 rng(20261121);
  const std::string path = (dir_ / "mutant.toml").string();
  int accepted = 0, rejected = 0;
  for (int n = 0; n < 2000; ++n) {
    std::string s = base_;
    const int kind = n % 6;
    const auto pos = [&] { return std::uniform_int_distribution<size_t>(0, s.size() - 1)(rng); };
    if (kind == 0) {  // flip a byte to anything, NUL and 0xFF included
      s[pos()] = static_cast<char>(std::uniform_int_distribution<int>(0, 255)(rng));
    } else if (kind == 1) {  // delete a span
      const size_t p = pos();
      s.erase(p, std::uniform_int_distribution<size_t>(1, 40)(rng));
    } else if (kind == 2) {  // truncate
      s.resize(pos());
    } else if (kind == 3) {  // duplicate a line (duplicate keys)
      const size_t p = s.rfind('\n', pos());
      const size_t b = p == std::string::npos ? 0 : p + 1, e = s.find('\n', b);
      s.insert(b, s.substr(b, e - b) + "\n");
    } else {  // replace the value of a random key by an extreme one
      size_t eq = s.find(" = ", pos());
      if (eq == std::string::npos) eq = s.find(" = ");
      const size_t end = s.find_first_of("#\n", eq + 3);
      s.replace(eq + 3, end - (eq + 3), std::string(kValues[std::uniform_int_distribution<size_t>(0, std::size(kValues) - 1)(rng)]) + " ");
    }
    {
      std::ofstream f(path, std::ios::binary);
      f << s;
    }
    bool was_error = false;
    const std::string r = check(path, {}, &was_error);
    if (!r.empty()) {
      fs::copy_file(path, dir_ / "failing.toml", fs::copy_options::overwrite_existing);
      ADD_FAILURE() << "mutant " << n << " (kind " << kind << "): " << r << "\n--- mutant ---\n" << s;
      break;
    }
    (was_error ? rejected : accepted) += 1;
  }
  std::printf("2000 mutated files: %d accepted, %d rejected with a ConfigError\n", accepted, rejected);
}

TEST_F(ConfigFuzzTest, RandomSetStringsGiveAModelOrAClearError) {
  std::mt19937_64 rng(77);
  const std::string path = test::config_path("mini");
  const char* keys[] = {"chain.links", "chain.pitch", "chain.plates_per_link", "geometry.ratio",
                        "geometry.centre_distance", "rocker.stations", "sheave.cone_angle", "sheave.hub_radius",
                        "friction.law", "integrator.method", "run.tracked_pin", "controller.enabled",
                        "run.t_end", "damping.scale", "chain", "chain.", ".links", "a.b.c", "", "chain.links.x"};
  const char* shapes[] = {"%s=%s", "%s = %s", "%s", "=%s", "%s==%s", "%s=%s=%s"};
  for (int n = 0; n < 600; ++n) {
    const char* key = keys[std::uniform_int_distribution<size_t>(0, std::size(keys) - 1)(rng)];
    const char* value = kValues[std::uniform_int_distribution<size_t>(0, std::size(kValues) - 1)(rng)];
    const char* shape = shapes[std::uniform_int_distribution<size_t>(0, std::size(shapes) - 1)(rng)];
    char buf[256];
    std::snprintf(buf, sizeof buf, shape, key, value, value);
    const std::string r = check(path, {buf});
    ASSERT_TRUE(r.empty()) << "--set '" << buf << "': " << r;
  }
  std::printf("600 random --set strings: every one gave a model or a ConfigError\n");
}

// Mutated shipped points files: a plan or a ConfigError that names a line, never another
// exception or a crash. A plan read is the file's: written back by RFC 4180 (every field
// quoted) it reads as the same plan, and each point's values go through the configuration's
// validation as a model or a ConfigError.
TEST_F(ConfigFuzzTest, MutatedPointsFilesGiveAPlanOrAClearError) {
  std::mt19937_64 rng(20261128);
  const std::string path = (dir_ / "mutant.csv").string(), back = (dir_ / "back.csv").string();
  const char inserts[] = {'"', ',', '#', '\n', '\r', ' ', '\0', 'x', '1'};
  int accepted = 0, rejected = 0;
  for (const char* name : {"envelope-reference", "envelope-mini"}) {
    const std::string base = read_text(std::string(CVT_SOURCE_DIR) + "/configs/" + name + ".csv");
    for (int n = 0; n < 300; ++n) {
      std::string s = base;
      const auto pos = [&] { return std::uniform_int_distribution<size_t>(0, s.size() - 1)(rng); };
      for (int k = 0; k <= n % 3; ++k) {
        if (n % 2) s.insert(pos(), 1, inserts[std::uniform_int_distribution<size_t>(0, std::size(inserts) - 1)(rng)]);
        else s.erase(pos(), std::uniform_int_distribution<size_t>(1, 12)(rng));
      }
      std::ofstream(path, std::ios::binary) << s;
      SweepPlan p;
      try {
        p = SweepPlan::from_file(path);
      } catch (const ConfigError& e) {
        ++rejected;
        ASSERT_NE(std::string(e.what()).find("line"), std::string::npos) << "no line named: " << e.what() << "\n" << s;
        continue;
      } catch (const std::exception& e) {
        FAIL() << "not a ConfigError: " << e.what() << "\n--- mutant ---\n" << s;
      }
      ++accepted;
      {
        std::ofstream out(back, std::ios::binary);
        const auto row = [&](const std::vector<std::string>& f) {
          for (std::size_t i = 0; i < f.size(); ++i) {
            out << (i ? "," : "") << '"';
            for (char ch : f[i]) out << (ch == '"' ? "\"\"" : std::string(1, ch));
            out << '"';
          }
          out << "\n";
        };
        row(p.keys);
        for (const auto& pt : p.points) row(pt);
      }
      const SweepPlan q = SweepPlan::from_file(back);
      ASSERT_EQ(q.keys, p.keys) << s;
      ASSERT_EQ(q.points, p.points) << s;
      for (long i = 0; i < static_cast<long>(p.points.size()); ++i) {
        try {
          parse_config(base_, p.overrides(i));
        } catch (const ConfigError&) {
        } catch (const std::exception& e) {
          FAIL() << "point " << i << ": not a ConfigError: " << e.what() << "\n--- mutant ---\n" << s;
        }
      }
    }
  }
  std::printf("600 mutated points files: %d read back as themselves, %d refused naming a line\n", accepted, rejected);
}

// The command line on mutated configuration files: exit 0 or 78 (or 70, a blow-up the file's
// physics makes), never a crash or a hang; an exit 0 ran what the file says (the resolved
// configuration in the output is the one the loader reads from the mutant).
TEST_F(ConfigFuzzTest, TheCommandLineOnMutatedFilesRunsThemOrSaysWhy) {
  std::mt19937_64 rng(5);
  const std::string path = (dir_ / "mutant.toml").string();
  int ran = 0, refused = 0;
  for (int n = 0; n < 24; ++n) {
    std::string s = base_;
    const auto pos = [&] { return std::uniform_int_distribution<size_t>(0, s.size() - 1)(rng); };
    if (n % 2) s[pos()] = static_cast<char>(std::uniform_int_distribution<int>(0, 255)(rng));
    else s.erase(pos(), std::uniform_int_distribution<size_t>(1, 30)(rng));
    std::ofstream(path, std::ios::binary) << s;
    fs::remove(dir_ / "m.h5");
    const std::string cmd = "cd " + test::shell_quote(dir_.string()) + " && timeout 120 " +
                            test::shell_quote(CVT_ENGINE_EXE) + " run mutant.toml --t-end 1e-5 -o m.h5 -q 2>err.txt";
    const int st = std::system(cmd.c_str());
    ASSERT_TRUE(st != -1 && WIFEXITED(st)) << "killed by a signal\n--- mutant ---\n" << s;
    const int code = WEXITSTATUS(st);
    ASSERT_TRUE(code == 0 || code == 78 || code == 70) << "exit " << code << ": " << read_text((dir_ / "err.txt").string())
                                                       << "\n--- mutant ---\n" << s;
    if (code == 78) {
      ++refused;
      EXPECT_NE(read_text((dir_ / "err.txt").string()).find("configuration error"), std::string::npos);
      EXPECT_FALSE(fs::exists(dir_ / "m.h5"));
      continue;
    }
    if (code != 0) continue;
    ++ran;
    const std::string expected = load_config(path, {"run.t_end=1e-5"}).resolved_toml;  // --t-end
    H5File f = H5File::open_for_reading((dir_ / "m.h5").string());
    EXPECT_EQ(f.read_string_attribute("/parameters", "config"), expected) << "ran another configuration\n--- mutant ---\n" << s;
  }
  std::printf("24 mutated files on the command line: %d ran what they say, %d refused with exit 78\n", ran, refused);
}

}  // namespace
}  // namespace cvt
