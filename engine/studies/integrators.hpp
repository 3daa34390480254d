// `cvt-engine study integrators`: the integrator study protocol of Orlov et al. 2016
// (section 4.1) on the CVT model (docs/integrators.md).
//   (a) the error after one step against h, from a running state, relative to RK4 with a
//       small step (2e-9 s), statuses frozen;
//   (b) the sample curve, the axial force in a pin half entering a pulley, over a window:
//       each method at its largest accurate step (fixed h for RK4, the loosest tolerance for
//       the adaptive ones), its deviation from the RK4 reference curve in % of the curve's
//       range, wall time, RHS evaluations, Jacobians and LU factorizations.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "engine/model/model.hpp"
#include "graph/schedule.hpp"

namespace cvt {

struct IntegratorStudyOptions {
  // The defaults are the advised comparison (docs/integrators.md): RK4 at 1e-8 against
  // ROS34PW2 at the configuration's own step, over the 5 ms window after the load ramp,
  // against RK4 at 5e-9.
  double t_warm = 2.5e-3;     // RK4 at warm_step from t = 0 to here: the running state
  double warm_step = 1e-8;    // RK4's production step [s]
  double t_sample = 5e-3;     // length of the sample-curve window [s]
  double sample_dt = 1e-5;    // spacing of the curve's samples [s]
  double ref_step = 5e-9;     // RK4 step of the reference curve [s]
  double one_step_ref = 2e-9; // RK4 step of the one-step reference [s]
  std::vector<std::string> methods = {"rk4", "ros34pw2"};
  std::vector<double> one_step_h = {1e-8, 2e-8, 5e-8, 1e-7, 2e-7, 5e-7, 1e-6, 2e-6, 4e-6};
  std::vector<double> rk4_steps = {1e-8};       // tried largest first
  // The W-methods (ROS2, ROS34PW2) run fixed steps, tried largest first (empty: adaptive with
  // the tolerances). Each entry a step, with its own matrix intervals where w_every > 0 (else
  // the study's), for one method where `method` is set (else for every W-method studied).
  struct WCandidate {
    double h = 0;
    double tol = 0;  // > 0: adaptive at this tolerance (the production norm, w_adaptive_options) in place of h
    int w_every = 0, w_k_every = 0;
    std::string method = "";  // empty: every W-method
  };
  // Empty: the configuration's integrator.step with its w_every and w_k_every.
  std::vector<WCandidate> w_steps;
  bool all = true;             // (b): run every candidate, not only up to each method's first accurate one
  int repeat = 1;               // runs of each candidate in (b); its wall time is their median
  std::vector<double> tolerances = {1.0, 0.3, 0.1, 0.03, 0.01};   // tried loosest first (scaled atol)
  double max_deviation = 0.01;  // accurate: max |F - F_ref| <= this x range of F_ref
  double max_wall = 600;        // per candidate run [s]; longer runs are stopped ("timeout")
  // (b): every candidate run starts from the running state with each position q_i moved by
  // perturb |q_i| u_i, u_i uniform in [-1, 1) from `seed` (perturb = 0: unperturbed). At rounding level
  // (1e-14 .. 1e-12) it shows how far such changes alone move a candidate's curve.
  double perturb = 0;
  std::uint64_t seed = 1;
  bool one_step = false, curve = true;
  bool exact_dense_rows = true;
  bool freeze_friction = true;  // ModelOdeOptions::freeze_friction
  double status_interval = 0;   // OdeRunOptions::status_interval
  int newton_max_iter = 7;      // OdeOptions
  bool max_norm = false;
  // The implicit methods (trapezoid, TR-BDF2, ESDIRK3): simplified Newton with the chain's
  // structured matrix (OdeOptions::newton_uses_w, the W-methods' block-cyclic LU) in place of
  // the coloured Jacobian and a sparse LU; and the chain's error norm (per pin, maximized;
  // ModelOdeOptions::error_tol) for every adaptive candidate.
  bool newton_w = false;
  bool chain_norm = false;
  double jac_theta = 0.3;
  int w_every = 0;              // ModelOdeOptions::w_every (ROS2; 0: the config's integrator.w_every)
  int w_k_every = 0;            // ModelOdeOptions::w_k_every (ROS2; 0: the config's integrator.w_k_every)
  bool w_no_stiffness = false;  // ModelOdeOptions::w_stiffness = false (ROS2)
  bool w_status_rebuild = false;  // ModelOdeOptions::w_status_rebuild (ROS2)
  int w_secant = -1;            // ModelOdeOptions::w_secant (W-methods; 1, 0, or -1: integrator.w_secant)
  double w_fresh = -1;          // ModelOdeOptions::w_fresh (W-methods; < 0: integrator.w_fresh)
  int w_fresh_max = 0;          // ModelOdeOptions::w_fresh_max (0: integrator.w_fresh_max)
  bool ros2_full_jacobian = false;  // ROS2 with the full finite-difference Jacobian (!ModelOdeOptions::w_blocks)
  ScheduleOptions schedule;
  // Keep the running state and the reference curve here and reuse them when the inputs that
  // make them are the same (empty: no cache). The reference's wall time is then an earlier
  // run's, so compare speed-ups only within a run made without the cache.
  std::string cache_dir;
  std::string out_csv;          // table as CSV; the curves go to <out without .csv>-curves.csv
};

// "H" or "H:W:K" (a step, and its matrix intervals) per entry; throws std::invalid_argument
// naming a bad entry.
std::vector<IntegratorStudyOptions::WCandidate> parse_w_candidates(const std::vector<std::string>& items);

// Runs the study on model m, prints the tables, writes the CSVs. Returns 0.
int run_integrator_study(const Model& m, const IntegratorStudyOptions& opt);

}  // namespace cvt
