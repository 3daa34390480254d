// Checkpoints and resume: N steps, then resume for N more, gives the same bits as 2N steps
// in one go, whatever schedule runs the second half; a resume that appends to the run's
// own file leaves it equal to an uninterrupted run's.
#include <gtest/gtest.h>

#include <hdf5.h>

#include <cstring>
#include <map>
#include <filesystem>

#include "engine/io/checkpoint.hpp"
#include "engine/io/h5_writer.hpp"
#include "engine/output.hpp"
#include "engine/run.hpp"
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
  // With `append`, the resumed run continues the file `name` it was checkpointed from.
  Checkpoint run(const std::string& name, const std::string& t_end, const Checkpoint* resume,
                 const ScheduleOptions& schedule = {}, std::vector<std::string> sets = {}, bool append = false) {
    sets.push_back("run.t_end=" + t_end);
    sets.push_back("run.sample_interval=1e-6");
    sets.push_back("run.snapshot_interval=2e-6");
    const Config cfg = resume ? parse_config(resume->config_toml, sets)
                              : load_config(test::config_path("mini"), test::rk4_overrides(sets));
    const Model m = build_model(cfg);
    RunOptions o;
    o.out_path = path(name);
    o.progress = false;
    o.checkpoint_every = 0;
    o.resume = resume;
    o.append = append;
    o.schedule = schedule;
    o.warn = [this](const std::string& w) { warnings_.push_back(w); };
    run_simulation(m, o);
    return read_checkpoint(o.out_path + ".ckpt");
  }
  std::string path(const std::string& name) const { return (dir_ / (name + ".h5")).string(); }
  std::vector<std::string> warnings_;
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

// Every dataset of a file (path -> raw bytes of its values), and its string datasets'
// paths, for a bit-for-bit comparison of two files.
std::map<std::string, std::vector<char>> datasets(const std::string& file) {
  std::map<std::string, std::vector<char>> out;
  const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  EXPECT_GE(f, 0) << file;
  const auto visit = [](hid_t obj, const char* name, const H5O_info_t* info, void* data) -> herr_t {
    if (info->type != H5O_TYPE_DATASET) return 0;
    auto& m = *static_cast<std::map<std::string, std::vector<char>>*>(data);
    const hid_t d = H5Dopen2(obj, name, H5P_DEFAULT);
    const hid_t type = H5Dget_type(d);
    std::vector<char>& bytes = m[std::string("/") + name];
    if (H5Tget_class(type) == H5T_FLOAT) {
      const hid_t space = H5Dget_space(d);
      bytes.resize(static_cast<std::size_t>(H5Sget_simple_extent_npoints(space)) * sizeof(double));
      H5Dread(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, bytes.data());
      H5Sclose(space);
    }
    H5Tclose(type);
    H5Dclose(d);
    return 0;
  };
  H5Ovisit2(f, H5_INDEX_NAME, H5_ITER_INC, visit, &out, H5O_INFO_BASIC);
  H5Fclose(f);
  return out;
}

// The numeric datasets that hold the run's history: observables and snapshots.
std::map<std::string, std::vector<char>> history(const std::string& file) {
  std::map<std::string, std::vector<char>> out;
  for (auto& [k, v] : datasets(file))
    if (k.rfind("/observables/", 0) == 0 || k.rfind("/particles/", 0) == 0) out.emplace(k, std::move(v));
  return out;
}

void expect_same_history(const std::string& a, const std::string& b) {
  const auto ha = history(a), hb = history(b);
  ASSERT_GT(ha.size(), 20u);
  ASSERT_EQ(ha.size(), hb.size());
  for (const auto& [k, v] : ha) {
    ASSERT_TRUE(hb.count(k)) << k << " missing in " << b;
    EXPECT_EQ(v.size(), hb.at(k).size()) << k;
    EXPECT_TRUE(v == hb.at(k)) << k << " differs";
  }
}

TEST_F(CheckpointTest, ResumeAppendsToTheRunsOwnFileBitForBit) {
  run("whole", "8e-6", nullptr);
  const Checkpoint half = run("run", "4e-6", nullptr);
  EXPECT_FALSE(history(path("run")) == history(path("whole")));  // the comparison below can fail
  run("run", "8e-6", &half, {}, {}, true);
  expect_same_history(path("run"), path("whole"));
}

