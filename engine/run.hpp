// A run (cvt-engine run): the simulation from its initial state or a checkpoint to
// run.t_end, with the output file (engine/output.hpp), checkpoints, the guards
// (engine/guards.hpp), progress on stderr and the end-of-run summary.
#pragma once

#include <functional>
#include <mutex>
#include <string>

#include "engine/base/timing.hpp"
#include "engine/guards.hpp"
#include "engine/io/checkpoint.hpp"
#include "engine/rhs/profile.hpp"
#include "engine/simulation.hpp"
#include "engine/summary.hpp"
#include "graph/schedule.hpp"

namespace cvt {

// SIGINT, SIGTERM and SIGHUP from this guard's construction to its end: a signal stops the
// run (or sweep) under way at its next stop point, with its file and checkpoint kept
// (docs/cli.md, exit 130); a run holds one, and a command holds one from its first
// instruction so that a signal before the run starts is not lost. Nested guards share the
// handlers.
class StopSignals {
 public:
  StopSignals();
  ~StopSignals();
  StopSignals(const StopSignals&) = delete;
  StopSignals& operator=(const StopSignals&) = delete;
  static int pending();  // the signal caught (0: none)

 private:
  static std::mutex mutex_;
  static int active_;
};

// Where a run stands, for RunOptions::on_progress.
struct RunProgress {
  long step = 0, steps = 0;  // steps done and the steps to run.t_end (the bound with run.until_steady)
  double t = 0, t_end = 0;   // model time now and at the end [s]
  double wall_s = 0;         // since the steps began
  double eta_s = 0;          // wall time to t_end at the rate so far
  // run.verify's second integration of the summary's window, after the run's steps: step,
  // steps, wall_s and eta_s then count its own steps, t runs again up to t_end.
  bool verifying = false;
};

struct RunOptions {
  std::string out_path = "results.h5";
  bool progress = true;
  ScheduleOptions schedule;
  // A checkpoint every this many steps (0: only at the end and on SIGINT/SIGTERM), to
  // checkpoint_path (default: out_path + ".ckpt"). The output file is flushed first, so
  // that it holds every sample up to the checkpoint.
  long checkpoint_every = 50000;
  double flush_seconds = 10.0;  // wall time between flushes of the output file
  std::string checkpoint_path;
  // Continue from this checkpoint (its model: build it from resume->config_toml).
  const Checkpoint* resume = nullptr;
  // With resume: append to out_path, the run's own file (its samples after the checkpoint
  // dropped), so that it equals an uninterrupted run; otherwise out_path is a new file that
  // holds the continuation only.
  bool append = false;
  // The end-of-run profile as JSON to this file as well (empty: not written).
  std::string profile_json;
  // The summary as JSON to this file as well (empty: not written).
  std::string summary_json;
  // Called every progress_seconds of wall time instead of the progress line on stderr
  // (with progress false too); returning false stops the run as SIGINT does, at the next
  // step where the W matrix is rebuilt (at most integrator.w_k_every steps on; the state at
  // that step sampled, the file kept, RunResult::interrupted set, signal 0).
  std::function<bool(const RunProgress&)> on_progress;
  double progress_seconds = 3.0;
  // Warnings as they happen (default: "cvt-engine: warning: ..." on stderr); they are also
  // kept in the summary and the file's /summary.
  std::function<void(const std::string&)> warn;
  // run.verify: the window's second integration takes steps of integrator.step /
  // verify_refine (2: the step halved). 1 repeats the run's own steps, whose errors are
  // then exactly 0 (the tests' check of the verification itself).
  int verify_refine = 2;
  // What run.max_wall counts from: the command's start (default: when these options were made).
  WallClock::time_point started = WallClock::now();
};

// What run_simulation returns: the summary and the profile.
struct RunResult : RunSummary {
  Profiler::Report profile;  // the end-of-run table (also in /profile of the file)
};

// Runs the model from its initial state to cfg.run.t_end and writes the HDF5 file.
RunResult run_simulation(const Model& m, const RunOptions& opt);

}  // namespace cvt
