#include "engine/summary.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <type_traits>

#include "engine/io/json.hpp"
#include "engine/run.hpp"
#include "engine/simulation.hpp"

namespace cvt {

void SummaryChannels::push(const Sample& s) {
  t.push_back(s.t);
  input_speed.push_back(s.input_speed);
  output_speed.push_back(s.output_speed);
  input_torque.push_back(s.input_torque);
  output_torque.push_back(s.output_torque);
  load_torque.push_back(s.load_torque);
  speed_ratio.push_back(s.speed_ratio);
  geometric_ratio.push_back(s.geometric_ratio);
  clamp_driving.push_back(s.clamp[0]);
  clamp_driven.push_back(s.clamp[1]);
  strand_upper.push_back(s.strand_tension[0]);
  strand_lower.push_back(s.strand_tension[1]);
  sheave_driving.push_back(s.sheave_position[0]);
  sheave_driven.push_back(s.sheave_position[1]);
  work_input.push_back(s.work_input);
  work_output.push_back(s.work_output);
  work_dissipated.push_back(s.work_dissipated);
  work_clamping.push_back(s.work_clamping);
}

namespace {

double mean(const std::vector<double>& v, std::size_t a, std::size_t b) {
  double s = 0;
  for (std::size_t i = a; i < b; ++i) s += v[i];
  return b > a ? s / static_cast<double>(b - a) : 0.0;
}

// The mean of the defined entries (> 0 and finite): the geometric ratio is 0 while no pin
// touches a sheave (the start from rest).
double mean_defined(const std::vector<double>& v, std::size_t a, std::size_t b) {
  double s = 0;
  std::size_t k = 0;
  for (std::size_t i = a; i < b; ++i)
    if (v[i] > 0 && std::isfinite(v[i])) s += v[i], ++k;
  return k ? s / static_cast<double>(k) : 0.0;
}

std::string fmt(const char* f, double a, double b = 0, double c = 0, double d = 0) {
  char buf[512];
  std::snprintf(buf, sizeof buf, f, a, b, c, d);
  return buf;
}

// The samples' interval, and the meshing period (a link passing, pitch / (omega_in R1)) in
// whole samples (at least one).
double sample_interval(const SummaryChannels& ch) {
  const std::size_t n = ch.size();
  return (ch.t.back() - ch.t.front()) / static_cast<double>(std::max<std::size_t>(1, n - 1));
}
double meshing_period(const Model& m, double input_speed) {
  const double v_chain = std::abs(input_speed) * m.pulley[0].running_radius;
  return v_chain > 0 ? m.cfg.chain.pitch / v_chain : 0;
}
std::size_t meshing_samples(double t_mesh, double dt) {
  return t_mesh > 0 && dt > 0 ? std::max<std::size_t>(1, std::lround(t_mesh / dt)) : 1;
}

// The output torque's swing over samples [a, b), averaged over k samples (one meshing
// period: the polygon ripple removed): its own period from the crossings about its mean,
// and its swing (half of max - min) over each half and over all of it.
struct Swing {
  double period = 0;             // [s]; 0: fewer than three crossings
  double first = 0, second = 0;  // the swing over the first and the second half [N m]
  double whole = 0;              // the swing over all of it [N m]; 0: shorter than k samples
  int crossings = 0;
  bool regular = false;  // the half periods between crossings agree within a quarter
};

Swing measure_swing(const SummaryChannels& ch, std::size_t a, std::size_t b, std::size_t k) {
  Swing w;
  std::vector<double> avg;
  double run = 0;
  for (std::size_t i = a; i < b; ++i) {
    run += ch.output_torque[i];
    if (i >= a + k) run -= ch.output_torque[i - k];
    if (i + 1 >= a + k) avg.push_back(run / static_cast<double>(k));
  }
  if (avg.empty()) return w;
  double lo[2] = {1e300, 1e300}, hi[2] = {-1e300, -1e300};
  for (std::size_t i = 0; i < avg.size(); ++i) {
    const int h = 2 * i < avg.size() ? 0 : 1;
    lo[h] = std::min(lo[h], avg[i]), hi[h] = std::max(hi[h], avg[i]);
  }
  w.whole = 0.5 * (std::max(hi[0], hi[1]) - std::min(lo[0], lo[1]));
  if (avg.size() < 4) return w;
  w.first = 0.5 * (hi[0] - lo[0]), w.second = 0.5 * (hi[1] - lo[1]);
  double mean = 0;
  for (double x : avg) mean += x;
  mean /= static_cast<double>(avg.size());
  // A crossing counts where the torque leaves a band of a tenth of the swing about the mean
  // on the other side (a residue of the ripple does not count) and is dated there: every one
  // a band's width from the mean, so the half periods between them are whole.
  const double band = 0.1 * std::max(w.first, w.second);
  int side = 0;
  std::vector<double> at;
  for (std::size_t i = 0; i < avg.size(); ++i) {
    const int now = avg[i] > mean + band ? 1 : (avg[i] < mean - band ? -1 : 0);
    if (now != 0 && side != 0 && now != side) at.push_back(ch.t[a + k - 1 + i]);
    if (now != 0) side = now;
  }
  w.crossings = static_cast<int>(at.size());
  if (at.size() < 3 || !(at.back() > at.front())) return w;
  const double half = (at.back() - at.front()) / static_cast<double>(at.size() - 1);
  w.period = 2 * half;
  double dev = 0;
  for (std::size_t i = 1; i < at.size(); ++i) dev = std::max(dev, std::abs(at[i] - at[i - 1] - half));
  w.regular = dev <= 0.25 * half;
  return w;
}

// Where the energy held in the model's inertias and springs passes the same phase of a
// swing, once per period, in samples [a, b). That energy, from its balance
// W_in - W_out - D + W_c (the residual aside), averaged over k samples (one meshing period),
// less its centred average over one period of the swing (`period` samples), crosses zero
// upwards once per period: the sample first at or above zero after it was below a tenth of
// its swing. Between two such crossings the stored energy changes by its trend alone, not
// by the swing's phase nor, to first order, by its amplitude; at a high speed the swing's
// energy is mostly J omega d(omega) of the turning inertias, so a window that ends at
// another phase carries that into its power ratio and torque means.
std::vector<std::size_t> stored_energy_crossings(const SummaryChannels& ch, std::size_t a, std::size_t b,
                                                 std::size_t k, std::size_t period) {
  std::vector<std::size_t> up;
  const std::size_t h = period / 2;
  if (b <= a || b - a < k + 2 * h + 2) return up;
  const std::size_t n = b - a - k + 1;  // avg[j]: samples a + j .. a + j + k - 1, dated at the last
  std::vector<double> avg(n), sum(n + 1, 0.0);
  double run = 0;
  const auto energy = [&ch](std::size_t i) {
    return ch.work_input[i] - ch.work_output[i] - ch.work_dissipated[i] + ch.work_clamping[i];
  };
  for (std::size_t i = a; i < b; ++i) {
    run += energy(i);
    if (i >= a + k) run -= energy(i - k);
    if (i + 1 >= a + k) avg[i + 1 - a - k] = run / static_cast<double>(k);
  }
  for (std::size_t j = 0; j < n; ++j) sum[j + 1] = sum[j] + avg[j];
  std::vector<double> x(n, 0.0);
  double lo = 1e300, hi = -1e300;
  for (std::size_t j = h; j + h < n; ++j) {
    x[j] = avg[j] - (sum[j + h + 1] - sum[j - h]) / static_cast<double>(2 * h + 1);
    lo = std::min(lo, x[j]), hi = std::max(hi, x[j]);
  }
  const double band = 0.05 * (hi - lo);
  bool armed = false;
  for (std::size_t j = h + 1; j + h < n; ++j) {
    if (x[j] < -band) armed = true;
    if (armed && x[j - 1] < 0 && x[j] >= 0) up.push_back(a + j + k - 1), armed = false;
  }
  return up;
}

// The first sample at or after time t (half a sample's slack: another run's grid).
std::size_t sample_at(const SummaryChannels& ch, double t) {
  const double slack = 0.5 * sample_interval(ch);
  return static_cast<std::size_t>(std::lower_bound(ch.t.begin(), ch.t.end(), t - slack) - ch.t.begin());
}

}  // namespace

namespace {

// The means over samples [a, b) into s.
void fill_means(const SummaryChannels& ch, std::size_t a, std::size_t b, RunSummary& s) {
  s.window_start = ch.t[a], s.window_end = ch.t[b - 1];
  s.speed_ratio = mean(ch.speed_ratio, a, b);
  s.geometric_ratio = mean_defined(ch.geometric_ratio, a, b);
  s.slip = slip_of(s.speed_ratio, s.geometric_ratio);
  s.input_speed = mean(ch.input_speed, a, b);
  s.output_speed = mean(ch.output_speed, a, b);
  s.input_torque = mean(ch.input_torque, a, b);
  s.output_torque = mean(ch.output_torque, a, b);
  s.load_torque = mean(ch.load_torque, a, b);
  s.clamp_driving = mean(ch.clamp_driving, a, b);
  s.clamp_driven = mean(ch.clamp_driven, a, b);
  s.strand_upper = mean(ch.strand_upper, a, b);
  s.strand_lower = mean(ch.strand_lower, a, b);
  s.sheave_driving = mean(ch.sheave_driving, a, b);
  s.sheave_driven = mean(ch.sheave_driven, a, b);
  double pin = 0, pout = 0;
  for (std::size_t i = a; i < b; ++i)
    pin += ch.input_torque[i] * ch.input_speed[i], pout += ch.output_torque[i] * ch.output_speed[i];
  s.efficiency = pin != 0 ? pout / pin : 0.0;
  // 1 - D / W_in over the window: unlike the ratio of mean powers it does not see energy
  // swinging in and out of the torsion springs and inertias.
  const double win = ch.work_input[b - 1] - ch.work_input[a];
  s.loss_efficiency = win > 0 ? 1.0 - (ch.work_dissipated[b - 1] - ch.work_dissipated[a]) / win : 0.0;
}

// The verdicts over samples [a, b): each check either holds (a line in s.criteria) or not
// (a line in slip or unsteady).
class Judge {
 public:
  // bounds: the spans' first samples and the window's end (whole periods of a swing,
  // until_steady_verdict), in place of spans of `span` counted back from b.
  Judge(const Model& m, const SummaryChannels& ch, std::size_t a, std::size_t b, RunSummary& s, const SteadyCriteria& c,
        double span, const std::vector<std::size_t>* bounds = nullptr)
      : ch_(ch), a_(a), b_(b), mid_((a + b) / 2), first_(a), s_(s), c_(c),
        torque_scale_(std::max({std::abs(s.load_torque), std::abs(s.output_torque), 1e-6})),
        controlled_(m.cfg.controller.enabled) {
    const double dt = sample_interval(ch);
    t_mesh_ = meshing_period(m, s.input_speed);
    k_ = meshing_samples(t_mesh_, dt);
    if (bounds) {
      bounds_ = *bounds, whole_periods_ = true;
      a_ = first_ = bounds_.front(), b_ = bounds_.back(), mid_ = bounds_[bounds_.size() / 2];
      t_torsion_ = (ch.t[b_ - 1] - ch.t[a_]) / static_cast<double>(bounds_.size() - 1);
      return;
    }
    // The span that averages out both the lowest torsion mode and the meshing ripple: half
    // the until-steady window, a torsion period in whole meshing periods (steady_window),
    // or the span given (a longer until-steady window's half).
    t_torsion_ = span > 0 ? span : 0.5 * steady_window(m);
    // Whole samples, rounded down: a pair of windows, 2 W long, then holds four spans of W / 2.
    k_torsion_ = t_torsion_ > 0 && dt > 0 ? static_cast<std::size_t>(std::floor(t_torsion_ / dt * (1 + 1e-9))) : 0;
    // Halves of whole spans where the window holds two or more (the until-steady run's two
    // windows): a mode ringing on then moves neither half's mean.
    if (const std::size_t half = k_torsion_ > 0 ? (b_ - a_) / k_torsion_ / 2 : 0; half > 0)
      a_ = b_ - 2 * half * k_torsion_, mid_ = b_ - half * k_torsion_;
    // The whole spans in [a_, b_), the last ones before b_.
    const std::size_t spans = k_torsion_ > 0 ? (b_ - a_) / k_torsion_ : 0;
    for (std::size_t p = 0; spans > 0 && p <= spans; ++p) bounds_.push_back(b_ - (spans - p) * k_torsion_);
  }
  void all(bool ramping, double ramp_end) {
    span_means();
    if (ramping)
      unsteady.push_back(fmt("load ramp: the loads and clamping forces ramp up until t = %.4g s, and the run "
                             "ends at %.4g s",
                             ramp_end, ch_.t.back()));
    slip_check();
    // A window shorter than two meshing periods says nothing about drift, shift or ringing.
    if (b_ - a_ < 2 * k_) {
      unsteady.push_back(fmt("window too short: %.3g s holds fewer than two meshing periods (%.3g s)",
                             s_.window_end - s_.window_start, t_mesh_));
      return;
    }
    falling();
    drift_check();
    shift();
    ringing();
    settled_efficiency();
    balance();
  }
  std::vector<std::string> slip, unsteady, held;

