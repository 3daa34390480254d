#include "engine/base/fingerprint.hpp"
#include "engine/base/timing.hpp"
#include "engine/studies/integrators.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <memory>

#include "engine/guards.hpp"
#include "engine/ode/ode.hpp"
#include "engine/io/checkpoint.hpp"
#include "engine/wmethod/driver.hpp"
#include "engine/rhs/rhs.hpp"
#include "engine/run.hpp"
#include "engine/simulation.hpp"
#include "modules/chain_forces.hpp"

namespace cvt {
namespace {

using Clock = WallClock;
const double kNaN = std::numeric_limits<double>::quiet_NaN();

// Axial forces of both halves of every pin [2N], and whether any end of each half touches
// a sheave in the current statuses [2N].
void pin_forces(const Model& m, const Eigen::VectorXd& y, const ContactStatus& st, std::vector<double>& f,
                std::vector<int>& touching) {
  const int N = m.links;
  f.resize(2 * N), touching.resize(2 * N);
  const double* q = y.data();
  const double* v = q + m.ndof;
  for (int j = 0; j < N; ++j)
    for (int h = 0; h < 2; ++h) {
      f[2 * j + h] = half_axial_force(m, q, v, h == 0 ? m.half_a(j) : m.half_b(j));
      int any = 0;
      for (int e = 0; e < 2; ++e)
        for (int k = 0; k < 2; ++k) any |= st.pulley[ContactStatus::pulley_index(j, h, e, k)];
      touching[2 * j + h] = any;
    }
}

struct CurveRun {
  std::string method, param_kind;  // "h" or "tol"
  double param = 0;
  bool w_adaptive = false;         // a W-method at a tolerance, as `cvt-engine run` takes it
  std::string status = "ok";       // ok | blow-up | timeout | error
  std::string why;                 // a blow-up's or error's message
  double deviation = kNaN;         // max |F - F_ref| / range(F_ref)
  double wall_s = 0;
  long long rhs = 0, jac = 0, lu = 0, steps = 0, rejected = 0, newton_failures = 0, newton_iterations = 0;
  double jac_s = 0, lu_s = 0, solve_s = 0;
  long long status_rebuilds = 0;  // ROS2: matrix rebuilds forced by contact status changes
  long long fresh_contacts = 0, fresh_rebuilds = 0;  // W-methods: ModelOde::w_fresh_contacts / w_fresh_rebuilds
  int w_every = 0, w_k_every = 0;  // ROS2: its matrix intervals
  std::vector<double> walls;       // each repeat's wall time
  double reached = kNaN;  // model time covered when stopped by the timeout [s]
  double h_mean = 0;
  bool chosen = false;
  std::vector<double> curve;  // the tracked half's axial force at the sample times
};

struct OneStep {
  std::string method;
  double h = 0, err_pos = kNaN, err_vel = kNaN;
};

// IntegratorStudyOptions::perturb: q_i += eps |q_i| u_i, u_i uniform in [-1, 1) from splitmix64 (the
// same numbers on every platform, unlike the standard distributions).
void perturb_positions(const Model& m, Eigen::VectorXd& y, double eps, std::uint64_t seed) {
  std::uint64_t x = seed;
  for (int i = 0; i < m.ndof; ++i) {
    std::uint64_t z = (x += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    z ^= z >> 31;
    const double u = static_cast<double>(z >> 11) * 0x1.0p-53 * 2.0 - 1.0;
    y[i] += eps * std::abs(y[i]) * u;
  }
}

// Largest |difference| over pin positions [m] and pin velocities [m/s].
void state_errors(const Model& m, const Eigen::VectorXd& a, const Eigen::VectorXd& b, double& ep, double& ev) {
  const int pins = kJointSize * m.links, n = m.ndof;
  ep = (a.head(pins) - b.head(pins)).cwiseAbs().maxCoeff();
  ev = (a.segment(n, pins) - b.segment(n, pins)).cwiseAbs().maxCoeff();
  if (!a.allFinite()) ep = ev = kNaN;
}

// The driver's counts and times into r; ROS2's stiffness differences run inside its
// w_factor: reported as the Jacobian's, not the factorization's.
void take_stats(const OdeDriver& drv, CurveRun& r) {
  const OdeStats& st = drv.stats();
  r.rhs = drv.rhs_evals(), r.jac = drv.model_ode().jacobian_evals(), r.lu = st.lu_factorizations;
  r.steps = st.steps, r.rejected = st.rejected, r.newton_failures = st.newton_failures;
  r.newton_iterations = st.newton_iterations;
  r.jac_s = st.jac_seconds + drv.model_ode().w_stiffness_seconds();
  r.lu_s = st.lu_seconds - drv.model_ode().w_stiffness_seconds();
  r.solve_s = st.solve_seconds;
  r.status_rebuilds = drv.model_ode().w_status_rebuilds();
  r.fresh_contacts = drv.model_ode().w_fresh_contacts();
  r.fresh_rebuilds = drv.model_ode().w_fresh_rebuilds();
}

// The resolved configuration without its [integrator] section: the study's RK4 runs set
// their method and step and read no other integrator key.
std::string without_integrator(const std::string& toml) {
  std::string out;
  bool skip = false;
  std::size_t a = 0;
  while (a < toml.size()) {
    std::size_t b = toml.find('\n', a);
    b = b == std::string::npos ? toml.size() : b + 1;
    const std::string line = toml.substr(a, b - a);
    if (!line.empty() && line[0] == '[') skip = line.rfind("[integrator]", 0) == 0;
    if (!skip) out += line;
    a = b;
  }
  return out;
}

// The study's cache (--cache DIR): the running state and the reference curve depend only on
// the resolved configuration (its physics and run keys), t_warm, t_sample, sample_dt and
// ref_step (the bits are the same on any thread count), so they are kept under a key of
// those and reused.
struct StudyCache {
  std::string ckpt, ref;  // empty: no cache
  StudyCache(const Model& m, const IntegratorStudyOptions& opt) {
    if (opt.cache_dir.empty()) return;
    char warm[64], curve[128];
    std::snprintf(warm, sizeof warm, "|%.17g", opt.t_warm);
    std::snprintf(curve, sizeof curve, "|%.17g|%.17g|%.17g", opt.t_sample, opt.sample_dt, opt.ref_step);
    const std::string physics = without_integrator(m.cfg.resolved_toml);
    ckpt = opt.cache_dir + "/study-" + fingerprint(physics + warm) + ".ckpt";
    ref = opt.cache_dir + "/study-" + fingerprint(physics + warm + curve) + "-reference.txt";
  }
  static bool exists(const std::string& p) { return !p.empty() && std::ifstream(p).good(); }
};

struct Reference {
  int tracked = -1;
  double wall = 0;
  std::vector<double> curve;
  std::vector<int> touch;  // the tracked half touches a sheave at each sample
};

void write_reference(const std::string& path, const Reference& r) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream f(tmp);
    f << "# cvt-engine study integrators: reference curve (tracked half, wall s, then sample force touch)\n";
    char buf[64];
    f << r.tracked << " " << r.curve.size() << "\n";
    std::snprintf(buf, sizeof buf, "%.17g", r.wall);
    f << buf << "\n";
    for (size_t k = 0; k < r.curve.size(); ++k) {
      std::snprintf(buf, sizeof buf, "%.17g", r.curve[k]);
      f << buf << " " << r.touch[k] << "\n";
    }
    if (!f) throw std::runtime_error("cannot write the study cache " + tmp);
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) throw std::runtime_error("cannot rename " + tmp + " to " + path);
}

Reference read_reference(const std::string& path, size_t samples) {
  std::ifstream f(path);
  std::string comment;
  std::getline(f, comment);
  Reference r;
  size_t n = 0;
  f >> r.tracked >> n >> r.wall;
  r.curve.resize(n), r.touch.resize(n);
  for (size_t k = 0; k < n; ++k) f >> r.curve[k] >> r.touch[k];
  if (!f || n != samples || r.tracked < 0)
    throw std::runtime_error("the study cache " + path + " is damaged (delete it to recompute)");
  return r;
}

}  // namespace

