// Per-module profiling of a run (the GROMACS and LAMMPS end-of-run tables). The schedules time each pass chunk on the worker that runs it, with the time
// stamp counter (about 10 ns a read here, against ~20 ns for steady_clock), into per-worker
// accumulators: no lock, no shared cache line between workers. The driver times the whole
// step, the output and the run; the table then adds up to the run's wall time:
//   sum over module rows of avg busy + scheduling + output + rest = total.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#if defined(__x86_64__) || defined(__i386__)
#include <x86intrin.h>
#else
#include <chrono>
#endif

namespace cvt {

enum class Section : int {
  chain,     // chain_forces
  pulley,    // pulley_contact
  other,     // other_forces
  inertia,   // link kinematics + inertia_decomposition
  accel,     // gather + structured solve (A0^-1, Woodbury) + dy
  update,    // the stage update (RK4: in the graph; the W-methods: their vector sums)
  status,    // contact status update
  // The W-methods' linear algebra, timed on the master (engine/wmethod/w_solver.cpp):
  w_stiffness,  // the chain's stiffness blocks by finite differences
  w_assembly,   // the matrix's blocks, and the fresh-friction correction
  w_factor,     // the block-cyclic LU
  w_solve,      // the solves (one per stage)
  count
};
inline constexpr int kSections = static_cast<int>(Section::count);

class Profiler {
 public:
  static std::uint64_t ticks() {
#if defined(__x86_64__) || defined(__i386__)
    return __rdtsc();
#else  // elsewhere the steady clock in ns (seconds_per_tick calibrates either)
    return static_cast<std::uint64_t>(std::chrono::steady_clock::now().time_since_epoch().count());
#endif
  }

  // workers: the number of threads that may run timed work (index 0..workers-1).
  explicit Profiler(int workers = 1);
  void reset();

  // Busy time of one chunk of `s` on worker w (w out of range goes to worker 0).
  void add(int w, Section s, std::uint64_t dt) {
    if (w < 0 || w >= workers_) w = 0;
    slots_[static_cast<std::size_t>(w)].busy[static_cast<int>(s)] += dt;
  }
  // One call of section s (counted once per stage by the master, not per chunk).
  void call(Section s) { ++calls_[static_cast<int>(s)]; }
  // One RHS evaluation: a call of every module section and, with a stage update, of it.
  void call_rhs(bool update) {
    for (Section s : {Section::chain, Section::pulley, Section::other, Section::inertia, Section::accel}) call(s);
    if (update) call(Section::update);
  }
  // Wall time of `s` on the master while the other workers wait or help (a section that is
  // not split into per-worker chunks): the whole of it counts as wall time.
  void add_master(Section s, std::uint64_t dt) { master_[static_cast<int>(s)] += dt; }
  // Wall time of whole RHS evaluations on the master (to find the rest of a step).
  void add_rhs_wall(std::uint64_t dt) { rhs_wall_ += dt; }
  std::uint64_t rhs_wall() const { return rhs_wall_; }
  std::uint64_t master_total() const {
    std::uint64_t s = 0;
    for (auto x : master_) s += x;
    return s;
  }
  // Wall time the master spent inside steps, in output, and the number of steps.
  void add_step(std::uint64_t dt) { step_ticks_ += dt, ++steps_; }
  // An output's dt less the step work done inside it (add_step_ahead).
  void add_output(std::uint64_t dt) {
    output_ticks_ += dt - std::min(dt, ahead_ticks_), ahead_ticks_ = 0, ++output_calls_;
  }
  // A step's work done inside the output (the next step's first evaluation, taken for a
  // sample): wall time of the steps, not of the output.
  void add_step_ahead(std::uint64_t dt) { step_ticks_ += dt, ahead_ticks_ += dt; }
  int workers() const { return workers_; }
  long steps() const { return steps_; }

  // Seconds per tick, calibrated against steady_clock since construction (or reset).
  double seconds_per_tick() const;

  struct Row {
    std::string name;
    long calls = 0;
    double wall_s = 0;  // avg busy over workers (what the row adds to the wall time)
    double us_per_step = 0, percent = 0;
    double busy_min_s = 0, busy_avg_s = 0, busy_max_s = 0;
    double imbalance_percent = 0;  // (max / avg - 1) * 100
  };
  struct Report {
    long steps = 0;
    double wall_s = 0, us_per_step = 0, model_s_per_hour = 0;
    int threads = 1, numa_nodes = 1;
    std::string scheduler;
    std::vector<Row> rows;  // the sections, scheduling, output, rest, total
  };
  // total_wall_s: the run's wall time (from the first step to the end of the output).
  Report report(double total_wall_s, double model_time, int numa_nodes, const std::string& scheduler) const;

 private:
  struct alignas(64) Slot {
    std::array<std::uint64_t, kSections> busy{};
  };
  int workers_;
  std::vector<Slot> slots_;
  std::array<long, kSections> calls_{};
  std::array<std::uint64_t, kSections> master_{};
  std::uint64_t rhs_wall_ = 0;
  std::uint64_t step_ticks_ = 0, output_ticks_ = 0, ahead_ticks_ = 0;
  long steps_ = 0, output_calls_ = 0;
  std::uint64_t tick0_ = 0;
  double clock0_ = 0;
};

// Times a scope into p (if p is not null) on worker w.
class ScopedTimer {
 public:
  ScopedTimer(Profiler* p, int w, Section s) : p_(p), w_(w), s_(s), t0_(p ? Profiler::ticks() : 0) {}
  ~ScopedTimer() {
    if (p_) p_->add(w_, s_, Profiler::ticks() - t0_);
  }
  ScopedTimer(const ScopedTimer&) = delete;
  ScopedTimer& operator=(const ScopedTimer&) = delete;

 private:
  Profiler* p_;
  int w_;
  Section s_;
  std::uint64_t t0_;
};

// The table as text (fixed-width, like GROMACS's), as JSON (docs/output.md), and into the
// HDF5 file's /profile group (engine/output.cpp).
std::string format_profile(const Profiler::Report& r);
std::string profile_json(const Profiler::Report& r);

}  // namespace cvt
