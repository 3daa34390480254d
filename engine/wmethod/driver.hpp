// OdeDriver: the generic integrators of engine/ode/ run on the model (ModelOde), with the
// contact statuses frozen within each macro step and updated after it; and the options of
// `cvt-engine run`'s W-methods from the configuration.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "engine/model/config.hpp"
#include "engine/wmethod/model_ode.hpp"

namespace cvt {

// How OdeDriver runs a method on the model.
struct OdeRunOptions {
  OdeMethod method = OdeMethod::TrBdf2;
  OdeOptions ode;        // rtol, atol, h0 (fixed step for Rk4), ...
  ModelOdeOptions jac;
  // Contact statuses are frozen within each integrate() call and updated after it. 0: one
  // accepted step per call (the statuses follow every step, like the RK4 driver); > 0: calls
  // of this length (several steps each).
  double status_interval = 0;
};

// The OdeRunOptions of `cvt-engine run`'s W-methods for steps of size h, from the
// configuration's [integrator] (the one place that maps it): fixed steps (or adaptive ones,
// h the first, with integrator.tolerance > 0 after the start-up), unscaled, the matrix
// intervals and the friction settings; startup: ROS2 (its start-up sub-steps).
OdeRunOptions w_run_options(const Config& c, double h, bool startup);

// The sub-steps of size hs between two takes of the W matrix's stiffness K (docs/integrators.md
// 12.3): w_k_every, halved while the chain runs more than kStiffnessTravel of a pitch over it
// and the half stays a multiple of w_every. The contact set changes as the links pass the
// wraps' four ends, one link per pitch of travel at each: with a quarter of a pitch between
// takes, about one pin changes the set between two of them. Only shortens, to a divisor of
// w_k_every, so that checkpoints at its multiples still fall on a take.
inline constexpr double kStiffnessTravel = 0.25;
int stiffness_every(const Model& m, double hs, int w_every, int w_k_every);

// Turns a W-method's OdeRunOptions adaptive at tolerance tol (ModelOdeOptions::error_tol: the
// largest error of any pin, shaft or the load per step, in units of tol x (1 um, 1 mm/s)),
// steps no longer than h_max, the first one ro.ode.h0; the factorized W is kept while the
// step stays within [h' / 4, 1.25 h'] of the one it was made for.
void w_adaptive_options(OdeRunOptions& ro, double tol, double h_max);

// Runs any OdeMethod on the model. Each macro step: integrate() from t to t + H with the
// statuses frozen, where H is the fixed step, the controller's proposed step
// (status_interval 0) or status_interval; then the statuses for the next step and the
// switching work (update_statuses_after_step, as after an RK4 step).
class OdeDriver {
 public:
  // Over the schedule and its workspace (whose statuses are the frozen ones); model,
  // workspace and schedule must outlive the driver.
  OdeDriver(const Model& m, Workspace& ws, Schedule& schedule, const OdeRunOptions& opt);
  // Advances the state y from time t to exactly t1; first_step is the run's index of the
  // first step taken (the W-method's matrix is rebuilt at fixed step indices; adaptive steps
  // count their own, from the driver's first). Returns the number of steps taken.
  long advance(double t, Eigen::VectorXd& y, double t1, long first_step);
  const OdeStats& stats() const { return solver_.stats(); }
  const ModelOde& model_ode() const { return ode_; }
  std::int64_t rhs_evals() const { return ode_.rhs_evals(); }

 private:
  const Model& m_;
  Workspace& ws_;
  Schedule& schedule_;
  OdeRunOptions opt_;
  ModelOde ode_;
  OdeSolver solver_;
  void integrate_piece(double t, double t_end, Eigen::VectorXd& y);
  bool fixed_steps() const;
  bool asks_w_blocks() const;
  long step_index(long first_step, std::int64_t steps0) const;
  double h_next_ = 0;
  Eigen::VectorXd z_;
  std::vector<std::uint8_t> rocker0_, pulley0_;  // the statuses before an update
};

}  // namespace cvt
