// Pulley contact (docs/model.md 4.5): the crowned ends of every pin half against the
// conical sheave faces, Hertz normal force and regularized friction. Grain: joint j
// writes pulley_slots[j] (its two halves, the torques of links j-1 and j, both shafts).
#pragma once

#include <cmath>

#include <Eigen/Core>

#include "engine/model/state.hpp"
#include "modules/beam.hpp"

namespace cvt {

// Geometry of one pin end against the face of pulley k on side sigma (4.5.1-4.5.3).
struct EndGeometry {
  double cx, cy, cz;      // sphere centre (global)
  double dx, dy, dz;      // c - O - u
  double pen;             // Delta
  double gdx, gdy, gdz;   // dDelta/dc (= -dDelta/du)
  double gtx, gty;        // dDelta/dtheta_x, dDelta/dtheta_y
  double gw;              // dDelta/dw (moving sheave), 0 on the fixed face
};

inline EndGeometry end_geometry(const Model& m, const double* hq, int e, int k, const double* sh) {
  const double sigma = e == 0 ? -1.0 : 1.0;
  const double R = m.cfg.pulley_contact.end_radius;
  const double* p = hq + e * half::kEnd;
  EndGeometry g;
  g.cx = p[half::kX] - sigma * R * p[half::kSx];
  g.cy = p[half::kY] - sigma * R * p[half::kSy];
  g.cz = p[half::kZ] - sigma * R;
  const Pulley& pu = m.pulley[k];
  g.dx = g.cx - pu.centre.x() - sh[kUx];
  g.dy = g.cy - pu.centre.y() - sh[kUy];
  g.dz = g.cz - sh[kUz];
  const double tx = sh[kTx], ty = sh[kTy];
  // Shaft frame, small tilt: l = d - theta x d.
  const double lx = g.dx - ty * g.dz, ly = g.dy + tx * g.dz, lz = g.dz - tx * g.dy + ty * g.dx;
  const double r = std::sqrt(lx * lx + ly * ly);
  const bool moving = (e == 0 ? -1 : 1) == pu.moving_side;
  const double w = moving ? sh[kW] : 0.0;
  const double Zs = pu.face_z[e];
  g.pen = R + sigma * (lz - Zs - w) * m.cos_beta - r * m.sin_beta;
  const double glx = -m.sin_beta * lx / r, gly = -m.sin_beta * ly / r, glz = sigma * m.cos_beta;
  g.gdx = glx + ty * glz;
  g.gdy = gly - tx * glz;
  g.gdz = -ty * glx + tx * gly + glz;
  g.gtx = gly * g.dz - glz * g.dy;
  g.gty = -glx * g.dz + glz * g.dx;
  g.gw = moving ? -sigma * m.cos_beta : 0.0;
  return g;
}

// Whether half hq lies within pulley k's outer radius (its mid-point), where its ends may touch.
inline bool near_pulley(const Model& m, const double* hq, int k) {
  const double x = mid(hq, 0) - m.pulley[k].centre.x(), y = mid(hq, 1) - m.pulley[k].centre.y();
  const double rmax = m.cfg.sheave.outer_radius;
  return x * x + y * y < rmax * rmax;
}

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

// The stiffness (-dF/dq at fixed velocities) of the pin ends' friction within link l's
// block (halves b_l, a_{l+1}, which both turn with link l), added to K: the friction force
// R = N rho follows the Hertz force's change, rho dN/dq, and the slip follows the sheave's
// spin at the moving contact point, du/dq = -omega x dc/dq (docs/integrators.md 12.2, "The
// analytic stiffness"). Reads ws's positions, velocities, link kinematics and statuses.
void add_pulley_friction_stiffness(const Model& m, const Workspace& ws, int l,
                                   Eigen::Matrix<double, 2 * half::kSize + 1, 2 * half::kSize + 1>& K);

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
