#include "engine/simulation.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include <tbb/parallel_invoke.h>

#include "engine/rhs/rhs.hpp"
#include "engine/wmethod/driver.hpp"
#include "engine/wmethod/w_step.hpp"
#include "modules/beam.hpp"
#include "modules/chain_forces.hpp"
#include "modules/pulley_contact.hpp"
#include "modules/inertia.hpp"
#include "numa/hand_off.hpp"

namespace cvt {

namespace {
// The energy that flowed between two states' work integrals a and b (in, out, dissipated,
// clamping), each counted by its magnitude.
double energy_flow(const double* a, const double* b) {
  return std::abs(b[kWorkIn] - a[kWorkIn]) + std::abs(b[kWorkOut] - a[kWorkOut]) +
         std::abs(b[kWorkDiss] - a[kWorkDiss]) + std::abs(b[kWorkClamp] - a[kWorkClamp]);
}
// f and g at once on the schedule's threads.
template <class F, class G>
void both(const F& f, const G& g) {
  const numa::ScopedForkJoin fj;
  tbb::parallel_invoke(fj.task(f), fj.task(g));
}
}  // namespace

Simulation::Simulation(const Model& m, const ScheduleOptions& schedule)
    : m_(m), ws_(m), diag_(m), schedule_(make_schedule(m, ws_, schedule)), rk_(m.nstate), y_(m.y0), dy_(m.nstate) {
  update_contact_status(m_, ws_, clock_.t, y_.data());
  const Energies e = energies(m_, clock_.t, y_.data(), &ws_.status);
  energy0_ = e.kinetic + e.elastic;
  std::vector<double*> state = rk_.buffers();
  state.push_back(y_.data());
  schedule_->place_state(state);
}

Profiler& Simulation::enable_profiling() {
  if (!prof_) {
    prof_ = std::make_unique<Profiler>(schedule_->threads());
    schedule_->set_profiler(prof_.get());
  }
  return *prof_;
}

Simulation::~Simulation() = default;

void Simulation::step(double h, bool update_status) {
  const std::uint64_t tick0 = prof_ ? Profiler::ticks() : 0;
  clock_.keep_origin(h);
  if (update_status && m_.cfg.integrator.method != IntegratorMethod::rk4) {
    w_step(h);
    watch_leak(h);
  } else {
    rk4_step(h, update_status);
  }
  if (prof_) prof_->add_step(Profiler::ticks() - tick0);
}

// RK4 (docs/model.md 7): the four stages through the schedule, each with its stage update
// inside the graph, then (unless frozen) the contact statuses for the next step.
void Simulation::rk4_step(double h, bool update_status) {
  ++steps_taken_;
  schedule_->within([&] {
    rk_.step([this](double t, const double* y, double* dy, const StageOp* op) { schedule_->rhs(t, y, dy, op); },
             clock_.t, h, y_);
    clock_.tick(h);
    if (update_status) update_statuses_after_step(m_, *schedule_, ws_, clock_.t, y_);
  });
}

// A W-method step of size h (docs/integrators.md 12), top-down: the step's sub-steps (the
// start-up's ROS2 sub-steps, the settling phase's, or the step itself), each its first
// evaluation (unless a sample of the state took it: begin_w_step), the matrix set up if due
// and the stages with their solves (WStep::finish), then the contact statuses; then the
// clock. Adaptive steps (integrator.tolerance) after the start-up run through the generic
// OdeSolver (w_adaptive_step). A state gone bad (not finite, an absurd penetration or
// stretch) that no retake of its sub-step (w_substep) avoided is reported as RK4's is, by
// check_finite() at the next sample (with the replay and the diagnosis): the step's own
// error ("solution is not finite", or a singular matrix built from such a state) only ends
// this step.
void Simulation::w_step(double h) {
  const WPhase p = w_phase(h);
  if (!p.step) return w_adaptive_step(h);
  const bool begun = begun_ && begun_h_ == h && begun_steps_ == clock_.steps;
  begun_ = false;
  const std::uint64_t tick0 = prof_ ? Profiler::ticks() : 0;
  const std::uint64_t rhs0 = prof_ ? prof_->rhs_wall() : 0, master0 = prof_ ? prof_->master_total() : 0;
  if (y_.allFinite()) {
    const double t0 = clock_.t, t1 = clock_.time_after(clock_.steps + 1, h), hs = h / p.sub;
    try {
      schedule_->within([&] {
        double t = t0;
        for (int i = 0; i < p.sub; ++i) {
          const double t_end = i + 1 == p.sub ? t1 : t0 + static_cast<double>(i + 1) * hs;
          w_substep(*p.step, t, t_end, p.first + i, i > 0 || !begun);
          if (!y_.allFinite()) throw OdeError(t, t_end - t, "solution is not finite");
          update_statuses_after_step(m_, *schedule_, ws_, t_end, y_);
          t = t_end;
        }
      });
    } catch (const std::exception&) {
      // A state gone bad (not finite, an absurd penetration or stretch, which makes the
      // matrix taken there singular) is a blow-up, which check_finite() names at the next
      // sample.
      if (state_problem(y_).empty()) throw;
      w_main_.reset(), w_startup_.reset();
    }
    // Adaptive runs count their start-up's sub-steps one by one, as their own steps.
    steps_taken_ += adaptive_steps(m_.cfg) ? p.sub : 1;
  }
  clock_.tick(h);
  profile_update(tick0, rhs0, master0);
}

// One sub-step of the production W-step from (t, y) to t_end: its first evaluation (unless
// a sample took it), the matrix if due and the stages. A sub-step that leaves the state bad
// (not finite, an absurd penetration or stretch, or a matrix that turns out singular) or,
// unless integrator.fixed_steps, whose error estimate is gross (WStep::gross()) or whose
// energy balance jumps (energy_jump: the residual moves by more than the energy that flowed
// and more than 10 mJ) is rejected and taken again from its start with the whole matrix
// rebuilt, then, if need be, in 2, 4, ... kMaxPieces pieces, each from a matrix rebuilt at
// its start. The sub-steps after it
// start with the pieces that held (pieces_), and halve them while the pieces' estimates stay
// below a quarter of the gross bound, so that a stretch of fast dynamics (the start from
// rest at a ratio whose pins land hard) costs one ladder, not one per sub-step. If none
// holds, the bad state stays for check_finite() to report as a blow-up. A sound sub-step in
// one piece runs exactly as it would without the checks (which cost about 30 us per
// sub-step on the reference model: the contacts' depths, the estimate's norm and the
// energies at its end).
void Simulation::w_substep(WStep& s, double t, double t_end, long index, bool evaluate) {
  constexpr int kMaxPieces = 64;
  const bool judge_error = !m_.cfg.integrator.fixed_steps;
  y_start_ = y_;
  std::string error;  // the last attempt's error (a singular matrix), if it threw
  std::array<double, kAuxSize> aux_piece{};  // the work integrals at the piece's start
  double worst = 0;   // the largest estimate of the pieces that held
  // The energy balance's residual at the piece's start: the last sub-step's end, if it ended here.
  double r0 = 0;
  if (judge_error) r0 = balance_t_ == t ? balance_r_ : balance_residual(t, y_);
  balance_t_ = -1;
  const auto attempt = [&](double a, double b) {
    try {
      s.finish(a, b - a, y_);
    } catch (const std::exception& e) {
      error = e.what();
      return false;
    }
    error.clear();
    if (!y_.allFinite() || !state_problem(y_).empty()) return false;
    worst = std::max(worst, s.error());
    if (!judge_error) return true;
    const double r1 = balance_residual(b, y_);
    if (energy_jump(std::abs(r1 - r0), energy_flow(aux_piece.data(), y_.data() + 2 * m_.ndof))) {
      ++energy_rejections_;
      return false;
    }
    r0 = r1;
    return s.error() <= s.gross();
  };
  const double span = t_end - t;
  // pieces from (t, y_start_), the first from a fresh matrix if `retake`
  const auto take = [&](int pieces, bool retake) {
    worst = 0;
    if (judge_error && retake) r0 = balance_residual(t, y_);
    for (int k = 0; k < pieces; ++k) {
      const double a = t + span * k / pieces, b = k + 1 == pieces ? t_end : t + span * (k + 1) / pieces;
      if (retake) s.retake();
      if (k > 0 || retake || evaluate) s.evaluate(a, y_, index);
      if (judge_error) std::copy_n(y_.data() + 2 * m_.ndof, kAuxSize, aux_piece.begin());
      if (!attempt(a, b)) return false;
    }
    return true;
  };
  const int first = std::min(pieces_, kMaxPieces);
  bool ok = take(first, false);
  int pieces = first;
  for (bool retake = true; !ok && pieces <= kMaxPieces; pieces *= 2, retake = true) {
    ++steps_rejected_;
    y_ = y_start_;
    ok = take(pieces, retake);
    if (ok) break;
  }
  if (ok) {
    pieces_ = pieces > 1 && worst < 0.25 * s.gross() ? pieces / 2 : pieces;
    if (judge_error) balance_t_ = t_end, balance_r_ = r0;
    return;
  }
  pieces_ = 1;
  // No attempt held: a bad state is a blow-up (check_finite); an error at a sound state ends the run.
  if (!error.empty() && y_.allFinite() && state_problem(y_).empty()) throw NumericalFailure(error);
}

// The step's control by the energy balance (integrator.energy_leak; docs/integrators.md
// 12.3): fixed W-steps after the settling phase. At every torsion span (half the steady
// window, in whole grid steps) the balance's residual and the input work are taken, and the
// leak is the residual's change per input work over the span; unless integrator.fixed_steps
// (or energy_leak 0, or a held step), where it passes energy_leak the steps after it are
// taken in twice as many sub-steps (w_phase), at most kMaxStepHalvings times. A W-method's
// numerical damping takes energy from the chain's fast vibrations that the model's dampers
// would dissipate: the leak measures it, and the efficiency's error follows it (about half
// the leak on the mini model at 550 rad/s).
void Simulation::watch_leak(double h) {
  const Config::Integrator& in = m_.cfg.integrator;
  if (adaptive_steps(m_.cfg) || !y_.allFinite() || clock_.t < settle_end(m_.cfg) || clock_.t < in.startup_time)
    return;
  const long span = std::max(1L, std::lround(0.5 * steady_window(m_) / h));
  if (clock_.steps % span != 0) return;
  const double r = balance_residual(clock_.t, y_), w = y_[2 * m_.ndof + kWorkIn];
  if (leak_from_ >= 0 && clock_.steps - leak_from_ == span && w > leak_w_) {
    leak_ = (r - leak_r_) / (w - leak_w_);
    const bool control = in.energy_leak > 0 && !in.fixed_steps && !hold_step_;
    if (control && std::abs(leak_) > in.energy_leak && halvings_ < kMaxStepHalvings) ++halvings_, halved_at_ = clock_.t;
  }
  leak_from_ = clock_.steps, leak_r_ = r, leak_w_ = w;
}

// The energy balance's residual at (t, y) with the statuses of the step (docs/model.md 6):
// the energy less the work that entered, plus the work that left and was dissipated.
double Simulation::balance_residual(double t, const Eigen::VectorXd& y) const {
  return balance_residual(energies(m_, t, y.data(), &ws_.status), y.data() + 2 * m_.ndof);
}

double Simulation::balance_residual(const Energies& e, const double* aux) const {
  return (e.kinetic + e.elastic) - energy0_ - aux[kWorkIn] - aux[kWorkClamp] - aux[kWorkSwitch] + aux[kWorkOut] +
         aux[kWorkDiss];
}

// Adaptive W-steps (integrator.tolerance) after the start-up: the generic OdeSolver through
// an OdeDriver, with its error test and step control, to exactly the clock's next time.
void Simulation::w_adaptive_step(double h) {
  const std::uint64_t tick0 = prof_ ? Profiler::ticks() : 0;
  const std::uint64_t rhs0 = prof_ ? prof_->rhs_wall() : 0, master0 = prof_ ? prof_->master_total() : 0;
  if (!w_adaptive_ || w_adaptive_h_ != m_.cfg.integrator.step) {
    w_adaptive_ = std::make_unique<OdeDriver>(m_, ws_, *schedule_, w_run_options(m_.cfg, m_.cfg.integrator.step, false));
    w_adaptive_h_ = m_.cfg.integrator.step;
  }
  w_startup_.reset();
  if (y_.allFinite()) {
    try {
      const std::int64_t rejected0 = w_adaptive_->stats().rejected;
      steps_taken_ += w_adaptive_->advance(clock_.t, y_, clock_.time_after(clock_.steps + 1, h), steps_taken_);
      steps_rejected_ += w_adaptive_->stats().rejected - rejected0;
    } catch (const std::exception&) {
      if (state_problem(y_).empty()) throw;  // else a blow-up, as in w_step
      w_adaptive_.reset(), w_startup_.reset();
    }
  }
  clock_.tick(h);
  profile_update(tick0, rhs0, master0);
}

// The step's rest on the master, outside the evaluations and the W rows: the method's
// vector sums and error norms, its "integrator update".
void Simulation::profile_update(std::uint64_t tick0, std::uint64_t rhs0, std::uint64_t master0) {
  if (!prof_) return;
  const std::uint64_t dt = Profiler::ticks() - tick0;
  const std::uint64_t inside = (prof_->rhs_wall() - rhs0) + (prof_->master_total() - master0);
  prof_->add_master(Section::update, dt > inside ? dt - inside : 0);
  prof_->call(Section::update);
}

// The W-step of size h from the clock's time: before integrator.startup_time, ROS2
// sub-steps; in the settling phase, the method's own sub-steps (its WStep, remade for the
// sub-step and again for h after the phase); adaptive steps after the start-up: none (the
// OdeDriver of w_adaptive_step). The matrix's rebuild schedule counts the sub-steps one by
// one: step n's are n sub .. n sub + sub - 1 (adaptive runs: from the steps taken so far).
Simulation::WPhase Simulation::w_phase(double h) {
  const Config::Integrator& in = m_.cfg.integrator;
  const int sub = startup_substeps(in, h);
  const bool startup = clock_.t < in.startup_time && sub > 1;
  const bool adaptive = adaptive_steps(m_.cfg);
  if (adaptive && !startup) return {nullptr, 1, 0};
  const int settle =
      startup || adaptive || !(clock_.t < settle_end(m_.cfg)) ? 1 << halvings_ : settle_substeps(in, h);
  const int n = startup ? sub : settle;
  const long first = adaptive ? steps_taken_ : clock_.steps * n;
  // The start-up's contacts load up from zero within microseconds: ROS2 (gamma = 1.71)
  // damps the mismatch of a matrix taken at the start, ROS34PW2 (gamma = 0.44) blows up on
  // it within microseconds (docs/integrators.md 12.3).
  std::unique_ptr<WStep>& step = startup ? w_startup_ : w_main_;
  double& made_for = startup ? w_startup_h_ : w_main_h_;
  const double hs = h / n;
  if (!step || made_for != hs) {
    OdeRunOptions ro = w_run_options(m_.cfg, hs, startup);
    if (!startup && !m_.cfg.integrator.fixed_steps)
      ro.jac.w_k_every = stiffness_every(m_, hs, ro.jac.w_every, ro.jac.w_k_every);
    step = std::make_unique<WStep>(m_, ws_, *schedule_, ro.method, ro.jac), made_for = hs;
  }
  if (!startup) w_startup_.reset();
  return {step.get(), n, first};
}

// The first evaluation of the next fixed W-step of size h (w_phase(h), p), taken now so that
// a sample of this state reads it (the step then starts from it): its f(t, y).
const Eigen::VectorXd* Simulation::begin_w_step(const WPhase& p, double h) {
  schedule_->within([&] { p.step->evaluate(clock_.t, y_, p.first); });
  begun_ = true, begun_h_ = h, begun_steps_ = clock_.steps;
  return &p.step->f0();
}

void Simulation::advance(OdeDriver& driver, double t1) {
  begun_ = false;
  const long n = driver.advance(clock_.t, y_, t1, clock_.steps);
  clock_ = StepClock::at(t1, clock_.steps + n);
}

Checkpoint Simulation::checkpoint() const {
  Checkpoint c;
  c.config_toml = m_.cfg.resolved_toml;
  c.state = y_;
  c.rocker = ws_.status.rocker;
  c.pulley = ws_.status.pulley;
  c.t = clock_.t, c.t0 = clock_.t0, c.steps = clock_.steps, c.steps0 = clock_.steps0;
  c.energy0 = energy0_;
  c.halvings = halvings_, c.halved_at = halved_at_, c.leak = leak_;
  c.leak_from = leak_from_, c.leak_residual = leak_r_, c.leak_work = leak_w_;
  return c;
}

void Simulation::restore(const Checkpoint& c) {
  w_main_.reset(), w_startup_.reset(), w_adaptive_.reset();  // their matrices belong to the old state
  begun_ = false;
  balance_t_ = -1;
  halvings_ = c.halvings, halved_at_ = c.halved_at, leak_ = c.leak, hold_step_ = false;
  leak_from_ = c.leak_from, leak_r_ = c.leak_residual, leak_w_ = c.leak_work;
  if (c.state.size() != m_.nstate || c.rocker.size() != ws_.status.rocker.size() ||
      c.pulley.size() != ws_.status.pulley.size())
    throw std::runtime_error("checkpoint does not fit the model (state of " + std::to_string(c.state.size()) +
                             " numbers for a model of " + std::to_string(m_.nstate) + ")");
  y_ = c.state;
  ws_.status.rocker = c.rocker;
  ws_.status.pulley = c.pulley;
  clock_.t = c.t, clock_.t0 = c.t0, clock_.steps = c.steps, clock_.steps0 = c.steps0;
  energy0_ = c.energy0;
}

std::string describe_state_index(const Model& m, int i) {
  const int n = m.ndof;
  std::string what = "position of ";
  if (i >= 2 * n) {
    static const char* aux[] = {"work in", "work out", "work dissipated", "work of clamping", "controller integral",
                                "contact switching work"};
    const int k = i - 2 * n;
    return std::string("work integral ") + (k < 6 ? aux[k] : "?");
  }
  if (i >= n) what = "velocity of ", i -= n;
  if (i < kJointSize * m.links) {
    const int j = i / kJointSize, r = i % kJointSize;
    if (r == kJointS) return what + "joint " + std::to_string(j) + ", plate pack";
    static const char* coord[] = {"x", "y", "z", "slope x", "slope y"};
    const int h = r < kJointB ? 0 : 1, e = (r % half::kSize) / half::kEnd, c = r % half::kEnd;
    return what + "joint " + std::to_string(j) + ", half " + (h ? "b" : "a") + ", end " + std::to_string(e) + ", " +
           coord[c];
  }
  if (i < m.load_index()) {
    static const char* coord[] = {"ux", "uy", "uz", "tilt x", "tilt y", "angle", "moving sheave"};
    const int k = (i - m.shaft(0)) / kShaftSize;
    return what + (k == 0 ? "driving" : "driven") + " shaft, " + coord[(i - m.shaft(0)) % kShaftSize];
  }
  return what + "load";
}

double Simulation::spectral_radius(const Eigen::VectorXd& y, double t, const ContactStatus& status, int iterations) {
  Workspace ws(m_);
  ws.status = status;
  Eigen::VectorXd f0(m_.nstate), f1(m_.nstate), v = Eigen::VectorXd::Ones(m_.nstate), yp(m_.nstate);
  rhs_serial(m_, ws, t, y.data(), f0.data());
  // Work integrals do not feed back into the dynamics: leave them out of the iteration.
  v.tail(kAuxSize).setZero();
  // Power iteration. J is far from normal (positions and velocities on very different
  // scales), so single ratios |J v| overshoot; the geometric mean of the last ten ratios
  // estimates |lambda_max| (and averages out the beat of a complex pair).
  double log_sum = 0;
  int counted = 0;
  for (int it = 0; it < iterations; ++it) {
    v /= v.norm();
    const double eps = 1e-9 * (1.0 + y.head(2 * m_.ndof).norm());
    yp = y + eps * v;
    rhs_serial(m_, ws, t, yp.data(), f1.data());
    v = (f1 - f0) / eps;
    v.tail(kAuxSize).setZero();
    const double r = v.norm();
    if (!std::isfinite(r) || r == 0) return 0.0;
    if (it >= iterations - 10) log_sum += std::log(r), ++counted;
  }
  const double rho = counted ? std::exp(log_sum / counted) : 0.0;
  return rho;
}

// Penetration depth at which the Hertz force would be ten times the largest clamping
// force: no physical state comes near it (docs/cli.md, exit 70).
static double absurd_depth(double stiffness, const Config& c) {
  const double F = 10.0 * std::max({c.clamping.driving, c.clamping.driven, 1e3});
  return std::pow(F / stiffness, 2.0 / 3.0);
}

// The first link stretched past where its plates' force would be 10x the largest clamping
// force (or folded to under half its length), -1 if none: the chain has come apart
// numerically, with no contact to show it. Its stretch and the limit [m].
int Simulation::absurd_stretch(const Eigen::VectorXd& y, double* stretch, double* limit) const {
  const Config& c = m_.cfg;
  const double F = 10.0 * std::max({c.clamping.driving, c.clamping.driven, 1e3});
  const double lim = F / (c.chain.plates_per_link * c.chain.plate_stiffness);
  for (int l = 0; l < m_.links; ++l) {
    const double* b = y.data() + m_.half_b(l);
    const double* a = y.data() + m_.half_a(l + 1);
    const double dx = mid(a, 0) - mid(b, 0), dy = mid(a, 1) - mid(b, 1);
    const double d = std::sqrt(dx * dx + dy * dy) - m_.plate_rest;
    if (!(d <= lim && d >= -0.5 * m_.plate_rest)) {
      if (stretch) *stretch = d, *limit = lim;
      return l;
    }
  }
  return -1;
}

std::string Simulation::state_problem(const Eigen::VectorXd& y) const {
  char buf[512];
  for (int i = 0; i < m_.nstate; ++i)
    if (!std::isfinite(y[i])) return describe_state_index(m_, i) + " is not finite";
  int j = -1;
  const double dp = max_pulley_penetration(m_, y.data(), &j);
  const double lim_p = absurd_depth(m_.cfg.pulley_contact.stiffness, m_.cfg);
  if (j >= 0 && dp > lim_p) {
    std::snprintf(buf, sizeof buf,
                  "absurd penetration: a pin end of joint %d is %.3g mm inside a sheave face (module pulley contact; "
                  "limit %.3g mm, where the Hertz force would be 10x the largest clamping force)",
                  j, 1e3 * dp, 1e3 * lim_p);
    return buf;
  }
  double stretch = 0, lim_l = 0;
  if ((j = absurd_stretch(y, &stretch, &lim_l)) >= 0) {
    std::snprintf(buf, sizeof buf,
                  "absurd stretch: link %d is %.3g mm %s than its plates' rest length (module chain forces, plates; "
                  "limit %.3g mm, where the plates' force would be 10x the largest clamping force)",
                  j, 1e3 * std::abs(stretch), stretch > 0 ? "longer" : "shorter", 1e3 * lim_l);
    return buf;
  }
  const double dr = max_rocker_penetration(m_, y.data(), &j);
  const double lim_r = absurd_depth(m_.cfg.rocker.stiffness, m_.cfg);
  if (dr > lim_r) {
    std::snprintf(buf, sizeof buf,
                  "absurd penetration: the rocker faces of joint %d overlap by %.3g mm (module chain forces, rocker "
                  "joint; limit %.3g mm, where the Hertz force would be 10x the largest clamping force)",
                  j, 1e3 * dr, 1e3 * lim_r);
    return buf;
  }
  return {};
}

// Replays the steps from the last good sample (bit-identical) to the first bad state, and
// names what drove it: the coordinate with the largest acceleration in the step before,
// its pin, and the module whose force on that pin is largest.
std::string Simulation::replay_diagnosis(double h) {
  if (good_y_.size() != m_.nstate || clock_.steps <= good_steps_) return {};
  const Eigen::VectorXd bad_y = y_;
  const ContactStatus bad_status = ws_.status;
  const long bad_steps = clock_.steps;
  y_ = good_y_, ws_.status = good_status_, clock_.steps = good_steps_, clock_.t = good_t_;
  std::string out;
  char buf[768];
  while (clock_.steps < bad_steps) {
    const Eigen::VectorXd prev = y_;
    const ContactStatus prev_status = ws_.status;
    const double prev_t = clock_.t;
    step(h);
    const std::string first = state_problem(y_);
    if (first.empty()) continue;
    diag_.status = prev_status;
    rhs_serial(m_, diag_, prev_t, prev.data(), dy_.data());
    const int n = m_.ndof;
    int worst = 0;
    for (int i = 1; i < m_.joint(m_.links); ++i)
      if (!(std::abs(dy_[n + i]) <= std::abs(dy_[n + worst]))) worst = i;
    const int joint = worst / kJointSize;
    const auto norm = [](const JointSlot& sl) {
      double s2 = 0;
      for (double f : sl.f) s2 += f * f;
      return std::sqrt(s2);
    };
    const double fc = norm(diag_.chain_slots[joint]), fp = norm(diag_.pulley_slots[joint]),
                 fi = norm(diag_.inertia_slots[joint]);
    const char* module = fc >= fp && fc >= fi ? "chain forces" : fp >= fi ? "pulley contact" : "inertia (velocity terms)";
    std::snprintf(buf, sizeof buf,
                  "replayed from t = %.9g s: the first bad state follows step %ld (t = %.9g s): %s; in the step "
                  "before, the largest acceleration is %.3g on %s, pin %d, where %s dominate (|F| chain %.3g, "
                  "pulley %.3g, inertia %.3g N)",
                  good_t_, clock_.steps, clock_.t, first.c_str(), dy_[n + worst], describe_state_index(m_, n + worst).c_str(), joint, module, fc,
                  fp, fi);
    out = buf;
    break;
  }
  y_ = bad_y, ws_.status = bad_status, clock_.steps = bad_steps, clock_.t = clock_.time_after(clock_.steps, h);
  return out;
}

void Simulation::check_finite() {
  const std::string problem = state_problem(y_);
  if (problem.empty()) {
    if (first_y_.size() == 0) first_y_ = y_, first_t_ = clock_.t, first_status_ = ws_.status;
    good_y_ = y_;
    good_t_ = clock_.t;
    good_steps_ = clock_.steps;
    good_status_ = ws_.status;
    return;
  }
  const double h = m_.cfg.integrator.step;
  const double t_bad = clock_.t;
  const long steps_bad = clock_.steps;
  const std::string replay = replay_diagnosis(h);
  std::string cause;
  char buf[1024];
  if (good_y_.size() == m_.nstate) {
    // The last good sample may already be on its way up; then the run's first state tells.
    double rho = spectral_radius(good_y_, good_t_, good_status_), at = good_t_;
    if (!(rho > 0 && std::isfinite(rho))) rho = spectral_radius(first_y_, first_t_, first_status_), at = first_t_;
    const double h_stable = rho > 0 ? 2.8 / rho : 0;
    std::snprintf(buf, sizeof buf,
                  "at t = %.9g s the Jacobian's spectral radius is about %.3g 1/s, so RK4 is "
                  "stable for h up to about %.3g s; ",
                  at, rho, h_stable);
    cause = buf;
    std::snprintf(buf, sizeof buf, "%.3g", h);
    const Config::Integrator& in = m_.cfg.integrator;
    if (in.method != IntegratorMethod::rk4 && in.fixed_steps)
      cause += "the run takes fixed " + std::string(to_string(in.method)) + " steps of h = " + std::string(buf) +
               " s (integrator.fixed_steps = true), which no gross error estimate retakes: run without "
               "integrator.fixed_steps, or with a smaller integrator.step";
    else if (in.method != IntegratorMethod::rk4)
      cause += "every retake of the " + std::string(to_string(in.method)) + " step of h = " + std::string(buf) +
               " s failed too (the whole matrix afresh, then up to 64 pieces): the model leaves what it can "
               "represent there, not the step; RK4 (--method rk4 --step 1e-8) shows whether it fails the same way";
    else
      cause += h > h_stable ? "the step h = " + std::string(buf) + " s is above it: reduce integrator.step"
                            : "the step is below it: look for a contact or friction instability, or an unphysical "
                              "parameter";
  } else {
    cause = "no good sample to analyse";
  }
  std::snprintf(buf, sizeof buf, "numerical blow-up at t = %.9g s (step %ld): ", t_bad, steps_bad);
  throw BlowUpError(buf + problem + "; " + (replay.empty() ? "" : replay + "; ") + cause);
}

Sample Simulation::sample(double next_step) {
  Sample s;
  s.t = clock_.t;
  s.step = clock_.steps;
  Energies e;
  const auto energy = [&] { e = energies(m_, clock_.t, y_.data(), &ws_.status); };
  // The evaluation the channels read. Before a fixed W-step: that step's first evaluation,
  // taken now on the schedule (begin_w_step: the step then starts from it), read from the
  // integrator's workspace. Otherwise a diagnostic evaluation into diag_, beside the energies
  // (pure functions of the state) on the schedule's threads; the same bits either way.
  // (The profile counts that evaluation, and the step's making when h changes, as the step's.)
  const std::uint64_t t0 = prof_ ? Profiler::ticks() : 0;
  const WPhase next = next_step > 0 && m_.cfg.integrator.method != IntegratorMethod::rk4 && y_.allFinite()
                         ? w_phase(next_step)
                         : WPhase{nullptr, 1, 0};
  const bool ahead = next.step != nullptr;
  const Eigen::VectorXd* f = &dy_;
  if (ahead) {
    // On more than one thread the energies run beside it (they read the state and the
    // statuses, which the evaluation leaves alone), and the profile counts both as the
    // step's; serially the energies are the output's.
    const auto evaluate = [&] { f = begin_w_step(next, next_step); };
    const bool beside = schedule_->threads() > 1;
    if (beside)
      schedule_->within([&] { both(evaluate, energy); });
    else
      evaluate();
    if (prof_) prof_->add_step_ahead(Profiler::ticks() - t0);
    if (!beside) energy();
  } else {
    diag_.status = ws_.status;
    const auto evaluate = [&] { rhs_serial(m_, diag_, clock_.t, y_.data(), dy_.data()); };
    if (schedule_->threads() > 1)
      schedule_->within([&] { both(evaluate, energy); });
    else
      evaluate(), energy();
  }
  Workspace& w = ahead ? ws_ : diag_;
  const double* q = y_.data();
  const double* v = q + m_.ndof;
  const double* aux = q + 2 * m_.ndof;
  const int p1 = m_.shaft(0) + kPhi, p2 = m_.shaft(1) + kPhi;
  s.input_speed = v[p1];
  s.output_speed = v[p2];
  s.load_speed = v[m_.load_index()];
  s.input_torque = w.other.input_torque;
  s.output_torque = w.other.output_torque;
  s.load_torque = w.other.load_torque;
  s.speed_ratio = v[p2] != 0 ? v[p1] / v[p2] : 0.0;
  const double r1 = wrapped_radius(m_, w, 0), r2 = wrapped_radius(m_, w, 1);
  s.geometric_ratio = r1 > 0 ? r2 / r1 : 0.0;
  const double pin = s.input_torque * s.input_speed;
  s.efficiency = pin != 0 ? s.output_torque * s.output_speed / pin : 0.0;
  for (int k = 0; k < 2; ++k) {
    s.clamp[k] = w.other.clamp[k];
    s.sheave_position[k] = q[m_.shaft(k) + kW];
    for (int b = 0; b < 2; ++b) s.support_force[2 * k + b] = w.other.support_force[k][b];
  }
  const int jp = m_.cfg.run.tracked_pin;
  s.pin_axial_force[0] = half_axial_force(m_, q, v, m_.half_a(jp));
  s.pin_axial_force[1] = half_axial_force(m_, q, v, m_.half_b(jp));
  PinContactReport rep;
  JointSlot scratch;
  pulley_contact_joint(m_, w, jp, scratch, &rep);
  for (int h = 0; h < 2; ++h)
    for (int e = 0; e < 2; ++e) {
      s.pin_end_normal[2 * h + e] = rep.end[h][e].normal;
      s.pin_end_friction[2 * h + e] = rep.end[h][e].friction;
    }
  s.link_tension = link_tension(m_, w, m_.cfg.run.tracked_link);
  strand_tensions(m_, w, s.strand_tension);
  s.plate_tension.resize(m_.plate_zeta.size());
  plate_tensions(m_, w, m_.cfg.run.tracked_link, s.plate_tension.data());
  s.rocker_force = rocker_force(m_, w, jp);
  s.chain_torsion_angle = chain_torsion_angle(m_, w, jp);
  s.input_angle = q[p1];
  s.output_angle = q[p2];
  s.load_angle = q[m_.load_index()];
  s.power_input = s.input_torque * s.input_speed;
  s.power_output = s.output_torque * s.output_speed;
  s.power_dissipated = (*f)[2 * m_.ndof + kWorkDiss];
  s.energy_kinetic = e.kinetic;
  s.energy_elastic = e.elastic;
  s.work_input = aux[kWorkIn];
  s.work_output = aux[kWorkOut];
  s.work_dissipated = aux[kWorkDiss];
  s.work_clamping = aux[kWorkClamp];
  s.work_contact_switching = aux[kWorkSwitch];
  s.energy_residual = balance_residual(e, aux);
  return s;
}

void Simulation::snapshot(std::vector<double>& positions, std::vector<double>& tensions,
                          std::vector<double>* pin_ends, std::vector<double>* contact_normal) {
  const int N = m_.links;
  positions.resize(3 * N);
  tensions.resize(N);
  diag_.status = ws_.status;  // the contacts of this state (a snapshot can fall between samples)
  set_stage_input(m_, diag_, clock_.t, y_.data());
  const double* q = y_.data();
  for (int j = 0; j < N; ++j) {
    const double* a = q + m_.half_a(j);
    const double* b = q + m_.half_b(j);
    const Eigen::Vector2d c = joint_centre(m_, q, j);
    positions[3 * j + 0] = c.x();
    positions[3 * j + 1] = c.y();
    positions[3 * j + 2] = 0.25 * (a[half::kZ] + a[half::kEnd + half::kZ] + b[half::kZ] + b[half::kEnd + half::kZ]);
    tensions[j] = link_tension(m_, diag_, j);
  }
  if (pin_ends) {
    pin_ends->resize(12 * N);
    for (int j = 0; j < N; ++j)
      for (int h = 0; h < 2; ++h) {
        const double* x = q + (h == 0 ? m_.half_a(j) : m_.half_b(j));
        for (int e = 0; e < 2; ++e)
          for (int c = 0; c < 3; ++c) (*pin_ends)[12 * j + 6 * h + 3 * e + c] = x[e * half::kEnd + half::kX + c];
      }
  }
  if (contact_normal) {
    contact_normal->resize(4 * N);
    PinContactReport rep;
    JointSlot scratch;
    for (int j = 0; j < N; ++j) {
      pulley_contact_joint(m_, diag_, j, scratch, &rep);
      for (int h = 0; h < 2; ++h)
        for (int e = 0; e < 2; ++e) (*contact_normal)[4 * j + 2 * h + e] = rep.end[h][e].normal;
    }
  }
}

}  // namespace cvt