// The history a continuation reads back for its summary holds every channel the summary
// reads, each as long as the time: its verdicts index them by sample.
TEST_F(CheckpointTest, AContinuationReadsBackEverySummaryChannel) {
  const Checkpoint half = run("run", "4e-6", nullptr);
  const Config cfg = parse_config(half.config_toml, {});
  const Model m = build_model(cfg);
  H5File f = H5File::open_for_reading(path("run"));
  const long every = std::lround(cfg.run.sample_interval / cfg.integrator.step);
  const FileHistory hist = continue_file(f, m, half, every, 0);
  const SummaryChannels& ch = hist.channels;
  ASSERT_GT(ch.size(), 2u);
  for (const std::vector<double>* v :
       {&ch.input_speed, &ch.output_speed, &ch.input_torque, &ch.output_torque, &ch.load_torque, &ch.speed_ratio,
        &ch.geometric_ratio, &ch.clamp_driving, &ch.clamp_driven, &ch.strand_upper, &ch.strand_lower,
        &ch.sheave_driving, &ch.sheave_driven, &ch.work_input, &ch.work_output, &ch.work_dissipated,
        &ch.work_clamping})
    EXPECT_EQ(v->size(), ch.size());
}

// A checkpoint between samples (as an interrupt leaves it; here t_end): the file's last,
// off-grid sample is dropped and the resumed run appends from the last grid sample on,
// again equal to the uninterrupted run.
TEST_F(CheckpointTest, ResumeFromBetweenSamplesAppendsBitForBit) {
  run("whole", "8e-6", nullptr);
  const Checkpoint part = run("run", "4.5e-6", nullptr);
  ASSERT_EQ(part.steps, 450);
  run("run", "8e-6", &part, {}, {}, true);
  expect_same_history(path("run"), path("whole"));
}

// ROS34PW2, the configs' method: its matrix is not in the checkpoint, so a continuation
// repeats the bits from a step that rebuilds all of it (a multiple of integrator.w_k_every,
// 16 on the mini model), and says so when it cannot.
TEST_F(CheckpointTest, Ros34pw2ResumeAtAMatrixRebuildAppendsBitForBit) {
  const std::vector<std::string> w = {"integrator.method=ros34pw2", "integrator.step=1e-6"};
  run("whole", "3.2e-4", nullptr, {}, w);
  const Checkpoint half = run("run", "1.6e-4", nullptr, {}, w);
  ASSERT_EQ(half.steps % 16, 0);
  warnings_.clear();
  run("run", "3.2e-4", &half, {}, {}, true);
  EXPECT_TRUE(warnings_.empty()) << warnings_.front();
  expect_same_history(path("run"), path("whole"));
  // Elsewhere the continuation warns, and is close but not the same.
  const Checkpoint odd = run("odd", "1.5e-4", nullptr, {}, w);
  warnings_.clear();
  run("odd", "3.2e-4", &odd, {}, {}, true);
  ASSERT_EQ(warnings_.size(), 1u);
  EXPECT_NE(warnings_[0].find("not a multiple of integrator.w_k_every = 16"), std::string::npos) << warnings_[0];
  EXPECT_NE(warnings_[0].find("not bit-identical"), std::string::npos) << warnings_[0];
}

// On two threads a sample's file writes run beside the steps (graph/side_job.hpp): the file,
// samples and snapshots, is the serial run's, also where a continuation appends to it.
TEST_F(CheckpointTest, AFileWrittenOnTwoThreadsIsTheSerialOne) {
  const std::vector<std::string> w = {"integrator.method=ros34pw2", "integrator.step=1e-6"};
  ScheduleOptions fg;
  fg.kind = SchedulerKind::flowgraph;
  fg.threads = 2;
  run("serial", "3.2e-4", nullptr, {}, w);
  run("two", "3.2e-4", nullptr, fg, w);
  expect_same_history(path("two"), path("serial"));
  const Checkpoint half = run("cont", "1.6e-4", nullptr, fg, w);
  run("cont", "3.2e-4", &half, fg, {}, true);
  expect_same_history(path("cont"), path("serial"));
}

TEST_F(CheckpointTest, ResumeRefusesAFileOfAnotherRun) {
  const Checkpoint half = run("run", "4e-6", nullptr);
  run("other", "4e-6", nullptr);
  fs::copy_file(path("other"), path("run"), fs::copy_options::overwrite_existing);
  try {
    run("run", "8e-6", &half, {}, {}, true);
    FAIL() << "a file of another run was continued";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("it belongs to another run"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("--out NEW"), std::string::npos) << e.what();
  }
  expect_same_history(path("run"), path("other"));  // the refused file is left as it was
}

TEST_F(CheckpointTest, ResumeRefusesAFileThatEndsBeforeTheCheckpoint) {
  const Checkpoint half = run("run", "4e-6", nullptr);
  {
    H5File f = H5File::open(path("run"));
    f.series("/observables/input_speed/time", {}).truncate(2);
  }
  try {
    run("run", "8e-6", &half, {}, {}, true);
    FAIL() << "a file that ends before the checkpoint was continued";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("before the checkpoint's last sample"), std::string::npos) << e.what();
  }
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
