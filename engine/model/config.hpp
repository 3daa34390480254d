// Configuration of one simulation: every key of the TOML file, in SI units.
// docs/config.md documents each key; load_config() validates each one at the door.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace cvt {

// A bad configuration value: names the key, the value and the reason (exit 78).
class ConfigError : public std::runtime_error {
 public:
  // "configuration error: KEY = VALUE: REASON" (without " = VALUE" when value is empty);
  // `more`: further errors found in the same input, one line each after the first.
  ConfigError(std::string key, std::string value, std::string reason, const std::vector<std::string>& more = {})
      : std::runtime_error(text(key, value, reason, more)),
        key_(std::move(key)), value_(std::move(value)), reason_(std::move(reason)) {}
  // A file that cannot be read: "configuration error: cannot read the configuration file ...".
  static ConfigError unreadable(const std::string& path, const std::string& why) {
    ConfigError e("<file>", path, why);
    e.message_ = "configuration error: cannot read the configuration file '" + path + "': " + why;
    return e;
  }
  const char* what() const noexcept override {
    return message_.empty() ? std::runtime_error::what() : message_.c_str();
  }
  const std::string& key() const { return key_; }
  const std::string& value() const { return value_; }
  const std::string& reason() const { return reason_; }

 private:
  // A value as the message shows it: at most 200 characters (a value of megabytes is named, not echoed).
  static std::string shown(const std::string& value) {
    constexpr std::size_t kShown = 200;
    if (value.size() <= kShown) return value;
    return value.substr(0, kShown) + "... (" + std::to_string(value.size()) + " characters)";
  }
  static std::string text(const std::string& key, const std::string& value, const std::string& reason,
                          const std::vector<std::string>& more) {
    std::string t = "configuration error: " + key + (value.empty() ? "" : " = " + shown(value)) + ": " + reason;
    for (const auto& m : more) t += "\nconfiguration error: " + m;
    return t;
  }
  std::string key_, value_, reason_, message_;
};

enum class FrictionLaw { nonsmooth, smooth, none };
// integrator.method (docs/integrators.md): the W-methods ROS34PW2 (advised) and ROS2, the
// linearly implicit ROS34PRW (order 3 on stiff components tracking a slow state), and RK4,
// the reference.
enum class IntegratorMethod { rk4, ros2, ros34pw2, ros34prw };

