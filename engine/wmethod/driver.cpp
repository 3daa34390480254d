#include "engine/wmethod/driver.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace cvt {

OdeRunOptions w_run_options(const Config& c, double h, bool startup) {
  const Config::Integrator& in = c.integrator;
  OdeRunOptions ro;
  ro.method = startup || in.method == IntegratorMethod::ros2 ? OdeMethod::Ros2
              : in.method == IntegratorMethod::ros34prw      ? OdeMethod::Ros34prw
                                                             : OdeMethod::Ros34pw2;
  ro.ode.fixed_step = true;
  ro.ode.h0 = h;
  ro.jac.scaled = false;
  ro.jac.w_every = in.w_every;
  // The start-up's contacts load up from zero within microseconds: its matrix takes the
  // stiffness afresh at every rebuild (a stiffness 32 sub-steps old let a mode grow 2.3x per
  // 0.125 us at 100 rad/s, docs/integrators.md 12.3).
  ro.jac.w_k_every = startup ? in.w_every : in.w_k_every;
  ro.jac.w_secant = in.w_secant;
  ro.jac.w_analytic_stiffness = in.w_analytic_stiffness;
  ro.jac.w_segments = in.w_segments;
  ro.jac.w_fresh = in.w_fresh;  // ModelOde leaves it off without the secant
  ro.jac.w_fresh_max = in.w_fresh_max;
  ro.jac.w_shafts = in.w_shafts;
  if (!startup && in.tolerance > 0) w_adaptive_options(ro, in.tolerance, c.run.sample_interval);
  return ro;
}

int stiffness_every(const Model& m, double hs, int w_every, int w_k_every) {
  const double v = peak_drive_speed(m.cfg) * m.pulley[0].running_radius;
  int k = w_k_every;
  while (w_every > 0 && k % 2 == 0 && (k / 2) % w_every == 0 && k * hs * v > kStiffnessTravel * m.cfg.chain.pitch)
    k /= 2;
  return k;
}

void w_adaptive_options(OdeRunOptions& ro, double tol, double h_max) {
  if (!(tol > 0)) throw std::invalid_argument("w_adaptive_options: the tolerance must be > 0");
  ro.ode.fixed_step = false;
  ro.ode.h_max = h_max;
  ro.jac.scaled = false;
  ro.jac.error_tol = tol;
  ro.jac.w_h_grow = 1.25;
  ro.jac.w_h_shrink = 4;
}

OdeDriver::OdeDriver(const Model& m, Workspace& ws, Schedule& schedule, const OdeRunOptions& opt)
    : m_(m), ws_(ws), schedule_(schedule), opt_(opt), ode_(m, ws, schedule, opt.jac),
      solver_(ode_.system(), opt.method, opt.ode) {
  solver_.options().keep_jacobian_across_calls = true;
  if (!(opt.ode.h0 > 0)) throw std::invalid_argument("OdeRunOptions: ode.h0 (first or fixed step) must be > 0");
  h_next_ = opt.ode.h0;
}

// integrate() from t to t_end with the statuses frozen (in the scaled state if asked).
void OdeDriver::integrate_piece(double t, double t_end, Eigen::VectorXd& y) {
  if (opt_.jac.scaled) {
    ode_.offset() = y;
    ode_.to_z(y, z_);
    solver_.integrate(t, t_end, z_);
    ode_.to_y(z_, y);
  } else {
    solver_.integrate(t, t_end, y);
  }
}

bool OdeDriver::fixed_steps() const { return opt_.method == OdeMethod::Rk4 || opt_.ode.fixed_step; }

// The chain's matrix: the W-methods', or Newton's for the implicit methods (newton_uses_w).
bool OdeDriver::asks_w_blocks() const {
  return (is_w_method(opt_.method) || opt_.ode.newton_uses_w) && opt_.jac.w_blocks;
}

// The index of the step the solver takes next: the run's (fixed steps: first_step plus the
// steps taken since the solver's count was steps0) or the driver's own count (adaptive).
long OdeDriver::step_index(long first_step, std::int64_t steps0) const {
  const std::int64_t taken = solver_.stats().steps;
  return fixed_steps() ? first_step + static_cast<long>(taken - steps0) : static_cast<long>(taken);
}

