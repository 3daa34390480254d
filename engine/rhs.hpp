// One evaluation of the first-order right-hand side y' = f(t, y), y = (q, qdot, aux)
// (docs/model.md 3, 6). The module kernels are scheduled by graph/ (serial here); the
// ordered gather and the accelerations are shared by every schedule.
#pragma once

#include "engine/state.hpp"

namespace cvt {

// Points the workspace at the stage input.
void set_stage_input(const Model& m, Workspace& ws, double t, const double* y);
// Sums the module slots in a fixed order into ws.force (bit-identical for any schedule).
void gather_forces(const Model& m, Workspace& ws);
// Writes dy = (qdot, qdd, aux rates) after accelerations().
void write_derivative(const Model& m, const Workspace& ws, double* dy);

// The serial schedule: modules one after the other (the baseline).
void rhs_serial(const Model& m, Workspace& ws, double t, const double* y, double* dy);

// Contact statuses for the next step from the state y (docs/model.md 4.4).
void update_contact_status(const Model& m, Workspace& ws, double t, const double* y);

// Energies of the state y at time t (docs/model.md 6).
struct Energies {
  double kinetic = 0, elastic = 0;
};
// With `status`, the contact energy counts only the pairs active in the next step.
Energies energies(const Model& m, double t, const double* y, const ContactStatus* status = nullptr);

}  // namespace cvt
