#include "engine/simulation.hpp"

#include "engine/model_ode.hpp"

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <set>
#include <unistd.h>

#include "engine/h5_writer.hpp"
#include "engine/rhs.hpp"
#include "modules/beam.hpp"
#include "modules/chain_forces.hpp"
#include "modules/pulley_contact.hpp"
#include "modules/inertia.hpp"

namespace cvt {

Simulation::Simulation(const Model& m, const ScheduleOptions& schedule)
    : m_(m), ws_(m), diag_(m), schedule_(make_schedule(m, ws_, schedule)), rk_(m.nstate), y_(m.y0), dy_(m.nstate) {
  update_contact_status(m_, ws_, t_, y_.data());
  const Energies e = energies(m_, t_, y_.data(), &ws_.status);
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
  // t = t0 + (steps - steps0) h keeps t free of accumulated rounding while h stays the
  // same; a caller that changes h (a run warmed at one step and continued at another) gets
  // the clock re-anchored here instead of a time jump. Unchanged h: no effect on the bits.
  if (std::abs(t0_ + static_cast<double>(steps_ - steps0_) * h - t_) > 1e-6 * h) t0_ = t_, steps0_ = steps_;
  if (update_status && m_.cfg.integrator.method != "rk4") {  // a W-method: ros2, ros34pw2
    // The start-up sub-steps always take ROS2: from rest the pins settle onto the sheaves and
    // the rocker faces load up, with contact stiffnesses that the matrix (taken at the start)
    // does not yet hold; ROS2 (gamma = 1.71) damps that mismatch, ROS34PW2 (gamma = 0.44)
    // blows up on it within microseconds (docs/integrators.md 13.4).
    auto make = [this](double hh, bool startup) {
      OdeRunOptions ro;
      ro.method = startup ? OdeMethod::Ros2 : parse_ode_method(m_.cfg.integrator.method);
      ro.ode.fixed_step = true;
      ro.ode.h0 = hh;
      ro.jac.scaled = false;
      ro.jac.w_every = m_.cfg.integrator.w_every;
      ro.jac.w_k_every = m_.cfg.integrator.w_k_every;
      ro.jac.w_secant = m_.cfg.integrator.w_secant;
      ro.jac.w_fresh = m_.cfg.integrator.w_fresh;  // ModelOde leaves it off without the secant
      ro.jac.w_fresh_max = m_.cfg.integrator.w_fresh_max;
      return std::make_unique<OdeDriver>(*this, ro);
    };
    // Before integrator.startup_time a step is taken as the fewest equal sub-steps no longer
    // than integrator.startup_step (ROS2, its own driver and matrix); the grid of the steps,
    // and so the clock, is the same.
    const int sub = startup_substeps(m_.cfg.integrator, h);
    const bool startup = t_ < m_.cfg.integrator.startup_time && sub > 1;
    OdeDriver* drv;
    if (startup) {
      if (!w_startup_ || w_startup_h_ != h / sub) w_startup_ = make(h / sub, true), w_startup_h_ = h / sub;
      drv = w_startup_.get();
    } else {
      if (!w_driver_ || w_h_ != h) w_driver_ = make(h, false), w_h_ = h;
      w_startup_.reset();
      drv = w_driver_.get();
    }
    // The driver takes one step (or the sub-steps) to exactly t0 + (n + 1) h and counts it;
    // the clock keeps its origin, so that t has no accumulated rounding, as with RK4.
    const double t0 = t0_, t1 = t0_ + static_cast<double>(steps_ + 1 - steps0_) * h;
    const long s0 = steps0_, n1 = steps_ + 1;
    // A state gone non-finite is reported as RK4's is, by check_finite() at the next sample
    // (with the replay and the diagnosis): the driver's own error ("solution is not
    // finite", or a singular matrix built from such a state) only ends this step, and the
    // steps up to that sample are not taken.
    if (y_.allFinite()) {
      try {
        drv->advance(t1);
      } catch (const std::exception&) {
        if (y_.allFinite()) throw;
        w_driver_.reset(), w_startup_.reset();
      }
    }
    t0_ = t0, steps0_ = s0, steps_ = n1, t_ = t1;
    if (prof_) prof_->add_step(Profiler::ticks() - tick0);
    return;
  }
  schedule_->within([&] {
    rk_.step([this](double t, const double* y, double* dy, const StageOp* op) { schedule_->rhs(t, y, dy, op); },
             t_, h, y_);
    ++steps_;
    t_ = t0_ + (steps_ - steps0_) * h;  // fixed step: no accumulated rounding in t
    if (update_status) {
      schedule_->update_status(t_, y_.data());
      y_[2 * m_.ndof + kWorkSwitch] += ws_.switch_work;
    }
  });
  if (prof_) prof_->add_step(Profiler::ticks() - tick0);
}

Checkpoint Simulation::checkpoint() const {
  Checkpoint c;
  c.config_toml = m_.cfg.resolved_toml;
  c.state = y_;
  c.rocker = ws_.status.rocker;
  c.pulley = ws_.status.pulley;
  c.t = t_, c.t0 = t0_, c.steps = steps_, c.steps0 = steps0_;
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
  t_ = c.t, t0_ = c.t0, steps_ = c.steps, steps0_ = c.steps0;
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
  if (good_y_.size() != m_.nstate || steps_ <= good_steps_) return {};
  const Eigen::VectorXd bad_y = y_;
  const ContactStatus bad_status = ws_.status;
  const long bad_steps = steps_;
  y_ = good_y_, ws_.status = good_status_, steps_ = good_steps_, t_ = good_t_;
  std::string out;
  char buf[768];
  while (steps_ < bad_steps) {
    const Eigen::VectorXd prev = y_;
    const ContactStatus prev_status = ws_.status;
    const double prev_t = t_;
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
                  good_t_, steps_, t_, first.c_str(), dy_[n + worst], describe_state_index(m_, n + worst).c_str(), joint, module, fc,
                  fp, fi);
    out = buf;
    break;
  }
  y_ = bad_y, ws_.status = bad_status, steps_ = bad_steps, t_ = t0_ + (steps_ - steps0_) * h;
  return out;
}