  // Where the spans are whole periods of the swing as measured (until_steady_verdict).
  // The whole spans in [a_, b_).
  std::size_t periods() const { return bounds_.empty() ? 0 : bounds_.size() - 1; }
  std::string whole_periods() const {
    const Swing w = measure_swing(ch_, a_, b_, k_);
    if (!(w.period > 0) || !whole_periods_) return "";
    return fmt("windows of whole periods of the drive line's self-sustained swing: %zu spans of %.0f of its periods "
               "(%.4g s, %.3g Hz, as measured), each from an upward crossing of the stored energy's swing to a "
               "later one, so that the window's ends hold the same energy; the window ends at the last crossing",
               bounds_.size() - 1, std::round(t_torsion_ / w.period), w.period, 1 / w.period);
  }
 private:
  void slip_check() {
    if (std::abs(s_.slip) > c_.gross_slip)
      slip.push_back(fmt("gross slip: speed ratio %.4f against geometric ratio %.4f (slip %.1f %%)", s_.speed_ratio,
                         s_.geometric_ratio, 100 * s_.slip));
    else
      held.push_back(fmt("no gross slip: slip %+.2f %% (limit %.3g %%)", 100 * s_.slip, 100 * c_.gross_slip));
  }
  // The slip growing across the window: the chain starting to slide. (The output speed
  // alone also falls when the ratio shifts towards underdrive without any slip.)
  void falling() {
    const auto half_slip = [&](std::size_t a, std::size_t b) {
      return slip_of(mean(ch_.speed_ratio, a, b), mean_defined(ch_.geometric_ratio, a, b));
    };
    const double s_a = half_slip(a_, mid_), s_b = half_slip(mid_, b_);
    if (s_b - s_a > c_.falling)
      slip.push_back(fmt("slip growing: %+.2f %% -> %+.2f %% across the window's halves (limit %.3g %% points)",
                         100 * s_a, 100 * s_b, 100 * c_.falling));
  }
  // The means over the window's two halves (two consecutive windows) agree; with a ratio
  // controller its clamping forces too, tighter: the losses follow the clamping, so a
  // controller still settling its forces (after a change of load) moves the efficiency.
  void drift_check() {
    std::string agree;
    bool held = true;
    const auto drift = [&](const char* name, const char* unit, const std::vector<double>& v, double scale,
                           double limit, double shown = 1) {
      const double x = mean(v, a_, mid_), y = mean(v, mid_, b_);
      const std::string text =
          std::string(name) + fmt(" %.4g -> %.4g", shown * x, shown * y) + (*unit ? " " : "") + unit;
      if (std::abs(y - x) > limit * scale) {
        unsteady.push_back("drift of the means: " + text + " over the window's halves (limit " +
                           fmt("%.2g", 100 * limit) + " %)");
        held = false;
      } else {
        agree += (agree.empty() ? "" : ", ") + text + (limit != c_.drift ? fmt(" (within %.2g %%)", 100 * limit) : "");
      }
    };
    drift("output torque", "N m", ch_.output_torque, torque_scale_, c_.drift);
    drift("input torque", "N m", ch_.input_torque, torque_scale_, c_.drift);
    drift("speed ratio", "", ch_.speed_ratio, std::abs(s_.speed_ratio), c_.drift);
    if (controlled_) {
      drift("clamping force F1", "kN", ch_.clamp_driving, std::abs(s_.clamp_driving), c_.force_drift, 1e-3);
      drift("F2", "kN", ch_.clamp_driven, std::abs(s_.clamp_driven), c_.force_drift, 1e-3);
    }
    if (held)
      this->held.push_back(fmt("means over t = %.5g .. %.5g s and %.5g .. %.5g s agree within ", ch_.t[a_],
                               ch_.t[mid_], ch_.t[mid_], s_.window_end) +
                           fmt("%.2g %%: ", 100 * c_.drift) + agree);
  }
  // A shift: the geometric ratio moving (the clamping forces do not hold this ratio at this
  // load), reported as a rate.
  void shift() {
    const double x = mean_defined(ch_.geometric_ratio, a_, mid_), y = mean_defined(ch_.geometric_ratio, mid_, b_);
    const double dt_halves = 0.5 * (s_.window_end - s_.window_start);
    if (!(x > 0 && y > 0 && dt_halves > 0)) return;
    const double rate = 100 * (y - x) / s_.geometric_ratio / dt_halves * 0.01;  // % per 10 ms
    if (std::abs(rate) > c_.shift)
      unsteady.push_back(fmt("shifting: the geometric ratio moves %.5f -> %.5f over the window's halves (%+.2g %% per "
                             "10 ms; limit %.2g): the clamping forces do not hold this ratio at this load",
                             x, y, rate, c_.shift));
    else
      held.push_back(fmt("ratio held: the geometric ratio moves %+.2g %% per 10 ms (limit %.2g)", rate, c_.shift));
  }
  // The statistical uncertainty of every verified mean: its means over each whole span of
  // the lowest torsion mode's period (t_torsion_) in the window, the last `periods()` of
  // them, and how far those scatter: the window's mean is uncertain by their standard
  // error (NaN with fewer than two spans).
  void span_means() {
    const auto& fields = summary_fields();
    s_.uncertainty.assign(fields.size(), std::numeric_limits<double>::quiet_NaN());
    s_.uncertainty_spans = periods() >= 2 ? static_cast<long>(periods()) : 0;
    s_.uncertainty_span = periods() >= 2 ? t_torsion_ : 0;
    if (periods() < 2) return;
    std::vector<RunSummary> span(periods());
    for (std::size_t p = 0; p < periods(); ++p) fill_means(ch_, bounds_[p], bounds_[p + 1], span[p]);
    const double n = static_cast<double>(periods());
    for (std::size_t i = 0; i < fields.size(); ++i) {
      if (!fields[i].verify.verified) continue;
      const auto member = std::get<double RunSummary::*>(fields[i].member);
      double sum = 0, sum2 = 0;
      for (const RunSummary& x : span) sum += x.*member, sum2 += x.*member * (x.*member);
      const double avg = sum / n, sd = std::sqrt(std::max(0.0, (sum2 - n * avg * avg) / (n - 1)));
      s_.uncertainty[i] = sd / std::sqrt(n);
    }
  }
  // The torsion modes of shafts and load: the output torque's mean over each whole span of
  // the lowest mode's period in the window, and how far those means scatter (span_means):
  // the criterion bounds the window mean's standard error. A mode
  // that rings on at a steady amplitude (a light load whose meshing keeps it going) leaves
  // the period means alone; one that is still decaying, or a drive line still winding up,
  // scatters them. The swing (a moving average over one meshing period, the time a link takes
  // to pass, pitch / (omega_in R1), removes the polygon ripple) is reported beside it. A
  // window of fewer than two spans judges the swing against the load instead.
  void ringing() {
    const double swing = measure_swing(ch_, a_, b_, k_).whole;
    if (periods() < 2) {
      if (swing > c_.ringing * torque_scale_)
        unsteady.push_back(fmt("torsion mode still ringing: the output torque swings +-%.3g N m (%.1f %% of the "
                               "load) with the meshing ripple removed",
                               swing, 100 * swing / torque_scale_));
      else
        held.push_back(fmt("torsion settled: the output torque swings +-%.3g N m (%.1f %% of the load; limit %.3g %%)",
                           swing, 100 * swing / torque_scale_, 100 * c_.ringing));
      return;
    }
    const double se = uncertainty(s_, "output_torque"), sd = se * std::sqrt(static_cast<double>(periods()));
    char text[512];
    std::snprintf(text, sizeof text,
                  "the output torque's means over %zu spans of %.3g s (a torsion period in whole meshing periods) "
                  "scatter by %.3g N m: the mean is "
                  "uncertain by +-%.3g N m (%.2f %% of the load; limit %.3g %%); it swings +-%.3g N m with the "
                  "meshing ripple removed",
                  periods(), t_torsion_, sd, se, 100 * se / torque_scale_, 100 * c_.torsion_uncertainty, swing);
    if (se > c_.torsion_uncertainty * torque_scale_)
      unsteady.push_back(std::string("torsion mode not settled: ") + text + swing_measured());
    else
      held.push_back(std::string("torsion settled: ") + text);
  }
  // What the output torque's swing is, where its span means scatter: its own period from
  // the crossings of the meshing-averaged torque about its mean, and its swing over each half
  // of the window: one that holds on is self-sustained, one that falls is still decaying.
  std::string swing_measured() const {
    const Swing w = measure_swing(ch_, a_, b_, k_);
    if (!(w.period > 0)) return "";
    const char* how = w.second >= 0.9 * w.first   ? "holding on: self-sustained, not decaying"
                      : w.second < 0.7 * w.first ? "falling: still decaying"
                                                 : "falling slowly";
    return fmt("; the swing's own period, by its zero crossings, is %.3g s (%.3g Hz), %.3g of them per span "
               "(spans that hold no whole number of them scatter its means), ",
               w.period, 1 / w.period, t_torsion_ / w.period) +
           fmt("+-%.3g N m over the first window and +-%.3g N m over the second (", w.first, w.second) + how + ")";
  }
  // The efficiency against the energy balance. Over a window W_out = W_in - D + W_c - dE:
  // the ratio of the mean powers carries the change dE of the kinetic and elastic energy
  // between input and output (the pulleys, the chain, the springs) from the window's start
  // to its end, over the input work: an oscillation of the drive line that the window does
  // not hold whole periods of leaves it there, most at light loads and high speeds. The
  // balance's 1 - (D - W_c) / W_in does not see that energy (W_c the clamping's work: a ratio
  // controller whose force follows its sheave's motion takes energy out, 0.9 % of the input
  // at a light load and high speed): where the run is steady the two agree, and the check
  // holds the window to it, and the losses' own scatter over the spans (the standard error
  // of loss_efficiency's span means).
  void settled_efficiency() {
    if (periods() < 2) return;
    // Over the means' samples, as loss_efficiency.
    const double win = ch_.work_input[b_ - 1] - ch_.work_input[first_];
    const double wc = win > 0 ? (ch_.work_clamping[b_ - 1] - ch_.work_clamping[first_]) / win : 0.0;
    const double balance = s_.loss_efficiency + wc;
    const double gap = s_.efficiency - balance, se = uncertainty(s_, "loss_efficiency");
    const std::string text =
        fmt("the power ratio %.4f against the energy balance's 1 - (dissipated - clamping work) / input work %.4f "
            "(%+.2g; limit %.2g), ",
            s_.efficiency, balance, gap, c_.efficiency_uncertainty) +
        fmt("1 - dissipated / input work uncertain by +-%.2g over %.0f spans", se, static_cast<double>(periods()));
    if (!(std::abs(gap) <= c_.efficiency_uncertainty && se <= c_.efficiency_uncertainty))
      unsteady.push_back("efficiency not settled: " + text +
                         ": energy swinging in and out of the drive line across the window's ends; a later window "
                         "(run.until_steady, a later run.t_end) holds it");
    else
      held.push_back("efficiency settled: " + text);
  }
  void balance() {
    if (!(std::abs(s_.load_torque) > 0)) return;
    const double off = std::abs(s_.output_torque - s_.load_torque);
    const std::string text = fmt("mean output torque %.4g N m against the load's %.4g N m (%+.1f %%", s_.output_torque,
                                 s_.load_torque, 100 * (s_.output_torque / s_.load_torque - 1));
    if (off > c_.balance * torque_scale_) unsteady.push_back("torque balance: " + text + ")");
    else held.push_back("torque balance: " + text + fmt("; limit %.2g %%)", 100 * c_.balance));
  }

