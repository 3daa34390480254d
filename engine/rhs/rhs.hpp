// One evaluation of the first-order right-hand side y' = f(t, y), y = (q, qdot, aux)
// (docs/model.md 3, 6, 7), cut into passes that every schedule (graph/) runs in its own
// way: the module kernels over pin ranges, then the ordered gather and the structured
// solve over pin ranges, then the shafts. Each pass writes only its own pins' data, and
// every sum has a fixed order, so any split over threads or NUMA nodes gives the same bits.
#pragma once

#include "engine/ode/rk4.hpp"
#include "engine/rhs/profile.hpp"
#include "engine/model/state.hpp"

namespace cvt {

// Points the workspace at the stage input.
void set_stage_input(const Model& m, Workspace& ws, double t, const double* y);

// Pass 2 (after the module kernels): generalized forces of joints [begin, end) from the
// module slots in a fixed order (docs/model.md 4.0), link torques through g_i, and
// y = A0^-1 F for those joints. Reads the slots of joints begin-1 .. end.
void gather_joints(const Model& m, Workspace& ws, int begin, int end);
// The same with the chain and pulley contributions already summed per coordinate, in a
// buffer laid out as [joint coordinates 21 N][link torques N] (graph/paper_omp.cpp). Each
// coordinate takes at most two contributions per module, so a zeroed buffer summed in any
// order holds exactly the sum gather_joints forms.
void gather_joints_from_sums(const Model& m, Workspace& ws, const double* chain_sum, const double* pulley_sum,
                             int begin, int end);
// Adds slot j into such a buffer.
void scatter_slot(const Model& m, const JointSlot& s, int j, double* buf);
// Forces on the shafts and the load (sums over all pins in pin order), their A0^-1, and
// the dissipated power. Runs beside gather_joints.
void gather_shafts(const Model& m, Workspace& ws);
// Pass 3: q'' of joints [begin, end) (Woodbury, 3.2), their part of dy, and `op` on it.
void finish_joints(const Model& m, Workspace& ws, double* dy, const StageOp* op, int begin, int end);
// The shafts', the load's and the work integrals' part of dy, and `op` on it.
void finish_shafts(const Model& m, Workspace& ws, double* dy, const StageOp* op);
// The stage update `op` alone, over the same coordinates as finish_joints / finish_shafts
// (finish_* with op = nullptr, then these, give the same bits: the update is elementwise).
void stage_update_joints(const Model& m, const StageOp* op, double* dy, int begin, int end);
void stage_update_shafts(const Model& m, const StageOp* op, double* dy);

// Whole-vector forms of the passes (tests, benchmarks, sampling).
void gather_forces(const Model& m, Workspace& ws);

// The serial schedule: the stages of engine/rhs/stages.hpp top to bottom, each over all
// pins (the baseline); each timed into prof (if given, as worker 0). With extras, the
// kernels' friction as they ask.
void rhs_serial(const Model& m, Workspace& ws, double t, const double* y, double* dy,
                const StageOp* op = nullptr, Profiler* prof = nullptr, const FrictionExtras& x = {});

// Contact statuses for the next step from the state y (docs/model.md 4.4), and the
// contact energy switched in or out (ws.switch_work). In passes like the RHS: the link
// kinematics, then joints [begin, end) (each writes its own statuses and switch_slot[j]),
// then the sum of switch_slot in pin order.
void update_contact_status(const Model& m, Workspace& ws, double t, const double* y, Profiler* prof = nullptr);
void begin_status_update(const Model& m, Workspace& ws, double t, const double* y);
void update_status_joints(const Model& m, Workspace& ws, int begin, int end);
void finish_status_update(const Model& m, Workspace& ws);

// After a step of any method: the contact statuses for the next step at (t, y) by
// `s.update_status(t, y)` (a schedule's, graph/schedule.hpp: it leaves the switched contact
// energy in ws.switch_work), and that energy added to y's work integral (docs/model.md 4.4).
template <class StatusUpdater>
void update_statuses_after_step(const Model& m, StatusUpdater& s, const Workspace& ws, double t, Eigen::VectorXd& y) {
  s.update_status(t, y.data());
  y[2 * m.ndof + kWorkSwitch] += ws.switch_work;
}

// Energies of the state y at time t (docs/model.md 6).
struct Energies {
  double kinetic = 0, elastic = 0;
};
// With `status`, the contact energy counts only the pairs active in the next step.
Energies energies(const Model& m, double t, const double* y, const ContactStatus* status = nullptr);

}  // namespace cvt