struct Config {
  struct Geometry {
    double centre_distance = 0.160;  // a [m]
    double ratio = 1.0;              // target geometric ratio R2/R1 of the initial state [-]
  } geometry;
  struct Chain {
    int links = 84;
    double pitch = 8.0e-3;           // joint-to-joint distance in the straight chain [m]
    int plates_per_link = 12;
    double plate_mass = 1.6e-3;      // [kg]
    double plate_stiffness = 1.0e8;  // k_pl [N/m]
    double plate_damping = 20.0;     // c_pl [N s/m]
    double plate_spread = 0.024;     // axial width over which the plates of a link sit [m]
    double link_inertia = 2.5e-7;    // J_link [kg m^2]
    double pack_stiffness = 1.0e7;   // axial spring pack <-> pins [N/m]
    double pack_damping = 40.0;      // [N s/m]
  } chain;
  struct Pin {
    double length = 0.036;   // [m]
    double ea = 2.7e6;       // [N]
    double ei = 2.9;         // [N m^2]
    double mass = 3.7e-3;    // per half [kg]
    double damping_time = 5.0e-7;  // stiffness-proportional damping coefficient beta [s]
    // The plate holes' hold on a half's tilt against the pack's normal (the shaft axis):
    // a spring on the offset of its two ends' lateral positions (docs/model.md 4.1). 0 turns it off.
    double tilt_stiffness = 1.0e3;  // [N m/rad]
  } pin;
  struct Rocker {
    int stations = 4;
    double radius = 4.0e-3;        // R_r [m]
    double half_distance = 2.6e-3; // d_h [m]
    double stiffness = 7.9e10;     // Hertz c per station [N/m^1.5]
    double damping = 50.0;         // b per station [N s/m]
    // Rolling keeper: spring on the offset of the two halves across the bisector, which
    // is zero for rolling without slip (docs/model.md 4.3). 0 turns it off.
    double keeper_stiffness = 1.0e7;  // [N/m]
  } rocker;
  struct PulleyContact {
    double end_radius = 0.02;   // R_end [m]
    double stiffness = 2.2e10;  // [N/m^1.5]
    double damping = 50.0;      // [N s/m]
  } pulley_contact;
  struct Friction {
    FrictionLaw law = FrictionLaw::nonsmooth;
    double f0 = 0.09;
    double v0 = 1.0e-3;  // [m/s]
  } friction;
  struct Sheave {
    double cone_angle = 11.0;     // beta [deg]
    double outer_radius = 0.085;  // [m]
    double hub_radius = 0.028;    // [m]
  } sheave;
  struct Shaft {
    double mass = 5.0;             // shaft + pulley set [kg]; axially + sheave_mass
    double polar_inertia = 0.02;   // [kg m^2]
    double tilt_inertia = 0.01;    // [kg m^2]
    double sheave_mass = 2.0;      // moving sheave, axial [kg]
  } shaft;
  struct Bearing {
    double half_span = 0.05;         // l_b [m]
    double k1 = 2.0e8;               // [N/m]
    double k3 = 1.0e16;              // [N/m^3]
    double radial_damping = 3.0e3;   // [N s/m]
    double axial_stiffness = 1.0e8;  // [N/m]
    double axial_damping = 2.0e3;    // [N s/m]
  } bearing;
  // A value over time (docs/config.md, "Inputs that change in time"): (time [s], value)
  // points, linear between them, held before the first and after the last; empty: the
  // constant key (with its ramp).
  using Profile = std::vector<std::array<double, 2>>;
  struct Drive {
    double speed = 209.4;      // omega_in [rad/s]
    Profile speed_profile;     // omega_in(t) [s, rad/s]
    double stiffness = 2.0e4;  // k_t [N m/rad]
    double damping = 2.0;      // [N m s/rad]
  } drive;
  struct Load {
    double torque = 150.0;            // M0 [N m]
    Profile torque_profile;           // M0(t) [s, N m], instead of torque and its ramp
    double inertia = 0.05;            // J_load [kg m^2]
    double speed_coefficient = 0.0;   // c_omega [N m s/rad]
    double stiffness = 2.0e4;         // torsion spring pulley <-> load [N m/rad]
    double damping = 2.0;             // [N m s/rad]
  } load;
  struct Clamping {
    double driving = 25.0e3;  // F1 [N]
    double driven = 30.0e3;   // F2 [N]
    Profile driving_profile, driven_profile;  // F1(t), F2(t) [s, N], instead of the ramp; times increasing
    double sheave_damping = 2.0e3;  // moving sheave on its shaft [N s/m]
  } clamping;
  struct Controller {
    bool enabled = false;
    double target_ratio = 1.0;  // ratio to hold (speed ratio; the sheaves' ratio when clamping_safety > 0)
    // (time [s], ratio) points, times non-decreasing: the target interpolated linearly
    // between them, held before the first and after the last; empty: target_ratio.
    std::vector<std::array<double, 2>> target_profile;
    double kp = 0.0;            // [N] on F1 (clamping_safety = 0)
    double ki = 0.0;            // [N/s]
    // > 0: slip-safe clamping (docs/model.md 4.6.4): both forces at least
    // S |M_load| cos(beta) / (2 f0 R2), the PI (shift_kp, shift_ki) setting ln(F1/F2)
    // from the ratio of the sheave positions. 0: the configured forces, kp and ki on F1.
    double clamping_safety = 0.0;  // S [1]
    double shift_kp = 0.0;         // ln(F1/F2) per unit ratio error [1]
    double shift_ki = 0.0;         // [1/s]
    double thrust_limit = 3.0;     // F1/F2 kept within [1/limit, limit] [1]
    // > 0: shift_kp and shift_ki act scaled by gain_speed / drive.speed (the loop's bandwidth
    // in seconds kept as at gain_speed); 0 (default): as given at every speed, the loop's
    // bandwidth growing with the speed like the shift rate and the chain's passes
    // (docs/studies.md, "The ratio controller").
    double gain_speed = 0.0;  // [rad/s]
  } controller;
  struct Ramp {
    double time = 2.0e-3;  // t_ramp [s] of the clamping forces (and of the load unless load_time); 0: at once
    // The load torque's own ramp (docs/model.md 4.6.3): from load_from at load_start to
    // load.torque at load_start + load_time. load_time < 0 (not given): ramp.time.
    double load_time = -1.0;  // [s]
    double load_start = 0.0;  // [s]
    double load_from = 0.0;   // [N m]
  } ramp;
  struct Damping {
    double scale = 1.0;  // multiplies every damping coefficient; 0 turns damping off
  } damping;
  struct Integrator {
    IntegratorMethod method = IntegratorMethod::ros34pw2;
    double step = 2.5e-6;  // [s]: 1e-5 / 4, divides run.sample_interval and run.t_end
    int w_every = 8;       // ros2: rebuild its matrix (friction blocks) every this many steps
    int w_k_every = 32;    // ros2: and its stiffness blocks (finite differences) every this many
    bool w_secant = true;  // ros2: secant friction slope along the sliding direction (else the exact one)
    // W-methods: the chain's stiffness blocks as the analytic Hessian of its elastic energy
    // (modules/elastic_hessian) instead of finite differences of its forces.
    bool w_analytic_stiffness = false;
    // W-methods: the chain's block LU on this many segments with a reduced system of their
    // separators (SegmentedBlockLU), whose work divides over up to as many threads; 0: the
    // two sweeps of CyclicBlockLU (docs/integrators.md 12.2, docs/performance.md 3).
    int w_segments = 0;
    // W-methods: keep the friction part of the matrix current between rebuilds as a low-rank
    // correction for the contacts whose stiffness gamma h mu / m_pin moved by more than this
    // (ModelOdeOptions::w_fresh, docs/integrators.md 12.4); 0: off. w_fresh_max such contacts
    // at most; more make the next step rebuild the friction blocks.
    double w_fresh = 5.0;
    int w_fresh_max = 12;
    // W-methods: the shafts' velocity rows in the matrix (ModelOdeOptions::w_shafts)
    bool w_shafts = true;
    // W-methods: before this model time each step is taken as the fewest equal ROS2 sub-steps
    // no longer than startup_step (the pins settling onto the sheaves from rest;
    // docs/integrators.md 12.3)
    double startup_time = 1.0e-4;   // [s]; 0: none
    double startup_step = 6.25e-8;  // [s]
    // Fixed W-steps: after the start-up and before settle_time each step is taken as the
    // fewest equal sub-steps of the method no longer than settle_step (the contacts loading
    // up under the ramps, which a step tuned to the loaded chain does not follow;
    // docs/integrators.md 12.3). < 0 (not given): the end of the ramps (ramps_end); 0: none.
    double settle_time = -1.0;  // [s]
    double settle_step = 8.333333333333333e-7;  // [s]
    // W-methods: > 0 chooses every step by error control after the start-up
    // (docs/integrators.md 16): each step's estimated error at the pin, shaft or load that
    // errs most is at most tolerance x (1 um, 1 mm/s); `step` is then the first step, the
    // steps end on the sample times, and no longer than run.sample_interval. 0: fixed steps
    // of `step`.
    double tolerance = 0.0;  // [1]
    // Fixed W-steps: true takes every step as scheduled and retakes it only where its state
    // went bad (the bits of the published comparisons); false (default) retakes a step whose
    // error estimate is gross too, with a fresh matrix and in pieces (docs/integrators.md 12.3).
    bool fixed_steps = false;
    // Fixed W-steps without fixed_steps: after the settling phase the energy balance's
    // leak over each torsion span (its residual's change per input work) is measured, and
    // where it passes this bound every later step is taken in twice as many sub-steps, up to
    // kMaxStepHalvings times (docs/integrators.md 12.3). 0: never.
    double energy_leak = 1.0e-3;  // [1]
  } integrator;
  struct Run {
    double t_end = 2.0e-2;            // [s]
    double sample_interval = 1.0e-5;  // [s]
    double snapshot_interval = 1.0e-4; // [s]; 0 turns snapshots off
    int tracked_pin = 0;
    int tracked_link = 0;
    double efficiency_window = 1.0e-3;  // [s] of the running-mean efficiency channel
    // Stop as soon as the operating point is steady (or grossly slipping), t_end the upper
    // bound: the means over two consecutive windows of steady_window agree within
    // steady_tolerance (docs/output.md, "Until steady").
    bool until_steady = false;
    double steady_window = 0.0;      // [s]; 0: two periods of the lowest torsion mode (torsion_period)
    double steady_tolerance = 0.02;  // [1] of the load torque (torques) and of the speed ratio
    // After the run, integrate the summary's window again from its start with the step
    // halved and report each mean's change as its numerical error (docs/output.md,
    // "Numerical error").
    bool verify = false;
    // Stop the run cleanly, with its checkpoint, before this much wall time has passed since
    // the command started (a cluster job's limit; 0: no limit). Not part of the model: a
    // continuation may change it (docs/cli.md, "On a cluster").
    double max_wall = 0.0;  // [s]
  } run;