void Simulation::check_finite() {
  const std::string problem = state_problem(y_);
  if (problem.empty()) {
    if (first_y_.size() == 0) first_y_ = y_, first_t_ = t_, first_status_ = ws_.status;
    good_y_ = y_;
    good_t_ = t_;
    good_steps_ = steps_;
    good_status_ = ws_.status;
    return;
  }
  const double h = m_.cfg.integrator.step;
  const double t_bad = t_;
  const long steps_bad = steps_;
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
    if (m_.cfg.integrator.method != "rk4")
      cause += "the run uses " + m_.cfg.integrator.method + " with h = " + std::string(buf) +
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
  s.t = t_;
  diag_.status = ws_.status;
  rhs_serial(m_, diag_, t_, y_.data(), dy_.data());
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
  const Energies e = energies(m_, t_, q, &ws_.status);
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
  set_stage_input(m_, diag_, t_, y_.data());
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
  f.write_strings("/profile/name", names);
  f.write_vector("/profile/calls", calls);
  f.write_vector("/profile/wall_s", wall);
  f.write_vector("/profile/us_per_step", us);
  f.write_vector("/profile/percent", pct);
  f.write_vector("/profile/busy_min_s", bmin);
  f.write_vector("/profile/busy_avg_s", bavg);
  f.write_vector("/profile/busy_max_s", bmax);
  f.write_vector("/profile/imbalance_percent", imb);
  f.set_double_attribute("/profile", "steps", static_cast<double>(r.steps));
  f.set_double_attribute("/profile", "us_per_step", r.us_per_step);
  f.set_double_attribute("/profile", "model_s_per_hour", r.model_s_per_hour);
  f.set_double_attribute("/profile", "threads", r.threads);
  f.set_double_attribute("/profile", "numa_nodes", r.numa_nodes);
  f.set_double_attribute("/profile", "wall_s", r.wall_s);
  f.set_string_attribute("/profile", "scheduler", r.scheduler);
}

// The HDF5 layout of docs/output.md.
class Recorder {
 public:
  Recorder(H5File& f, const Model& m) : f_(f), N_(m.links) {}

