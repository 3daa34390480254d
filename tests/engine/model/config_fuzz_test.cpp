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

#include "engine/model/config.hpp"
#include "engine/model/model.hpp"
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

}  // namespace
}  // namespace cvt