std::vector<IntegratorStudyOptions::WCandidate> parse_w_candidates(const std::vector<std::string>& items) {
  std::vector<IntegratorStudyOptions::WCandidate> out;
  for (const std::string& entry : items) {
    IntegratorStudyOptions::WCandidate c;
    const size_t at = entry.find('@');
    const std::string item = at == std::string::npos ? entry : entry.substr(at + 1);
    if (at != std::string::npos) {
      c.method = entry.substr(0, at);
      bool w = false;
      try {
        w = is_w_method(parse_ode_method(c.method));
      } catch (const std::invalid_argument&) {
      }
      if (!w)
        throw std::invalid_argument("--w-steps: '" + entry +
                                    "' names no W-method (ros2, ros34pw2, ros34prw) before '@'");
    }
    char tail = 0;
    const bool tol = item.rfind("tol=", 0) == 0;
    const int n = std::sscanf(item.c_str() + (tol ? 4 : 0), "%lf:%d:%d%c", &c.h, &c.w_every, &c.w_k_every, &tail);
    const bool plain = n == 1 && item.find(':') == std::string::npos;
    if (!(plain || n == 3) || !(c.h > 0) ||
        (n == 3 && (c.w_every < 1 || c.w_k_every < 1 || c.w_k_every % c.w_every != 0)))
      throw std::invalid_argument("--w-steps: '" + entry +
                                  "' is not [METHOD@]H, [METHOD@]tol=T or either with :W:K (a step > 0 s, a tolerance > 0; K "
                                  "a positive multiple of W > 0)");
    if (plain) c.w_every = c.w_k_every = 0;
    if (tol) c.tol = c.h, c.h = 0;
    out.push_back(c);
  }
  return out;
}