  void scalar(const std::string& name, const std::string& unit, double t, double value) {
    series(name, unit, {}).append(value);
    time(name).append(t);
  }
  void vector(const std::string& name, const std::string& unit, double t, const double* v, hsize_t k) {
    series(name, unit, {k}).append(v);
    time(name).append(t);
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
    scalar("slip", "1", s.t, s.geometric_ratio != 0 ? 1.0 - s.speed_ratio / s.geometric_ratio : 0.0);
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
    if (!snap_init_) {
      f_.set_string_attribute("/particles/chain/position/value", "unit", "m");
      f_.series("/particles/chain/link_tension/value", {hsize_t(N_)}, 16);
      f_.set_string_attribute("/particles/chain/link_tension/value", "unit", "N");
      snap_init_ = true;
    }
    p.append(pos.data());
    f_.series("/particles/chain/position/time", {}, 256).append(t);
    f_.series("/particles/chain/link_tension/value", {hsize_t(N_)}, 16).append(tension.data());
    f_.series("/particles/chain/link_tension/time", {}, 256).append(t);
  }

 private:
  H5Series& series(const std::string& name, const std::string& unit, std::vector<hsize_t> shape) {
    const std::string path = "/observables/" + name + "/value";
    H5Series& s = f_.series(path, shape);
    if (!units_done_.count(name)) {
      f_.set_string_attribute(path, "unit", unit);
      units_done_.insert(name);
    }
    return s;
  }
  H5Series& time(const std::string& name) {
    const std::string path = "/observables/" + name + "/time";
    H5Series& s = f_.series(path, {});
    if (!units_done_.count(name + "/time")) {
      f_.set_string_attribute(path, "unit", "s");
      units_done_.insert(name + "/time");
    }
    return s;
  }
  H5File& f_;
  int N_;
  bool snap_init_ = false;
  std::set<std::string> units_done_;
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

}  // namespace

