// cvt-engine sweep (docs/studies.md): a set of operating points, each a run until steady,
// into one CSV and one HDF5 file, one row per point. The points are a full grid over config
// keys or the rows of a points file. A point that blows up or fails is a row with its
// reason; the sweep goes on. A sweep started again with the same command skips the points
// its CSV already holds. With MPI (engine/studies/sweep_mpi.cpp) rank 0 hands the points
// out and writes; every point's numbers are the same bits whatever the number of ranks
// and threads.
#pragma once

#include <functional>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "engine/base/timing.hpp"
#include "engine/guards.hpp"
#include "graph/schedule.hpp"

namespace cvt {

// One axis of a grid: a config key and its values as written ("load.torque=50,100,150").
struct SweepAxis {
  std::string key;
  std::vector<std::string> values;
};
SweepAxis parse_axis(const std::string& text);

// The points: the keys (the CSV's first columns) and each point's values as written.
struct SweepPlan {
  std::vector<std::string> keys;
  std::vector<std::vector<std::string>> points;
  // Where each point was given: "--axis", or "FILE line N".
  std::vector<std::string> origins;
  // Each point's resolved configuration (base, --set and its keys) as a fingerprint
  // (sweep_plan): a restart continues only rows run with the same.
  std::vector<std::string> fingerprints;
  // With continuation (SweepOptions::continuation): the point each point continues from
  // (-1: from rest), and the order the points run in, every point after its parent. Empty:
  // every point from rest, in point order.
  std::vector<long> parents;
  std::vector<long> order;
  long parent(long i) const { return parents.empty() ? -1 : parents[static_cast<std::size_t>(i)]; }
  long at(long k) const { return order.empty() ? k : order[static_cast<std::size_t>(k)]; }
  // The full grid; the first axis varies slowest.
  static SweepPlan grid(const std::vector<SweepAxis>& axes);
  // A CSV file by RFC 4180: a header of keys, then one row of values per point; a line whose
  // first non-blank character is '#' outside quotes is a comment. ConfigError names the
  // line of a malformed row, a key given twice, a row with too few or too many values.
  static SweepPlan from_file(const std::string& path);
  // The --set overrides of point i.
  std::vector<std::string> overrides(long i) const;
  // "load.torque=100, clamping.driving=3.7e4"
  std::string label(long i) const;
};

// What a point gave: the run summary's status (steady, not_steady, slip) and its means over
// the last two windows, or blow_up / error with the reason.
struct SweepRow {
  long point = -1;
  std::vector<std::string> values;
  std::string status = "error", reason;
  double speed_ratio = 0, geometric_ratio = 0, slip = 0, input_torque = 0, output_torque = 0, efficiency = 0,
         loss_efficiency = 0, input_speed = 0, output_speed = 0, load_torque = 0, clamping_force_driving = 0,
         clamping_force_driven = 0, strand_tension_upper = 0, strand_tension_lower = 0, model_time = 0,
         steady_window = 0, step = 0, energy_leak = 0, wall_s = 0;
  // run.verify: the numerical error of each verified mean among the columns, by column
  // name (speed_ratio, efficiency, ...); empty when the point was not verified.
  std::map<std::string, double> numerical_error;
  // The statistical uncertainty of the same means (RunSummary::uncertainty); a mean the
  // point's window gave none (fewer than two spans) is absent.
  std::map<std::string, double> uncertainty;
  // The fingerprint of the configuration it ran (SweepPlan::fingerprints; "" none).
  std::string config;
  // The point whose steady state it continued from; -1: from rest (or from --from).
  long from_point = -1;
};

// The CSV (docs/studies.md): the keys, then the results, then point, reason, wall_s and
// config (the fingerprint of the point's resolved configuration).
// Numbers are written to 17 significant digits: they read back to the same bits.
std::string sweep_csv_header(const SweepPlan& plan);
std::string sweep_csv_row(const SweepRow& r);
// A row read back; throws std::runtime_error when the line does not hold one.
SweepRow parse_sweep_csv_row(const std::string& line, const SweepPlan& plan);

struct SweepOptions {
  std::string config_path;
  std::vector<std::string> overrides;  // --set, for every point (before the point's own keys)
  std::string out = "sweep";           // OUT.csv and OUT.h5
  bool keep_runs = false;              // keep each point's run file in OUT.runs/
  // Start every point from this checkpoint (a steady state of the same model) instead of
  // from rest; run.t_end is then the bound on each point's run beyond it. A point whose
  // load.torque differs from the checkpoint's ramps it over warm_ramp from there.
  std::string from;
  double warm_ramp = -1;  // [s]; < 0: the point's steady window (two torsion periods)
  // Maps by continuation (--continuation): a point whose keys differ from another point's in
  // load.torque only starts from that point's steady state (the nearest load; the group's
  // middle load from rest), its load ramped over warm_ramp (continuation_parents).
  bool continuation = false;
  ScheduleOptions schedule;
  // What run.max_wall counts from: the command's start.
  WallClock::time_point started = WallClock::now();
  // Lines of progress (default: stdout).
  std::function<void(const std::string&)> log;
};

// The plan of a sweep from --axis texts or a --points file (exactly one of the two), with
// every point's configuration checked before the first runs, so that a typo fails at once.
// Throws ConfigError; also when o has both or neither of config_path and from.
SweepPlan sweep_plan(const SweepOptions& o, const std::vector<std::string>& axes, const std::string& points);

// The continuation tree (docs/studies.md, "Maps by continuation"): the points whose keys
// agree but for load.torque form a group; the point of the group's middle load (the lower
// middle, the first in point order among equals) runs from rest, every other continues from
// the nearest load already in the tree (Prim's tree by |load difference|, ties to the lower
// point index). loads[i] is point i's load torque. Returns each point's parent (-1: none)
// and fills *order with the points by their depth in the tree, then by index.
std::vector<long> continuation_parents(const SweepPlan& plan, const std::vector<double>& loads,
                                       std::vector<long>* order);

// A point stopped by a signal or by run.max_wall: the sweep stops without a row for it (a
// restart continues it from its checkpoint).
struct SweepInterrupted : std::runtime_error {
  SweepInterrupted(const std::string& what, bool wall = false) : std::runtime_error(what), wall_limit(wall) {}
  bool wall_limit;  // run.max_wall, not a signal
};

// Runs point i until steady, its run file in OUT.runs/; never throws for the point's own
// failure (a blow-up, a bad value): the row says it. Throws SweepInterrupted on a signal.
SweepRow run_sweep_point(const SweepOptions& o, const SweepPlan& plan, long i);

// The rows of a sweep on disk: OUT.csv grows a row per finished point (flushed to the
// disk at once, so a kill loses no finished point); at the end it is rewritten in point
// order and OUT.h5 written. OUT.csv.lock keeps a second sweep from writing the same
// files at the same time.
class SweepLedger {
 public:
  // Reads the rows of an earlier, interrupted run of the same sweep (a torn last line is
  // dropped); throws if OUT.csv belongs to another sweep (other keys or values).
  SweepLedger(const SweepOptions& o, const SweepPlan& plan);
  SweepLedger(const SweepLedger&) = delete;
  SweepLedger& operator=(const SweepLedger&) = delete;
  bool done(long i) const { return done_[static_cast<std::size_t>(i)]; }
  long finished() const { return static_cast<long>(rows_.size()); }
  long points() const { return static_cast<long>(done_.size()); }
  void add(const SweepRow& r);
  // OUT.csv in point order, and OUT.h5.
  void finish(const std::string& config_text) const;
  const std::vector<SweepRow>& rows() const { return rows_; }

