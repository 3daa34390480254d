// The serial schedule: one thread, the stage table top to bottom (the baseline).
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
    std::string dot = "digraph stage {\n  rankdir=LR;\n  start";
    for (const StageDecl& s : kStages) (dot += " -> ") += s.name;
    dot += ";\n  accelerations [label=\"accelerations\\n+ stage update\"];\n}\n";
    return dot;
  }
  int threads() const override { return 1; }

 private:
  const Model& m_;
  Workspace& ws_;
};

}  // namespace

std::unique_ptr<Schedule> make_serial_schedule(const Model& m, Workspace& ws) {
  return std::make_unique<SerialSchedule>(m, ws);
}

}  // namespace cvt