  const SummaryChannels& ch_;
  std::size_t a_, b_, mid_;  // the judged samples [a_, b_), their halves split at mid_
  std::size_t first_;        // the means' first sample (fill_means; a_ is trimmed to whole spans)
  RunSummary& s_;
  const SteadyCriteria& c_;
  const double torque_scale_;
  const bool controlled_;  // a ratio controller sets the clamping forces
  double t_torsion_ = 0;        // the span of the torsion judgement [s]
  std::size_t k_torsion_ = 0;  // its samples (0: none)
  double t_mesh_ = 0;
  std::size_t k_ = 1;
  std::vector<std::size_t> bounds_;  // the spans run between these samples
  bool whole_periods_ = false;       // bounds_ given: whole periods of a swing
};

}  // namespace

SteadyCriteria SteadyCriteria::of(const Config& cfg) {
  SteadyCriteria c;
  c.drift = c.balance = cfg.run.steady_tolerance;
  c.force_drift = 0.25 * cfg.run.steady_tolerance;
  c.efficiency_uncertainty = 0.05 * cfg.run.steady_tolerance;
  return c;
}

namespace {

// The controller in one line: off, or which control and its target ("1 -> 1.2 -> 0.8"
// for a profile).
std::string controller_text(const Config& cfg) {
  const auto& c = cfg.controller;
  if (!c.enabled) return "off";
  std::string target = fmt("%.4g", c.target_ratio);
  if (!c.target_profile.empty()) {
    target = fmt("%.4g", c.target_profile.front()[1]);
    for (std::size_t i = 1; i < c.target_profile.size(); ++i)
      if (c.target_profile[i][1] != c.target_profile[i - 1][1]) target += fmt(" -> %.4g", c.target_profile[i][1]);
  }
  if (c.clamping_safety > 0)
    return fmt("slip-safe clamping (S %.3g), PI on ln(F1/F2), target ratio ", c.clamping_safety) + target + " (sheaves)";
  return "PI on F1, target speed ratio " + target;
}

}  // namespace

namespace {

// The configured inputs and the run's method into s, its verdicts cleared.
void summary_header(const Model& m, RunSummary& s) {
  const Config& cfg = m.cfg;
  // As configured, or where an input's profile ends.
  const auto last = [](const Config::Profile& p, double constant) { return p.empty() ? constant : p.back()[1]; };
  s.drive_speed = final_drive_speed(cfg);
  s.load_torque_nominal = last(cfg.load.torque_profile, cfg.load.torque);
  s.clamp_driving_nominal = last(cfg.clamping.driving_profile, cfg.clamping.driving);
  s.clamp_driven_nominal = last(cfg.clamping.driven_profile, cfg.clamping.driven);
  s.ratio_target = cfg.geometry.ratio;
  s.method = to_string(cfg.integrator.method);
  s.step = cfg.integrator.step;
  s.controller = controller_text(cfg);
  s.reasons.clear();
  s.criteria.clear();
}

// The means over samples [a, b) and the verdicts on them (Judge's arguments).
void judge_window(const Model& m, const SummaryChannels& ch, RunSummary& s, const SteadyCriteria& c, std::size_t a,
                  std::size_t b, bool ramping, double span, const std::vector<std::size_t>* bounds) {
  fill_means(ch, a, b, s);
  Judge judge(m, ch, a, b, s, c, span, bounds);
  judge.all(ramping, ramps_end(m.cfg));
  s.status = !judge.slip.empty() ? "slip" : judge.unsteady.empty() ? "steady" : "not_steady";
  s.reasons = judge.slip;
  s.reasons.insert(s.reasons.end(), judge.unsteady.begin(), judge.unsteady.end());
  s.criteria = judge.held;
  if (const std::string note = judge.whole_periods(); !note.empty()) s.criteria.push_back(note);
  s.efficiency_meaningful = s.status == "steady" && s.efficiency >= 0 && s.efficiency <= 1;
}

}  // namespace

void summarize(const Model& m, const SummaryChannels& ch, RunSummary& s, const SteadyCriteria& c,
               double window_start, double span) {
  summary_header(m, s);
  const std::size_t n = ch.size();
  if (n == 0) return;
  // The window: the last window_fraction of the run (or from window_start), not before
  // the ramps have ended.
  const double t0 = ch.t.front(), t1 = ch.t.back();
  const double ramp_end = ramps_end(m.cfg);
  double w0 = window_start >= 0 ? window_start : t1 - c.window_fraction * (t1 - t0);
  const bool ramping = w0 < ramp_end;
  if (ramping && ramp_end < t1) w0 = std::max(w0, ramp_end);
  if (w0 < ch.from && ch.from < t1) w0 = ch.from;  // not across a change of the step
  std::size_t a = static_cast<std::size_t>(std::lower_bound(ch.t.begin(), ch.t.end(), w0) - ch.t.begin());
  if (a + 2 > n) a = n >= 2 ? n - 2 : 0;
  judge_window(m, ch, s, c, a, n, ramping, span, nullptr);
}

void summarize(const Model& m, const SummaryChannels& ch, RunSummary& s, const SteadyCriteria& c,
               const std::vector<double>& span_bounds) {
  summary_header(m, s);
  std::vector<std::size_t> at;
  for (double t : span_bounds) at.push_back(sample_at(ch, t));
  for (std::size_t i = 1; i < at.size(); ++i)
    if (!(at[i] > at[i - 1] + 1) || at[i] > ch.size())
      throw std::invalid_argument("summarize: the spans' bounds are not ascending times within the channels");
  if (at.size() < 3) throw std::invalid_argument("summarize: the spans' bounds hold fewer than two spans");
  judge_window(m, ch, s, c, at.front(), at.back(), span_bounds.front() < ramps_end(m.cfg), 0, &at);
}

double until_steady_verdict(const Model& m, const SummaryChannels& ch, const SteadyCriteria& c, RunSummary& s,
                            std::vector<double>* span_bounds) {
  if (span_bounds) span_bounds->clear();
  const double W = steady_window(m);
  if (ch.size() < 2 || !(W > 0)) return 0;
  const double t1 = ch.t.back(), earliest = std::max({ramps_end(m.cfg), ch.t.front(), ch.from});
  const double slack = 1e-9 * std::max(1.0, t1);
  double w = W, longest = W;
  for (int d = 0; d <= kSteadyWindowDoublings; ++d, w *= 2) {
    // A longer pair must fit where the data are; W's is judged regardless (its ramp verdict).
    if (d > 0 && t1 - 2 * w < earliest - slack) break;
    RunSummary probe;
    summarize(m, ch, probe, c, t1 - 2 * w, 0.5 * w);
    if (probe.status == "steady" || probe.status == "slip") {
      s = std::move(probe);
      return w;
    }
    if (d == 0) s = std::move(probe);
    longest = w;
  }
  // A swing that holds on over the longest pair that fits, regular and larger than the
  // ringing criterion's 3 % of the load (a limit cycle of the drive line, whose period the
  // torsion mode's estimate, and so the spans of W / 2, need not hold whole: docs/output.md,
  // "Until steady"): four spans of whole periods of it, each from an upward crossing of the
  // stored energy's swing to a later one (stored_energy_crossings), the number of periods
  // per span nearest W / 2 and its doublings, the pair no longer than the longest of 16 W.
  const double from = std::max(earliest, t1 - 2 * longest);
  const std::size_t a = static_cast<std::size_t>(std::lower_bound(ch.t.begin(), ch.t.end(), from) - ch.t.begin());
  const double dt = sample_interval(ch);
  const std::size_t k = meshing_samples(meshing_period(m, s.input_speed), dt);
  const Swing sw = measure_swing(ch, a, ch.size(), k);
  const double scale = std::max({std::abs(s.load_torque), std::abs(s.output_torque), 1e-6});
  if (!(sw.period > 0) || sw.crossings < 8 || !sw.regular || sw.second < 0.9 * sw.first || sw.first < c.ringing * scale)
    return 0;
  const double reach = 2 * W * (1 << kSteadyWindowDoublings) * (1 + 1e-9);
  const std::size_t e = sample_at(ch, std::max(earliest, t1 - reach - sw.period));
  const std::vector<std::size_t> up =
      stored_energy_crossings(ch, e, ch.size(), k, std::max<std::size_t>(1, std::lround(sw.period / dt)));
  for (std::size_t per = std::max(1L, std::lround(0.5 * W / sw.period)); 4 * per < up.size(); per *= 2) {
    const std::size_t last = up.size() - 1, first = last - 4 * per;
    if (ch.t[up[first]] < t1 - reach) break;
    std::vector<double> bounds;
    for (std::size_t i = 0; i <= 4; ++i) bounds.push_back(ch.t[up[first + i * per]]);
    RunSummary probe;
    summarize(m, ch, probe, c, bounds);
    if (probe.status == "steady" || probe.status == "slip") {
      s = std::move(probe);
      if (span_bounds) *span_bounds = std::move(bounds);
      return 0.5 * (s.window_end - s.window_start);
    }
  }
  return 0;
}

const std::vector<SummaryField>& summary_fields() {
  using S = RunSummary;
  static const std::vector<SummaryField> fields = {
      {"status", "", "steady, not_steady or slip (printed as steady, not yet steady, slip)", &S::status},
      {"reasons", "", "why the run is not steady, or its slip, the slip reasons first; then the means whose numerical error passes its goal (run.verify); empty when steady and within the goals", &S::reasons},
      {"criteria", "", "the checks that held, each with its figures", &S::criteria},
      {"stopped", "", "what ended the run: t_end, steady or slip (run.until_steady), signal, callback, max_wall", &S::stopped},
      {"steady_window", "s", "with run.until_steady: the length of each of the two windows compared; else 0",
       &S::steady_window},
      {"warnings", "", "what the run warned about (energy residual, RK4 step past its limit)", &S::warnings},
      {"efficiency_meaningful", "", "the status is steady and the efficiency within [0, 1]",
       &S::efficiency_meaningful},
      {"interrupted", "", "stopped by a signal, a progress callback or run.max_wall", &S::interrupted},
      {"method", "", "integrator.method", &S::method},
      {"controller", "", "off, or the ratio controller and its target", &S::controller},
      {"step", "s", "the step the window was taken with: integrator.step / 2^step_halvings", &S::step},
      {"step_halvings", "", "times the energy balance's leak halved the step (integrator.energy_leak)",
       &S::step_halvings},
      {"step_halved_at", "s", "the model time of the last halving; -1: none", &S::step_halved_at},
      {"energy_leak", "1",
       "the energy balance's residual change per input work over the last torsion span measured (null: none)",
       &S::energy_leak},
      {"drive_speed", "rad/s", "drive.speed: the input speed as configured (a profile's last value)", &S::drive_speed},
      {"load_torque_nominal", "N m", "load.torque as configured (a profile's last value)", &S::load_torque_nominal},
      {"clamping_force_driving_nominal", "N", "clamping.driving as configured (a profile's last value)",
       &S::clamp_driving_nominal},
      {"clamping_force_driven_nominal", "N", "clamping.driven as configured (a profile's last value)",
       &S::clamp_driven_nominal},
      {"ratio_target", "1", "geometry.ratio as configured", &S::ratio_target},
      {"window_start", "s", "the start of the window of the means", &S::window_start},
      {"window_end", "s", "the end of the window of the means", &S::window_end},
      {"speed_ratio", "1", "the mean speed ratio over the window", &S::speed_ratio, {true}},
      {"geometric_ratio", "1", "the mean geometric ratio over the window's samples above 0", &S::geometric_ratio,
       {true}},
      {"slip", "1", "1 - geometric_ratio / speed_ratio of the two means (0 where undefined)", &S::slip,
       {true, VerifiedMean::absolute, 5e-4}},
      {"input_speed", "rad/s", "the mean input speed over the window", &S::input_speed, {true}},
      {"output_speed", "rad/s", "the mean output speed over the window", &S::output_speed, {true}},
      {"input_torque", "N m", "the mean input torque over the window", &S::input_torque,
       {true, VerifiedMean::relative, 5e-3}},
      {"output_torque", "N m", "the mean output torque over the window", &S::output_torque,
       {true, VerifiedMean::relative, 5e-3}},
      {"load_torque", "N m", "the mean load torque over the window", &S::load_torque,
       {true, VerifiedMean::relative, 5e-3}},
      {"clamping_force_driving", "N", "the mean driving clamping force over the window", &S::clamp_driving,
       {true, VerifiedMean::relative, 5e-3}},
      {"clamping_force_driven", "N", "the mean driven clamping force over the window", &S::clamp_driven,
       {true, VerifiedMean::relative, 5e-3}},
      {"strand_tension_upper", "N", "the mean link tension of the upper free strand over the window",
       &S::strand_upper, {true, VerifiedMean::relative, 5e-3}},
      {"strand_tension_lower", "N", "the mean link tension of the lower free strand over the window",
       &S::strand_lower, {true, VerifiedMean::relative, 5e-3}},
      {"sheave_position_driving", "m", "the mean driving sheave position over the window", &S::sheave_driving,
       {true}},
      {"sheave_position_driven", "m", "the mean driven sheave position over the window", &S::sheave_driven,
       {true}},
      {"efficiency", "1", "mean output power / mean input power over the window", &S::efficiency,
       {true, VerifiedMean::absolute, 1e-3}},
      {"loss_efficiency", "1", "1 - dissipated work / input work over the window", &S::loss_efficiency,
       {true, VerifiedMean::absolute, 1e-3}},
      {"verify_step", "s", "run.verify: the step of the window's second integration (integrator.step / 2); 0: not verified",
       &S::verify_step},
      {"verify_wall_s", "s", "run.verify: wall time of the window's second integration", &S::verify_wall_s},
      {"uncertainty_spans", "",
       "the whole torsion spans in the window whose means give each mean's statistical uncertainty (0: fewer than "
       "two)",
       &S::uncertainty_spans},
      {"uncertainty_span", "s", "the length of each of those spans (0: none)", &S::uncertainty_span},
      {"energy_residual", "J", "the energy balance's residual at the end", &S::energy_residual},
      {"energy_turnover", "J", "|W_in| + |W_out| + |W_diss| + |W_clamp| + |W_switch| at the end", &S::energy_turnover},
      {"residual_fraction", "1", "|energy_residual| / energy_turnover (printed in %)", &S::residual_fraction},
      {"t_start", "s", "the model time this invocation started from: 0, or the checkpoint's", &S::t_start},
      {"model_time", "s", "the model time reached", &S::model_time},
      {"steps", "", "steps taken by this invocation (adaptive: the integrator's accepted steps, start-up sub-steps too)",
       &S::steps},
      {"rejected_steps", "", "steps rejected and taken again: adaptive steps the error test rejected, fixed W-steps whose state went bad", &S::rejected_steps},
      {"mean_step", "s", "model time of this invocation / steps", &S::mean_step},
      {"wall_s", "s", "wall time of the steps", &S::wall_s},
      {"us_per_step", "us", "wall time per step", &S::us_per_step},
      {"model_s_per_hour", "s/h", "model time per hour of wall time", &S::model_s_per_hour},
  };
  return fields;
}

void set_numerical_errors(RunSummary& s, const RunSummary& tight, double tight_step) {
  const auto& fields = summary_fields();
  s.verify_step = tight_step;
  s.numerical_error.assign(fields.size(), std::numeric_limits<double>::quiet_NaN());
  for (std::size_t i = 0; i < fields.size(); ++i) {
    const SummaryField& f = fields[i];
    if (!f.verify.verified) continue;
    const auto member = std::get<double RunSummary::*>(f.member);
    const double x = s.*member, ref = tight.*member, e = std::abs(ref - x);
    s.numerical_error[i] = e;
    const double bound = f.verify.goal == VerifiedMean::relative ? f.verify.bound * std::abs(ref) : f.verify.bound;
    // A NaN error (a mean that is not finite in one of the runs) passes every goal.
    if (f.verify.goal == VerifiedMean::no_goal || e <= bound) continue;
    const std::string unit = f.unit == "1" ? "" : " " + std::string(f.unit);
    s.reasons.push_back(
        "numerical error of " + std::string(f.name) + " " + fmt("%.3g", e) + unit + " > " +
        (f.verify.goal == VerifiedMean::relative ? fmt("%.3g", bound) + unit + fmt(" (%.3g %%)", 100 * f.verify.bound)
                                                  : fmt("%.3g", bound) + unit) +
        fmt(": the mean moves from %.6g to %.6g", x, ref) + unit +
        fmt(" with the step %.4g s; take a smaller integrator.step", tight_step));
  }
}

namespace {

double by_name(const std::vector<double>& v, std::string_view name) {
  const auto& fields = summary_fields();
  for (std::size_t i = 0; i < fields.size() && i < v.size(); ++i)
    if (fields[i].name == name) return v[i];
  return std::numeric_limits<double>::quiet_NaN();
}

}  // namespace

double numerical_error(const RunSummary& s, std::string_view name) { return by_name(s.numerical_error, name); }

double uncertainty(const RunSummary& s, std::string_view name) { return by_name(s.uncertainty, name); }

namespace {

// The summary's entries read by name through the table; the ones never read are the
// text's last line.
class Entries {
 public:
  explicit Entries(const RunSummary& s) : s_(s), read_(summary_fields().size(), false) {}
  template <class T>
  const T& get(std::string_view name) {
    const auto& fields = summary_fields();
    for (std::size_t i = 0; i < fields.size(); ++i)
      if (fields[i].name == name) {
        read_[i] = true;
        return s_.*std::get<T RunSummary::*>(fields[i].member);
      }
    throw std::logic_error("the summary has no entry " + std::string(name));
  }
  double num(std::string_view name) { return get<double>(name); }
  long count(std::string_view name) { return get<long>(name); }
  bool flag(std::string_view name) { return get<bool>(name); }
  const char* str(std::string_view name) { return get<std::string>(name).c_str(); }
  const std::string& text(std::string_view name) { return get<std::string>(name); }
  // " +- e" with the numerical error of a verified mean (times scale, in the value's printf
  // format f), or "" when the run is not verified.
  std::string pm(std::string_view name, const char* f = "%.2g", double scale = 1) const {
    const double e = numerical_error(s_, name);
    return std::isnan(e) ? "" : " +- " + fmt(f, scale * e);
  }
  const std::vector<std::string>& list(std::string_view name) { return get<std::vector<std::string>>(name); }
  // "name value unit" of every entry not read, separated by ", " (empty when all were read).
  std::string rest() const {
    std::string o;
    const auto& fields = summary_fields();
    for (std::size_t i = 0; i < fields.size(); ++i) {
      if (read_[i]) continue;
      const SummaryField& f = fields[i];
      std::string v = std::visit(
          [&](auto m) -> std::string {
            const auto& x = s_.*m;
            using T = std::decay_t<decltype(x)>;
            if constexpr (std::is_same_v<T, double>) return fmt("%.6g", x);
            else if constexpr (std::is_same_v<T, long>) return std::to_string(x);
            else if constexpr (std::is_same_v<T, bool>) return x ? "yes" : "no";
            else if constexpr (std::is_same_v<T, std::string>) return x;
            else {
              std::string j;
              for (const auto& e : x) j += (j.empty() ? "" : "; ") + e;
              return "[" + j + "]";
            }
          },
          f.member);
      o += (o.empty() ? "" : ", ") + std::string(f.name) + " " + v + (f.unit.empty() ? "" : " ") + std::string(f.unit);
    }
    return o;
  }

