#include "engine/base/timing.hpp"
#include "engine/simulation.hpp"

#include "engine/wmethod/model_ode.hpp"

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <set>
#include <unistd.h>

#include "engine/io/h5_writer.hpp"
#include "engine/rhs/rhs.hpp"
#include "modules/beam.hpp"
#include "modules/chain_forces.hpp"
#include "modules/pulley_contact.hpp"
#include "modules/inertia.hpp"

namespace cvt {

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
  if (update_status && m_.cfg.integrator.method != IntegratorMethod::rk4)
    w_step(h);
  else
    rk4_step(h, update_status);
  if (prof_) prof_->add_step(Profiler::ticks() - tick0);
}

// RK4 (docs/model.md 7): the four stages through the schedule, each with its stage update
// inside the graph, then (unless frozen) the contact statuses for the next step.
void Simulation::rk4_step(double h, bool update_status) {
  schedule_->within([&] {
    rk_.step([this](double t, const double* y, double* dy, const StageOp* op) { schedule_->rhs(t, y, dy, op); },
             clock_.t, h, y_);
    clock_.tick(h);
    if (update_status) update_statuses_after_step(m_, *schedule_, ws_, clock_.t, y_);
  });
}

// A W-method step (docs/integrators.md 12): the driver takes the step (or, before
// integrator.startup_time, its ROS2 sub-steps) to exactly the clock's next time and updates
// the statuses after it. A state gone non-finite is reported as RK4's is, by check_finite()
// at the next sample (with the replay and the diagnosis): the driver's own error ("solution
// is not finite", or a singular matrix built from such a state) only ends this step.
void Simulation::w_step(double h) {
  const int sub = startup_substeps(m_.cfg.integrator, h);
  const bool startup = clock_.t < m_.cfg.integrator.startup_time && sub > 1;
  OdeDriver& drv = w_driver(startup ? h / sub : h, startup);
  const std::uint64_t tick0 = prof_ ? Profiler::ticks() : 0;
  const std::uint64_t rhs0 = prof_ ? prof_->rhs_wall() : 0, master0 = prof_ ? prof_->master_total() : 0;
  if (y_.allFinite()) {
    try {
      drv.advance(clock_.t, y_, clock_.time_after(clock_.steps + 1, h), clock_.steps);
    } catch (const std::exception&) {
      if (y_.allFinite()) throw;
      w_driver_.reset(), w_startup_.reset();
    }
  }
  clock_.tick(h);
  if (prof_) {
    // The step's rest on the master, outside the evaluations and the W rows: the method's
    // vector sums and error norms, its "integrator update".
    const std::uint64_t dt = Profiler::ticks() - tick0;
    const std::uint64_t inside = (prof_->rhs_wall() - rhs0) + (prof_->master_total() - master0);
    prof_->add_master(Section::update, dt > inside ? dt - inside : 0);
    prof_->call(Section::update);
  }
}

// The start-up sub-steps always take ROS2: from rest the pins settle onto the sheaves and the
// rocker faces load up, with contact stiffnesses that the matrix (taken at the start) does
// not yet hold; ROS2 (gamma = 1.71) damps that mismatch, ROS34PW2 (gamma = 0.44) blows up
// on it within microseconds (docs/integrators.md 12.3).
OdeDriver& Simulation::w_driver(double h, bool startup) {
  std::unique_ptr<OdeDriver>& drv = startup ? w_startup_ : w_driver_;
  double& made_for = startup ? w_startup_h_ : w_h_;
  if (!drv || made_for != h)
    drv = std::make_unique<OdeDriver>(m_, ws_, *schedule_, w_run_options(m_.cfg, h, startup)), made_for = h;
  if (!startup) w_startup_.reset();
  return *drv;
}

void Simulation::advance(OdeDriver& driver, double t1) {
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
  return c;
}

