#include "engine/run.hpp"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <mutex>
#include <cmath>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <fstream>
#include <numeric>
#include <optional>
#include <utility>

#include "engine/base/timing.hpp"
#include "engine/io/files.hpp"
#include "engine/model/envelope.hpp"
#include "engine/ode/ode.hpp"
#include "engine/output.hpp"
#include "graph/side_job.hpp"

namespace cvt {

namespace {

long steps_for(double interval, double h) { return interval > 0 ? std::max(1L, std::lround(interval / h)) : 0; }

// SIGINT / SIGTERM / SIGHUP during a run: the step in progress finishes, the state at that
// moment is sampled, and the file is closed and kept (docs/cli.md, exit code 130).
volatile std::sig_atomic_t g_stop_signal = 0;
extern "C" void on_stop_signal(int sig) { g_stop_signal = sig; }

}  // namespace

// The handlers are installed by the first guard and the previous ones restored after the
// last: runs side by side in threads of one process (the Python module) share them, and a
// signal stops them all. A signal that arrives before a run starts (the command's guard
// holds them from its first instruction) stops that run at its first stop point.
std::mutex StopSignals::mutex_;
int StopSignals::active_ = 0;
static struct sigaction g_old_handlers[3];
static constexpr int kStopSignals[3] = {SIGINT, SIGTERM, SIGHUP};

StopSignals::StopSignals() {
  const std::lock_guard lock(mutex_);
  if (active_++ > 0) return;
  g_stop_signal = 0;
  struct sigaction sa {};
  sa.sa_handler = on_stop_signal;
  sigemptyset(&sa.sa_mask);
  for (int k = 0; k < 3; ++k) sigaction(kStopSignals[k], &sa, &g_old_handlers[k]);
}

StopSignals::~StopSignals() {
  const std::lock_guard lock(mutex_);
  if (--active_ > 0) return;
  for (int k = 0; k < 3; ++k) sigaction(kStopSignals[k], &g_old_handlers[k], nullptr);
}

int StopSignals::pending() { return g_stop_signal; }

namespace {

// The checks before anything is built: the step grid (exit 78), every output writable, a
// regular file or none, and no two of them one file (exit 73).
void checked(const Model& m, const RunOptions& opt, const std::string& ckpt_path) {
  check_step_grid(m.cfg);
  check_writable(opt.out_path, "output file", std::string(".partial").size());  // .lock, .ckpt (shorter)
  check_writable(ckpt_path, "checkpoint", std::string(".tmp").size());
  for (const std::string* p : {&opt.profile_json, &opt.summary_json})
    if (!p->empty()) check_writable(*p, "JSON file", std::string(".lock").size());
  check_distinct({}, {{"output file", opt.out_path}, {"checkpoint", ckpt_path}, {"summary JSON", opt.summary_json},
                      {"profile JSON", opt.profile_json}});
}

// The run's output held against a second writer (FILE.lock, exit 73), after the checks.
FileLock output_lock(const Model& m, const RunOptions& opt, const std::string& ckpt_path) {
  checked(m, opt, ckpt_path);
  return FileLock(opt.out_path + ".lock", "'" + opt.out_path + "'", true);
}

void write_text(const std::string& path, const std::string& text) {
  try {
    replace_file(path, text.data(), text.size());
  } catch (const std::runtime_error& e) {
    throw OutputError(e.what());
  }
}

// One run, in the order it happens: the checks and the simulation at its start
// (constructor), the output file opened and its series declared (open_output), the steps
// with their samples, snapshots, checkpoints, stops and progress (steps), and the end:
// the last checkpoint, the summary and the profile into the file, which gets its final
// name (finish).
class Run {
 public:
  Run(const Model& m, const RunOptions& opt);
  void open_output();
  void steps();
  [[noreturn]] void blown_up(const std::string& what);
  RunResult finish();

 private:
  void warn(const std::string& w);
  // Times f as the profile's output row (sampling, snapshots, flushes, checkpoints); a write
  // that fails (a full disk, an I/O error) ends the run (write_failed).
  template <class F>
  void output(F&& f) {
    const std::uint64_t k0 = Profiler::ticks();
    try {
      f();
    } catch (const std::exception& e) {
      write_failed(e.what());
    }
    prof_.add_output(Profiler::ticks() - k0);
  }
  [[noreturn]] void write_failed(const std::string& what);
  void record();
  void watch(const Sample& s);
  void snapshot();
  // The file writes of the step's sample and snapshot, staged by record() and snapshot():
  // started beside the steps (graph/side_job.hpp), and ended before anything else touches
  // the file (sync_writes).
  void start_writes();
  void sync_writes();
  // The checkpoint of the state now; with_verify: with the states kept for run.verify (a
  // run that goes on, or was cut short: its continuation verifies a window that starts
  // before it).
  Checkpoint checkpoint(bool with_verify) const;
  void progress(long n, WallClock::time_point now);
  bool steady_now();
  void plan_verify();
  void keep_for_verify(long n);
  void verify();
  // run.verify's progress, every progress_seconds: a line on stderr, or the callback
  // (RunProgress::verifying); false where the callback asks to stop.
  bool verify_progress(long done, long total, double t_end, WallClock::time_point t0);
  // The summary over the until-steady verdict's spans (whole periods of a swing) where they
  // decided, otherwise over the window from w0 in spans of half the judged window.
  void summarize_judged(const SummaryChannels& ch, RunSummary& s, double w0) const;