 private:
  const RunSummary& s_;
  std::vector<bool> read_;
};

}  // namespace

std::string format_summary(const RunSummary& s) {
  std::ostringstream os;
  char b[512];
  const auto line = [&](const char* f, auto... x) {
    std::snprintf(b, sizeof b, f, x...);
    os << b;
  };
  Entries e(s);
  line("  operating point: input speed %.4g rad/s, load %.4g N m, clamping %.4g / %.4g kN, ratio %.4g;\n",
       e.num("drive_speed"), e.num("load_torque_nominal"), 1e-3 * e.num("clamping_force_driving_nominal"),
       1e-3 * e.num("clamping_force_driven_nominal"), e.num("ratio_target"));
  line("                   %s, step %.4g s, controller %s\n", e.str("method"), e.num("step"), e.str("controller"));
  const std::string& status = e.text("status");
  line("  status: %s\n", status == "not_steady" ? "not yet steady" : status.c_str());
  const std::string& stopped = e.text("stopped");
  if (stopped == "steady" || stopped == "slip")
    line("    (run.until_steady: stopped at t = %.5g s, %s; windows of %.4g s)\n", e.num("model_time"),
         stopped == "steady" ? "every criterion held" : "gross slip", e.num("steady_window"));
  else if (e.num("steady_window") > 0 && stopped == "t_end")
    line("    (run.until_steady: not steady by t_end = %.5g s; windows of %.4g s)\n", e.num("model_time"),
         e.num("steady_window"));
  for (const auto& r : e.list("reasons")) line("    - %s\n", r.c_str());
  for (const auto& r : e.list("criteria")) line("    held: %s\n", r.c_str());
  line("  means over t = %.5g .. %.5g s:\n", e.num("window_start"), e.num("window_end"));
  const auto pm = [&](std::string_view name, const char* f = "%.2g", double scale = 1) {
    return e.pm(name, f, scale);
  };
  line("    speed ratio              %.5f%s   (geometric ratio %.5f%s, slip %+.2f%s %%)\n", e.num("speed_ratio"),
       pm("speed_ratio").c_str(), e.num("geometric_ratio"), pm("geometric_ratio").c_str(), 100 * e.num("slip"),
       pm("slip", "%.2g", 100).c_str());
  line("    input / output speed     %.3f%s / %.3f%s rad/s\n", e.num("input_speed"), pm("input_speed").c_str(),
       e.num("output_speed"), pm("output_speed").c_str());
  line("    input / output torque    %.3f%s / %.3f%s N m   (load %.3f%s N m)\n", e.num("input_torque"),
       pm("input_torque").c_str(), e.num("output_torque"), pm("output_torque").c_str(), e.num("load_torque"),
       pm("load_torque").c_str());
  line("    clamping forces          %.4g%s / %.4g%s kN   (sheaves at %.4f%s / %.4f%s mm)\n",
       1e-3 * e.num("clamping_force_driving"), pm("clamping_force_driving", "%.2g", 1e-3).c_str(),
       1e-3 * e.num("clamping_force_driven"), pm("clamping_force_driven", "%.2g", 1e-3).c_str(),
       1e3 * e.num("sheave_position_driving"), pm("sheave_position_driving", "%.2g", 1e3).c_str(),
       1e3 * e.num("sheave_position_driven"), pm("sheave_position_driven", "%.2g", 1e3).c_str());
  const double upper = e.num("strand_tension_upper"), lower = e.num("strand_tension_lower");
  line("    strand tensions          %.4g%s / %.4g%s kN   (upper / lower free strand: difference %.4g kN)\n",
       1e-3 * upper, pm("strand_tension_upper", "%.2g", 1e-3).c_str(), 1e-3 * lower,
       pm("strand_tension_lower", "%.2g", 1e-3).c_str(), 1e-3 * (upper - lower));
  const double efficiency = e.num("efficiency"), loss_efficiency = e.num("loss_efficiency");
  const bool outside = !(efficiency >= 0 && efficiency <= 1);
  if (e.flag("efficiency_meaningful") && !outside)
    line("    efficiency               %.4f%s   (mean output / input power; 1 - dissipated/input work %.4f%s)\n",
         efficiency, pm("efficiency").c_str(), loss_efficiency, pm("loss_efficiency").c_str());
  else
    line("    efficiency               not meaningful (%s: the power ratio is %.4g%s%s; 1 - dissipated/input work "
         "%.4f%s)\n",
         status == "steady" ? "outside [0, 1]" : "the run is not steady", efficiency, pm("efficiency").c_str(),
         outside ? ", outside [0, 1]" : "", loss_efficiency, pm("loss_efficiency").c_str());
  const double verify_step = e.num("verify_step"), verify_wall = e.num("verify_wall_s");
  if (verify_step > 0)
    line("    (+- numerical error: |mean - the same window's mean with the step %.4g s| (run.verify); %.3g s wall "
         "time)\n",
         verify_step, verify_wall);
  const long spans = e.count("uncertainty_spans");
  const double span = e.num("uncertainty_span");
  if (spans >= 2) {
    const auto u = [&](std::string_view name, const char* f, double scale = 1) { return fmt(f, scale * uncertainty(s, name)); };
    line("    (statistical uncertainty, the standard error of the means over %ld whole spans of %.3g s: efficiency "
         "+-%s, slip +-%s %%, torques +-%s / %s N m, forces +-%s / %s kN, strands +-%s / %s kN)\n",
         spans, span, u("efficiency", "%.2g").c_str(), u("slip", "%.2g", 100).c_str(), u("input_torque", "%.2g").c_str(),
         u("output_torque", "%.2g").c_str(), u("clamping_force_driving", "%.2g", 1e-3).c_str(),
         u("clamping_force_driven", "%.2g", 1e-3).c_str(), u("strand_tension_upper", "%.2g", 1e-3).c_str(),
         u("strand_tension_lower", "%.2g", 1e-3).c_str());
  }
  line("  energy balance residual    %.4g J (%.3g %% of the energy turned over, %.4g J)\n", e.num("energy_residual"),
       100 * e.num("residual_fraction"), e.num("energy_turnover"));
  const long halvings = e.count("step_halvings");
  const double leak = e.num("energy_leak"), halved_at = e.num("step_halved_at");
  if (halvings > 0)
    line("  energy leak                %.3g %% of the input work per torsion span; the step halved %ld time%s, the "
         "last at t = %.5g s (integrator.energy_leak)\n",
         100 * leak, halvings, halvings > 1 ? "s" : "", halved_at);
  else if (std::isfinite(leak))
    line("  energy leak                %.3g %% of the input work per torsion span\n", 100 * leak);
  line("  run: t = %.6g .. %.6g s, %ld steps (mean %.4g s, %ld rejected), stopped: %s%s; %.3g s wall time, %.1f us "
       "per step, %.4g model s per hour\n",
       e.num("t_start"), e.num("model_time"), e.count("steps"), e.num("mean_step"), e.count("rejected_steps"),
       stopped.c_str(), e.flag("interrupted") ? " (interrupted)" : "", e.num("wall_s"), e.num("us_per_step"),
       e.num("model_s_per_hour"));
  for (const auto& w : e.list("warnings")) line("  warning: %s\n", w.c_str());
  const std::string rest = e.rest();
  if (!rest.empty()) os << "  also: " << rest << "\n";
  return os.str();
}

namespace {

Json summary_units() {
  Json u = Json::object();
  for (const SummaryField& f : summary_fields()) {
    if (f.unit.empty()) continue;
    u[std::string(f.name)] = std::string(f.unit);
    if (f.verify.verified) u[std::string(f.name) + "_numerical_error"] = u[std::string(f.name) + "_uncertainty"] =
        std::string(f.unit);
  }
  return u;
}

}  // namespace

std::string summary_units_json() { return json_inline(summary_units()); }

std::string summary_json(const RunSummary& s) {
  Json j = Json::object();
  const auto& fields = summary_fields();
  for (std::size_t i = 0; i < fields.size(); ++i) {
    const SummaryField& f = fields[i];
    std::visit(
        [&](auto m) {
          const auto& x = s.*m;
          if constexpr (std::is_same_v<std::decay_t<decltype(x)>, double>) j[std::string(f.name)] = json_number(x);
          else j[std::string(f.name)] = x;
        },
        f.member);
    // A verified mean's numerical error beside it (run.verify).
    if (f.verify.verified && i < s.numerical_error.size())
      j[std::string(f.name) + "_numerical_error"] = json_number(s.numerical_error[i]);
    // And its statistical uncertainty (null: fewer than two spans).
    if (f.verify.verified && i < s.uncertainty.size())
      j[std::string(f.name) + "_uncertainty"] = json_number(s.uncertainty[i]);
  }
  j["units"] = summary_units();  // after the table's entries
  return json_text(j);
}

}  // namespace cvt