RunSummary run_simulation(const Model& m, const RunOptions& opt) {
  const Config& c = m.cfg;
  const double h = c.integrator.step;
  const long total = std::max(1L, std::lround(c.run.t_end / h));
  const long every_sample = steps_for(c.run.sample_interval, h);
  const long every_snapshot = steps_for(c.run.snapshot_interval, h);

  // Write to a temporary name and rename at the end: a failed run never leaves a file
  // that looks complete.
  const std::string tmp = opt.out_path + ".partial";
  H5File file = H5File::create(tmp);
  file.write_string("/parameters/config", c.resolved_toml);
  file.write_string("/parameters/version", CVT_VERSION);
  file.set_string_attribute("/parameters", "geometry",
                            "R1 = " + std::to_string(m.pulley[0].running_radius) + " m, R2 = " +
                                std::to_string(m.pulley[1].running_radius) +
                                " m, closure residual = " + std::to_string(m.closure_residual) + " m");
  Recorder rec(file, m);
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
  const std::string ckpt_path = opt.checkpoint_path.empty() ? opt.out_path + ".ckpt" : opt.checkpoint_path;
  std::printf("  schedule: %s\n", sim.schedule().describe().c_str());
  if (opt.resume) std::printf("  resumed at t = %.9g s, step %ld\n", sim.time(), start);
  std::fflush(stdout);
  std::vector<Sample> samples;
  std::vector<double> pos, ten;

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
  auto record = [&]() {
    output([&] {
      samples.push_back(sim.sample());
      // Running-mean efficiency: work out over work in across the last window (or since
      // the first sample of this run while the run is shorter than the window).
      Sample& s = samples.back();
      const double t_from = s.t - c.run.efficiency_window;
      const auto it = std::lower_bound(samples.begin(), samples.end(), t_from,
                                       [](const Sample& x, double t) { return x.t < t; });
      const double win = s.work_input - it->work_input;
      s.running_efficiency = win > 0 ? (s.work_output - it->work_output) / win : 0.0;
      rec.record(samples.back());
    });
  };
  sim.check_finite();
  record();
  if (every_snapshot) {
    sim.snapshot(pos, ten);
    rec.snapshot(sim.time(), pos, ten);
  }
  // Every dataset exists now: from here on the file is only appended to, and readers
  // (h5py.File(path, "r", swmr=True)) can follow the run while it writes.
  file.start_swmr();
  double step_wall = 0;
  StopSignals signals;
  long done = total;
  try {
  for (long n = start + 1; n <= total; ++n) {
    sim.step(h);
    if (opt.checkpoint_every > 0 && n % opt.checkpoint_every == 0)
      output([&] { write_checkpoint(ckpt_path, sim.checkpoint()); });
    if (g_stop_signal) {
      // Keep everything up to this step: its sample ends the series.
      done = n;
      if (n % every_sample != 0) {
        sim.check_finite();
        record();
      }
      break;
    }
    if (n % every_sample == 0 || n == total) {
      sim.check_finite();
      record();
      const auto now = Clock::now();
      if (std::chrono::duration<double>(now - last_flush).count() > opt.flush_seconds) {
        output([&] { file.flush(); });
        last_flush = now;
      }
      if (opt.progress && now - last_progress > std::chrono::seconds(3)) {
        const double el = std::chrono::duration<double>(now - t0).count();
        const double eta = el / (n - start) * (total - n);
        std::fprintf(stderr, "%sstep %ld/%ld  t = %.6f s  %5.1f %%  %.3g model s/h  ETA %.0f s%s",
                     tty ? "\r" : "", n, total, sim.time(), 100.0 * n / total, sim.time() / el * 3600, eta,
                     tty ? "   " : "\n");
        last_progress = now;
      }
    }
    if (every_snapshot && n % every_snapshot == 0) {
      output([&] {
        sim.snapshot(pos, ten);
        rec.snapshot(sim.time(), pos, ten);
      });
    }
  }
  } catch (const BlowUpError& e) {
    // Keep every good sample: close the file under its final name, then report.
    if (opt.progress && tty) std::fprintf(stderr, "\n");
    file.close();
    std::filesystem::rename(tmp, opt.out_path);
    throw BlowUpError(std::string(e.what()) + ". Every sample before the blow-up is in " + opt.out_path);
  }
  step_wall = std::chrono::duration<double>(Clock::now() - t0).count();
  if (opt.progress && tty) std::fprintf(stderr, "\n");
  output([&] {
    write_checkpoint(ckpt_path, sim.checkpoint());
    file.close();
  });
  RunSummary r;
  r.profile = prof.report(std::chrono::duration<double>(Clock::now() - t0).count(), sim.time() - (opt.resume ? opt.resume->t : 0.0),
                          sim.schedule().numa_nodes(), scheduler_name(opt.schedule.kind));
  // SWMR allows no new objects: the profile goes in after the file is closed.
  {
    H5File f = H5File::open(tmp);
    write_profile(f, r.profile);
    f.close();
  }
  if (!opt.profile_json.empty()) {
    std::ofstream js(opt.profile_json);
    js << profile_json(r.profile);
    if (!js) throw std::runtime_error("cannot write the profile to '" + opt.profile_json + "'");
  }
  std::filesystem::rename(tmp, opt.out_path);

  r.steps = done - start;
  r.interrupted = g_stop_signal != 0;
  r.signal = g_stop_signal;
  r.model_time = sim.time();
  r.wall_s = step_wall;
  r.us_per_step = 1e6 * step_wall / std::max(1L, done - start);
  r.model_s_per_hour = (done - start) * h / step_wall * 3600.0;
  // Means over the last 20 % of the samples; efficiency as the ratio of mean powers.
  const size_t from = samples.size() - std::max<size_t>(1, samples.size() / 5);
  double pin = 0, pout = 0;
  size_t cnt = 0;
  for (size_t i = from; i < samples.size(); ++i, ++cnt) {
    const Sample& s = samples[i];
    r.speed_ratio += s.speed_ratio;
    r.geometric_ratio += s.geometric_ratio;
    r.input_torque += s.input_torque;
    r.output_torque += s.output_torque;
    r.load_torque += s.load_torque;
    pin += s.input_torque * s.input_speed;
    pout += s.output_torque * s.output_speed;
  }
  r.speed_ratio /= cnt;
  r.geometric_ratio /= cnt;
  r.input_torque /= cnt;
  r.output_torque /= cnt;
  r.load_torque /= cnt;
  r.efficiency = pin != 0 ? pout / pin : 0.0;
  // 1 - D / W_in over the same window: unlike the ratio of mean powers, it does not see
  // energy swinging in and out of the torsion springs and inertias.
  const Sample& a = samples[from];
  const Sample& b = samples.back();
  const double win = b.work_input - a.work_input;
  r.loss_efficiency = win > 0 ? 1.0 - (b.work_dissipated - a.work_dissipated) / win : 0.0;
  r.energy_residual = samples.back().energy_residual;
  r.work_input = samples.back().work_input;
  return r;
}

}  // namespace cvt
