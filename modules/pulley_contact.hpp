// Pulley contact (docs/model.md 4.5): the crowned ends of every pin half against the
// conical sheave faces, Hertz normal force and regularized friction. Grain: joint j
// writes pulley_slots[j] (its two halves, the torques of links j-1 and j, both shafts).
#pragma once

#include "engine/model/state.hpp"

namespace cvt {

// What one pin-end contact carries (for the tracked-pin channels).
struct EndContact {
  double normal = 0;    // N [N]
  double friction = 0;  // |R| [N]
  double penetration = 0;
  int pulley = -1;      // -1: no contact
};
struct PinContactReport {
  EndContact end[2][2];  // [half a/b][end -z/+z]
};

// Joints [begin, end). With extras (FrictionExtras), the pin ends' friction under the
// frozen branch, and what the friction Jacobian asks for.
void pulley_contact(const Model& m, Workspace& ws, int begin, int end, const FrictionExtras& x = {});
// One joint; fills `report` when given.
void pulley_contact_joint(const Model& m, Workspace& ws, int j, JointSlot& s, PinContactReport* report,
                          const FrictionExtras& x = {});

// Hertz energy of the pin ends (with `status`, only the active pairs).
double pulley_energy(const Model& m, const double* q, const ContactStatus* status = nullptr);
// Pin-end statuses of joints [begin, end); switched energy into ws.switch_slot[j].
void update_pulley_status(const Model& m, Workspace& ws, int begin, int end);

// Largest penetration Delta of any pin end near a pulley, whatever its status [m];
// the joint it belongs to in *joint (-1 if no end is near a pulley).
double max_pulley_penetration(const Model& m, const double* q, int* joint);
// Mean radius of the joint centres in contact with pulley k (the running radius of the
// current state, for the geometric ratio); 0 if none.
double wrapped_radius(const Model& m, const Workspace& ws, int k);

}  // namespace cvt
