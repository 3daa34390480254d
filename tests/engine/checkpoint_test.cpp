// Checkpoints and resume (issue 4): N steps, then resume for N more, gives the same bits
// as 2N steps in one go, whatever schedule runs the second half.
#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>

#include "engine/checkpoint.hpp"
#include "engine/simulation.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

namespace fs = std::filesystem;

class CheckpointTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("cvt_ckpt_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  // Runs the mini model to t_end (from `resume` if given) and returns its final checkpoint.
  Checkpoint run(const std::string& name, const std::string& t_end, const Checkpoint* resume,
                 const ScheduleOptions& schedule = {}, std::vector<std::string> sets = {}) {
    sets.push_back("run.t_end=" + t_end);
    sets.push_back("run.sample_interval=1e-6");
    const Config cfg = resume ? parse_config(resume->config_toml, sets) : load_config(test::config_path("mini"), sets);
    const Model m = build_model(cfg);
    RunOptions o;
    o.out_path = (dir_ / (name + ".h5")).string();
    o.progress = false;
    o.checkpoint_every = 0;
    o.resume = resume;
    o.schedule = schedule;
    run_simulation(m, o);
    return read_checkpoint(o.out_path + ".ckpt");
  }
  fs::path dir_;
};

bool same_bits(const Checkpoint& a, const Checkpoint& b) {
  return a.state.size() == b.state.size() &&
         std::memcmp(a.state.data(), b.state.data(), sizeof(double) * a.state.size()) == 0 && a.rocker == b.rocker &&
         a.pulley == b.pulley && a.steps == b.steps && std::memcmp(&a.t, &b.t, sizeof a.t) == 0 &&
         a.energy0 == b.energy0;
}

TEST_F(CheckpointTest, ResumeContinuesBitIdentically) {
  // 800 steps of 1e-8 s in one go, against 400 + resume 400 (serial, then flow graph).
  const Checkpoint whole = run("whole", "8e-6", nullptr);
  const Checkpoint half = run("half", "4e-6", nullptr);
  EXPECT_EQ(half.steps, 400);
  EXPECT_FALSE(same_bits(half, whole));  // the comparison below can fail
  const Checkpoint resumed = run("resumed", "8e-6", &half);
  EXPECT_EQ(resumed.steps, 800);
  EXPECT_TRUE(same_bits(resumed, whole));
  ScheduleOptions fg;
  fg.kind = SchedulerKind::flowgraph;
  fg.threads = 2;
  const Checkpoint resumed_fg = run("resumed_fg", "8e-6", &half, fg);
  EXPECT_TRUE(same_bits(resumed_fg, whole));
}

// Warm up with RK4 at 1e-8, continue with ROS2 at 1e-7: the resumed run counts steps of
// the new step from the checkpoint's time, and ends at t_end with the steps that make it.
TEST_F(CheckpointTest, ResumeWithAnotherStepContinuesFromTheCheckpointsTime) {
  const Checkpoint warm = run("warm", "4e-6", nullptr);
  EXPECT_EQ(warm.steps, 400);
  const Checkpoint on = run("on", "8e-6", &warm, {}, {"integrator.method=ros2", "integrator.step=1e-7"});
  EXPECT_EQ(on.steps, 80);
  EXPECT_NEAR(on.t, 8e-6, 1e-18);
  EXPECT_GT((on.state - warm.state).norm(), 0);
  // A step that does not divide the checkpoint's time is refused, not rounded.
  EXPECT_THROW(run("odd", "8e-6", &warm, {}, {"integrator.step=3e-7"}), std::runtime_error);
}

TEST_F(CheckpointTest, ResumeAtOrPastTheEndIsRefused) {
  const Checkpoint half = run("half", "4e-6", nullptr);
  EXPECT_THROW(run("again", "4e-6", &half), std::runtime_error);
}

TEST_F(CheckpointTest, MissingOrBrokenCheckpointIsAClearError) {
  EXPECT_THROW(read_checkpoint((dir_ / "nothing.ckpt").string()), std::runtime_error);
  const fs::path junk = dir_ / "junk.ckpt";
  {
    std::FILE* f = std::fopen(junk.c_str(), "w");
    std::fputs("not hdf5", f);
    std::fclose(f);
  }
  EXPECT_THROW(read_checkpoint(junk.string()), std::runtime_error);
}

}  // namespace
}  // namespace cvt
