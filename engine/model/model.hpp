// The immutable model (docs/model.md sections 1-3): parameters in SI units, the layout of
// the generalized coordinates, the constant inertia blocks and the reference geometry.
// Everything that changes during a run lives in State / Workspace (engine/model/state.hpp).
#pragma once

#include <Eigen/Dense>
#include <array>
#include <string>
#include <vector>

#include "engine/model/config.hpp"

namespace cvt {

// Coordinates of one pin half (docs/model.md 2.1): two ends, each x, y, z, sx, sy.
namespace half {
inline constexpr int kEnd = 5;  // stride between end 0 (z < 0) and end 1 (z > 0)
inline constexpr int kX = 0, kY = 1, kZ = 2, kSx = 3, kSy = 4;
inline constexpr int kSize = 10;
}  // namespace half

// Per joint j: half a_j (10), half b_j (10), plate pack s_j of link j (1).
inline constexpr int kJointSize = 21;
inline constexpr int kJointA = 0, kJointB = 10, kJointS = 20;
// Per shaft k (0 driving, 1 driven): ux, uy, uz, theta_x, theta_y, phi, w.
inline constexpr int kShaftSize = 7;
inline constexpr int kUx = 0, kUy = 1, kUz = 2, kTx = 3, kTy = 4, kPhi = 5, kW = 6;
// Auxiliary integrated quantities appended to the first-order state (docs/model.md 6).
enum Aux : int { kWorkIn = 0, kWorkOut, kWorkDiss, kWorkClamp, kCtrlIntegral, kWorkSwitch, kAuxSize };

struct Pulley {
  Eigen::Vector2d centre;       // shaft axis in the xy plane [m]
  int moving_side = +1;         // +1: moving sheave on the +z side, -1 on the -z side
  std::array<double, 2> face_z; // nominal face offsets Z_- (index 0) and Z_+ (index 1) [m]
  double running_radius = 0;    // R of the initial state [m]
};

struct Model {
  Config cfg;

  // Sizes.
  int links = 0;   // N = number of joints = number of links
  int ndof = 0;    // generalized coordinates n
  int nstate = 0;  // 2n + kAuxSize

  // Derived parameters (docs/model.md 4).
  double L0 = 0;          // pin half length
  double plate_rest = 0;  // l0 = p + d_h
  double kappa = 0;       // rocker: d_h/2 - R_r
  double tan_beta = 0, sin_beta = 0, cos_beta = 0;
  std::vector<double> plate_zeta;    // axial offsets zeta_k of the plates in a pack
  std::vector<double> station_xi;    // rocker stations along the half, xi in (0,1)
  double damp = 1;                   // damping scale
  double beam_beta = 0;              // stiffness-proportional damping (scaled)

  std::array<Pulley, 2> pulley;

  // Constant inertia A0 (docs/model.md 3): the blocks and their inverses.
  Eigen::Matrix4d bend_mass, bend_mass_inv;   // (w1, s1, w2, s2) of one half, one plane
  Eigen::Matrix2d axial_mass, axial_mass_inv; // (z1, z2)
  double pack_mass = 0;
  Eigen::Matrix2d shaft_axial_mass, shaft_axial_mass_inv;  // (uz, w)
  Eigen::Vector4d bend_inv_w;  // bend_mass_inv * (1, 0, 1, 0): A0^-1 applied to g (3.2)
  double bend_inv_s = 0;       // (1,0,1,0) . bend_inv_w

  // Reference initial state (docs/model.md 5) and what the geometry solver reports.
  Eigen::VectorXd y0;
  double closure_residual = 0;  // [m]
  int geometry_iterations = 0;

  // Index helpers.
  int joint(int j) const { return kJointSize * wrap(j); }
  int half_a(int j) const { return joint(j) + kJointA; }
  int half_b(int j) const { return joint(j) + kJointB; }
  int pack(int j) const { return joint(j) + kJointS; }
  int shaft(int k) const { return kJointSize * links + kShaftSize * k; }
  int load_index() const { return kJointSize * links + 2 * kShaftSize; }
  int wrap(int j) const { return ((j % links) + links) % links; }
};

// Builds the model from a validated configuration: derived parameters, inertia blocks,
// and the initial state from the geometry solver. Throws ConfigError for geometry that
// cannot be built (chain too short or too long, impossible ratio).
Model build_model(const Config& cfg);

// Smooth load ramp (docs/model.md 4.6): 0 at t = 0, 1 for t >= t_ramp, C1.
double ramp(double t, double t_ramp);
double ramp_rate(double t, double t_ramp);

// The load torque's ramped part at t (docs/model.md 4.6.3): ramp.load_from until
// ramp.load_start, then along the ramp to load.torque over ramp.load_time; or, with
// load.torque_profile, the profile at t.
double ramped_load_torque(const Config& c, double t);

// An input that changes in time (Config::Profile): its value at t, linear between its
// points and held before the first and after the last; its rate (0 where it is held); its
// integral from 0 to t.
double profile_value(const Config::Profile& p, double t);
double profile_rate(const Config::Profile& p, double t);
double profile_integral(const Config::Profile& p, double t);
// The drive's prescribed speed omega_in(t) and angle (its integral from 0): drive.speed, or
// drive.speed_profile.
double drive_speed(const Config& c, double t);
double drive_angle(const Config& c, double t);
// The largest drive speed the run prescribes (what the numerics' intervals must resolve)
// and the one it ends at (what its steady state turns at).
double peak_drive_speed(const Config& c);
double final_drive_speed(const Config& c);

// The period [s] of the lowest torsion mode of the drive line: the prescribed drive, its
// torsion spring, both pulleys turning together through a rigid chain at the geometric
// ratio, the load's torsion spring and the load inertia (docs/output.md, "Until steady");
// 0 when neither spring holds it.
double torsion_period(const Model& m);

// The length of each of the two windows whose means an until-steady run compares:
// run.steady_window, or two torsion periods rounded up to a whole number of meshing
// periods (the time a link takes to pass, pitch / (omega_in R1)), at least 4 of them.
double steady_window(const Model& m);

// The clamping forces' potential part at t (docs/model.md 4.6.4), F_k rho(t), and its
// time rate (with clamping.driving_profile / driven_profile: the profile and its rate);
// the controller's forces are external to it.
void clamping_schedule(const Model& m, double t, double F[2], double Fdot[2]);
// The controller's target ratio at t: controller.target_profile interpolated linearly
// (held before its first point and after its last), or controller.target_ratio.
double target_ratio(const Config& c, double t);
// The target's rate d(ratio)/dt at t (0 outside the profile's sloped segments).
double target_rate(const Config& c, double t);
// The torque the driven pulley must transmit at t by the schedule: |M_load(t)| plus what
// accelerates the load along the target, J_load omega_in |d(ratio)/dt| / ratio^2.
double transmitted_torque(const Config& c, double t);
// The running radius of pulley k's chain with its moving sheave at w (docs/model.md
// 4.6.4): the initial radius less sigma_k w / (2 tan beta), within hub and outer radius.
double sheave_radius(const Model& m, int k, double w);
// S cos(beta) / (2 f0) of the slip-safe clamping (the controller on with
// controller.clamping_safety S > 0), else 0: the least clamping force per newton of
// strand tension difference M_load / R2.
double slip_safe_gain(const Model& m);

// The time from which every ramp (clamping forces and load torque) and every input's
// profile has ended.
double ramps_end(const Config& c);
// The end of the W-methods' settling phase: integrator.settle_time, or ramps_end when < 0.
double settle_end(const Config& c);

}  // namespace cvt