  // The fully resolved configuration as TOML text (what /parameters/config stores).
  std::string resolved_toml;
};

// The most times the energy balance's leak halves a run's step (integrator.energy_leak).
inline constexpr int kMaxStepHalvings = 4;

// With the slip-safe controller the W matrix's stiffness is rebuilt at least every this many
// steps (parse_config lowers integrator.w_k_every to it).
inline constexpr int kSlipSafeStiffnessEvery = 16;

// Parses TOML text, applies the overrides ("section.key=value") and validates every key.
// Throws ConfigError. `origin` names the source in messages.
// Every problem in the text is reported (one line each), not only the first. `shortcuts`
// names the command-line option an override came from ({"integrator.step", "--step"}):
// messages then say "(from --step)" instead of "(from --set)"; the entry "*" names where
// the other overrides came from (the Python module: "the overrides").
Config parse_config(const std::string& toml_text, const std::vector<std::string>& overrides = {},
                    const std::string& origin = "<string>",
                    const std::map<std::string, std::string>& shortcuts = {});
// Reads the file and calls parse_config. A missing file is a ConfigError too.
// The candidate a word begins (when only one does), else the closest within two edits
// (insertions, deletions, substitutions, adjacent swaps): for "did you mean".
std::optional<std::string> closest_name(std::string_view word, const std::vector<std::string>& candidates);

