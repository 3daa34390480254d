// Chain forces (docs/model.md 4.1-4.3): pin-half beams, rocker joints, plates, plate packs.
// Grain: joint j computes the beams of a_j and b_j, the rocker joint j, the plates and the
// pack of link j, and writes only chain_slots[j].
#pragma once

#include "engine/model/state.hpp"
#include "modules/elastic_hessian.hpp"

namespace cvt {

// Joints [begin, end). With extras (FrictionExtras), the rocker stations' friction under
// the frozen branch, and what the friction Jacobian asks for.
void chain_forces(const Model& m, Workspace& ws, int begin, int end, const FrictionExtras& x = {});

// 4.1: adds the elastic and damping forces of one pin-half beam (q, v, f: its 10
// coordinates) to f; returns the dissipated power. Public for the modal tests, which take
// a single half's stiffness from it.
double beam(const Model& m, const double* q, const double* v, double* f);

// The stiffness (-dF/dq at fixed velocities) of joint j's rocker friction, added to its
// blocks (J.prev, own, cross, up): the friction R = N rho follows the Hertz force's change,
// rho dN/dq, and the faces' slip follows the links' spins: psi_dot (the lever to the contact
// point) changes with the link vectors, and the levers turn with the halves (docs/
// integrators.md 12.2, "The analytic stiffness"). Reads ws's positions, velocities, link
// kinematics and statuses.
void add_rocker_friction_stiffness(const Model& m, const Workspace& ws, int j, JointHessian& J);

// Potential energy of the chain's elastic elements (beams, plates, packs, rocker Hertz;
// with `status`, only the active rocker pairs count).
double chain_energy(const Model& m, const double* q, const ContactStatus* status = nullptr);

// Per-link plate tension sum (k (d - l0) + c ddot over stretched plates) [N].
double link_tension(const Model& m, const Workspace& ws, int link);
// Joint j's centre in the xy plane: the mean of its two halves' chord middles [m].
Eigen::Vector2d joint_centre(const Model& m, const double* q, int j);
// The mean link tension of the two free strands [N]: over the links whose middle lies
// between 20 % and 80 % of the way from the driving to the driven shaft's axis, on the left
// of the line of centres seen from the driving shaft (out[0], the upper strand of the
// models, whose driven shaft lies along +x) and on its right (out[1], the lower); 0 for a
// strand without such a link (docs/model.md 6).
void strand_tensions(const Model& m, const Workspace& ws, double out[2]);
// Tension of each plate of link `link` (k (d - l0) + c ddot where stretched, else 0) [N],
// into out[0 .. plates_per_link).
void plate_tensions(const Model& m, const Workspace& ws, int link, double* out);
// Normal force of rocker joint j: the sum over its active stations of Hertz + damping [N].
double rocker_force(const Model& m, const Workspace& ws, int j);
// Relative tilt of pins j+1 and j about the chain direction e_j (docs/model.md 6) [rad]:
// n_j . (s_{j+1} - s_j), with s the mean chord slope d(x, y)/dz of a pin's two halves and
// n_j = (-e_y, e_x) the in-plane normal of link j.
double chain_torsion_angle(const Model& m, const Workspace& ws, int j);
// Largest rocker-face penetration delta over every joint and station, whatever its
// status [m]; its joint in *joint.
double max_rocker_penetration(const Model& m, const double* q, int* joint);
// Axial force in a half (EA strain + damping) [N], tensile positive.
double half_axial_force(const Model& m, const double* q, const double* v, int half_offset);

// Updates the rocker statuses after a step (4.4): active where the faces penetrate and
// the normal force is compressive.
// Rocker statuses of joints [begin, end); energy switched in or out goes to ws.switch_slot[j].
void update_rocker_status(const Model& m, Workspace& ws, int begin, int end);

}  // namespace cvt
