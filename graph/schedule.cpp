// Choosing a schedule by name and building it.
#include "graph/schedule.hpp"

#include <stdexcept>

namespace cvt {

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
    case SchedulerKind::serial: return make_serial_schedule(m, ws);
    case SchedulerKind::flowgraph: return make_flowgraph_schedule(m, ws, opt);
    case SchedulerKind::paper_omp: return make_paper_omp_schedule(m, ws, opt);
  }
  throw std::invalid_argument("unknown scheduler");
}

}  // namespace cvt
