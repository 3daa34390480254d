// Checkpoints: everything a run needs to continue bit-identically, in a small
// HDF5 file of its own: the resolved configuration, the state, the contact statuses, the
// clock (its origin included, so that t = t0 + (n - n0) h is formed as in the first run)
// and the reference energy of the balance. Written to FILE.tmp and renamed, so that a
// crash while writing never leaves a broken checkpoint.
#pragma once

#include <limits>
#include <string>
#include <vector>

#include <Eigen/Dense>

namespace cvt {

struct Checkpoint {
  std::string config_toml;               // the fully resolved TOML of the run
  Eigen::VectorXd state;                 // y
  std::vector<std::uint8_t> rocker, pulley;  // contact statuses for the next step
  double t = 0, t0 = 0;                  // time, and the clock's origin
  long steps = 0, steps0 = 0;            // steps done, and the clock's origin
  double energy0 = 0;                    // E at the start of the first run (balance)
  // The step's control by the energy balance (Simulation::watch_leak): its halvings, the
  // last one's time (-1: none), the last span's leak (NaN: none), and the current span's
  // start (grid step, -1: none; residual and input work there). Checkpoints without them
  // continue from none.
  int halvings = 0;
  double halved_at = -1, leak = std::numeric_limits<double>::quiet_NaN();
  long leak_from = -1;
  double leak_residual = 0, leak_work = 0;
  // The run this checkpoint continues: its id (also in its output file's /parameters) and
  // the output file it writes. Empty in checkpoints that predate them.
  std::string run_id, output;
  // What ended the run that wrote it, as RunSummary::stopped (t_end, steady, slip, signal,
  // callback, max_wall); empty in a periodic checkpoint, taken while the run went on.
  std::string stopped;
  // run.verify: the states kept for the summary's window's second integration (their own
  // state, statuses, clock, energy reference and step control; not their configuration,
  // which is this one's), so that a continuation of the same configuration can verify a
  // window that starts before it (docs/output.md, "Numerical error"). Empty where the run
  // did not verify, or ended.
  std::vector<Checkpoint> verify_states;
};

void write_checkpoint(const std::string& path, const Checkpoint& c);
// Throws std::runtime_error naming the file and what is missing or wrong.
Checkpoint read_checkpoint(const std::string& path);

}  // namespace cvt
