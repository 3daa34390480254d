// The guards of a run against silent garbage (docs/cli.md, docs/output.md): a step that
// does not fit the sample grid, an output that cannot be written, the energy balance, and
// RK4's step against its stability limit.
#pragma once

#include <stdexcept>
#include <string>
#include <vector>

#include "engine/model/config.hpp"
#include "engine/simulation.hpp"

namespace cvt {

// The energy turned over so far, sum of |W_in|, |W_out|, |W_diss|, |W_clamp| and
// |W_switch|: what the balance's residual is measured against (docs/output.md).
double energy_turnover(const Sample& s);

// The energy guard of a run: warns (once) when the balance's residual passes `limit` of the
// energy turned over, judged once the turnover reaches `turnover_min` [J] (before that the
// residual of the start from rest dominates a small sum). Returns the warning, or "".
struct EnergyGuard {
  double limit = 0.05;
  double turnover_min = 10.0;
  bool warned = false;
  std::string check(const Sample& s);
};

// The RK4 guard: the warning for a step h above the stability limit 2.8 / rho (rho the
// Jacobian's spectral radius at time t), or "" when h is within it.
std::string rk4_stability_warning(double h, double rho, double t);

// Whether the step h divides the interval x: x a whole number of steps, to rounding (1e-12
// of x), so that the samples fall on the interval's multiples.
bool divides(double h, double x);

// A configuration whose step does not divide run.t_end, run.sample_interval or
// run.snapshot_interval: ConfigError naming both keys (exit 78).
void check_step_grid(const Config& c);

// The output cannot be written (a folder that does not exist, no permission): exit 73.
class OutputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};
// A write that failed during a run (a full disk, an I/O error): what failed, then the way on
// from the run's last checkpoint (exit 73).
class WriteFailed : public OutputError {
 public:
  WriteFailed(const std::string& cause, const std::string& way_on) : OutputError(cause + "; " + way_on), cause_(cause) {}
  const std::string& cause() const { return cause_; }

 private:
  std::string cause_;
};
// An exclusive lock on a file (made if missing) for the lifetime of this object, let go of
// by the kernel when the process ends (kill -9 included); throws OutputError, naming
// `what`, when another process holds it (exit 73).
class FileLock {
 public:
  // remove: the lock file is removed when let go of (a run's FILE.lock; a sweep removes its
  // own at its end).
  FileLock(const std::string& path, const std::string& what, bool remove = false);
  ~FileLock();
  FileLock(const FileLock&) = delete;
  FileLock& operator=(const FileLock&) = delete;

 private:
  int fd_ = -1;
  std::string remove_;  // the path to remove at the end ("" none)
};

// The files a command writes must be none of those it reads, nor one another: OutputError
// naming both roles where two paths are one file (the same path, a link to it, a hard link).
struct PathRole {
  std::string role, path;
};
void check_distinct(const std::vector<PathRole>& inputs, const std::vector<PathRole>& outputs);

// Throws OutputError unless a file can be created at path (its folder exists and is writable,
// the path is no folder, link, FIFO or device) and its name, with `suffix` bytes more for the
// files derived from it (FILE.partial, FILE.lock, ...), is within the file system's limit.
void check_writable(const std::string& path, const std::string& what, std::size_t suffix = 0);


}  // namespace cvt
