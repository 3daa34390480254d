// The CVT model as a first-order system y' = f(t, y) for the generic integrators of
// engine/ode/ode.hpp (docs/integrators.md 11), in the shape of a SUNDIALS problem: what the
// ODE library's system needs (the right-hand side, Schedule::rhs with the contact statuses
// frozen; the state's layout and scaling; the coloured finite-difference Jacobian over a
// sparsity pattern built from the model's structure; the error norm), with the W-method's
// linear solver (engine/wmethod/w_solver.hpp) installed through the system's w_factor /
// w_solve hooks. engine/wmethod/driver.hpp runs any OdeMethod on it.
#pragma once

#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include "engine/ode/ode.hpp"
#include "engine/wmethod/options.hpp"
#include "engine/wmethod/w_solver.hpp"

namespace cvt {

// The unit vector s of ModelOdeOptions::scaled.
Eigen::VectorXd model_state_units(const Model& m, const ModelOdeOptions& opt);

// Nonzero pattern of df/dy for model m. With pin_to_tail the dense rows (shaft
// accelerations, dissipated power) carry every pin column; without, only the tail columns.
std::vector<std::pair<int, int>> model_jacobian_pattern(const Model& m, int band, bool pin_to_tail);

// The adapter. Holds references: model, workspace and schedule must outlive it. The
// workspace must be the schedule's (its statuses are the frozen ones, its slots are read
// by the Jacobian).
class ModelOde {
 public:
  ModelOde(const Model& m, Workspace& ws, Schedule& schedule, const ModelOdeOptions& opt = {});
  const OdeSystem& system() const { return sys_; }
  // State units (all ones unless scaled): the system integrates z = y / units().
  const Eigen::VectorXd& units() const { return unit_; }
  // The shift c (scaled mode): y = c + units() * z.
  Eigen::VectorXd& offset() { return offset_; }
  void to_z(const Eigen::VectorXd& y, Eigen::VectorXd& z) const { z = (y - offset_).cwiseQuotient(unit_); }
  void to_y(const Eigen::VectorXd& z, Eigen::VectorXd& y) const { y = offset_ + z.cwiseProduct(unit_); }
  // Every evaluation of f, including the Jacobian's (OdeStats does not see the latter:
  // to the solver the Jacobian is "analytic").
  // The stiffness's force evaluations count as evaluations, each stiffness as a Jacobian.
  std::int64_t rhs_evals() const { return rhs_evals_ + w_.stiffness().evaluations(); }
  std::int64_t jacobian_evals() const { return jac_evals_ + w_.stiffness().takes(); }
  int colors() const {
    ensure_colors();
    return n_colors_;
  }
  // Wall seconds spent in the W-method's stiffness differences (part of its w_factor time).
  double w_stiffness_seconds() const { return w_.stiffness().seconds(); }
  // The coloured finite-difference Jacobian at (t, y) into jac (which has sys.sparsity).
  void jacobian(double t, const double* y, Eigen::SparseMatrix<double>& jac);
  // The W-method's linear solver (installed as the system's w_factor / w_solve unless
  // ModelOdeOptions::w_blocks is false).
  WSolver& w_solver() { return w_; }
  const WSolver& w_solver() const { return w_; }
  // The next step is the run's step `index`: its first evaluation also fills the friction
  // part of W where the step needs it (WSolver::ask).
  void ask_friction_jacobian(long index) { w_.ask(index); }
  // The implicit methods' frozen friction branch (FrozenFriction): from now on the
  // evaluations keep each contact's branch, and the next one records it afresh (OdeDriver,
  // at the start of each macro step).
  void record_friction_branches() { freeze_ = frozen_.record = true; }
  // What the kernels filled at the last request (tests).
  const FrictionJacobian& friction_jacobian() const { return w_.friction_jacobian(); }
  bool w_due() const { return w_.due(); }
  double w_gh() const { return w_.gh(); }
  void w_invalidate() { w_.invalidate(); }
  std::int64_t w_status_rebuilds() const { return w_.status_rebuilds(); }
  std::int64_t w_fresh_contacts() const { return w_.fresh_contacts(); }
  std::int64_t w_fresh_rebuilds() const { return w_.fresh_rebuilds(); }

 private:
  void eval(double t, const double* y, double* dy) {
    Profiler* prof = schedule_.profiler();
    const std::uint64_t t0 = prof ? Profiler::ticks() : 0;
    // The friction part of W comes from the first evaluation of a step that asks for it
    // (ask_friction_jacobian); the step's later evaluations compute f alone.
    schedule_.rhs(t, y, dy, nullptr, {w_.recording(), freeze_ ? &frozen_ : nullptr});
    if (prof) prof->add_rhs_wall(Profiler::ticks() - t0);
    ++rhs_evals_;
    w_.recorded();
    frozen_.record = false;  // the evaluation that recorded the branches was this one
  }
  void eval_scaled(double t, const double* z, double* dz);
  double chain_error_norm(const double* err) const;  // ModelOdeOptions::error_tol's norm
  void set_error_norm();
  std::vector<double> norm_weight_;  // per state component: 1 / (error_tol * its unit), 0: left out
  std::vector<int> norm_group_;      // group boundaries in state order (joints, shafts, load)
  // The per-pin parts of the dense rows after an evaluation: shaft forces [N][14] and
  // dissipated power [N] of the chain and pulley slots.
  void read_slots(std::vector<double>& shaft, std::vector<double>& pdiss) const;
  bool is_pin(int col) const { return col < 2 * m_.ndof && col % m_.ndof < kJointSize * m_.links; }
  int joint_of(int col) const { return (col % m_.ndof) / kJointSize; }

  const Model& m_;
  Workspace& ws_;
  Schedule& schedule_;
  ModelOdeOptions opt_;
  FrozenFriction frozen_;  // the implicit methods' friction branches
  bool freeze_ = false;    // the evaluations take frozen_ (record_friction_branches)
  OdeSystem sys_;
  std::int64_t rhs_evals_ = 0, jac_evals_ = 0;
  // Column colours (the pins by the pattern without pin -> tail entries).
  void ensure_colors() const;  // the colouring below, made at the first Jacobian
  mutable bool colored_ = false;
  mutable std::vector<std::vector<int>> columns_of_color_;
  mutable std::vector<int> owner_;  // [colour * N + joint]: index in columns_of_color_ of the column near the joint, or -1
  mutable int n_colors_ = 0;
  Eigen::MatrixXd a0_shaft_inv_;  // (2 shafts + load) x 14
  Eigen::VectorXd f0_, f1_, yp_, delta_, unit_, ys_, offset_;
  std::vector<double> shaft0_, pdiss0_, shaft1_, pdiss1_;
  mutable Eigen::MatrixXd acc_shaft_;  // [14][columns in the colour] (sized by ensure_colors)
  mutable Eigen::VectorXd acc_p_;
  WSolver w_;  // last: it refers to unit_ and offset_
};

}  // namespace cvt
