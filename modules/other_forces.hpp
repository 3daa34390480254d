// Other forces (docs/model.md 4.6): shaft supports, drive, load, clamping and the optional
// ratio controller. Small; not split per pin. Writes ws.other.
#pragma once

#include "engine/model/state.hpp"

namespace cvt {

void other_forces(const Model& m, Workspace& ws);

// Potential energy of supports, drive and load springs, and the clamping potential
// sigma_m F_ramp(t) w (4.6.4).
double other_energy(const Model& m, double t, const double* q);

// Prescribed input angle phi_in(t): the integral of omega_in (drive.speed t, or of
// drive.speed_profile).
inline double input_angle(const Model& m, double t) { return drive_angle(m.cfg, t); }

}  // namespace cvt