void Simulation::restore(const Checkpoint& c) {
  w_driver_.reset(), w_startup_.reset();  // their matrices belong to the old state
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
    if (in.method != IntegratorMethod::rk4 && t_bad <= std::max(in.startup_time, m_.cfg.ramp.time) * (1 + 1e-9)) {
      const int k1 = std::max(1, in.w_k_every / 4), k2 = std::max(1, in.w_k_every / 8);
      cause += std::string(to_string(in.method)) + " could not start from rest at h = " + std::string(buf) +
               " s: while the pins settle onto the sheaves and the loads ramp up, its matrix (the stiffness "
               "rebuilt every integrator.w_k_every = " + std::to_string(in.w_k_every) +
               " steps) falls behind the contacts loading up. Rebuild the stiffness more often (--set "
               "integrator.w_k_every=" + std::to_string(k1) + (k2 < k1 ? ", or " + std::to_string(k2) : "") +
               "), or take a smaller integrator.step; RK4 (--method rk4 --step 1e-8) always starts";
    }
    else if (in.method != IntegratorMethod::rk4)
      cause += "the run uses " + std::string(to_string(in.method)) + " with h = " + std::string(buf) +
               " s, stable past that limit only while its matrix holds the stiff terms: reduce integrator.step, or "
               "rebuild the matrix more often (integrator.w_every, integrator.w_k_every)";
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

Sample Simulation::sample() {
  Sample s;
  s.t = clock_.t;
  diag_.status = ws_.status;
  rhs_serial(m_, diag_, clock_.t, y_.data(), dy_.data());
  const double* q = y_.data();
  const double* v = q + m_.ndof;
  const double* aux = q + 2 * m_.ndof;
  const int p1 = m_.shaft(0) + kPhi, p2 = m_.shaft(1) + kPhi;
  s.input_speed = v[p1];
  s.output_speed = v[p2];
  s.load_speed = v[m_.load_index()];
  s.input_torque = diag_.other.input_torque;
  s.output_torque = diag_.other.output_torque;
  s.load_torque = diag_.other.load_torque;
  s.speed_ratio = v[p2] != 0 ? v[p1] / v[p2] : 0.0;
  const double r1 = wrapped_radius(m_, diag_, 0), r2 = wrapped_radius(m_, diag_, 1);
  s.geometric_ratio = r1 > 0 ? r2 / r1 : 0.0;
  const double pin = s.input_torque * s.input_speed;
  s.efficiency = pin != 0 ? s.output_torque * s.output_speed / pin : 0.0;
  for (int k = 0; k < 2; ++k) {
    s.clamp[k] = diag_.other.clamp[k];
    s.sheave_position[k] = q[m_.shaft(k) + kW];
    for (int b = 0; b < 2; ++b) s.support_force[2 * k + b] = diag_.other.support_force[k][b];
  }
  const int jp = m_.cfg.run.tracked_pin;
  s.pin_axial_force[0] = half_axial_force(m_, q, v, m_.half_a(jp));
  s.pin_axial_force[1] = half_axial_force(m_, q, v, m_.half_b(jp));
  PinContactReport rep;
  JointSlot scratch;
  pulley_contact_joint(m_, diag_, jp, scratch, &rep);
  for (int h = 0; h < 2; ++h)
    for (int e = 0; e < 2; ++e) {
      s.pin_end_normal[2 * h + e] = rep.end[h][e].normal;
      s.pin_end_friction[2 * h + e] = rep.end[h][e].friction;
    }
  s.link_tension = link_tension(m_, diag_, m_.cfg.run.tracked_link);
  s.plate_tension.resize(m_.plate_zeta.size());
  plate_tensions(m_, diag_, m_.cfg.run.tracked_link, s.plate_tension.data());
  s.rocker_force = rocker_force(m_, diag_, jp);
  s.chain_torsion_angle = chain_torsion_angle(m_, diag_, jp);
  s.input_angle = q[p1];
  s.output_angle = q[p2];
  s.load_angle = q[m_.load_index()];
  s.power_input = s.input_torque * s.input_speed;
  s.power_output = s.output_torque * s.output_speed;
  s.power_dissipated = dy_[2 * m_.ndof + kWorkDiss];
  const Energies e = energies(m_, clock_.t, q, &ws_.status);
  s.energy_kinetic = e.kinetic;
  s.energy_elastic = e.elastic;
  s.work_input = aux[kWorkIn];
  s.work_output = aux[kWorkOut];
  s.work_dissipated = aux[kWorkDiss];
  s.work_clamping = aux[kWorkClamp];
  s.work_contact_switching = aux[kWorkSwitch];
  s.energy_residual = (e.kinetic + e.elastic) - energy0_ - s.work_input - s.work_clamping -
                      s.work_contact_switching + s.work_output + s.work_dissipated;
  return s;
}

void Simulation::snapshot(std::vector<double>& positions, std::vector<double>& tensions) {
  const int N = m_.links;
  positions.resize(3 * N);
  tensions.resize(N);
  set_stage_input(m_, diag_, clock_.t, y_.data());
  const double* q = y_.data();
  for (int j = 0; j < N; ++j) {
    const double* a = q + m_.half_a(j);
    const double* b = q + m_.half_b(j);
    positions[3 * j + 0] = 0.5 * (mid(a, 0) + mid(b, 0));
    positions[3 * j + 1] = 0.5 * (mid(a, 1) + mid(b, 1));
    positions[3 * j + 2] = 0.25 * (a[half::kZ] + a[half::kEnd + half::kZ] + b[half::kZ] + b[half::kEnd + half::kZ]);
    tensions[j] = link_tension(m_, diag_, j);
  }
}

namespace {

// The /profile group (docs/output.md): one entry per row of the table.
void write_profile(H5File& f, const Profiler::Report& r) {
  std::vector<std::string> names;
  std::vector<double> calls, wall, us, pct, bmin, bavg, bmax, imb;
  for (const auto& row : r.rows) {
    names.push_back(row.name);
    calls.push_back(static_cast<double>(row.calls));
    wall.push_back(row.wall_s), us.push_back(row.us_per_step), pct.push_back(row.percent);
    bmin.push_back(row.busy_min_s), bavg.push_back(row.busy_avg_s), bmax.push_back(row.busy_max_s);
    imb.push_back(row.imbalance_percent);
  }
  f.set_strings_attribute("/profile", "rows", names);  // the rows' names, in the order of the columns
  f.write_vector("/profile/calls", calls);
  f.write_vector("/profile/wall_s", wall);
  f.write_vector("/profile/us_per_step", us);
  f.write_vector("/profile/percent", pct);
  f.write_vector("/profile/busy_min_s", bmin);
  f.write_vector("/profile/busy_avg_s", bavg);
  f.write_vector("/profile/busy_max_s", bmax);
  f.write_vector("/profile/imbalance_percent", imb);
  f.set_int_attribute("/profile", "steps", r.steps);
  f.set_double_attribute("/profile", "us_per_step", r.us_per_step);
  f.set_double_attribute("/profile", "model_s_per_hour", r.model_s_per_hour);
  f.set_int_attribute("/profile", "threads", r.threads);
  f.set_int_attribute("/profile", "numa_nodes", r.numa_nodes);
  f.set_double_attribute("/profile", "wall_s", r.wall_s);
  f.set_string_attribute("/profile", "scheduler", r.scheduler);
}

// The HDF5 layout of docs/output.md.
class Recorder {
 public:
  Recorder(H5File& f, const Model& m) : f_(f), N_(m.links) {}

  void scalar(const std::string& name, const std::string& unit, double t, double value) {
    H5Series& v = series(name, unit, {});
    H5Series& tt = time(name);
    if (declare_only_) return;
    v.append(value);
    tt.append(t);
  }
  void vector(const std::string& name, const std::string& unit, double t, const double* v, hsize_t k) {
    H5Series& s = series(name, unit, {k});
    H5Series& tt = time(name);
    if (declare_only_) return;
    s.append(v);
    tt.append(t);
  }
  // Creates (or opens, in a continued file) every series and its unit without appending:
  // in SWMR mode no object may be created later.
  void declare(const Sample& s, bool snapshots) {
    declare_only_ = true;
    record(s);
    if (snapshots) snapshot(s.t, {}, {});
    declare_only_ = false;
  }
  // Keeps the first `samples` rows of every observable and `snaps` of every snapshot series.
  void truncate(hsize_t samples, hsize_t snaps) {
    for (H5Series* x : observables_) x->truncate(samples);
    for (H5Series* x : snapshots_) x->truncate(snaps);
  }
  void record(const Sample& s) {
    scalar("input_speed", "rad/s", s.t, s.input_speed);
    scalar("output_speed", "rad/s", s.t, s.output_speed);
    scalar("load_speed", "rad/s", s.t, s.load_speed);
    scalar("input_torque", "N m", s.t, s.input_torque);
    scalar("output_torque", "N m", s.t, s.output_torque);
    scalar("load_torque", "N m", s.t, s.load_torque);
    scalar("speed_ratio", "1", s.t, s.speed_ratio);
    scalar("geometric_ratio", "1", s.t, s.geometric_ratio);
    scalar("slip", "1", s.t,  // 0 while undefined: no pin touches a sheave yet (geometric ratio 0)
           s.speed_ratio != 0 && s.geometric_ratio > 0 ? 1.0 - s.geometric_ratio / s.speed_ratio : 0.0);
    scalar("efficiency", "1", s.t, s.efficiency);
    scalar("clamping_force_driving", "N", s.t, s.clamp[0]);
    scalar("clamping_force_driven", "N", s.t, s.clamp[1]);
    vector("sheave_position", "m", s.t, s.sheave_position, 2);
    vector("support_force", "N", s.t, s.support_force, 4);
    vector("pin_axial_force", "N", s.t, s.pin_axial_force, 2);
    vector("pin_end_normal_force", "N", s.t, s.pin_end_normal, 4);
    vector("pin_end_friction_force", "N", s.t, s.pin_end_friction, 4);
    scalar("link_tension", "N", s.t, s.link_tension);
    vector("plate_tension", "N", s.t, s.plate_tension.data(), static_cast<int>(s.plate_tension.size()));
    scalar("rocker_force", "N", s.t, s.rocker_force);
    scalar("chain_torsion_angle", "rad", s.t, s.chain_torsion_angle);
    scalar("input_angle", "rad", s.t, s.input_angle);
    scalar("output_angle", "rad", s.t, s.output_angle);
    scalar("load_angle", "rad", s.t, s.load_angle);
    scalar("power_input", "W", s.t, s.power_input);
    scalar("power_output", "W", s.t, s.power_output);
    scalar("power_dissipated", "W", s.t, s.power_dissipated);
    scalar("running_efficiency", "1", s.t, s.running_efficiency);
    scalar("energy_kinetic", "J", s.t, s.energy_kinetic);
    scalar("energy_elastic", "J", s.t, s.energy_elastic);
    scalar("work_input", "J", s.t, s.work_input);
    scalar("work_output", "J", s.t, s.work_output);
    scalar("work_dissipated", "J", s.t, s.work_dissipated);
    scalar("work_clamping", "J", s.t, s.work_clamping);
    scalar("work_contact_switching", "J", s.t, s.work_contact_switching);
    scalar("energy_residual", "J", s.t, s.energy_residual);
  }
  void snapshot(double t, const std::vector<double>& pos, const std::vector<double>& tension) {
    auto& p = f_.series("/particles/chain/position/value", {hsize_t(N_), 3}, 16);
    auto& pt = f_.series("/particles/chain/position/time", {}, 256);
    auto& l = f_.series("/particles/chain/link_tension/value", {hsize_t(N_)}, 16);
    auto& lt = f_.series("/particles/chain/link_tension/time", {}, 256);
    if (!snap_init_) {
      f_.set_string_attribute("/particles/chain/position/value", "unit", "m");
      f_.set_string_attribute("/particles/chain/link_tension/value", "unit", "N");
      snapshots_ = {&p, &pt, &l, &lt};
      snap_init_ = true;
    }
    if (declare_only_) return;
    p.append(pos.data());
    pt.append(t);
    l.append(tension.data());
    lt.append(t);
  }

 private:
  H5Series& series(const std::string& name, const std::string& unit, std::vector<hsize_t> shape) {
    const std::string path = "/observables/" + name + "/value";
    H5Series& s = f_.series(path, shape);
    if (!units_done_.count(name)) {
      f_.set_string_attribute(path, "unit", unit);
      units_done_.insert(name);
      observables_.push_back(&s);
    }
    return s;
  }
  H5Series& time(const std::string& name) {
    const std::string path = "/observables/" + name + "/time";
    H5Series& s = f_.series(path, {});
    if (!units_done_.count(name + "/time")) {
      f_.set_string_attribute(path, "unit", "s");
      units_done_.insert(name + "/time");
      observables_.push_back(&s);
    }
    return s;
  }
  H5File& f_;
  int N_;
  bool snap_init_ = false, declare_only_ = false;
  std::set<std::string> units_done_;
  std::vector<H5Series*> observables_, snapshots_;
};

long steps_for(double interval, double h) { return interval > 0 ? std::max(1L, std::lround(interval / h)) : 0; }

// SIGINT / SIGTERM during a run: the step in progress finishes, the state at that moment
// is sampled, and the file is closed and kept (docs/cli.md, exit code 130).
volatile std::sig_atomic_t g_stop_signal = 0;
extern "C" void on_stop_signal(int sig) { g_stop_signal = sig; }

// Installs the handlers for the lifetime of a run and restores the previous ones.
struct StopSignals {
  struct sigaction old_int {}, old_term {};
  StopSignals() {
    g_stop_signal = 0;
    struct sigaction sa {};
    sa.sa_handler = on_stop_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGINT, &sa, &old_int);
    sigaction(SIGTERM, &sa, &old_term);
  }
  ~StopSignals() {
    sigaction(SIGINT, &old_int, nullptr);
    sigaction(SIGTERM, &old_term, nullptr);
  }
};

std::string new_run_id() {
  std::random_device rd;
  const std::uint64_t x = (static_cast<std::uint64_t>(rd()) << 32) ^ rd() ^
                          static_cast<std::uint64_t>(std::chrono::steady_clock::now().time_since_epoch().count());
  char b[20];
  std::snprintf(b, sizeof b, "%016llx", static_cast<unsigned long long>(x));
  return b;
}

// The /summary group (docs/output.md): every entry an attribute (strings that h5py reads as
// str, flags and counts as integers, the rest as doubles).
void write_summary(H5File& f, const RunSummary& s) {
  f.remove("/summary");
  f.set_strings_attribute("/summary", "reasons", s.reasons);
  f.set_strings_attribute("/summary", "warnings", s.warnings);
  f.set_string_attribute("/summary", "status", s.status);
  f.set_string_attribute("/summary", "method", s.method);
  f.set_string_attribute("/summary", "controller", s.controller);
  f.set_int_attribute("/summary", "efficiency_meaningful", s.efficiency_meaningful ? 1 : 0);
  f.set_int_attribute("/summary", "interrupted", s.interrupted ? 1 : 0);
  f.set_int_attribute("/summary", "steps", s.steps);
  for (auto [name, v] : std::initializer_list<std::pair<const char*, double>>{
           {"step", s.step},
           {"drive_speed", s.drive_speed},
           {"load_torque_nominal", s.load_torque_nominal},
           {"clamping_force_driving_nominal", s.clamp_driving_nominal},
           {"clamping_force_driven_nominal", s.clamp_driven_nominal},
           {"ratio_target", s.ratio_target},
           {"window_start", s.window_start},
           {"window_end", s.window_end},
           {"speed_ratio", s.speed_ratio},
           {"geometric_ratio", s.geometric_ratio},
           {"slip", s.slip},
           {"input_speed", s.input_speed},
           {"output_speed", s.output_speed},
           {"input_torque", s.input_torque},
           {"output_torque", s.output_torque},
           {"load_torque", s.load_torque},
           {"clamping_force_driving", s.clamp_driving},
           {"clamping_force_driven", s.clamp_driven},
           {"sheave_position_driving", s.sheave_driving},
           {"sheave_position_driven", s.sheave_driven},
           {"efficiency", s.efficiency},
           {"loss_efficiency", s.loss_efficiency},
           {"energy_residual", s.energy_residual},
           {"energy_turnover", s.energy_turnover},
           {"residual_fraction", s.residual_fraction},
           {"model_time", s.model_time},
           {"wall_s", s.wall_s}})
    f.set_double_attribute("/summary", name, v);
}

// The earlier part of a continued run, read back from its file: the rows up to the
// checkpoint on the sample grid, for the summary and the running efficiency's window.
struct FileHistory {
  hsize_t samples = 0, snapshots = 0;
  SummaryChannels channels;
  std::vector<Sample> tail;  // the rows within run.efficiency_window of the checkpoint (t and works)
};

// Opens the run's own file for a continuation, checks that it belongs to the checkpoint and
// holds every sample up to it, and reads the history. Throws std::runtime_error otherwise.
FileHistory continue_file(H5File& f, const Model& m, const Checkpoint& ck, long every_sample, long every_snapshot) {
  const Config& c = m.cfg;
  const double h = c.integrator.step;
  std::string path = f.path();  // the run's file, moved to FILE.partial while it is continued
  if (path.size() > 8 && path.compare(path.size() - 8, 8, ".partial") == 0) path.resize(path.size() - 8);
  const auto refuse = [&](const std::string& why) {
    throw std::runtime_error("cannot continue " + path + " from the checkpoint: " + why +
                             "; give --out NEW to write the continuation to a new file");
  };
  std::string id;
  try {
    id = f.read_string_attribute("/parameters", "run_id");
  } catch (const H5Error&) {
    refuse("the file has no run id (it was not written by this run)");
  }
  if (id != ck.run_id) refuse("it belongs to another run (run id " + id + ", the checkpoint's " + ck.run_id + ")");
  const auto on_grid = [&](double t, long every) {
    const double k = std::round(t / h);
    return std::abs(k * h - t) <= 1e-6 * h && static_cast<long>(k) % every == 0;
  };
  const auto kept = [&](const std::vector<double>& t, long every) {
    hsize_t n = 0;
    while (n < t.size() && t[n] <= ck.t + 1e-6 * h) ++n;
    if (n > 0 && !on_grid(t[n - 1], every) && n > 1) --n;  // an off-grid last sample (an interrupt, t_end)
    return n;
  };
  FileHistory hist;
  const std::vector<double> t = f.read_doubles("/observables/input_speed/time");
  hist.samples = kept(t, every_sample);
  const long last_grid = (ck.steps / every_sample) * every_sample;
  if (hist.samples == 0 || std::abs(t[hist.samples - 1] - static_cast<double>(last_grid) * h) > 1e-6 * h) {
    char b[256];
    std::snprintf(b, sizeof b, "its samples end at t = %.9g s, before the checkpoint's last sample at t = %.9g s",
                  hist.samples ? t[hist.samples - 1] : 0.0, static_cast<double>(last_grid) * h);
    refuse(b);
  }
  if (every_snapshot && f.exists("/particles/chain/position/time"))
    hist.snapshots = kept(f.read_doubles("/particles/chain/position/time"), every_snapshot);
  const auto read = [&](const char* name) {
    std::vector<double> v = f.read_doubles(std::string("/observables/") + name + "/value");
    if (v.size() < hist.samples) refuse(std::string("its channel ") + name + " is shorter than its time");
    return v;
  };
  SummaryChannels& ch = hist.channels;
  const std::size_t n = hist.samples;
  ch.t.assign(t.begin(), t.begin() + static_cast<long>(n));
  for (auto [name, to] : std::initializer_list<std::pair<const char*, std::vector<double>*>>{
           {"input_speed", &ch.input_speed},
           {"output_speed", &ch.output_speed},
           {"input_torque", &ch.input_torque},
           {"output_torque", &ch.output_torque},
           {"load_torque", &ch.load_torque},
           {"speed_ratio", &ch.speed_ratio},
           {"geometric_ratio", &ch.geometric_ratio},
           {"clamping_force_driving", &ch.clamp_driving},
           {"clamping_force_driven", &ch.clamp_driven},
           {"work_input", &ch.work_input},
           {"work_output", &ch.work_output},
           {"work_dissipated", &ch.work_dissipated}}) {
    const std::vector<double> v = read(name);
    to->assign(v.begin(), v.begin() + static_cast<long>(n));
  }
  const std::vector<double> sheave = read("sheave_position");
  for (std::size_t i = 0; i < n; ++i) ch.sheave_driving.push_back(sheave[2 * i]), ch.sheave_driven.push_back(sheave[2 * i + 1]);
  for (std::size_t i = 0; i < n; ++i)
    if (ch.t[i] >= ck.t - c.run.efficiency_window - 1e-6 * h) {
      Sample s;
      s.t = ch.t[i], s.work_input = ch.work_input[i], s.work_output = ch.work_output[i];
      hist.tail.push_back(s);
    }
  return hist;
}

// The shortest decimal that reads back as x ("3e-07", not "2.9999999999999999e-07").
std::string shortest(double x) {
  char b[64];
  for (int p = 1; p <= 17; ++p) {
    std::snprintf(b, sizeof b, "%.*g", p, x);
    if (std::strtod(b, nullptr) == x) break;
  }
  return b;
}

// Whether h divides x to within a millionth of a step.
bool divides(double h, double x) {
  const double k = std::round(x / h);
  return k >= 1 && std::abs(k * h - x) <= 1e-6 * h;
}

}  // namespace

