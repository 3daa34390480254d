// The simulation (MuJoCo's mj_step): the model's state, its clock and the step of the
// configured method (RK4, or a W-method: WStep, or with adaptive steps an OdeDriver), the contact statuses after
// each step, the channels of a state (Sample), snapshots, the blow-up guard and
// checkpoints. engine/run.hpp runs it to t_end with the output.
#pragma once

#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "engine/io/checkpoint.hpp"
#include "engine/ode/rk4.hpp"
#include "graph/schedule.hpp"
#include "engine/model/model.hpp"
#include "engine/model/state.hpp"
#include "engine/rhs/profile.hpp"

namespace cvt {

// Numerical blow-up: non-finite state or absurd penetration.
class BlowUpError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// A step that no retake could take from a sound state (a singular matrix every time): a
// numerical failure, reported like a blow-up (the run keeps its samples and says what to
// change).
class NumericalFailure : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// One sample of the channels (docs/model.md 6).
struct Sample {
  double t = 0;
  long step = 0;  // the clock's step count at t (H5MD's `step`)
  double input_speed = 0, output_speed = 0, load_speed = 0;
  double input_torque = 0, output_torque = 0, load_torque = 0;
  double speed_ratio = 0, geometric_ratio = 0, efficiency = 0;
  double clamp[2] = {0, 0};
  double sheave_position[2] = {0, 0};
  double support_force[4] = {0, 0, 0, 0};
  double pin_axial_force[2] = {0, 0};
  double pin_end_normal[4] = {0, 0, 0, 0};
  double pin_end_friction[4] = {0, 0, 0, 0};
  double link_tension = 0;
  double strand_tension[2] = {0, 0};  // the mean link tension of the upper and lower free strand [N]
  std::vector<double> plate_tension;  // the tracked link's plates
  double rocker_force = 0;            // the tracked pin's rocker joint (normal) [N]
  double chain_torsion_angle = 0;     // tracked pin vs the next, about the chain direction [rad]
  double input_angle = 0, output_angle = 0, load_angle = 0;  // phi [rad]
  double power_input = 0, power_output = 0, power_dissipated = 0;  // [W]
  double running_efficiency = 0;  // dW_out / dW_in over the last run.efficiency_window
  double energy_kinetic = 0, energy_elastic = 0;
  double work_input = 0, work_output = 0, work_dissipated = 0, work_clamping = 0, energy_residual = 0;
  double work_contact_switching = 0;  // energy added by contact status switches (4.4)
};

class OdeDriver;
class WStep;

class Simulation {
 public:
  explicit Simulation(const Model& m, const ScheduleOptions& schedule = {});
  ~Simulation();

  const Model& model() const { return m_; }
  double time() const { return clock_.t; }
  long steps() const { return clock_.steps; }
  // The integrator's accepted steps since construction: the clock's steps, or with adaptive
  // W-steps (integrator.tolerance) the driver's, start-up sub-steps included; and the
  // adaptive steps it rejected.
  long steps_taken() const { return steps_taken_; }
  long steps_rejected() const { return steps_rejected_; }
  const StepClock& clock() const { return clock_; }
  const Eigen::VectorXd& state() const { return y_; }
  Eigen::VectorXd& mutable_state() {
    begun_ = false;       // a step begun for a sample starts from the state it evaluated
    balance_t_ = -1;      // and the energy test from the state's own balance
    return y_;
  }
  // Continues from (t, steps): for restarts from a saved state.
  void set_clock(double t, long steps) { clock_ = StepClock::at(t, steps), begun_ = false, balance_t_ = -1; }
  // W sub-steps rejected because their energy balance jumped (energy_jump), counted in
  // steps_rejected() too.
  long energy_rejections() const { return energy_rejections_; }
  // The step's control by the energy balance (integrator.energy_leak): the times it halved
  // the step (each grid step then taken in 2^halvings sub-steps), the time of the last
  // halving (-1: none), and the leak of the last torsion span measured (NaN: none yet;
  // measured on fixed W-steps with the control off too).
  int step_halvings() const { return halvings_; }
  double step_halved_at() const { return halved_at_; }
  double energy_leak() const { return leak_; }
  // Takes every step from here on in 2^halvings sub-steps, unchanged (run.verify's second
  // integration; restore() lets the control go on).
  void hold_step(int halvings) { halvings_ = halvings, hold_step_ = true; }
  Workspace& workspace() { return ws_; }
  const Schedule& schedule() const { return *schedule_; }
  Schedule& schedule() { return *schedule_; }
  // Per-module timing of every following step (engine/rhs/profile.hpp); the profiler lives
  // as long as the simulation.
  Profiler& enable_profiling();
  Profiler* profiler() { return prof_.get(); }

