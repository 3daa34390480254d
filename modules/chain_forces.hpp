// Chain forces (docs/model.md 4.1-4.3): pin-half beams, rocker joints, plates, plate packs.
// Grain: joint j computes the beams of a_j and b_j, the rocker joint j, the plates and the
// pack of link j, and writes only chain_slots[j].
#pragma once

#include "engine/state.hpp"

namespace cvt {

void chain_forces(const Model& m, Workspace& ws, int begin, int end);

// 4.1: adds the elastic and damping forces of one pin-half beam (q, v, f: its 10
// coordinates) to f; returns the dissipated power. Public for the modal tests, which take
// a single half's stiffness from it.
double beam(const Model& m, const double* q, const double* v, double* f);

// Potential energy of the chain's elastic elements (beams, plates, packs, rocker Hertz;
// with `status`, only the active rocker pairs count).
double chain_energy(const Model& m, const double* q, const ContactStatus* status = nullptr);

// Per-link plate tension sum (k (d - l0) + c ddot over stretched plates) [N].
double link_tension(const Model& m, const Workspace& ws, int link);
// Axial force in a half (EA strain + damping) [N], tensile positive.
double half_axial_force(const Model& m, const double* q, const double* v, int half_offset);

// Updates the rocker statuses after a step (4.4): active where the faces penetrate and
// the normal force is compressive.
// Rocker statuses of joints [begin, end); energy switched in or out goes to ws.switch_slot[j].
void update_rocker_status(const Model& m, Workspace& ws, int begin, int end);

}  // namespace cvt