void check_step_grid(const Config& c) {
  const double h = c.integrator.step;
  const std::vector<std::pair<const char*, double>> keys = {{"run.sample_interval", c.run.sample_interval},
                                                            {"run.snapshot_interval", c.run.snapshot_interval},
                                                            {"run.t_end", c.run.t_end}};
  const auto all_divide = [&](double step) {
    for (const auto& [key, x] : keys)
      if (x > 0 && !divides(step, x)) return false;
    return true;
  };
  for (const auto& [key, x] : keys) {
    if (!(x > 0) || divides(h, x)) continue;
    // The largest step below h that divides all three: x / n for the smallest n that fits.
    const double base = std::min(c.run.sample_interval > 0 ? c.run.sample_interval : c.run.t_end, c.run.t_end);
    double fit = 0;
    for (double n = std::ceil(base / h * (1 - 1e-12)); n < 1e6 && fit == 0; ++n)
      if (all_divide(base / n)) fit = base / n;
    char steps[32];
    std::snprintf(steps, sizeof steps, "%.4g", x / h);
    std::string reason = "does not divide " + std::string(key) + " = " + shortest(x) + " s (" + steps +
                         " steps): samples would not fall on multiples of the step and the run would not end at "
                         "run.t_end; choose a step that divides run.t_end, run.sample_interval and "
                         "run.snapshot_interval";
    if (fit > 0) reason += ", e.g. --step " + shortest(fit);
    else reason += ", with run.t_end a multiple of run.sample_interval";
    throw ConfigError("integrator.step", shortest(h), reason);
  }
}

