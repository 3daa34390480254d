// How one RHS evaluation is scheduled: the same stages and kernels (the stage DAG of
// engine/rhs/stages.hpp) run top to bottom on one thread, as a oneTBB flow graph per NUMA
// arena, or as the published OpenMP scheme. All three give the same bits.
#pragma once

#include <type_traits>
#include <memory>
#include <string>
#include <vector>

#include "engine/rhs/profile.hpp"
#include "engine/rhs/rhs.hpp"
#include "engine/rhs/stages.hpp"

namespace cvt {

enum class SchedulerKind { serial, flowgraph, paper_omp };

struct ScheduleOptions {
  SchedulerKind kind = SchedulerKind::serial;
  int threads = 1;  // flowgraph, paper-omp
  int grain = 4;    // pins per task in the module nodes (flowgraph)
  // Benchmarks only: the flow graph with every node body empty (its own overhead).
  bool empty_kernels = false;
};

// When a node of the last traced stage ran (flowgraph with tracing on) [s, steady clock].
struct NodeSpan {
  std::string name;
  double begin = 0, end = 0;
};

// Parses "serial" | "flowgraph" | "paper-omp"; throws std::invalid_argument otherwise.
SchedulerKind parse_scheduler(const std::string& name);
const char* scheduler_name(SchedulerKind kind);

// Time spent in the parts of paper-omp (its buffer zeroing and gathering against the
// kernels, paper 2 Fig. 8), summed over threads [s].
struct ScheduleCounters {
  double zero_s = 0, compute_s = 0, gather_s = 0;
};

class Schedule {
 public:
  virtual ~Schedule() = default;
  // dy = f(t, y) into dy, then (if given) the stage update `op`; the workspace is the one
  // the schedule was built with. With extras, the kernels' friction as they ask
  // (FrictionExtras: the W-method's friction Jacobian, the implicit methods' frozen branch).
  virtual void rhs(double t, const double* y, double* dy, const StageOp* op, const FrictionExtras& x = {}) = 0;
  // Contact statuses for the next step (engine/rhs/rhs.hpp update_contact_status), scheduled
  // like the RHS; the same bits for every schedule.
  virtual void update_status(double t, const double* y) = 0;
  // Runs f (a whole step: its stages and the status update) where the schedule's threads
  // live, so that they stay awake between the stages instead of leaving the arena after
  // each one (wake-up dominates short stages; docs/runtime.md).
  // (No std::function: a step's lambda would not fit its small buffer, and allocating
  // once per step is what the house style forbids.)
  template <class F>
  void within(F&& f) {
    using Body = std::remove_reference_t<F>;
    within_impl([](void* c) { (*static_cast<Body*>(c))(); }, const_cast<void*>(static_cast<const void*>(&f)));
  }
  virtual void within_impl(void (*body)(void*), void* ctx) { body(ctx); }
  // Hands job(ctx) to the schedule's threads to run when one is free, beside the caller (the
  // flow graph on one NUMA arena with more than one thread; graph/side_job.hpp). False:
  // nothing was taken, the caller runs it itself.
  virtual bool enqueue(void (*job)(void*), void* ctx) { return false; }
  virtual std::string describe() const = 0;
  // GraphViz of one evaluation: the table's stages (engine/rhs/stages.hpp) as this schedule
  // runs them (flowgraph: its nodes and edges; the others: the order they run them in).
  virtual std::string graphviz() const = 0;
  virtual int threads() const = 0;
  virtual ScheduleCounters counters() const { return {}; }
  // Tracing of the module nodes' start and end (flowgraph; others record nothing).
  virtual void set_tracing(bool) {}
  virtual std::vector<NodeSpan> last_spans() const { return {}; }
  // Per-module timing (engine/rhs/profile.hpp) into p, which must have at least threads()
  // workers; nullptr turns it off (the default).
  void set_profiler(Profiler* p) { prof_ = p; }
  Profiler* profiler() const { return prof_; }
  // Places the given state-sized vectors (y = [q; v; aux]) so that each NUMA node's pin
  // segment of positions and velocities lies in its own memory (flowgraph with several
  // nodes; a no-op otherwise). Returns what was done, for describe().
  virtual void place_state(const std::vector<double*>& vectors) {}
  // NUMA nodes the schedule spans (1 unless flowgraph found several).
  virtual int numa_nodes() const { return 1; }

 protected:
  Profiler* prof_ = nullptr;
};

// Builds the schedule for model m over workspace ws (both must outlive it)
// (graph/schedule.cpp).
std::unique_ptr<Schedule> make_schedule(const Model& m, Workspace& ws, const ScheduleOptions& opt);

// The schedules make_schedule chooses from (graph/serial.cpp, flowgraph.cpp, paper_omp.cpp).
std::unique_ptr<Schedule> make_serial_schedule(const Model& m, Workspace& ws);
std::unique_ptr<Schedule> make_flowgraph_schedule(const Model& m, Workspace& ws, const ScheduleOptions& opt);
std::unique_ptr<Schedule> make_paper_omp_schedule(const Model& m, Workspace& ws, const ScheduleOptions& opt);

}  // namespace cvt
