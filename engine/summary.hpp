// The end-of-run summary (docs/output.md, /summary): the operating point, means over a
// settled window, and verdicts a user can trust: steady or not (and why), gross slip,
// whether the efficiency means anything, and the warnings the run raised.
#pragma once

#include <limits>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include "engine/model/model.hpp"

namespace cvt {

struct Sample;

// The chain's slip (creep) 1 - geometric / speed ratio (docs/model.md 6); 0 while it is
// undefined: no pin on a sheave yet (geometric ratio 0) or the output at rest.
inline double slip_of(double speed_ratio, double geometric_ratio) {
  return speed_ratio != 0 && geometric_ratio > 0 ? 1.0 - geometric_ratio / speed_ratio : 0.0;
}

// The channels the summary reads, one entry per output sample (a run's samples, or the
// observables read back from a run's file).
struct SummaryChannels {
  std::vector<double> t, input_speed, output_speed, input_torque, output_torque, load_torque, speed_ratio,
      geometric_ratio, clamp_driving, clamp_driven, strand_upper, strand_lower, sheave_driving, sheave_driven,
      work_input, work_output, work_dissipated, work_clamping;
  void push(const Sample& s);
  std::size_t size() const { return t.size(); }
  // The earliest time a window may start besides the ramps' end: the run's last change of
  // its step (Simulation::step_halved_at; 0: none).
  double from = 0;
};

// The thresholds of the verdicts (docs/output.md, "The summary's verdicts").
struct SteadyCriteria {
  double window_fraction = 0.2;  // the window: the last 20 % of the run, after the ramp
  double drift = 0.02;           // means of the window's halves agree within 2 % (torques: of the load)
  double force_drift = 0.005;    // with a ratio controller, its clamping forces' means within 0.5 %
  double ringing = 0.03;         // slow swing of the output torque, meshing ripple removed: 3 % of the load
                                 // (windows of fewer than two torsion periods)
  double torsion_uncertainty = 0.005;  // the output torque's mean over whole torsion periods: its standard
                                       // error within 0.5 % of the load
  double efficiency_uncertainty = 0.001;  // where the window holds two or more torsion spans: the efficiency
                                          // (power ratio) and 1 - dissipated / input work agree within 0.1
                                          // points, and the latter's standard error over the spans too
  double balance = 0.02;         // mean output torque against the mean load torque: 2 %
  double shift = 0.1;            // geometric ratio moving by less than 0.1 % per 10 ms [1/s]
  double gross_slip = 0.05;      // slip 1 - geometric ratio / speed ratio above 5 %: gross slip
  double falling = 0.02;         // slip growing by 2 % points across the window's halves: slip
  // drift and balance from run.steady_tolerance, force_drift a quarter of it,
  // efficiency_uncertainty a twentieth of it, the rest as above.
  static SteadyCriteria of(const Config& cfg);
};

struct RunSummary {
  // The run.
  long steps = 0;           // the integrator's accepted steps (adaptive: its own, start-up sub-steps too)
  long rejected_steps = 0;  // adaptive steps rejected by the error test
  double mean_step = 0;     // model time / steps [s]
  double t_start = 0, model_time = 0, wall_s = 0, us_per_step = 0, model_s_per_hour = 0;
  bool interrupted = false;  // stopped by a signal, a progress callback or run.max_wall (the file holds the run so far)
  int signal = 0;
  std::string method, controller;
  double step = 0;  // the step the window was taken with: integrator.step / 2^step_halvings
  // The step's control by the energy balance (integrator.energy_leak): the halvings, the
  // last one's time (-1: none), and the last torsion span's leak (NaN: none measured).
  long step_halvings = 0;
  double step_halved_at = -1, energy_leak = std::numeric_limits<double>::quiet_NaN();
  // The operating point as configured.
  double drive_speed = 0, load_torque_nominal = 0, clamp_driving_nominal = 0, clamp_driven_nominal = 0,
         ratio_target = 0;
  // The window and the means over it.
  double window_start = 0, window_end = 0;
  double speed_ratio = 0, geometric_ratio = 0, slip = 0, input_speed = 0, output_speed = 0, input_torque = 0,
         output_torque = 0, load_torque = 0, clamp_driving = 0, clamp_driven = 0, strand_upper = 0, strand_lower = 0,
         sheave_driving = 0, sheave_driven = 0;
  double efficiency = 0;       // mean output power / mean input power over the window
  double loss_efficiency = 0;  // 1 - dissipated / input work over the window
  bool efficiency_meaningful = false;
  // "steady", "not_steady" or "slip"; the reasons of the last two (empty when steady).
  std::string status = "not_steady";
  std::vector<std::string> reasons;
  std::vector<std::string> criteria;  // the checks that held, with their figures
  // What ended the run: "t_end", "steady" or "slip" (run.until_steady), "signal",
  // "callback" (RunOptions::on_progress asked to stop: the Python module's progress callback),
  // "max_wall" (run.max_wall: the wall-time limit was near).
  std::string stopped = "t_end";
  double steady_window = 0;  // each of the two windows compared (run.until_steady) [s]
  // Energy balance at the end: residual [J] and its fraction of the energy turned over.
  double energy_residual = 0, work_input = 0, energy_turnover = 0, residual_fraction = 0;
  // What the run warned about (also printed when it happened).
  std::vector<std::string> warnings;
  // run.verify: the step of the window's second integration (0: not verified), its wall
  // time, and each mean's numerical error |mean with that step - mean|, one entry per
  // summary_fields() entry (NaN for those that are not a verified mean; empty when not
  // verified). numerical_error() reads it by name.
  double verify_step = 0, verify_wall_s = 0;
  std::string unverified;  // why run.verify verified nothing (empty: verified, or not asked)
  std::vector<double> numerical_error;
  // Each verified mean's statistical uncertainty: the standard error of the means over the
  // window's whole torsion spans (uncertainty_spans of them, each uncertainty_span long),
  // one entry per summary_fields() entry (NaN for those that are not a verified mean, and
  // for every entry when the window holds fewer than two spans). uncertainty() reads it by
  // name.
  long uncertainty_spans = 0;
  double uncertainty_span = 0;
  std::vector<double> uncertainty;
};

// One entry of the summary: its key in /summary and in the JSON, its unit ("1": a ratio;
// "" for text, flags and counts), what it means, and the member of RunSummary that holds it.
// /summary writes a double as a double attribute, a long or a bool as an integer, a string
// or a list of strings as UTF-8 strings; the JSON as numbers (null when not finite),
// integers, true/false, strings and arrays.
// A mean over the window that run.verify checks, and the goal its numerical error is held
// to: an absolute bound (in the entry's unit), a bound relative to the value of the tighter
// integration, or none (reported, not judged).
struct VerifiedMean {
  enum Goal { no_goal, absolute, relative };
  bool verified = false;
  Goal goal = no_goal;
  double bound = 0;
};

struct SummaryField {
  using Member = std::variant<double RunSummary::*, long RunSummary::*, bool RunSummary::*, std::string RunSummary::*,
                              std::vector<std::string> RunSummary::*>;
  std::string_view name, unit, meaning;
  Member member;
  VerifiedMean verify = {};  // run.verify: this mean's numerical error, as <name>_numerical_error;
                             // and its statistical uncertainty, as <name>_uncertainty
};

// Every entry of the summary, in the order of the JSON: the text, /summary and the JSON are
// written from this table (docs/output.md lists it).
const std::vector<SummaryField>& summary_fields();

// The unit of every summary entry that has one (and of its numerical error), as a JSON
// object {"input_torque": "N m", ...}: /summary's attribute `units` and the JSON's "units".
std::string summary_units_json();

// Fills the window, the means and the verdicts of s from the channels (the whole run).
// The window is the last c.window_fraction of the run, or from window_start when that is
// >= 0; never before the ramps have ended. span: the torsion span whose whole multiples the
// torsion verdict averages over [s]; 0: half the steady window (steady_window(m)).
void summarize(const Model& m, const SummaryChannels& ch, RunSummary& s, const SteadyCriteria& c = {},
               double window_start = -1, double span = 0);
// The same over the spans between consecutive times of span_bounds (ascending, at least
// three, each the time of a sample or within half a sample of one): the window from the
// first to the last, its halves split at the middle bound (until_steady_verdict's windows of
// whole periods of a swing).
void summarize(const Model& m, const SummaryChannels& ch, RunSummary& s, const SteadyCriteria& c,
               const std::vector<double>& span_bounds);

// The longest steady window run.until_steady compares: the steady window W times 2^this.
inline constexpr int kSteadyWindowDoublings = 4;

// run.until_steady's verdict at the channels' end (docs/output.md, "Until steady"): the last
// two windows of length w, for w = W, 2W, 4W, ... up to 2^kSteadyWindowDoublings W (W =
// steady_window(m)), as long as both fit after the ramps' end and the first sample, each
// judged with torsion spans of w / 2; the first that is steady or slips decides. Where none
// does and the output torque carries a self-sustained swing, pairs of windows of whole
// periods of it as measured, between upward crossings of the stored energy's swing, up to
// the same reach: then span_bounds (if given) receives the spans' bounds, for summarize's
// second form, and the window ends at its last crossing. Returns that w (half the pair's
// length) with s its summary, or 0 when none does (s then holds W's).
double until_steady_verdict(const Model& m, const SummaryChannels& ch, const SteadyCriteria& c, RunSummary& s,
                            std::vector<double>* span_bounds = nullptr);

// run.verify: the numerical errors of s's means against tight, the same window's summary
// from an integration with the step `tight_step`; a mean whose error passes its goal adds
// a line to s.reasons (the status stays: docs/output.md, "Numerical error").
void set_numerical_errors(RunSummary& s, const RunSummary& tight, double tight_step);
// The numerical error of the entry `name` (NaN when s is not verified or the entry is not a
// verified mean).
double numerical_error(const RunSummary& s, std::string_view name);
// The statistical uncertainty of the entry `name` (NaN when the window holds fewer than two
// whole spans or the entry is not a verified mean).
double uncertainty(const RunSummary& s, std::string_view name);

// The summary as text (the end of `cvt-engine run`) and as JSON (--summary-json). The text
// shows every entry of the table: those its lines do not place, on its last line as
// "name value unit".
std::string format_summary(const RunSummary& s);
std::string summary_json(const RunSummary& s);

}  // namespace cvt