double energy_turnover(const Sample& s) {
  return std::abs(s.work_input) + std::abs(s.work_output) + std::abs(s.work_dissipated) + std::abs(s.work_clamping) +
         std::abs(s.work_contact_switching);
}

std::string EnergyGuard::check(const Sample& s) {
  const double turnover = energy_turnover(s);
  if (warned || !(turnover >= turnover_min)) return "";
  if (std::abs(s.energy_residual) <= limit * turnover && std::isfinite(s.energy_residual)) return "";
  warned = true;
  char b[512];
  std::snprintf(b, sizeof b,
                "at t = %.6g s the energy balance's residual is %.4g J, %.1f %% of the energy turned over (%.4g J; "
                "limit %.0f %%): the integration is not accurate, reduce integrator.step",
                s.t, s.energy_residual, 100 * std::abs(s.energy_residual) / turnover, turnover, 100 * limit);
  return b;
}

std::string rk4_stability_warning(double h, double rho, double t) {
  const double h_stable = rho > 0 && std::isfinite(rho) ? 2.8 / rho : 0;
  if (!(h_stable > 0) || h <= h_stable) return "";
  char b[512];
  std::snprintf(b, sizeof b,
                "RK4's step %.4g s is above its stability limit of about %.3g s, estimated at t = %.6g s (the "
                "Jacobian's spectral radius %.3g 1/s): the results are not to be trusted; use --step %.2g or less, "
                "or --method ros34pw2",
                h, h_stable, t, rho, 0.5 * h_stable);
  return b;
}

