// The damping coefficients of the force laws, each scaled by the model's damping scale
// (damping.scale, m.damp; 0 turns damping off): the one place where the scale enters them
// (the beams' stiffness-proportional beta is scaled with the model, m.beam_beta).
#pragma once

#include "engine/model/model.hpp"

namespace cvt {

struct Damping {
  double plate, pack, rocker, pulley_contact;  // [N s/m]
  double bearing_radial, bearing_axial, sheave;  // [N s/m]
  double drive, load;                            // [N m s/rad]
};

inline Damping damping(const Model& m) {
  const Config& c = m.cfg;
  const double d = m.damp;
  return {.plate = c.chain.plate_damping * d,
          .pack = c.chain.pack_damping * d,
          .rocker = c.rocker.damping * d,
          .pulley_contact = c.pulley_contact.damping * d,
          .bearing_radial = c.bearing.radial_damping * d,
          .bearing_axial = c.bearing.axial_damping * d,
          .sheave = c.clamping.sheave_damping * d,
          .drive = c.drive.damping * d,
          .load = c.load.damping * d};
}

}  // namespace cvt