 private:
  const SweepOptions& o_;
  const SweepPlan& plan_;
  std::string csv_;
  std::vector<SweepRow> rows_;
  std::vector<bool> done_;
  // OUT.csv.lock, held while the sweep runs (and let go of if the constructor throws).
  std::optional<FileLock> lock_;
};

// A job array's task (cvt-engine sweep --point I): point i (0-based, as the CSV's point
// column) alone, its row written whole to OUT.points/point-NNNN.csv (task_file), so that
// tasks running at once share no file. Throws ConfigError for an i outside the plan, and
// SweepInterrupted as run_sweep_point.
std::string task_file(const SweepOptions& o, long i);
SweepRow run_sweep_task(const SweepOptions& o, const SweepPlan& plan, long i);

// The step after a job array (cvt-engine sweep --gather): the tasks' rows into OUT.csv (a
// row of another sweep or configuration refused); returns the points that have no row yet.
// When none is missing, OUT.csv in point order and OUT.h5 are written, OUT.points/ removed,
// and *unsteady set to the points that did not end steady.
std::vector<long> gather_sweep(const SweepOptions& o, const SweepPlan& plan, long* unsteady);

// The whole sweep in this process: the points the ledger lacks, in order. Returns the
// number of points that did not end steady.
long run_sweep(const SweepOptions& o, const SweepPlan& plan);

// "N of M points already in OUT.csv: skipped", when the ledger holds an earlier run's rows.
void log_resumed(const SweepOptions& o, const SweepLedger& ledger);

// The end of a sweep: OUT.csv in point order and OUT.h5, OUT.runs/ removed unless kept or
// not empty; returns the number of points that did not end steady.
long close_sweep(const SweepOptions& o, const SweepLedger& ledger);

// The base configuration's text (CONFIG's, or with `from` the checkpoint's): OUT.h5's /config.
std::string sweep_config_text(const SweepOptions& o);

// x to 17 significant digits: reads back to the same bits.
std::string exact_number(double x);

// o.log, or lines on stdout.
std::function<void(const std::string&)> sweep_log(const SweepOptions& o);

// The line a finished point prints.
std::string sweep_point_line(const SweepPlan& plan, const SweepRow& r, long total);

}  // namespace cvt