void check_writable(const std::string& path, const std::string& what) {
  namespace fs = std::filesystem;
  const fs::path p(path);
  const fs::path dir = p.has_parent_path() ? p.parent_path() : fs::path(".");
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    throw OutputError("cannot write the " + what + " '" + path + "': the folder '" + dir.string() +
                      "' does not exist (create it first, or choose another path)");
  if (fs::is_directory(p, ec)) throw OutputError("cannot write the " + what + " '" + path + "': it is a folder");
  if (access(dir.c_str(), W_OK) != 0)
    throw OutputError("cannot write the " + what + " '" + path + "': no permission to write in '" + dir.string() + "'");
}

RunResult run_simulation(const Model& m, const RunOptions& opt) {
  const Config& c = m.cfg;
  check_step_grid(c);
  const double h = c.integrator.step;
  const long total = std::max(1L, std::lround(c.run.t_end / h));
  const long every_sample = steps_for(c.run.sample_interval, h);
  const long every_snapshot = steps_for(c.run.snapshot_interval, h);
  const bool append = opt.append && opt.resume;
  const std::string ckpt_path = opt.checkpoint_path.empty() ? opt.out_path + ".ckpt" : opt.checkpoint_path;
  check_writable(opt.out_path, "output file");
  check_writable(ckpt_path, "checkpoint");
  for (const std::string* p : {&opt.profile_json, &opt.summary_json})
    if (!p->empty()) check_writable(*p, "JSON file");
  const auto warn = [&](const std::string& w) {
    if (opt.warn) opt.warn(w);
    else std::fprintf(stderr, "cvt-engine: warning: %s\n", w.c_str());
  };

  Simulation sim(m, opt.schedule);
  if (opt.resume) {
    sim.restore(*opt.resume);
    // A checkpoint of a run at another step (RK4 warmed at 1e-8, continued with ROS2 at
    // 2e-7): the run counts steps of the new h, so its step count is t / h.
    const double t = sim.time();
    if (std::abs(static_cast<double>(sim.steps()) * h - t) > 1e-6 * h) {
      const long k = std::lround(t / h);
      if (std::abs(static_cast<double>(k) * h - t) > 1e-6 * h)
        throw std::runtime_error("the checkpoint's time t = " + std::to_string(t) +
                                 " s is not a multiple of the step h = " + std::to_string(h) +
                                 " s: choose a step that divides it");
      sim.set_clock(t, k);
    }
  }
  const long start = sim.steps();
  if (start >= total)
    throw std::runtime_error("the checkpoint is at step " + std::to_string(start) + " (t = " + std::to_string(sim.time()) +
                             " s), not before t_end = " + std::to_string(c.run.t_end) + " s: raise --t-end");
  // A W-method's matrix is not in a checkpoint: a continuation repeats the bits only from a
  // step that rebuilds all of it, a multiple of integrator.w_k_every. Periodic checkpoints
  // and stops on a signal fall on such steps (docs/cli.md).
  const long rebuild_every = c.integrator.method == IntegratorMethod::rk4 ? 1 : std::max(1, c.integrator.w_k_every);
  const long checkpoint_every =
      opt.checkpoint_every > 0 ? (opt.checkpoint_every + rebuild_every - 1) / rebuild_every * rebuild_every : 0;

  // Write to a temporary name and rename at the end: a failed run never leaves a file
  // that looks complete. A continued run moves its file there while it writes.
  const std::string tmp = opt.out_path + ".partial";
  std::string run_id = opt.resume && append ? opt.resume->run_id : new_run_id();
  FileHistory hist;
  H5File file = [&] {
    if (!append) return H5File::create(tmp);
    namespace fs = std::filesystem;
    if (!fs::exists(opt.out_path) && !fs::exists(tmp))
      throw std::runtime_error("cannot continue " + opt.out_path + ": the file does not exist; give --out NEW to write "
                               "the continuation to a new file");
    if (fs::exists(opt.out_path)) fs::rename(opt.out_path, tmp);
    return H5File::open(tmp);
  }();
  if (append) {
    try {
      hist = continue_file(file, m, *opt.resume, every_sample, every_snapshot);
    } catch (...) {
      file.close();
      std::filesystem::rename(tmp, opt.out_path);
      throw;
    }
    file.remove("/profile");
    file.remove("/summary");
  }
  file.set_string_attribute("/parameters", "version", CVT_VERSION);
  file.set_string_attribute("/parameters", "config", c.resolved_toml);
  file.set_string_attribute("/parameters", "run_id", run_id);
  file.set_string_attribute("/parameters", "geometry",
                            "R1 = " + std::to_string(m.pulley[0].running_radius) + " m, R2 = " +
                                std::to_string(m.pulley[1].running_radius) +
                                " m, closure residual = " + std::to_string(m.closure_residual) + " m");
  Recorder rec(file, m);
  std::printf("  schedule: %s\n", sim.schedule().describe().c_str());
  if (opt.resume)
    std::printf("  resumed at t = %.9g s, step %ld%s\n", sim.time(), start,
                append ? (", appending to " + opt.out_path).c_str() : "");
  std::fflush(stdout);
  std::vector<Sample> samples = hist.tail;  // the running efficiency's window reaches back into the file
  SummaryChannels channels = hist.channels;
  std::vector<double> pos, ten;
  RunResult r;
  if (opt.resume && start % rebuild_every != 0) {
    const std::string w = "the checkpoint is at step " + std::to_string(start) + ", not a multiple of "
                          "integrator.w_k_every = " + std::to_string(rebuild_every) + ": " + to_string(c.integrator.method) +
                          "'s matrix is rebuilt here, so the continuation is close to, not bit-identical with, an "
                          "uninterrupted run";
    r.warnings.push_back(w);
    warn(w);
  }

  const bool tty = isatty(fileno(stderr));
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  auto last_progress = t0, last_flush = t0;
  Profiler& prof = sim.enable_profiling();
  // Output (sampling, snapshots, flushes, checkpoints) is timed as one row of the profile.
  const auto output = [&](auto&& f) {
    const std::uint64_t k0 = Profiler::ticks();
    f();
    prof.add_output(Profiler::ticks() - k0);
  };
  // Guards: the energy balance, and RK4's step against its stability limit.
  EnergyGuard energy;
  bool warned_stability = false;
  // RK4's step against its stability limit: first when the loads have ramped up (at rest,
  // while the contacts form, the linearization overstates the limit: RK4 at 1e-8 runs the
  // mini model, whose estimate at t = 0 is 6.4e-9), then every millisecond.
  double next_stability_check = std::max(sim.time(), c.ramp.time);
  const auto watch = [&](const Sample& s) {
    if (std::string w = energy.check(s); !w.empty()) r.warnings.push_back(w), warn(w);
    if (c.integrator.method == IntegratorMethod::rk4 && !warned_stability && s.t >= next_stability_check) {
      next_stability_check = s.t + 1e-3;
      const double rho = sim.spectral_radius(sim.state(), sim.time(), sim.workspace().status);
      if (std::string w = rk4_stability_warning(h, rho, s.t); !w.empty())
        r.warnings.push_back(w), warn(w), warned_stability = true;
    }
  };
  auto record = [&]() {
    output([&] {
      samples.push_back(sim.sample());
      // Running-mean efficiency: work out over work in across the last window (or since
      // the first sample of the run while the run is shorter than the window).
      Sample& s = samples.back();
      const double t_from = s.t - c.run.efficiency_window;
      const auto it = std::lower_bound(samples.begin(), samples.end(), t_from,
                                       [](const Sample& x, double t) { return x.t < t; });
      const double win = s.work_input - it->work_input;
      s.running_efficiency = win > 0 ? (s.work_output - it->work_output) / win : 0.0;
      rec.record(s);
      channels.push(s);
      watch(s);
      // Only the running efficiency's window is needed later.
      if (samples.size() > 4096 && samples.front().t < t_from - c.run.efficiency_window)
        samples.erase(samples.begin(), samples.begin() + 2048);
    });
  };
  sim.check_finite();
  if (append) {
    // The file holds this state's sample if it is on the grid: declare the series (none may
    // be created once SWMR starts) and drop the rows after the checkpoint.
    const Sample s0 = sim.sample();
    rec.declare(s0, every_snapshot > 0);
    rec.truncate(hist.samples, hist.snapshots);
  } else {
    record();
    if (every_snapshot) {
      sim.snapshot(pos, ten);
      rec.snapshot(sim.time(), pos, ten);
    }
  }
  // Every dataset exists now: from here on the file is only appended to, and readers
  // (h5py.File(path, "r", swmr=True)) can follow the run while it writes.
  file.start_swmr();
  const auto checkpoint = [&] {
    Checkpoint ck = sim.checkpoint();
    ck.run_id = run_id;
    ck.output = std::filesystem::absolute(opt.out_path).string();
    return ck;
  };
  double step_wall = 0;
  StopSignals signals;
  long done = total;
  try {
  for (long n = start + 1; n <= total; ++n) {
    sim.step(h);
    // The sample and the snapshot of this step, then a checkpoint (after a flush: a crash
    // leaves a file that holds every sample up to the checkpoint), then a stop.
    const bool on_grid = n % every_sample == 0;
    if (on_grid || n == total) {
      sim.check_finite();
      record();
    }
    if (every_snapshot && n % every_snapshot == 0) {
      output([&] {
        sim.snapshot(pos, ten);
        rec.snapshot(sim.time(), pos, ten);
      });
    }
    if (checkpoint_every > 0 && n % checkpoint_every == 0)
      output([&] {
        file.flush();
        last_flush = Clock::now();
        write_checkpoint(ckpt_path, checkpoint());
      });
    if (g_stop_signal && (n % rebuild_every == 0 || n == total)) {
      // Keep everything up to this step: its sample ends the series.
      done = n;
      if (!(on_grid || n == total)) {
        sim.check_finite();
        record();
      }
      break;
    }
    if (on_grid || n == total) {
      const auto now = Clock::now();
      if (std::chrono::duration<double>(now - last_flush).count() > opt.flush_seconds) {
        output([&] { file.flush(); });
        last_flush = now;
      }
      if (opt.progress && now - last_progress > std::chrono::seconds(3)) {
        const double el = std::chrono::duration<double>(now - t0).count();
        const double eta = el / static_cast<double>(n - start) * static_cast<double>(total - n);
        std::fprintf(stderr, "%sstep %ld/%ld  t = %.6f s  %5.1f %%  %.3g model s/h  ETA %.0f s%s",
                     tty ? "\r" : "", n, total, sim.time(), 100.0 * static_cast<double>(n) / static_cast<double>(total),
                     (sim.time() - (opt.resume ? opt.resume->t : 0.0)) / el * 3600, eta, tty ? "   " : "\n");
        last_progress = now;
      }
    }
  }
  } catch (const BlowUpError& e) {
    // Keep every good sample: close the file under its final name, then report.
    if (opt.progress && tty) std::fprintf(stderr, "\n");
    file.close();
    std::filesystem::rename(tmp, opt.out_path);
    throw BlowUpError(std::string(e.what()) + ". Every sample before the blow-up is in " + opt.out_path);
  }
  step_wall = seconds_since(t0);
  if (opt.progress && tty) std::fprintf(stderr, "\n");
  output([&] {
    write_checkpoint(ckpt_path, checkpoint());
    file.close();
  });
  r.profile = prof.report(seconds_since(t0),
                          sim.time() - (opt.resume ? opt.resume->t : 0.0), sim.schedule().numa_nodes(),
                          scheduler_name(opt.schedule.kind));
  r.steps = done - start;
  r.interrupted = g_stop_signal != 0;
  r.signal = g_stop_signal;
  r.t_start = opt.resume ? opt.resume->t : 0.0;
  r.model_time = sim.time();
  r.wall_s = step_wall;
  r.us_per_step = 1e6 * step_wall / static_cast<double>(std::max(1L, done - start));
  r.model_s_per_hour = static_cast<double>(done - start) * h / step_wall * 3600.0;
  summarize(m, channels, r);
  const Sample& last = samples.back();
  r.energy_residual = last.energy_residual;
  r.work_input = last.work_input;
  r.energy_turnover = energy_turnover(last);
  r.residual_fraction = r.energy_turnover > 0 ? std::abs(r.energy_residual) / r.energy_turnover : 0.0;
  // SWMR allows no new objects: the profile and the summary go in after the file is closed.
  {
    H5File f = H5File::open(tmp);
    write_profile(f, r.profile);
    write_summary(f, r);
    f.close();
  }
  const auto write_text = [](const std::string& path, const std::string& text) {
    std::ofstream js(path);
    js << text;
    js.close();
    if (!js) throw OutputError("cannot write '" + path + "'");
  };
  if (!opt.profile_json.empty()) write_text(opt.profile_json, profile_json(r.profile));
  if (!opt.summary_json.empty()) write_text(opt.summary_json, summary_json(r));
  std::filesystem::rename(tmp, opt.out_path);
  return r;
}

}  // namespace cvt