  const Model& m_;
  const Config& c_;
  const RunOptions& opt_;
  const double h_;
  const long total_, every_sample_, every_snapshot_;
  const bool append_;
  const std::string ckpt_path_, tmp_;
  FileLock lock_;  // one writer per output
  std::deque<FileLock> json_locks_;  // and per JSON file
  Simulation sim_;
  Profiler& prof_;
  long start_ = 0, rebuild_every_ = 1, checkpoint_every_ = 0, done_ = 0;
  std::string run_id_;
  std::optional<H5File> file_;  // opened by open_output
  std::unique_ptr<Recorder> rec_;
  FileHistory hist_;
  std::vector<Sample> samples_;  // the running efficiency's window (reaching back into the file)
  SummaryChannels channels_;
  std::vector<double> pos_, ten_, ends_, normal_;  // a snapshot
  Sample written_;  // the sample the writes hold
  double snapshot_t_ = 0;
  long snapshot_step_ = 0;
  bool write_sample_ = false, write_snapshot_ = false;
  RunResult r_;
  EnergyGuard energy_;
  bool warned_stability_ = false;
  // Gross slip (SteadyCriteria::gross_slip) at every sample since slip_from_ (< 0: not
  // slipping); warned once it has lasted run.efficiency_window, and named by a blow-up.
  const double gross_slip_ = SteadyCriteria::of(c_).gross_slip;
  double slip_from_ = -1;
  bool warned_slip_ = false;
  double slipped_from_ = -1, slipped_most_ = 0;  // the warned gross slip's start and largest slip
  bool stop_asked_ = false;  // RunOptions::on_progress returned false
  // run.max_wall: the stop is begun once the wall time since RunOptions::started comes
  // within wall_reserve() of it, which covers the wait for the next rebuild (at most 1 s)
  // and three times the longest flush and checkpoint so far (the last ones, and the summary).
  bool wall_stop_ = false;
  double longest_write_ = 0;
  bool wall_near() {
    if (wall_stop_ || !(c_.run.max_wall > 0)) return wall_stop_;
    const double reserve = std::min(0.5 * c_.run.max_wall, std::max(5.0, 1.0 + 3 * longest_write_));
    return wall_stop_ = seconds_since(opt_.started) >= c_.run.max_wall - reserve;
  }
  std::optional<WallClock::time_point> stop_seen_;  // when a stop was first seen
  // A stop is taken at the next step where the W matrix is rebuilt (its continuation then
  // repeats the uninterrupted run's bits), or at once where that is more than a second away
  // (slow steps: the start-up's sub-steps, many threads on few cores).
  bool stop_now(long n) {
    if (!stop_seen_) stop_seen_ = WallClock::now();
    return n % rebuild_every_ == 0 || n == total_ || seconds_since(*stop_seen_) > 1.0;
  }
  double next_stability_check_ = 0;
  const bool tty_ = isatty(fileno(stderr));
  WallClock::time_point t0_ = WallClock::now(), last_progress_ = t0_, last_flush_ = t0_;
  double step_wall_ = 0;
  long steps0_ = 0, rejected0_ = 0;  // the simulation's integrator steps at the start
  // run.until_steady: the windows' length, the first model time at which two fit after the
  // ramps, and the steps between checks (on the sample grid, at steps a continuation
  // repeats bit for bit).
  const bool until_ = c_.run.until_steady;
  double window_ = 0, first_check_ = 0;
  double judged_ = 0;  // the windows' length that decided (until_steady_verdict), else window_
  std::vector<double> judged_bounds_;  // its spans' bounds, where whole periods of a swing decided
  long check_every_ = 1;
  std::string stopped_ = "t_end";
  // run.verify: the states the summary's window may start from, kept in memory: at step
  // verify_at_ (a run to t_end: the last step before the window's start at which a
  // continuation repeats the bits), or every verify_every_ steps (run.until_steady: those
  // within reach of the last two windows).
  const bool verify_ = c_.run.verify;
  long verify_at_ = -1, verify_every_ = 0;
  std::deque<Checkpoint> verify_states_;
  SideJob writes_{sim_.schedule()};  // last: it ends its job before the file and buffers go
};

// The checks, the simulation at its start or at the checkpoint, and the checkpoint interval: a W-method's matrix is not in a checkpoint, so a
// continuation repeats the bits only from a step that rebuilds all of it, a multiple of
// integrator.w_k_every; periodic checkpoints and stops on a signal fall on such steps.
Run::Run(const Model& m, const RunOptions& opt)
    : m_(m), c_(m.cfg), opt_(opt), h_(grid_step(c_)), total_(std::max(1L, std::lround(c_.run.t_end / h_))),
      every_sample_(steps_for(c_.run.sample_interval, h_)), every_snapshot_(steps_for(c_.run.snapshot_interval, h_)),
      append_(opt.append && opt.resume),
      ckpt_path_(opt.checkpoint_path.empty() ? opt.out_path + ".ckpt" : opt.checkpoint_path),
      tmp_(opt.out_path + ".partial"), lock_(output_lock(m, opt, ckpt_path_)), sim_(m, opt.schedule),
      prof_(sim_.enable_profiling()) {
  for (const std::string* p : {&opt.summary_json, &opt.profile_json})
    if (!p->empty()) json_locks_.emplace_back(*p + ".lock", "'" + *p + "'", true);
  if (opt.resume) {
    sim_.restore(*opt.resume);
    // A checkpoint of a run at another step (RK4 warmed at 1e-8, continued with ROS2 at
    // 2e-7): the run counts steps of the new h, so its step count is t / h.
    const double t = sim_.time();
    if (std::abs(static_cast<double>(sim_.steps()) * h_ - t) > 1e-6 * h_) {
      const long k = std::lround(t / h_);
      if (std::abs(static_cast<double>(k) * h_ - t) > 1e-6 * h_)
        throw std::runtime_error("the checkpoint's time t = " + std::to_string(t) +
                                 " s is not a multiple of the step h = " + std::to_string(h_) +
                                 " s: choose a step that divides it");
      sim_.set_clock(t, k);
    }
  }
  start_ = done_ = sim_.steps();
  steps0_ = sim_.steps_taken(), rejected0_ = sim_.steps_rejected();
  if (start_ >= total_)
    throw std::runtime_error("the checkpoint is at step " + std::to_string(start_) + " (t = " +
                             std::to_string(sim_.time()) + " s), not before t_end = " + std::to_string(c_.run.t_end) +
                             " s: raise --t-end");
  rebuild_every_ = c_.integrator.method == IntegratorMethod::rk4 ? 1 : std::max(1, c_.integrator.w_k_every);
  checkpoint_every_ = opt.checkpoint_every > 0
                          ? (opt.checkpoint_every + rebuild_every_ - 1) / rebuild_every_ * rebuild_every_
                          : 0;
  run_id_ = opt.resume && append_ ? opt.resume->run_id : new_run_id();
  // RK4's step against its stability limit: first when the loads have ramped up (at rest,
  // while the contacts form, the linearization overstates the limit: RK4 at 1e-8 runs the
  // mini model, whose estimate at t = 0 is 6.4e-9), then every millisecond.
  next_stability_check_ = std::max(sim_.time(), ramps_end(c_));
  if (until_) {
    window_ = judged_ = steady_window(m);
    // A continuation into a new file has only its own samples: two windows of them.
    first_check_ = std::max(ramps_end(c_), append_ ? 0.0 : sim_.time()) + 2 * window_;
    check_every_ = std::lcm(every_sample_, rebuild_every_);
  }
  // Outside the envelope (docs/envelope.md): in the summary's warnings; `cvt-engine` prints
  // them before the model is built.
  for (const std::string& w : envelope_warnings(c_)) r_.warnings.push_back(w);
}

void Run::warn(const std::string& w) {
  r_.warnings.push_back(w);
  if (opt_.warn) opt_.warn(w);
  else std::fprintf(stderr, "cvt-engine: warning: %s\n", w.c_str());
}

// The file is written under a temporary name and renamed at the end: a failed run never
// leaves a file that looks complete; a continued run moves its own file there while it
// writes, and drops its rows after the checkpoint. Every series is created here, after
// which the file is only appended to and readers can follow the run (SWMR).
void Run::open_output() {
  if (!append_) {
    file_.emplace(H5File::create(tmp_));
  } else {
    namespace fs = std::filesystem;
    if (!fs::exists(opt_.out_path) && !fs::exists(tmp_))
      throw std::runtime_error("cannot continue " + opt_.out_path +
                               ": the file does not exist; give --out NEW to write the continuation to a new file");
    // The run's own file (FILE, or FILE.partial after kill -9 or a full disk) is checked
    // read-only, with everything the continuation needs read from it, before it is touched:
    // a refusal leaves it byte for byte as it was, under its name. One that a full disk cut
    // short is extended to the end its superblock records (undone on a refusal); one that a
    // killed run left marked as open for writing has that mark cleared (FILE.lock, held
    // here, shows that no writer is left).
    const std::string own = fs::exists(opt_.out_path) ? opt_.out_path : tmp_;
    const long long cut = extend_to_recorded_end(own);
    bool left_open = false;
    try {
      H5File probe = [&] {
        try {
          return H5File::open_for_reading(own, &left_open);
        } catch (const H5Error&) {
          throw std::runtime_error("cannot continue " + own + ": it does not open as an HDF5 file (not one, or "
                                   "truncated); the file is left as it was");
        }
      }();
      hist_ = continue_file(probe, m_, *opt_.resume, every_sample_, every_snapshot_);
      probe.close();
    } catch (...) {
      std::error_code ec;
      if (cut >= 0) fs::resize_file(own, static_cast<std::uintmax_t>(cut), ec);
      throw;
    }
    fs::rename(own, tmp_);
    try {
      file_.emplace(H5File::open(tmp_, left_open));
    } catch (...) {
      std::error_code ec;
      fs::rename(tmp_, own, ec);
      throw;
    }
    file_->remove("/profile");
    file_->remove("/summary");
  }
  write_parameters(*file_, m_, run_id_);
  rec_ = std::make_unique<Recorder>(*file_, m_);
  if (opt_.progress) std::printf("  schedule: %s\n", sim_.schedule().describe().c_str());
  if (opt_.resume && opt_.progress)
    std::printf("  resumed at t = %.9g s, step %ld%s\n", sim_.time(), start_,
                append_ ? (", appending to " + opt_.out_path).c_str() : "");
  std::fflush(stdout);
  samples_ = hist_.tail;
  channels_ = hist_.channels;
  if (opt_.resume && start_ % rebuild_every_ != 0)
    warn("the checkpoint is at step " + std::to_string(start_) + ", not a multiple of integrator.w_k_every = " +
         std::to_string(rebuild_every_) + ": " + to_string(c_.integrator.method) +
         "'s matrix is rebuilt here, so the continuation is close to, not bit-identical with, an uninterrupted run");
  t0_ = last_progress_ = last_flush_ = WallClock::now();
  sim_.check_finite();
  if (append_) {
    // The file holds this state's sample if it is on the grid: declare the series (none may
    // be created once SWMR starts) and drop the rows after the checkpoint.
    rec_->declare(sim_.sample(), every_snapshot_ > 0);
    rec_->truncate(hist_.samples, hist_.snapshots);
  } else {
    record();
    if (every_snapshot_) snapshot();
    sync_writes();
  }
  file_->start_swmr();
  plan_verify();
}

// run.verify: where the states for the window's second integration are kept. A run to
// t_end knows its window in advance (summarize's: the last window_fraction of the samples,
// not before the ramps end); a run until steady keeps about 16 states per window and
// drops those before the last two windows. A continuation of the same configuration (but
// for run.t_end and run.max_wall) takes over the states its checkpoint kept.
void Run::plan_verify() {
  if (!verify_) return;
  if (opt_.resume && !opt_.resume->verify_states.empty() &&
      continuation_toml(opt_.resume->config_toml, true) == continuation_toml(c_.resolved_toml, true))
    for (const Checkpoint& k : opt_.resume->verify_states)
      if (k.steps < start_) verify_states_.push_back(k);
  if (until_) {
    verify_every_ = rebuild_every_ * std::max(1L, std::lround(window_ / (16 * h_ * rebuild_every_)));
  } else {
    const double t1 = static_cast<double>(total_) * h_, t0 = channels_.t.front(), ramp_end = ramps_end(c_);
    double w0 = t1 - SteadyCriteria::of(c_).window_fraction * (t1 - t0);
    if (w0 < ramp_end && ramp_end < t1) w0 = ramp_end;
    // A step's margin: the window's first sample is the first at or after w0.
    verify_at_ = static_cast<long>(std::floor((w0 / h_ - 1) / static_cast<double>(rebuild_every_))) * rebuild_every_;
  }
  keep_for_verify(start_);
}

void Run::keep_for_verify(long n) {
  if (!verify_ || !(n == verify_at_ || (verify_every_ > 0 && n % verify_every_ == 0))) return;
  verify_states_.push_back(sim_.checkpoint());
  const double reach = 2 * window_ * (1 << kSteadyWindowDoublings);  // the longest pair of windows
  while (verify_states_.size() > 1 && verify_states_[1].t <= sim_.time() - reach) verify_states_.pop_front();
}

// The energy balance's leak that the efficiency's goal allows (Run::finish).
constexpr double kLeakGoal = 1e-3;

// Why a leak past kLeakGoal remains, and what to change.
std::string fmt_leak(double leak, int halvings, double halved_at, const Config::Integrator& in) {
  char buf[200];
  std::snprintf(buf, sizeof buf, "energy leak %.3g %% of the input work over the last torsion span > %.3g %%",
                100 * leak, 100 * kLeakGoal);
  std::string why = buf;
  if (in.fixed_steps || !(in.energy_leak > 0))
    why += ": the step is kept (integrator.fixed_steps or integrator.energy_leak = 0); the efficiency may be off by "
           "about half the leak: take a smaller integrator.step";
  else if (halvings >= kMaxStepHalvings)
    why += ": the step was halved " + std::to_string(halvings) + " times, the most; take a smaller integrator.step";
  else if (std::abs(leak) <= in.energy_leak)
    why += ": integrator.energy_leak = " + std::to_string(in.energy_leak) + " keeps the step up to that leak";
  else
    why += ": the step was halved at the span's end (t = " + std::to_string(halved_at) +
           " s) and no span at the new step followed: run longer";
  return why;
}

// "gross slip since t = 0.1 s (slip +8.1 %, over 5 %)": the slip at its start, or the largest
static std::string fmt_slip(const char* what, double from, double slip, double limit) {
  char buf[160];
  std::snprintf(buf, sizeof buf, "%s since t = %.6g s (slip %+.1f %%, over %.3g %%)", what, from, 100 * slip, 100 * limit);
  return buf;
}

// The sample of the current state, with the running-mean efficiency (work out over work
// in across the last run.efficiency_window, or since the first sample while the run is
// shorter), into the file, the summary's channels and the guards.
void Run::record() {
  output([&] {
    samples_.push_back(sim_.sample(h_));  // the next step's first evaluation, taken ahead
    Sample& s = samples_.back();
    const double t_from = s.t - c_.run.efficiency_window;
    const auto it = std::lower_bound(samples_.begin(), samples_.end(), t_from,
                                     [](const Sample& x, double t) { return x.t < t; });
    const double win = s.work_input - it->work_input;
    s.running_efficiency = win > 0 ? (s.work_output - it->work_output) / win : 0.0;
    channels_.push(s);
    watch(s);
    writes_.wait();
    written_ = s;
    write_sample_ = true;
    // Only the running efficiency's window is needed later.
    if (samples_.size() > 4096 && samples_.front().t < t_from - c_.run.efficiency_window)
      samples_.erase(samples_.begin(), samples_.begin() + 2048);
  });
}

// The guards at a sample: the energy balance, gross slip, and RK4's step against its
// stability limit.
void Run::watch(const Sample& s) {
  if (std::string w = energy_.check(s); !w.empty()) warn(w);
  const double slip = slip_of(s.speed_ratio, s.geometric_ratio);
  if (!(std::abs(slip) > gross_slip_) || s.t < ramps_end(c_)) {
    slip_from_ = -1;
  } else {
    if (slip_from_ < 0) slip_from_ = s.t;
    if (warned_slip_ && std::abs(slip) > std::abs(slipped_most_)) slipped_most_ = slip;
    if (!warned_slip_ && s.t - slip_from_ >= c_.run.efficiency_window) {
      warned_slip_ = true;
      slipped_from_ = slip_from_, slipped_most_ = slip;
      warn(fmt_slip("gross slip", slip_from_, slip, gross_slip_) +
           ": the load exceeds what the clamping holds; the chain slides over the sheaves and the model is not "
           "meant to run on there (raise the clamping, turn on the ratio controller, or lower the load)");
    }
  }
  if (c_.integrator.method == IntegratorMethod::rk4 && !warned_stability_ && s.t >= next_stability_check_) {
    next_stability_check_ = s.t + 1e-3;
    const double rho = sim_.spectral_radius(sim_.state(), sim_.time(), sim_.workspace().status);
    if (std::string w = rk4_stability_warning(h_, rho, s.t); !w.empty()) warn(w), warned_stability_ = true;
  }
}

void Run::snapshot() {
  output([&] {
    writes_.wait();
    sim_.snapshot(pos_, ten_, &ends_, &normal_);
    snapshot_t_ = sim_.time();
    snapshot_step_ = sim_.steps();
    write_snapshot_ = true;
  });
}

void Run::start_writes() {
  if (!write_sample_ && !write_snapshot_) return;
  // The flags are the master's: the job gets copies.
  const bool sample = std::exchange(write_sample_, false), snap = std::exchange(write_snapshot_, false);
  output([&] {
    writes_.start([this, sample, snap] {
      h5_silence_error_printing();  // per thread: the job may run on a worker
      if (sample) rec_->record(written_);
      if (snap) rec_->snapshot(snapshot_t_, snapshot_step_, pos_, ten_, ends_, normal_);
    });
  });
}

void Run::sync_writes() {
  start_writes();
  writes_.wait();
}

Checkpoint Run::checkpoint(bool with_verify) const {
  Checkpoint ck = sim_.checkpoint();
  if (with_verify) ck.verify_states.assign(verify_states_.begin(), verify_states_.end());
  ck.run_id = run_id_;
  ck.output = std::filesystem::absolute(opt_.out_path).string();
  return ck;
}

void Run::progress(long n, WallClock::time_point now) {
  if ((!opt_.progress && !opt_.on_progress) ||
      std::chrono::duration<double>(now - last_progress_).count() <= opt_.progress_seconds)
    return;
  const double el = std::chrono::duration<double>(now - t0_).count();
  const double eta = el / static_cast<double>(n - start_) * static_cast<double>(total_ - n);
  if (opt_.on_progress) {
    last_progress_ = now;
    if (!opt_.on_progress({n, total_, sim_.time(), c_.run.t_end, el, eta, false})) stop_asked_ = true;
    return;
  }
  std::fprintf(stderr, "%sstep %ld/%ld  t = %.6f s  %5.1f %%  %.3g model s/h  ETA %.0f s%s", tty_ ? "\r" : "", n,
               total_, sim_.time(), 100.0 * static_cast<double>(n) / static_cast<double>(total_),
               (sim_.time() - (opt_.resume ? opt_.resume->t : 0.0)) / el * 3600, eta, tty_ ? "   " : "\n");
  last_progress_ = now;
}

// run.until_steady: the summary's verdicts over the last two windows, of the steady window's
// length or longer (until_steady_verdict); true when they say steady (every criterion held)
// or gross slip.
bool Run::steady_now() {
  if (sim_.time() < first_check_ * (1 - 1e-12)) return false;
  // Two windows of the step as it is now (the energy balance's control may halve it).
  channels_.from = std::max(0.0, sim_.step_halved_at());
  if (sim_.time() < (channels_.from + 2 * window_) * (1 - 1e-12)) return false;
  RunSummary probe;
  std::vector<double> bounds;
  const double w = until_steady_verdict(m_, channels_, SteadyCriteria::of(c_), probe, &bounds);
  if (!(w > 0)) return false;
  judged_ = w, judged_bounds_ = std::move(bounds);
  stopped_ = probe.status;
  return true;
}

// Each step, then its sample and snapshot, then a checkpoint (after a flush: a crash
// leaves a file that holds every sample up to the checkpoint), then a stop on a signal
// (at a step a continuation repeats bit for bit), then the periodic flush and progress.
// A blow-up keeps every good sample: the file is closed under its final name.
void Run::steps() {
  StopSignals signals;
  done_ = total_;
  try {
    for (long n = start_ + 1; n <= total_; ++n) {
      sim_.step(h_);
      const bool on_grid = n % every_sample_ == 0 || n == total_;
      if (on_grid) sim_.check_finite(), record();
      if (every_snapshot_ && n % every_snapshot_ == 0) snapshot();
      keep_for_verify(n);
      start_writes();
      if (checkpoint_every_ > 0 && n % checkpoint_every_ == 0)
        output([&] {
          const auto w0 = WallClock::now();
          sync_writes();
          file_->flush();
          last_flush_ = WallClock::now();
          write_checkpoint(ckpt_path_, checkpoint(true));
          longest_write_ = std::max(longest_write_, seconds_since(w0));
        });
      if (until_ && n % check_every_ == 0 && steady_now()) {
        done_ = n;
        break;
      }
      if ((g_stop_signal || stop_asked_ || wall_near()) && stop_now(n)) {
        done_ = n;  // its sample ends the series
        if (!on_grid) sim_.check_finite(), record();
        break;
      }
      if (on_grid) {
        const auto now = WallClock::now();
        if (std::chrono::duration<double>(now - last_flush_).count() > opt_.flush_seconds) {
          output([&] {
            sync_writes();
            file_->flush();
          });
          longest_write_ = std::max(longest_write_, seconds_since(now));
          last_flush_ = now;
        }
        progress(n, now);
      }
    }
  } catch (const BlowUpError& e) {
    blown_up(e.what());
  } catch (const NumericalFailure& e) {
    blown_up(std::string("numerical failure: ") + e.what());
  } catch (const OdeError& e) {
    blown_up(std::string("numerical failure: ") + e.what());
  }
  step_wall_ = seconds_since(t0_);
  if (opt_.progress && tty_) std::fprintf(stderr, "\n");
}

// A blow-up or a numerical failure: every good sample kept, the file closed under its final
// name (exit 70), the slip that came before it named.
void Run::blown_up(const std::string& what) {
  if (opt_.progress && tty_) std::fprintf(stderr, "\n");
  try {
    sync_writes();  // every good sample; a write error here must not hide the blow-up
  } catch (const std::exception&) {
  }
  file_->close();
  std::filesystem::rename(tmp_, opt_.out_path);
  std::string slip;
  if (warned_slip_)
    slip = ". It followed " + fmt_slip("gross slip", slipped_from_, slipped_most_, gross_slip_) +
           ": the load exceeds what the clamping holds (a physical limit, not the integrator's): raise the clamping, "
           "turn on the ratio controller, or lower the load";
  throw BlowUpError(what + slip + ". Every sample before the blow-up is in " + opt_.out_path);
}

// A write that failed: the file closed as far as the library can (its errors ignored), the
// run ended with exit 73 (OutputError), and the way on named: the last checkpoint, written
// whole or not at all, continues the run once there is room.
void Run::write_failed(const std::string& what) {
  if (opt_.progress && tty_) std::fprintf(stderr, "\n");
  try {
    file_->close();
  } catch (const std::exception&) {
  }
  const auto g = [](double x) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.9g", x);
    return std::string(buf);
  };
  std::string next = "nothing to continue from yet: free space and run again";
  if (std::filesystem::exists(ckpt_path_)) {
    try {
      const Checkpoint last = read_checkpoint(ckpt_path_);
      if (last.run_id == run_id_)
        next = "the checkpoint " + ckpt_path_ + " (t = " + g(last.t) +
               " s) is whole: free space and continue with: cvt-engine run --resume " + ckpt_path_;
    } catch (const std::exception&) {
    }
  }
  throw WriteFailed("writing the run's output failed at t = " + g(sim_.time()) + " s: " + what, next);
}

// The last checkpoint, the summary and the profile. SWMR allows no new objects: the
// profile and the summary go into the file after it is closed, and it gets its name last.
RunResult Run::finish() {
  // A stop asked for at the last step, or before a verdict it waited on (the next matrix
  // rebuild), stopped nothing: the run ended, and is not continued as if cut short.
  const bool ended = done_ == total_ || stopped_ != "t_end";
  const bool cut = !ended && (g_stop_signal != 0 || stop_asked_ || wall_stop_);
  const std::string stopped = !cut               ? stopped_
                              : g_stop_signal    ? "signal"
                              : stop_asked_      ? "callback"
                                                 : "max_wall";
  output([&] {
    sync_writes();
    Checkpoint last = checkpoint(cut);
    last.stopped = stopped;
    write_checkpoint(ckpt_path_, last);
    file_->close();
  });
  const double t_start = opt_.resume ? opt_.resume->t : 0.0;
  r_.profile = prof_.report(seconds_since(t0_), sim_.time() - t_start, sim_.schedule().numa_nodes(),
                            scheduler_name(opt_.schedule.kind));
  const long steps = sim_.steps_taken() - steps0_;
  r_.steps = steps;
  r_.rejected_steps = sim_.steps_rejected() - rejected0_;
  r_.mean_step = (sim_.time() - t_start) / static_cast<double>(std::max(1L, steps));
  r_.interrupted = cut;
  r_.signal = cut ? g_stop_signal : 0;
  r_.t_start = t_start;
  r_.model_time = sim_.time();
  r_.wall_s = step_wall_;
  r_.us_per_step = 1e6 * step_wall_ / static_cast<double>(std::max(1L, steps));
  r_.model_s_per_hour = static_cast<double>(done_ - start_) * h_ / step_wall_ * 3600.0;
  r_.stopped = stopped;
  r_.steady_window = judged_;
  channels_.from = std::max(0.0, sim_.step_halved_at());
  summarize_judged(channels_, r_, until_ ? sim_.time() - 2 * judged_ : -1.0);
  // The step the window was taken with, and the energy balance's control of it.
  r_.step = h_ / (1 << sim_.step_halvings());
  r_.step_halvings = sim_.step_halvings();
  r_.step_halved_at = sim_.step_halved_at();
  r_.energy_leak = sim_.energy_leak();
  // A leak past the efficiency's goal (0.001; its error is about half the leak) is a
  // numerical error the run reports, as run.verify's are (docs/output.md, "Numerical error").
  if (std::abs(r_.energy_leak) > kLeakGoal)
    r_.reasons.push_back(fmt_leak(r_.energy_leak, r_.step_halvings, r_.step_halved_at, c_.integrator));
  const Sample& last = samples_.back();
  r_.energy_residual = last.energy_residual;
  r_.work_input = last.work_input;
  r_.energy_turnover = energy_turnover(last);
  r_.residual_fraction = r_.energy_turnover > 0 ? std::abs(r_.energy_residual) / r_.energy_turnover : 0.0;
  verify();
  {
    H5File f = H5File::open(tmp_);
    write_profile(f, r_.profile);
    write_summary(f, r_);
    f.close();
  }
  if (!opt_.profile_json.empty()) write_text(opt_.profile_json, profile_json(r_.profile));
  if (!opt_.summary_json.empty()) write_text(opt_.summary_json, summary_json(r_));
  std::filesystem::rename(tmp_, opt_.out_path);
  return r_;
}

void Run::summarize_judged(const SummaryChannels& ch, RunSummary& s, double w0) const {
  if (!judged_bounds_.empty())
    summarize(m_, ch, s, SteadyCriteria::of(c_), judged_bounds_);
  else
    summarize(m_, ch, s, SteadyCriteria::of(c_), w0, 0.5 * judged_);
}

bool Run::verify_progress(long done, long total, double t_end, WallClock::time_point t0) {
  const auto now = WallClock::now();
  if ((!opt_.progress && !opt_.on_progress) ||
      std::chrono::duration<double>(now - last_progress_).count() <= opt_.progress_seconds)
    return true;
  last_progress_ = now;
  const double el = std::chrono::duration<double>(now - t0).count();
  const double eta = el / static_cast<double>(std::max(1L, done)) * static_cast<double>(total - done);
  if (opt_.on_progress) return opt_.on_progress({done, total, sim_.time(), t_end, el, eta, true});
  std::fprintf(stderr, "%sverify step %ld/%ld  t = %.6f s  %5.1f %%  ETA %.0f s%s", tty_ ? "\r" : "", done, total,
               sim_.time(), 100.0 * static_cast<double>(done) / static_cast<double>(total), eta, tty_ ? "   " : "\n");
  return true;
}

// run.verify (docs/output.md, "Numerical error"): the summary's window integrated again from
// the state kept at or before its start, with the step h / verify_refine and every other key
// as it is, sampled on the same grid in memory (nothing is written), and summarized by the
// same code over the same window; each mean's numerical error is its change. The run's
// simulation does it: its output is complete by now.
void Run::verify() {
  if (!verify_) return;
  const auto skip = [&](const std::string& why) {
    r_.unverified = why;
    warn("run.verify: the means are not verified: " + why);
  };
  if (r_.interrupted) return skip("the run was interrupted");
  if (adaptive_steps(c_)) return skip("adaptive steps (integrator.tolerance) are not verified by a halved step");
  const Checkpoint* ck = nullptr;
  for (const Checkpoint& c : verify_states_)
    if (c.t <= r_.window_start) ck = &c;
  if (!ck)
    return skip("no state was kept at or before the window's start (t = " + std::to_string(r_.window_start) +
                " s; a continuation of another configuration, or from a checkpoint of an ended run, has none before its own start)");
  const int k = std::max(1, opt_.verify_refine);
  const double hv = h_ / k, from = r_.window_start - 0.5 * h_;
  const int halvings = sim_.step_halvings();  // the window's (it starts after the last halving)
  const double sub = hv / (1 << halvings);       // its sub-steps, halved
  const long n_end = sim_.steps() * k, every = every_sample_ * k;
  if (opt_.progress) {
    std::printf("  verifying: t = %.6g .. %.6g s again with the step %.4g s\n", ck->t, sim_.time(), sub);
    std::fflush(stdout);
  }
  const auto t0 = WallClock::now();
  const double t_end = sim_.time();
  const long n0 = ck->steps * k;
  StopSignals signals;
  SummaryChannels ch;
  try {
    sim_.restore(*ck);
    sim_.hold_step(halvings);  // the window's own sub-steps, halved
    if (k > 1) sim_.set_clock(ck->t, ck->steps * k);
    if (sim_.time() >= from) ch.push(sim_.sample(hv));
    for (long n = ck->steps * k + 1; n <= n_end; ++n) {
      sim_.step(hv);
      if (n % every == 0 || n == n_end) {
        sim_.check_finite();
        if (sim_.time() >= from) ch.push(sim_.sample(hv));
      }
      if (g_stop_signal) return skip("stopped by a signal");
      if (!verify_progress(n - n0, n_end - n0, t_end, t0)) return skip("stopped by the progress callback");
    }
    if (opt_.progress && tty_) std::fprintf(stderr, "\n");
  } catch (const BlowUpError& e) {
    return skip(std::string("the integration with the step ") + std::to_string(hv) + " s blew up: " + e.what());
  }
  if (ch.size() < 2) return skip("the window holds fewer than two samples");
  RunSummary tight;
  summarize_judged(ch, tight, std::max(0.0, from));
  if (std::abs(tight.window_start - r_.window_start) > 0.5 * h_ || std::abs(tight.window_end - r_.window_end) > 0.5 * h_)
    return skip("its window " + std::to_string(tight.window_start) + " .. " + std::to_string(tight.window_end) +
                " s is not the run's");
  set_numerical_errors(r_, tight, sub);
  r_.verify_wall_s = seconds_since(t0);
}

}  // namespace

RunResult run_simulation(const Model& m, const RunOptions& opt) {
  Run run(m, opt);
  run.open_output();
  run.steps();
  return run.finish();
}

}  // namespace cvt
