// The serial schedule: one thread, module after module (the baseline).
#include <stdexcept>

#include "graph/schedule.hpp"

namespace cvt {

namespace {

class SerialSchedule final : public Schedule {
 public:
  SerialSchedule(const Model& m, Workspace& ws) : m_(m), ws_(ws) {}
  void rhs(double t, const double* y, double* dy, const StageOp* op, const FrictionExtras& x) override {
    rhs_serial(m_, ws_, t, y, dy, op, prof_, x);
  }
  void update_status(double t, const double* y) override { update_contact_status(m_, ws_, t, y, prof_); }
  std::string describe() const override { return "serial (1 thread)"; }
  std::string graphviz() const override {
    return "digraph stage {\n  rankdir=LR;\n  start -> link_kinematics -> chain_forces -> pulley_contact -> "
           "other_forces -> inertia_decomposition -> gather -> accelerations -> stage_update;\n}\n";
  }
  int threads() const override { return 1; }

 private:
  const Model& m_;
  Workspace& ws_;
};

}  // namespace

std::unique_ptr<Schedule> make_flowgraph_schedule(const Model& m, Workspace& ws, const ScheduleOptions& opt);
std::unique_ptr<Schedule> make_paper_omp_schedule(const Model& m, Workspace& ws, const ScheduleOptions& opt);

SchedulerKind parse_scheduler(const std::string& name) {
  if (name == "serial") return SchedulerKind::serial;
  if (name == "flowgraph") return SchedulerKind::flowgraph;
  if (name == "paper-omp") return SchedulerKind::paper_omp;
  throw std::invalid_argument("unknown scheduler '" + name + "' (serial, flowgraph or paper-omp)");
}

const char* scheduler_name(SchedulerKind kind) {
  switch (kind) {
    case SchedulerKind::serial: return "serial";
    case SchedulerKind::flowgraph: return "flowgraph";
    case SchedulerKind::paper_omp: return "paper-omp";
  }
  return "?";
}

std::unique_ptr<Schedule> make_schedule(const Model& m, Workspace& ws, const ScheduleOptions& opt) {
  if (opt.threads < 1) throw std::invalid_argument("threads must be >= 1");
  if (opt.grain < 1) throw std::invalid_argument("grain must be >= 1");
  switch (opt.kind) {
    case SchedulerKind::serial: return std::make_unique<SerialSchedule>(m, ws);
    case SchedulerKind::flowgraph: return make_flowgraph_schedule(m, ws, opt);
    case SchedulerKind::paper_omp: return make_paper_omp_schedule(m, ws, opt);
  }
  throw std::invalid_argument("unknown scheduler");
}

}  // namespace cvt
