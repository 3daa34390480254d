#include "engine/wmethod/driver.hpp"

#include <algorithm>
#include <sstream>
#include <stdexcept>

namespace cvt {

OdeMethod parse_ode_method(const std::string& name) {
  for (OdeMethod m : {OdeMethod::Rk4, OdeMethod::Dopri5, OdeMethod::Rkc, OdeMethod::Dumka3, OdeMethod::Trapezoid,
                      OdeMethod::TrBdf2, OdeMethod::Esdirk3, OdeMethod::Ros2, OdeMethod::Ros34pw2})
    if (name == to_string(m)) return m;
  throw std::invalid_argument("unknown method '" + name +
                              "' (rk4, dopri5, rkc, dumka3, trapezoid, trbdf2, esdirk3, ros2, ros34pw2)");
}

std::string w_step_graphviz(const Config& c, int threads) {
  const Config::Integrator& in = c.integrator;
  const int stages = in.method == IntegratorMethod::ros2 ? 2 : 4;
  const std::string sweeps = threads > 1 ? "top sweep (thread 0) | bottom sweep (thread 1)" : "top sweep, then bottom sweep";
  std::ostringstream tol;
  tol << in.tolerance;
  std::ostringstream os;
  os << "digraph w_step {\n  rankdir=TB;\n  node [shape=box];\n  label=\"one " << to_string(in.method) << " step "
     << (in.tolerance > 0 ? "(adaptive, tolerance " + tol.str() + ")" : "(fixed)") << "\";\n";
  os << "  f1 [label=\"evaluation 1: the stage graph\\n(cvt-engine graph, digraph stage)\\n+ friction blocks and mu\"];\n";
  os << "  subgraph cluster_rebuild {\n    label=\"every " << in.w_every << " steps (stiffness every " << in.w_k_every
     << ")\";\n    stiffness [label=\"stiffness K: 63 force evaluations\\n(per colour and coordinate; "
     << (threads > 1 ? "two halves on two workspaces" : "one after the other") << ")\"];\n"
     << "    assembly [label=\"link blocks A + gh C + gh^2 K\\nper joint, over the threads\"];\n"
     << "    factor [label=\"block LU\\n" << sweeps << "\\nthen the middle and last block\"];\n"
     << "    stiffness -> assembly -> factor;\n  }\n";
  os << "  fresh [label=\"fresh friction: Woodbury terms\\nfor the contacts whose mu moved\\n(per contact: two columns, "
     << (in.w_shafts ? "sweeps, shafts' steps, z - Y x_s; " : "sweeps; ") << "one fork)\"];\n"
     << "  f1 -> stiffness;\n  factor -> fresh;\n";
  std::string prev = "fresh";
  for (int i = 1; i <= stages; ++i) {
    const std::string f = "f" + std::to_string(i), w = "solve" + std::to_string(i);
    if (i > 1)
      os << "  " << f << " [label=\"evaluation " << i << ": the stage graph\\n(cvt-engine graph, digraph stage)\"];\n"
         << "  " << prev << " -> " << f << ";\n";
    os << "  " << w << " [label=\"right side per link, then\\n" << sweeps
       << (in.w_shafts ? "\\nmiddle block, shafts' Schur step, z - Y x_s per link" : "\\nmiddle block")
       << "\\n(one fork: claimed phases)"
       << "\\n+ Woodbury correction\"];\n";
    os << "  " << (i > 1 ? f : prev) << " -> " << w << ";\n";
    prev = w;
  }
  os << "  sums [label=\"stage sums and the new state\\n(master)\"];\n  " << prev << " -> sums;\n";
  os << "  status [label=\"contact statuses\\nper pin, over the threads\"];\n";
  if (in.tolerance > 0)
    os << "  test [label=\"error norm per pin, shaft, load\\naccept, or retake with a shorter step\"];\n"
       << "  sums -> test -> status;\n";
  else
    os << "  sums -> status;\n";
  os << "}\n";
  return os.str();
}

OdeRunOptions w_run_options(const Config& c, double h, bool startup) {
  const Config::Integrator& in = c.integrator;
  OdeRunOptions ro;
  ro.method = startup || in.method == IntegratorMethod::ros2 ? OdeMethod::Ros2 : OdeMethod::Ros34pw2;
  ro.ode.fixed_step = true;
  ro.ode.h0 = h;
  ro.jac.scaled = false;
  ro.jac.w_every = in.w_every;
  // The start-up's contacts load up from zero within microseconds: its matrix takes the
  // stiffness afresh at every rebuild (a stiffness 32 sub-steps old let a mode grow 2.3x per
  // 0.125 us at 100 rad/s, docs/integrators.md 12.3).
  ro.jac.w_k_every = startup ? in.w_every : in.w_k_every;
  ro.jac.w_secant = in.w_secant;
  ro.jac.w_fresh = in.w_fresh;  // ModelOde leaves it off without the secant
  ro.jac.w_fresh_max = in.w_fresh_max;
  ro.jac.w_shafts = in.w_shafts;
  if (!startup && in.tolerance > 0) w_adaptive_options(ro, in.tolerance, c.run.sample_interval);
  return ro;
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

void OdeDriver::evaluate_ahead(double t, const Eigen::VectorXd& y, long first_step, double* dy) {
  // The request of advance's first step (below).
  const long index = step_index(first_step, solver_.stats().steps);
  schedule_.within([&] {
    if (asks_w_blocks()) ode_.ask_friction_jacobian(index);
    ode_.eval_ahead(t, y.data(), dy);
  });
}

long OdeDriver::advance(double t, Eigen::VectorXd& y, double t1, long first_step) {
  const std::int64_t steps0 = solver_.stats().steps;
  const bool fixed = fixed_steps();
  // Fixed steps: their times from a clock of the driver's own that starts here.
  const StepClock grid = StepClock::at(t, 0);
  std::int64_t k = 0;
  const bool freeze = opt_.jac.freeze_friction && m_.cfg.friction.law == FrictionLaw::nonsmooth &&
                      is_implicit_method(opt_.method);
  const bool w_blocks = asks_w_blocks();
  schedule_.within([&] {
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