namespace {

// One integrator study (docs/integrators.md 13), in the order it runs: the running state
// (RK4 at the production step, or the cache), (a) the error after one step against h, (b)
// the reference curve and each method's candidates on it, the repeats, the table, the CSV.
class Study {
 public:
  Study(const Model& model, const IntegratorStudyOptions& opt);
  void running_state();
  void one_step_errors();
  void reference_curve();
  void candidates();
  void repeats();
  void table() const;
  void write_csv() const;

 private:
  static Model rk4_model(const Model& model, const IntegratorStudyOptions& opt);
  void matrix_options();
  Reference compute_reference(long n_samples) const;
  CurveRun run_once(const std::string& name, double p, int w_every, int w_k_every, bool w_tol = false) const;
  void check_divides_samples(double h) const;
  void rk4_curve(Simulation& s, double h, CurveRun& r, WallClock::time_point w0) const;
  void driver_curve(Simulation& s, OdeMethod method, double p, int w_every, int w_k_every, bool w_tol, CurveRun& r,
                    WallClock::time_point w0) const;
  void sample(Simulation& s, CurveRun& r) const;
  double deviation(const std::vector<double>& c) const;

  const IntegratorStudyOptions& opt_;
  const Model m_;  // the configuration with RK4 at the study's production step (opt.warm_step)
  const StudyCache cache_;
  Checkpoint start_;  // the running state
  double t0_ = 0;
  OdeOptions base_;
  ModelOdeOptions jac_opt_;
  std::vector<OneStep> one_;
  std::vector<CurveRun> runs_;
  std::vector<double> times_, ref_curve_;
  int tracked_ = -1;
  double range_ = 1, ref_wall_ = 0;
  bool ref_from_cache_ = false;
};

// The running state, the reference and the RK4 candidates are RK4 whatever the
// configuration's method (the W candidates name theirs); the running state at RK4's
// production step, 1e-8 s. The cache stays keyed on the configuration as given.
Model Study::rk4_model(const Model& model, const IntegratorStudyOptions& opt) {
  Config rk4_cfg = model.cfg;
  rk4_cfg.integrator.method = IntegratorMethod::rk4;
  rk4_cfg.integrator.step = opt.warm_step;
  return build_model(rk4_cfg);
}

Study::Study(const Model& model, const IntegratorStudyOptions& opt)
    : opt_(opt), m_(rk4_model(model, opt)), cache_(m_, opt) {
  matrix_options();
}

// The solvers' options: Newton's, and the model's as an ODE system, scaled and shifted
// (ModelOdeOptions::scaled: tolerances in units of 1 um, 1 mm/s, 1 mJ), with the study's
// matrix settings over the configuration's (w_run_options: the one mapping of [integrator]).
void Study::matrix_options() {
  base_.newton_max_iter = opt_.newton_max_iter;
  base_.jac_theta = opt_.jac_theta;
  base_.max_norm = opt_.max_norm;
  jac_opt_ = w_run_options(m_.cfg, m_.cfg.integrator.step, false).jac;
  jac_opt_.exact_dense_rows = opt_.exact_dense_rows;
  jac_opt_.scaled = true;
  jac_opt_.freeze_friction = opt_.freeze_friction;
  if (opt_.w_every < 1 || opt_.w_k_every < 1 || opt_.w_k_every % opt_.w_every != 0)
    throw std::invalid_argument("--w-k-every must be a multiple of --w-every");
  jac_opt_.w_every = opt_.w_every;
  jac_opt_.w_k_every = opt_.w_k_every;
  jac_opt_.w_stiffness = !opt_.w_no_stiffness;
  if (opt_.w_secant >= 0) jac_opt_.w_secant = opt_.w_secant != 0;
  if (opt_.w_fresh >= 0) jac_opt_.w_fresh = opt_.w_fresh;
  if (opt_.w_fresh_max > 0) jac_opt_.w_fresh_max = opt_.w_fresh_max;
  jac_opt_.w_status_rebuild = opt_.w_status_rebuild;
  jac_opt_.w_blocks = !opt_.ros2_full_jacobian;
}

// RK4 at the production step to opt.t_warm (or the cache), then the Jacobian's size and
// the spectral radius there.
void Study::running_state() {
  const double h_prod = m_.cfg.integrator.step;
  Simulation warm(m_, opt_.schedule);
  const long warm_steps = std::lround(opt_.t_warm / h_prod);
  std::printf("integrator study: %d links, %d unknowns; running state: RK4 h = %.3g s to t = %.4g s ...\n", m_.links,
              m_.nstate, h_prod, warm_steps * h_prod);
  std::fflush(stdout);
  if (!cache_.ckpt.empty())
    std::printf("  (cache: running state %s, reference %s)\n", cache_.ckpt.c_str(), cache_.ref.c_str());
  if (StudyCache::exists(cache_.ckpt)) {
    const Checkpoint c = read_checkpoint(cache_.ckpt);
    if (without_integrator(c.config_toml) != without_integrator(m_.cfg.resolved_toml))
      throw std::runtime_error("the study cache " + cache_.ckpt + " is of another configuration");
    warm.restore(c);
    std::printf("  (running state from the cache %s)\n", cache_.ckpt.c_str());
  } else {
    for (long k = 0; k < warm_steps; ++k) warm.step(h_prod);
    if (!cache_.ckpt.empty()) write_checkpoint(cache_.ckpt, warm.checkpoint());
  }
  start_ = warm.checkpoint();
  t0_ = warm.time();
  Workspace ws(m_);
  auto sched = make_schedule(m_, ws, ScheduleOptions{});
  ModelOde probe(m_, ws, *sched, ModelOdeOptions{2, opt_.exact_dense_rows});
  const double rho = warm.spectral_radius(start_.state, t0_, warm.workspace().status);
  std::printf("spectral radius of df/dy at the running state: about %.3g 1/s (RK4 stable for h up to about "
              "%.3g s)\n", rho, 2.8 / rho);
  std::printf("Jacobian: %ld nonzeros (%s dense rows), %d colours (RHS evaluations per Jacobian: %d)\n",
              static_cast<long>(probe.system().sparsity.nonZeros()), opt_.exact_dense_rows ? "exact" : "approximate",
              probe.colors(), probe.colors() + 1);
}

// (a) The error after one step of each method and h from the running state, against RK4
// with a small step, the statuses frozen.
void Study::one_step_errors() {
  std::vector<double> hs = opt_.one_step_h;
  std::sort(hs.begin(), hs.end());
  std::vector<Eigen::VectorXd> ref(hs.size());  // the reference at every h
  {
    Simulation s(m_, ScheduleOptions{});
    s.restore(start_);
    long done = 0;
    for (size_t i = 0; i < hs.size(); ++i) {
      const long want = std::lround(hs[i] / opt_.one_step_ref);
      for (; done < want; ++done) s.step(opt_.one_step_ref, false);
      ref[i] = s.state();
    }
  }
  std::printf("\n(a) error after one step from t = %.4g s against RK4 with h = %.3g s (statuses frozen)\n", t0_,
              opt_.one_step_ref);
  std::printf("%-10s %10s %14s %14s\n", "method", "h [s]", "pos err [m]", "vel err [m/s]");
  for (const std::string& name : opt_.methods) {
    const OdeMethod method = parse_ode_method(name);
    for (size_t i = 0; i < hs.size(); ++i) {
      Workspace ws(m_);
      ws.status.rocker = start_.rocker;
      ws.status.pulley = start_.pulley;
      auto sched = make_schedule(m_, ws, ScheduleOptions{});
      ModelOde ode(m_, ws, *sched, jac_opt_);
      OdeOptions o = base_;
      o.atol = o.rtol = 1e-3;
      o.fixed_step = true;
      o.h0 = hs[i];
      OneStep r{name, hs[i]};
      if (is_implicit_method(method) && opt_.freeze_friction && m_.cfg.friction.law == FrictionLaw::nonsmooth)
        ode.record_friction_branches();
      if (is_w_method(method) && !opt_.ros2_full_jacobian) ode.ask_friction_jacobian(0);  // the W-method's matrix
      ode.offset() = start_.state;
      Eigen::VectorXd z;
      ode.to_z(start_.state, z);
      try {
        OdeSolver solver(ode.system(), method, o);
        solver.integrate(t0_, t0_ + hs[i], z);
        Eigen::VectorXd y;
        ode.to_y(z, y);
        state_errors(m_, y, ref[i], r.err_pos, r.err_vel);
      } catch (const std::exception&) {
      }
      std::printf("%-10s %10.3g %14.4g %14.4g\n", name.c_str(), r.h, r.err_pos, r.err_vel);
      one_.push_back(r);
    }
  }
  std::fflush(stdout);
}

// (b) The reference curve: production RK4 at ref_step, the axial force of every pin half at
// the sample times; the tracked half is one that starts off the sheaves and touches them
// from 10 % .. 60 % of the window on, among those the one with the largest range.
Reference Study::compute_reference(long n_samples) const {
  Reference ref;
  std::vector<std::vector<double>> all_f;
  std::vector<std::vector<int>> all_touch;
  Simulation s(m_, opt_.schedule);
  s.restore(start_);
  s.set_clock(t0_, 0);
  std::vector<double> f;
  std::vector<int> touch;
  const auto w0 = Clock::now();
  pin_forces(m_, s.state(), s.workspace().status, f, touch);
  all_f.push_back(f), all_touch.push_back(touch);
  const long per = std::lround(opt_.sample_dt / opt_.ref_step);
  for (long k = 1; k <= n_samples; ++k) {
    for (long i = 0; i < per; ++i) s.step(opt_.ref_step);
    pin_forces(m_, s.state(), s.workspace().status, f, touch);
    all_f.push_back(f), all_touch.push_back(touch);
  }
  ref.wall = seconds_since(w0);
  double best_range = -1;
  for (int i = 0; i < 2 * m_.links; ++i) {
    if (all_touch[0][i]) continue;
    long first = -1;
    for (long k = 0; k <= n_samples; ++k)
      if (all_touch[k][i]) {
        first = k;
        break;
      }
    if (first < 0) continue;
    const bool early_enough = first <= 0.6 * n_samples, late_enough = first >= 0.1 * n_samples;
    double lo = 1e300, hi = -1e300;
    for (long k = 0; k <= n_samples; ++k) lo = std::min(lo, all_f[k][i]), hi = std::max(hi, all_f[k][i]);
    const double score = (hi - lo) * (early_enough && late_enough ? 1.0 : 1e-3);
    if (score > best_range) best_range = score, ref.tracked = i;
  }
  if (ref.tracked < 0) ref.tracked = 0;  // nothing enters in this window: take pin 0, half a
  for (long k = 0; k <= n_samples; ++k)
    ref.curve.push_back(all_f[k][ref.tracked]), ref.touch.push_back(all_touch[k][ref.tracked]);
  return ref;
}

// The sample times, the reference curve (computed, or from the cache) and its range.
void Study::reference_curve() {
  const long n_samples = std::max(1L, std::lround(opt_.t_sample / opt_.sample_dt));
  for (long k = 0; k <= n_samples; ++k) times_.push_back(t0_ + k * opt_.sample_dt);
  Reference ref;
  ref_from_cache_ = StudyCache::exists(cache_.ref);
  if (ref_from_cache_) {
    ref = read_reference(cache_.ref, times_.size());
    std::printf("  (reference curve from the cache %s)\n", cache_.ref.c_str());
  } else {
    ref = compute_reference(n_samples);
    if (!cache_.ref.empty()) write_reference(cache_.ref, ref);
  }
  tracked_ = ref.tracked;
  ref_wall_ = ref.wall;
  ref_curve_ = ref.curve;
  const double lo = *std::min_element(ref_curve_.begin(), ref_curve_.end());
  const double hi = *std::max_element(ref_curve_.begin(), ref_curve_.end());
  range_ = std::max(hi - lo, 1e-12);
  long enters = -1;
  for (long k = 0; k <= n_samples; ++k)
    if (ref.touch[k]) {
      enters = k;
      break;
    }
  std::printf("\n(b) sample curve: axial force of pin %d, half %c over %.4g .. %.4g s (enters a pulley at %.4g s); "
              "reference RK4 h = %.3g s: range %.1f .. %.1f N, %.2f s wall\n",
              tracked_ / 2, tracked_ % 2 ? 'b' : 'a', t0_, times_.back(), enters >= 0 ? times_[enters] : kNaN,
              opt_.ref_step, lo, hi, ref_wall_);
  if (opt_.perturb > 0)
    std::printf("  every run starts from the running state with its positions moved by %.3g |q| u (seed %llu)\n",
                opt_.perturb, static_cast<unsigned long long>(opt_.seed));
  std::fflush(stdout);
}

double Study::deviation(const std::vector<double>& c) const {
  double d = 0;
  for (size_t k = 0; k < c.size(); ++k) d = std::max(d, std::abs(c[k] - ref_curve_[k]));
  return c.size() == ref_curve_.size() ? d / range_ : kNaN;
}

// The tracked half's force at the state of s into r's curve; a blow-up is a state not
// finite or a force far out of the reference's range.
void Study::sample(Simulation& s, CurveRun& r) const {
  std::vector<double> f;
  std::vector<int> touch;
  pin_forces(m_, s.state(), s.workspace().status, f, touch);
  r.curve.push_back(f[tracked_]);
  char b[160];
  if (!s.state().allFinite())
    std::snprintf(b, sizeof b, "the state is not finite at t = %.9g s", s.time());
  else if (std::abs(f[tracked_]) > 1e3 * range_ + 1e6)
    std::snprintf(b, sizeof b, "the tracked force is %.3g N at t = %.9g s, far outside the reference's range", f[tracked_],
                  s.time());
  else
    return;
  throw BlowUpError(b);
}

// A fixed-step candidate's step must divide the sample spacing (its row an error otherwise).
void Study::check_divides_samples(double h) const {
  if (divides(h, opt_.sample_dt)) return;
  char b[160];
  std::snprintf(b, sizeof b, "the step %.6g s does not divide the sample spacing %.6g s (--sample-dt)", h,
                opt_.sample_dt);
  throw std::invalid_argument(b);
}

// RK4 candidates: the production path (Simulation::step, fused stage update).
void Study::rk4_curve(Simulation& s, double h, CurveRun& r, WallClock::time_point w0) const {
  check_divides_samples(h);
  const long per = std::lround(opt_.sample_dt / h);
  for (size_t k = 1; k < times_.size(); ++k) {
    for (long i = 0; i < per; ++i) s.step(h);
    r.steps += per, r.rhs += 4 * per;
    sample(s, r);
    if (seconds_since(w0) > opt_.max_wall) throw std::runtime_error("timeout");
  }
}

// The other methods through an OdeDriver: tolerance p, or the W-methods' fixed step p with
// their matrix intervals. Fixed-step W-methods as `cvt-engine run` takes them: unscaled
// (the units only serve error norms, which fixed steps do not use).
void Study::driver_curve(Simulation& s, OdeMethod method, double p, int w_every, int w_k_every, bool w_tol,
                         CurveRun& r, WallClock::time_point w0) const {
  const bool w_fixed = is_w_method(method) && !opt_.w_steps.empty() && !w_tol;
  OdeRunOptions ro;
  ro.method = method;
  ro.ode = base_;
  ro.ode.atol = ro.ode.rtol = p;
  ro.ode.h0 = 1e-8;
  if (w_fixed) {
    // (The driver ends its steps on the sample times: a step that does not divide their
    // spacing would be cut to it at every sample, and the row would not be the step it names.)
    check_divides_samples(p);
    ro.ode.fixed_step = true;
    ro.ode.h0 = p;
  }
  ro.ode.w_reuse_steps = opt_.w_every;  // ROS2 with the full Jacobian
  ro.jac = jac_opt_;
  if (is_w_method(method)) ro.jac.w_every = w_every, ro.jac.w_k_every = w_k_every;
  if (w_fixed) ro.jac.scaled = false;
  if (is_implicit_method(method) && opt_.newton_w) {
    ro.ode.newton_uses_w = true;
    ro.jac.w_h_grow = ro.jac.w_h_shrink = 1.25;  // Newton contracts with a matrix for a nearby d h
  }
  if (opt_.chain_norm && !w_fixed) ro.jac.error_tol = p;
  if (is_sundials_method(method)) {
    // SUNDIALS' own error control over the unscaled state (a history that goes on from step
    // to step needs the same state in every piece; the scaled system moves its offset to each
    // piece's start): absolute tolerances p x (1 um, 1 mm/s, 1 mJ), the scaled units.
    ModelOdeOptions units = ro.jac;
    units.scaled = true;
    const Eigen::VectorXd u = model_state_units(m_, units);
    ro.jac.scaled = false;
    ro.jac.error_tol = 0;
    ro.ode.rtol = 0;
    ro.ode.atol_vector.resize(u.size());
    for (int i = 0; i < u.size(); ++i) ro.ode.atol_vector[i] = p * u[i];
  }
  if (w_tol) {  // adaptive as `cvt-engine run` takes it
    ro.ode.h0 = m_.cfg.integrator.step;
    w_adaptive_options(ro, p, opt_.sample_dt);
  }
  ro.status_interval = opt_.status_interval;
  OdeDriver drv(s.model(), s.workspace(), s.schedule(), ro);
  try {
    for (size_t k = 1; k < times_.size(); ++k) {
      s.advance(drv, times_[k]);
      sample(s, r);
      if (seconds_since(w0) > opt_.max_wall) {
        r.reached = times_[k] - t0_;
        throw std::runtime_error("timeout");
      }
    }
  } catch (...) {
    take_stats(drv, r);  // a blow-up's or an error's row shows the work done until it
    throw;
  }
  take_stats(drv, r);
}

// One run of a candidate of a method (step or tolerance p; W-methods: their matrix
// intervals) from the running state over the window.
CurveRun Study::run_once(const std::string& name, double p, int w_every, int w_k_every, bool w_tol) const {
  const OdeMethod method = parse_ode_method(name);
  const bool fixed = method == OdeMethod::Rk4;
  const bool w_fixed = is_w_method(method) && !opt_.w_steps.empty() && !w_tol;
  CurveRun r;
  r.method = name, r.param_kind = fixed || w_fixed ? "h" : "tol", r.param = p, r.w_adaptive = w_tol;
  r.w_every = w_every, r.w_k_every = w_k_every;
  Simulation s(m_, opt_.schedule);
  s.restore(start_);
  s.set_clock(t0_, 0);
  if (opt_.perturb > 0) perturb_positions(m_, s.mutable_state(), opt_.perturb, opt_.seed);
  std::vector<double> f;
  std::vector<int> touch;
  pin_forces(m_, s.state(), s.workspace().status, f, touch);
  r.curve.push_back(f[tracked_]);
  const auto w0 = Clock::now();
  try {
    if (fixed)
      rk4_curve(s, p, r, w0);
    else
      driver_curve(s, method, p, w_every, w_k_every, w_tol, r, w0);
  } catch (const BlowUpError& e) {
    r.status = "blow-up", r.why = e.what();
  } catch (const OdeError& e) {  // a step-size underflow: a numerical failure, reported like a blow-up
    r.status = "blow-up", r.why = std::string("numerical failure: ") + e.what();
  } catch (const NumericalFailure& e) {
    r.status = "blow-up", r.why = std::string("numerical failure: ") + e.what();
  } catch (const std::exception& e) {
    r.status = std::string(e.what()) == "timeout" ? "timeout" : std::string("error");
    if (r.status == "error") r.why = e.what();
  }
  r.wall_s = seconds_since(w0);
  return r;
}

// Each method's candidates, largest step or loosest tolerance first; the first accurate
// one is chosen, and (without --all) the others are not run.
void Study::candidates() {
  for (const std::string& name : opt_.methods) {
    const OdeMethod method = parse_ode_method(name);
    const bool fixed = method == OdeMethod::Rk4;
    const bool w_fixed = is_w_method(method) && !opt_.w_steps.empty();
    std::vector<IntegratorStudyOptions::WCandidate> cands;
    if (w_fixed) {
      for (const auto& c : opt_.w_steps)
        if (c.method.empty() || c.method == name) cands.push_back(c);
    } else {
      for (double p : fixed ? opt_.rk4_steps : opt_.tolerances) cands.push_back({p});
    }
    bool found = false;
    for (const auto& cand : cands) {
      const double p = cand.tol > 0 ? cand.tol : cand.h;
      const bool own = is_w_method(method) && cand.w_every > 0;  // H:W:K
      const int we = !is_w_method(method) ? 0 : own ? cand.w_every : opt_.w_every;
      const int wk = !is_w_method(method) ? 0 : own ? cand.w_k_every : opt_.w_k_every;
      // The first round; --repeat adds rounds over all runs (repeats()).
      CurveRun r = run_once(name, p, we, wk, cand.tol > 0);
      r.walls = {r.wall_s};
      // (A blow-up or an error stops the run somewhere in the window: no mean step.)
      r.h_mean = r.steps > 0 && (r.status == "ok" || r.status == "timeout")
                     ? (r.status == "timeout" ? r.reached : times_.back() - t0_) / r.steps
                     : kNaN;
      if (r.status == "timeout")
        std::printf("  (%s %s %.3g stopped after %.3g s of model time)\n", name.c_str(), r.param_kind.c_str(), p, r.reached);
      if (r.status == "ok") r.deviation = deviation(r.curve);
      const bool good = r.status == "ok" && r.deviation <= opt_.max_deviation;
      if (good && !found) r.chosen = found = true;
      if (r.w_every > 0) std::printf("  (W matrix every %d steps, its stiffness every %d)\n", r.w_every, r.w_k_every);
      std::printf("  %-10s %-3s %-8.3g %-8s dev %8.3f %%  wall %8.2f s  rhs %9lld  jac %5lld  lu %6lld  steps %8lld "
                  "(rej %lld, Newton it %lld, fail %lld)  mean h %.3g s  [jac %.1f s, LU %.1f s, solves %.1f s]%s\n",
                  name.c_str(), r.param_kind.c_str(), p, r.status.c_str(), 100 * r.deviation, r.wall_s, r.rhs, r.jac,
                  r.lu, r.steps, r.rejected, r.newton_iterations, r.newton_failures, r.h_mean, r.jac_s, r.lu_s, r.solve_s,
                  r.chosen ? "  <- chosen" : "");
      if (!r.why.empty()) std::printf("             (%s: %s)\n", r.status.c_str(), r.why.c_str());
      if (is_w_method(method) && !opt_.ros2_full_jacobian)
        std::printf("             (%s: %lld of its matrix rebuilds forced by contact status changes; fresh friction: "
                    "%lld contacts corrected, %lld rebuilds forced)\n",
                    name.c_str(), r.status_rebuilds, r.fresh_contacts, r.fresh_rebuilds);
      std::fflush(stdout);
      runs_.push_back(std::move(r));
      if (found && !opt_.all) break;
    }
  }
}

// The repeats (--repeat N): N - 1 more rounds over every finished run, in the study's order,
// so that RK4 and the others meet the machine's drifting load alike (the ratios are what
// counts); the same bits every time; each run's wall time is its median.
void Study::repeats() {
  for (int rep = 1; rep < opt_.repeat; ++rep)
    for (CurveRun& r : runs_) {
      if (r.status != "ok") continue;
      CurveRun again = run_once(r.method, r.param, r.w_every, r.w_k_every, r.w_adaptive);
      if (again.status != r.status || again.curve != r.curve)
        throw std::runtime_error("study: a repeated run of " + r.method + " gave other bits (not reproducible)");
      r.walls.push_back(again.wall_s);
    }
  if (opt_.repeat <= 1) return;
  std::printf("\nrepeats, in %d rounds over the runs (wall s, round by round; the median counts):\n", opt_.repeat);
  for (CurveRun& r : runs_) {
    if (r.walls.size() < 2) continue;
    std::printf("  %-10s %s %-8.3g", r.method.c_str(), r.param_kind.c_str(), r.param);
    if (r.w_every > 0) std::printf(" W%d/%d", r.w_every, r.w_k_every);
    std::printf(":");
    for (double w : r.walls) std::printf(" %.2f", w);
    r.wall_s = median(r.walls);
    std::printf("  -> %.2f\n", r.wall_s);
  }
}

// The summary table: every run that finished, against the chosen RK4 run of this study (*:
// each method's chosen run, its largest accurate step or loosest accurate tolerance).
void Study::table() const {
  double rk4_wall = kNaN;
  for (const CurveRun& r : runs_)
    if (r.chosen && r.method == "rk4") rk4_wall = r.wall_s;
  std::printf("\n%-10s %-22s %9s %10s %10s %6s %6s %9s %10s %12s\n", "method", "step/tol", "dev %", "wall s", "rhs",
              "jac", "lu", "steps", "mean h s", "vs rk4");
  for (const CurveRun& r : runs_) {
    if (r.status != "ok") continue;
    char p[48];
    if (r.w_every > 0)
      std::snprintf(p, sizeof p, "%s=%.3g W%d/%d%s", r.param_kind.c_str(), r.param, r.w_every, r.w_k_every,
                    r.chosen ? "*" : "");
    else
      std::snprintf(p, sizeof p, "%s=%.3g%s", r.param_kind.c_str(), r.param, r.chosen ? "*" : "");
    char vs[32] = "-";  // without an RK4 candidate in this study
    if (std::isfinite(rk4_wall) && rk4_wall > 0) std::snprintf(vs, sizeof vs, "%.2fx", rk4_wall / r.wall_s);
    std::printf("%-10s %-22s %9.3f %10.2f %10lld %6lld %6lld %9lld %10.3g %12s\n", r.method.c_str(), p,
                100 * r.deviation, r.wall_s, r.rhs, r.jac, r.lu, r.steps, r.h_mean, vs);
  }
  if (opt_.repeat > 1) std::printf("(wall s: the median of %d runs each)\n", opt_.repeat);
  std::printf("(reference RK4 h = %.3g s: %.2f s wall%s)\n", opt_.ref_step, ref_wall_,
              ref_from_cache_ ? ", from the cache: an earlier run's time" : "");
  for (const CurveRun& r : runs_)
    if (r.chosen)
      std::printf("  %-10s extrapolated to 1 s of model time: %.0f s (%.1f min)\n", r.method.c_str(),
                  r.wall_s / (times_.back() - t0_), r.wall_s / (times_.back() - t0_) / 60);
}

// --out FILE.csv: one row per one-step error and per run; the chosen runs' curves beside the
// reference in FILE-curves.csv.
void Study::write_csv() const {
  std::ofstream f(opt_.out_csv);
  f << "part,method,param_kind,param,h,err_pos_m,err_vel_m_s,status,deviation_percent,wall_s,rhs_evals,jac_evals,"
       "lu_factorizations,steps,rejected,newton_iterations,newton_failures,mean_h_s,jac_s,lu_s,solve_s,chosen,"
       "w_every,w_k_every,repeats\n";
  f.precision(10);
  for (const OneStep& r : one_)
    f << "one_step," << r.method << ",h," << r.h << "," << r.h << "," << r.err_pos << "," << r.err_vel
      << ",,,,,,,,,,,,,,,,,,\n";
  for (const CurveRun& r : runs_)
    f << "curve," << r.method << "," << r.param_kind << "," << r.param << ",,,," << r.status << ","
      << 100 * r.deviation << "," << r.wall_s << "," << r.rhs << "," << r.jac << "," << r.lu << "," << r.steps << ","
      << r.rejected << "," << r.newton_iterations << "," << r.newton_failures << "," << r.h_mean << "," << r.jac_s
      << "," << r.lu_s << "," << r.solve_s << "," << (r.chosen ? 1 : 0) << "," << r.w_every << "," << r.w_k_every
      << "," << std::max<size_t>(1, r.walls.size()) << "\n";
  if (!f) throw std::runtime_error("cannot write '" + opt_.out_csv + "'");
  if (times_.empty()) return;
  std::string cpath = opt_.out_csv;
  if (cpath.size() > 4 && cpath.substr(cpath.size() - 4) == ".csv") cpath.resize(cpath.size() - 4);
  cpath += "-curves.csv";
  std::ofstream c(cpath);
  c.precision(10);
  c << "t_s,reference";
  for (const CurveRun& r : runs_)
    if (r.chosen) c << "," << r.method;
  c << "\n";
  for (size_t k = 0; k < times_.size(); ++k) {
    c << times_[k] << "," << ref_curve_[k];
    for (const CurveRun& r : runs_)
      if (r.chosen) c << "," << r.curve[k];
    c << "\n";
  }
  std::printf("wrote %s and %s (pin %d, half %c)\n", opt_.out_csv.c_str(), cpath.c_str(), tracked_ / 2,
              tracked_ % 2 ? 'b' : 'a');
}

}  // namespace

int run_integrator_study(const Model& model, const IntegratorStudyOptions& opt) {
  Study study(model, opt);
  study.running_state();
  if (opt.one_step) study.one_step_errors();
  if (opt.curve) {
    study.reference_curve();
    study.candidates();
    study.repeats();
    study.table();
  }
  if (!opt.out_csv.empty()) study.write_csv();
  return 0;
}

}  // namespace cvt
