// Shared helpers of the test suite.
#pragma once

#include <unistd.h>

#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "engine/model/config.hpp"
#include "engine/model/model.hpp"
#include "engine/run.hpp"

namespace cvt::test {

// Single-quotes a word for /bin/sh.
inline std::string shell_quote(const std::string& s) {
  std::string out = "'";
  for (char c : s) {
    if (c == '\'') out += "'\\''";
    else out += c;
  }
  return out + "'";
}

inline std::string config_path(const std::string& name) {
  return std::string(CVT_SOURCE_DIR) + "/configs/" + name + ".toml";
}

// A test run's options: its own file NAME_PID.h5 in the temp folder, no progress lines, the
// warnings swallowed, the flow graph on 2 threads (the same bits as any schedule).
inline RunOptions quiet_run_options(const std::string& name) {
  RunOptions o;
  o.out_path = (std::filesystem::temp_directory_path() / (name + "_" + std::to_string(getpid()) + ".h5")).string();
  o.progress = false;
  o.schedule.kind = SchedulerKind::flowgraph;
  o.schedule.threads = 2;
  o.warn = [](const std::string&) {};
  return o;
}

// Removes a test run's file and its checkpoint.
inline void remove_run_files(const std::string& out_path) {
  for (const char* ext : {"", ".ckpt"}) std::filesystem::remove(out_path + ext);
}

// The shipped configs run ROS34PW2; the tests' reference is RK4 at 1e-8 over a short
// span (5 ms), with the given overrides applied after these.
inline std::vector<std::string> rk4_overrides(std::vector<std::string> overrides = {}) {
  overrides.insert(overrides.begin(),
                   {"integrator.method=rk4", "integrator.step=1e-8", "run.t_end=5e-3"});
  return overrides;
}

inline Model model(const std::string& name, const std::vector<std::string>& overrides = {}) {
  return build_model(load_config(config_path(name), rk4_overrides(overrides)));
}

// The initial state with positions perturbed at random (lengths by +-dx, slopes and
// angles by +-da), velocities by +-dv.
inline Eigen::VectorXd perturbed_state(const Model& m, unsigned seed, double dx, double da, double dv) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Eigen::VectorXd y = m.y0;
  for (int j = 0; j < m.links; ++j)
    for (int i = 0; i < kJointSize; ++i) {
      const int r = i % half::kEnd;
      const bool slope = i < 2 * half::kSize && (r == half::kSx || r == half::kSy);
      y[m.joint(j) + i] += (slope ? da : dx) * u(rng);
      y[m.ndof + m.joint(j) + i] += dv * u(rng);
    }
  for (int k = 0; k < 2; ++k)
    for (int i = 0; i < kShaftSize; ++i) {
      const bool angle = i == kTx || i == kTy || i == kPhi;
      y[m.shaft(k) + i] += (angle ? da : dx) * u(rng);
      y[m.ndof + m.shaft(k) + i] += dv * u(rng);
    }
  y[m.load_index()] += da * u(rng);
  return y;
}

}  // namespace cvt::test
