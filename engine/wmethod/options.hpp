// The settings of the model's ODE system (ModelOde) and of its W linear solver (WSolver).
#pragma once

#include "engine/model/config.hpp"

namespace cvt {

struct ModelOdeOptions {
  // Joints on each side whose coordinates a joint's acceleration may depend on (pattern
  // half-width; 2 covers the rocker faces turning with the neighbouring links and the
  // Woodbury correction, verified by tests/engine/wmethod/model_ode_test.cpp).
  int band = 2;
  // true: the pins -> shaft accelerations and pins -> dissipated power entries (the dense
  // rows) are in the Jacobian, computed from the per-pin force slots of the same coloured
  // evaluations (no extra RHS); false: they are left out (an approximate Jacobian, which
  // only slows Newton's convergence).
  bool exact_dense_rows = true;
  // Integrate z = (y - c) / s instead of y, with s the unit vector below and c the state at
  // the start of each OdeDriver macro step (s_i = 1, c = 0 when off): the solvers have a
  // scalar atol, and the CVT's state mixes absolute positions (0.05 m, to be known to
  // 1e-8 m), slopes, velocities and energies. With the shift, |z| is the motion within the
  // macro step, so rtol = atol = tol is meaningful (and so is Newton's tolerance, which
  // RADAU5-style is a fraction of rtol: a tiny rtol made Newton chase 1e-10 m).
  bool scaled = false;
  // The Jacobian's sparsity pattern in the system (OdeSystem::sparsity), which the generic
  // solvers' Jacobians and Newton need; the production W-step (WStep) has none (the pattern
  // of the reference model takes tens of milliseconds to build).
  bool sparsity = true;
  // Freeze each contact's friction branch (stick / slide) within a macro step: the first
  // evaluation of each OdeDriver macro step records it (FrozenFriction). Only
  // for the implicit methods; without it Newton diverges at h ~ 1e-6 on the kink of the
  // nonsmooth law at v0 (docs/integrators.md 11).
  bool freeze_friction = true;
  // The W-method settings default to the configuration's [integrator] defaults (one source:
  // Config::Integrator; w_run_options maps a configuration).
  // W-methods: rebuild the friction blocks and refactorize at every step whose index is a
  // multiple of this (a W-method keeps its order with a stale matrix; only the stiff part
  // must be captured).
  int w_every = Config::Integrator{}.w_every;
  // FrictionJacobian::secant: true (the secant slope N f(v)/v along the sliding direction
  // too, never below the exact one) keeps a sliding contact that is about to stick stiff in
  // W; with the exact slope (0 above v0 for the nonsmooth law) a stale W meets such a
  // contact explicitly, and its friction chatters (docs/integrators.md 12.2).
  bool w_secant = Config::Integrator{}.w_secant;
  // false: no friction blocks; ROS2 then takes the full coloured finite-difference Jacobian
  // and a sparse LU at every step (slow: for checking what the blocks leave out).
  bool w_blocks = true;
  // true: W carries the chain's stiffness K = -dF/dq (finite differences over link colours,
  // 21 evaluations per colour: 63 for 3 colours), taken at every w_k_every-th step's rebuild
  // (the elastic forces change slowly; the friction blocks, every w_every steps).
  bool w_stiffness = true;
  // true: K as the analytic Hessian of the chain's elastic energy (modules/elastic_hessian)
  // and the friction's change with position at the pin ends and the rockers
  // (add_pulley_friction_stiffness, add_rocker_friction_stiffness; the damping's change left
  // out); false: the finite differences of all the chain's forces.
  bool w_analytic_stiffness = Config::Integrator{}.w_analytic_stiffness;
  int w_k_every = Config::Integrator{}.w_k_every;
  // true: a change of the contact statuses (after a step) makes the next step rebuild the
  // whole matrix. Off: measured worse (8-10 % against 0.8 % over the 5 ms window at 2.5e-7,
  // and 5x further from RK4 in the mini model's load ramp), as the stiffness differences
  // taken right where a contact switches step across its boundary (docs/integrators.md 15).
  bool w_status_rebuild = false;
  // The block LU of W drops the fill of its cyclic corners below this fraction of the next
  // pivot block (CyclicBlockLU::set_drop_tolerance): W is then factored exactly as W + E,
  // |E| <= 1e-12 |W|, the same for every stage, far below the approximation a W-method
  // works with anyway (a matrix up to w_every steps old). On the reference model at 1e-6
  // the fill rows fall from 58 to 21 of 83 per factorization (docs/integrators.md 12.2).
  double w_fill_drop = 1e-12;
  // The block LU on this many segments (SegmentedBlockLU; 0: CyclicBlockLU's two sweeps).
  int w_segments = Config::Integrator{}.w_segments;
  // Fresh friction between rebuilds (docs/integrators.md 12.4): > 0 keeps W's friction part
  // current at every step, as a low-rank (Woodbury) correction of the factorized W for the
  // contacts whose friction coefficient mu (the secant N f(v)/v) moved since the rebuild by
  // more than w_fresh * m_pin / (gamma h), i.e. whose stiffness gamma h mu / m_pin changed by
  // more than w_fresh. Each such contact costs two solves with the factorized W when it
  // joins, and a rank-2 term in every solve after. More than w_fresh_max of them make the
  // next step rebuild the friction blocks. 0: off (the stale blocks of docs/integrators.md 12.3); off too
  // without w_secant.
  double w_fresh = Config::Integrator{}.w_fresh;
  // true: W holds the shafts' velocity rows too (their mass and the pulley friction's damping
  // between sheaves and pins, both ways), solved by the Schur complement of the 14 shaft
  // unknowns on the factorized chain (docs/integrators.md 12.2); false: the identity there
  // (the shafts' increments are the right side's and drag the pins).
  bool w_shafts = Config::Integrator{}.w_shafts;
  int w_fresh_max = Config::Integrator{}.w_fresh_max;
  // Adaptive steps (OdeSystem::error_norm): > 0 gives the system the norm of the chain's
  // error, per joint (its two pin halves and its plate pack, positions and velocities), per
  // shaft and for the load, each the RMS of its components in units of tol * (length_unit,
  // velocity_unit), maximized over these groups; the work integrals are left out. So
  // error_tol = 1 accepts a step whose estimate is about 1 um and 1 mm/s at the pin that errs
  // most, however smoothly the other 83 run. 0: the library's norm over atol / rtol.
  double error_tol = 0;
  // Adaptive steps: W = I - gh' J~ is kept while the step's gh stays within
  // [gh' / w_h_shrink, gh' w_h_grow] (a W-method keeps its order with J~' = (h'/h) J~; with
  // the exact J ROS34PW2 stays stable for h'/h >= 0.67, |R(-inf)| <= 0.2 for h'/h in
  // 0.67 .. 4, docs/integrators.md 16), and refactorized outside it. 1, 1: any change of gh
  // (beyond rounding) refactorizes, as fixed steps need.
  double w_h_grow = 1, w_h_shrink = 1;
  double length_unit = 1e-6;    // [m] for positions; slopes and angles: length_unit / 0.05 m
  double velocity_unit = 1e-3;  // [m/s] for velocities; angular: velocity_unit / 0.05 m
  double energy_unit = 1e-3;    // [J] for the work integrals
};

}  // namespace cvt