long OdeDriver::advance(double t, Eigen::VectorXd& y, double t1, long first_step) {
  const std::int64_t steps0 = solver_.stats().steps;
  const bool fixed = fixed_steps();
  // Fixed steps: their times from a clock of the driver's own that starts here.
  const StepClock grid = StepClock::at(t, 0);
  std::int64_t k = 0;
  const bool freeze = opt_.jac.freeze_friction && m_.cfg.friction.law == FrictionLaw::nonsmooth &&
                      (is_implicit_method(opt_.method) || is_sundials_method(opt_.method));
  const bool w_blocks = asks_w_blocks();
  const bool sundials = is_sundials_method(opt_.method);
  if (sundials && opt_.jac.scaled)
    throw std::invalid_argument("OdeDriver: SUNDIALS' methods run on the unscaled state (their history spans the steps)");
  schedule_.within([&] {
    // SUNDIALS' methods: each macro step is one step of their own (OdeSolver::step), whose
    // history goes on across the status updates; a piece cut to a proposed length would
    // keep their step at that length (they propose the step they were cut to).
    while (sundials && t < t1) {
      if (freeze) ode_.record_friction_branches();
      t = solver_.step(t, t1, y);
      update_statuses_after_step(m_, schedule_, ws_, t, y);
    }
    while (t < t1) {
      const double H = fixed ? opt_.ode.h0 : opt_.status_interval > 0 ? opt_.status_interval : h_next_;
      double t_end = fixed ? grid.time_after(k + 1, H) : t + H;
      // No sliver shorter than 1 % of a macro step before t1.
      const bool clipped = t_end > t1;
      if (t_end > t1 || t1 - t_end < 0.01 * H) t_end = t1;
      const std::int64_t rejected0 = solver_.stats().rejected;
      if (freeze) ode_.record_friction_branches();
      const long index = step_index(first_step, steps0);
      if (w_blocks) ode_.ask_friction_jacobian(index);
      if (!fixed) {
        // Between the scheduled rebuilds the step grows no further than the factorized W
        // allows (ModelOdeOptions::w_h_grow): a longer one would refactorize out of turn.
        double h = std::min(h_next_, t_end - t);
        // (The implicit methods' Newton matrix, newton_uses_w, is I - d h J~ with their own d;
        // the cap takes ROS34PW2's gamma for them: ESDIRK3's d, not the trapezoid's or TR-BDF2's.)
        const OdeMethod as = is_w_method(opt_.method) ? opt_.method : OdeMethod::Ros34pw2;
        if (w_blocks && ode_.w_gh() > 0 && !ode_.w_due()) h = std::min(h, ode_.w_gh() / w_method_gamma(as) * opt_.jac.w_h_grow);
        // A cap that would leave a sliver (under 1 % of h) before the piece's end splits the
        // piece into two equal steps instead: a sliver of a few ulps is below any step the
        // solver can take (it would stop with "step size underflow").
        if (h < t_end - t && t_end - (t + h) < 0.01 * h) h = 0.5 * (t_end - t);
        solver_.options().h0 = h;
        if (h < t_end - t) t_end = t + h;
      }
      integrate_piece(t, t_end, y);
      if (!fixed && solver_.stats().h_next > 0) {
        h_next_ = solver_.stats().h_next;
        // A step cut short to end on t1 and accepted at once says nothing against the step
        // that was proposed before the cut.
        if (clipped && solver_.stats().rejected == rejected0) h_next_ = std::max(h_next_, H);
      }
      const bool watch = w_blocks && opt_.jac.w_status_rebuild;
      if (watch) rocker0_ = ws_.status.rocker, pulley0_ = ws_.status.pulley;
      update_statuses_after_step(m_, schedule_, ws_, t_end, y);
      t = t_end;
      ++k;
      if (watch && (rocker0_ != ws_.status.rocker || pulley0_ != ws_.status.pulley)) ode_.w_invalidate();
    }
  });
  return static_cast<long>(solver_.stats().steps - steps0);
}

}  // namespace cvt