Config load_config(const std::string& path, const std::vector<std::string>& overrides = {},
                   const std::map<std::string, std::string>& shortcuts = {});

// A resolved configuration (Config::resolved_toml) with the keys that do not change a run's
// trajectory set to fixed values: run.max_wall, and with `any_t_end` run.t_end too. Two
// configurations with the same text here continue each other's runs (cvt-engine run
// --continue, a sweep's interrupted point, a sweep's config column).
std::string continuation_toml(const std::string& resolved_toml, bool any_t_end);

const char* to_string(FrictionLaw law);
const char* to_string(IntegratorMethod method);

// The W-methods' start-up phase: the sub-steps per step of h before integrator.startup_time,
// the fewest whose length h / n is at most integrator.startup_step; 1 without a phase.
// Adaptive W-steps (integrator.tolerance > 0, not RK4).
inline bool adaptive_steps(const Config& c) {
  return c.integrator.tolerance > 0 && c.integrator.method != IntegratorMethod::rk4;
}
// The run's grid step: the clock's tick, between which the run samples, snapshots and checks:
// the step itself, or with adaptive steps the sample interval (the driver's steps in between).
// The most steps a run counts (its clock's times stay exact) and the most sub-steps of one
// step (start-up, settling): beyond them a run is refused (exit 78), not started.
inline constexpr double kMaxRunSteps = 4503599627370496.0;  // 2^52
inline constexpr int kMaxSubsteps = 4096;
inline double grid_step(const Config& c) { return adaptive_steps(c) ? c.run.sample_interval : c.integrator.step; }
inline int startup_substeps(const Config::Integrator& in, double h) {
  if (!(in.startup_time > 0)) return 1;
  return std::max(1, static_cast<int>(std::ceil(h / in.startup_step * (1 - 1e-12))));
}
// The settling phase after it: the sub-steps per step of h before integrator.settle_time,
// the fewest whose length h / n is at most integrator.settle_step; 1 without a phase.
inline int settle_substeps(const Config::Integrator& in, double h) {
  if (in.settle_time == 0) return 1;  // < 0: until the ramps end (settle_end)
  return std::max(1, static_cast<int>(std::ceil(h / in.settle_step * (1 - 1e-12))));
}

}  // namespace cvt
