#include "engine/wmethod/driver.hpp"

#include <algorithm>
#include <stdexcept>

namespace cvt {

OdeMethod parse_ode_method(const std::string& name) {
  for (OdeMethod m : {OdeMethod::Rk4, OdeMethod::Dopri5, OdeMethod::Rkc, OdeMethod::Trapezoid, OdeMethod::TrBdf2,
                      OdeMethod::Esdirk3, OdeMethod::Ros2, OdeMethod::Ros34pw2})
    if (name == to_string(m)) return m;
  throw std::invalid_argument("unknown method '" + name +
                              "' (rk4, dopri5, rkc, trapezoid, trbdf2, esdirk3, ros2, ros34pw2)");
}

OdeRunOptions w_run_options(const Config& c, double h, bool startup) {
  const Config::Integrator& in = c.integrator;
  OdeRunOptions ro;
  ro.method = startup || in.method == IntegratorMethod::ros2 ? OdeMethod::Ros2 : OdeMethod::Ros34pw2;
  ro.ode.fixed_step = true;
  ro.ode.h0 = h;
  ro.jac.scaled = false;
  ro.jac.w_every = in.w_every;
  ro.jac.w_k_every = in.w_k_every;
  ro.jac.w_secant = in.w_secant;
  ro.jac.w_fresh = in.w_fresh;  // ModelOde leaves it off without the secant
  ro.jac.w_fresh_max = in.w_fresh_max;
  return ro;
}

OdeDriver::OdeDriver(const Model& m, Workspace& ws, Schedule& schedule, const OdeRunOptions& opt)
    : m_(m), ws_(ws), schedule_(schedule), opt_(opt), ode_(m, ws, schedule, opt.jac),
      solver_(ode_.system(), opt.method, opt.ode) {
  solver_.options().keep_jacobian_across_calls = true;
  if (!(opt.ode.h0 > 0)) throw std::invalid_argument("OdeRunOptions: ode.h0 (first or fixed step) must be > 0");
  h_next_ = opt.ode.h0;
}

long OdeDriver::advance(double t, Eigen::VectorXd& y, double t1, long first_step) {
  const std::int64_t steps0 = solver_.stats().steps;
  const bool fixed = opt_.method == OdeMethod::Rk4 || opt_.ode.fixed_step;
  // Fixed steps: their times from a clock of the driver's own that starts here.
  const StepClock grid = StepClock::at(t, 0);
  std::int64_t k = 0;
  const bool freeze = opt_.jac.freeze_friction && m_.cfg.friction.law == FrictionLaw::nonsmooth &&
                      (opt_.method == OdeMethod::Trapezoid || opt_.method == OdeMethod::TrBdf2 ||
                       opt_.method == OdeMethod::Esdirk3);
  const bool w_blocks = is_w_method(opt_.method) && opt_.jac.w_blocks;
  schedule_.within([&] {
    while (t < t1) {
      const double H = fixed ? opt_.ode.h0 : opt_.status_interval > 0 ? opt_.status_interval : h_next_;
      double t_end = fixed ? grid.time_after(k + 1, H) : t + H;
      // No sliver shorter than 1 % of a macro step before t1.
      if (t_end > t1 || t1 - t_end < 0.01 * H) t_end = t1;
      if (!fixed) solver_.options().h0 = std::min(h_next_, t_end - t);
      if (freeze) ode_.record_friction_branches();
      if (w_blocks) ode_.ask_friction_jacobian(first_step + static_cast<long>(solver_.stats().steps - steps0));
      if (opt_.jac.scaled) {
        ode_.offset() = y;
        ode_.to_z(y, z_);
        solver_.integrate(t, t_end, z_);
        ode_.to_y(z_, y);
      } else {
        solver_.integrate(t, t_end, y);
      }
      if (!fixed && solver_.stats().h_next > 0) h_next_ = solver_.stats().h_next;
      t = t_end;
      ++k;
      const bool watch = w_blocks && opt_.jac.w_status_rebuild;
      if (watch) rocker0_ = ws_.status.rocker, pulley0_ = ws_.status.pulley;
      update_statuses_after_step(m_, schedule_, ws_, t, y);
      if (watch && (rocker0_ != ws_.status.rocker || pulley0_ != ws_.status.pulley)) ode_.w_invalidate();
    }
  });
  return static_cast<long>(solver_.stats().steps - steps0);
}

}  // namespace cvt
