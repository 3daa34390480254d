// The production step of the W-methods (docs/integrators.md 12): ROS2 or ROS34PW2 with a
// fixed step on the model's ODE system (ModelOde) and its W linear solver (WSolver), in
// the order it runs: evaluate (the step's first evaluation, which also records the friction
// part of W where the step needs it), then finish (W set up, rebuilt if due; the stages,
// each an evaluation and a solve). Simulation::w_step runs it with the contact statuses
// and the clock; the generic OdeSolver (engine/wmethod/driver.hpp) runs the same stages
// (engine/ode/w_stages.hpp) for the studies and adaptive steps.
#pragma once

#include <string>

#include "engine/model/config.hpp"
#include "engine/ode/w_stages.hpp"
#include "engine/wmethod/model_ode.hpp"

namespace cvt {

class WStep {
 public:
  // method: OdeMethod::Ros2, Ros34pw2 or Ros34prw. Model, workspace and schedule must outlive it.
  WStep(const Model& m, Workspace& ws, Schedule& schedule, OdeMethod method, const ModelOdeOptions& opt);
  // The first evaluation of the run's step `index` from (t, y): f(t, y), the workspace left
  // as it leaves it (a sample of the state reads it).
  void evaluate(double t, const Eigen::VectorXd& y, long index);
  // The rest of that step, of size h: y <- y(t + h).
  void finish(double t, double h, Eigen::VectorXd& y);
  // The next step rebuilds the whole matrix, its stiffness included (a step taken again).
  void retake() { ode_.w_solver().retake(); }
  const ModelOde& system() const { return ode_; }
  const Eigen::VectorXd& f0() const { return f0_; }  // the last evaluate()'s f(t, y)
  // The last finish()'s error estimate in units of (1 um, 1 mm/s) at the pin, shaft or load
  // that errs most (ModelOde's error norm, docs/integrators.md 16), and the estimate above
  // which a step is gross: no accuracy the run reports survives it (ROS2's first-order
  // estimate runs about ten times ROS34PW2's on the same step).
  double error() const { return err_; }
  double gross() const { return method_ == OdeMethod::Ros2 ? 1000.0 : 100.0; }

 private:
  ModelOde ode_;
  OdeMethod method_;
  const W4Tableau* w4_;  // the four-stage method's tableau; null for ROS2
  double gamma_;
  double err_ = 0;
  Eigen::VectorXd f0_;
  WStageVectors v_;
};

// The W-method's step of `cvt-engine run` as GraphViz (`cvt-engine graph`): its stages, each an
// evaluation (the schedule's graph) and a solve with the block LU on two sweeps, the matrix's
// rebuilds, and for adaptive steps the error test; `threads` the schedule's.
std::string w_step_graphviz(const Config& c, int threads);

}  // namespace cvt