  // One step of size h with integrator.method (RK4, or the ROS2 W-method of
  // docs/integrators.md 12 through an OdeDriver), then (unless frozen) the contact statuses
  // for the next step. Frozen steps (update_status false) are always RK4.
  void step(double h, bool update_status = true);
  // Advances to exactly t1 with a driver of another method or setting (studies, tests): its
  // steps count as the run's, and the clock's origin moves to t1.
  void advance(OdeDriver& driver, double t1);
  // Channels of the current state. With next_step > 0 and a fixed W-step, the state's
  // evaluation is the first of the next step (of that size), taken now: that step does not
  // repeat it, unless the state or the clock changes before it (mutable_state, restore).
  Sample sample(double next_step = 0);
  // Joint centres [N][3] and link tensions [N] of the current state; with pin_ends, the
  // ends of every pin half [N][2 halves a, b][2 ends z < 0, z > 0][3]; with contact_normal,
  // the normal force of each of those ends on a sheave [N][2][2] (0 off the sheaves).
  void snapshot(std::vector<double>& positions, std::vector<double>& tensions,
                std::vector<double>* pin_ends = nullptr, std::vector<double>* contact_normal = nullptr);
  // Throws BlowUpError when the state is not finite or a contact penetrates absurdly
  // deep: names time, step, the coordinate or the contact, then replays the steps from
  // the last good state to name the pin and the module that drove it, and gives the
  // stable RK4 step estimated at the last good state. Otherwise remembers the state as the
  // last good one.
  void check_finite();
  // Largest |eigenvalue| of the Jacobian of f at a state (power iteration on finite
  // differences, statuses as given) [1/s]; RK4 is stable for h up to about 2.8 / rho.
  double spectral_radius(const Eigen::VectorXd& y, double t, const ContactStatus& status, int iterations = 40);
  // Everything needed to continue bit-identically (engine/io/checkpoint.hpp), and back.
  Checkpoint checkpoint() const;
  // Throws std::runtime_error if the checkpoint does not fit this model.
  void restore(const Checkpoint& c);

 private:
  // "" if y is fine; else what is wrong (non-finite coordinate, absurd penetration).
  std::string state_problem(const Eigen::VectorXd& y) const;
  int absurd_stretch(const Eigen::VectorXd& y, double* stretch = nullptr, double* limit = nullptr) const;
  std::string replay_diagnosis(double h);
  // The two kinds of step (step() above), and adaptive W-steps.
  void rk4_step(double h, bool update_status);
  void w_step(double h);
  void w_adaptive_step(double h);
  void profile_update(std::uint64_t tick0, std::uint64_t rhs0, std::uint64_t master0);
  // The W-step of size h from the clock's time: its stepper (nullptr: an adaptive step), its
  // sub-steps and the index of the first (w_phase, which makes the stepper when h changes).
  struct WPhase {
    WStep* step;
    int sub;
    long first;
  };
  WPhase w_phase(double h);
  void w_substep(WStep& s, double t, double t_end, long index, bool evaluate);
  double balance_residual(double t, const Eigen::VectorXd& y) const;
  double balance_residual(const Energies& e, const double* aux) const;  // of energies e, work integrals aux
  void watch_leak(double h);
  const Eigen::VectorXd* begin_w_step(const WPhase& p, double h);

  const Model& m_;
  Workspace ws_;     // the integrator's
  Workspace diag_;   // sampling (RK4 and samples with no W-method step after them; snapshots)
  std::unique_ptr<Schedule> schedule_;  // runs every RHS of the integrator
  std::unique_ptr<Profiler> prof_;
  Rk4 rk_;
  std::unique_ptr<WStep> w_main_;  // integrator.method ros2, ros34pw2 or ros34prw, made at the first step
  double w_main_h_ = 0;
  std::unique_ptr<WStep> w_startup_;  // its ROS2 sub-steps before integrator.startup_time
  double w_startup_h_ = 0;
  std::unique_ptr<OdeDriver> w_adaptive_;  // adaptive W-steps (integrator.tolerance) after the start-up
  double w_adaptive_h_ = 0;
  // The first evaluation of the step of size begun_h_ from clock step begun_steps_ is done
  // (a sample took it: begin_w_step).
  bool begun_ = false;
  double begun_h_ = 0;
  long begun_steps_ = 0;
  Eigen::VectorXd y_, dy_;
  Eigen::VectorXd y_start_;  // the state a W sub-step starts from (taken again if it fails)
  int pieces_ = 1;           // the pieces the next W sub-step starts with (w_substep)
  // The energy balance's residual at the end of the last W sub-step that held, and its time
  // (-1: none), so that the next sub-step's energy test starts from it.
  double balance_t_ = -1, balance_r_ = 0;
  long energy_rejections_ = 0;
  // The energy balance's leak (watch_leak): the halvings so far, the last one's time, the
  // last span's leak, and the span's start (its grid step, -1: none; its residual and
  // input work).
  int halvings_ = 0;
  double halved_at_ = -1, leak_ = std::numeric_limits<double>::quiet_NaN();
  long leak_from_ = -1;
  double leak_r_ = 0, leak_w_ = 0;
  bool hold_step_ = false;
  StepClock clock_;  // the run's clock (the only one)
  double energy0_ = 0;
  long steps_taken_ = 0, steps_rejected_ = 0;
  Eigen::VectorXd good_y_;  // last state that passed check_finite, with its time and statuses
  double good_t_ = 0;
  long good_steps_ = 0;
  ContactStatus good_status_;
  Eigen::VectorXd first_y_;  // the first state that passed check_finite
  double first_t_ = 0;
  ContactStatus first_status_;
};

// A W sub-step whose energy balance jumped (Simulation::w_substep, docs/integrators.md 12.3):
// its residual moved by `jump` [J] while `flow` [J] passed through the work integrals (in,
// out, dissipated, clamping). Gross when the jump passes both the flow and kEnergyJumpFloor:
// sound steps of the envelope's points move it by at most 1.7 mJ, and by more than the flow
// only where that is tiny.
inline constexpr double kEnergyJumpFloor = 0.01;  // [J]
inline bool energy_jump(double jump, double flow) { return jump > kEnergyJumpFloor && jump > flow; }

// Names coordinate i of the first-order state (e.g. "velocity of joint 17, half b, end 1, x").
std::string describe_state_index(const Model& m, int i);

}  // namespace cvt
