// SUNDIALS' integrators behind OdeSolver (OdeMethod::Cvode, OdeMethod::Arkode; docs/integrators.md
// 17): CVODE's variable-order BDF and ARKODE's ESDIRK with their own step, order and error
// control and their own Newton iteration, on the system's right-hand side. A system with
// w_factor / w_solve (the CVT's block-cyclic W solver) is their linear solver, as a SUNDIALS
// matrix-embedded SUNLinearSolver; others get SUNDIALS' dense LU with its difference-quotient
// Jacobian (or the system's dense one). Built only where SUNDIALS is found
// (CVT_WITH_SUNDIALS); elsewhere the constructor throws, naming the package. Not part of the
// public interface.
#pragma once

#include <memory>

#include "engine/ode/ode.hpp"

namespace cvt {
inline namespace CVT_ODE_ABI {

class SundialsSolver {
 public:
  // opt and stats are the OdeSolver's: options are read at every integrate(), the
  // statistics accumulate there.
  SundialsSolver(const OdeSystem& sys, OdeMethod method, const OdeOptions& opt, OdeStats& stats);
  ~SundialsSolver();
  SundialsSolver(const SundialsSolver&) = delete;
  SundialsSolver& operator=(const SundialsSolver&) = delete;
  // From (t0, y) to t1, observer after every step. A call that starts where the last one
  // ended (same t, same y to the bit) continues the solver's history (BDF's order and
  // differences, the step); any other starts afresh from opt.h0 (or SUNDIALS' own first step).
  void integrate(double t0, double t1, Eigen::VectorXd& y, const OdeObserver& observer);
  // One step of the method's own choice from (t0, y), ending at or before t_max; returns
  // where it ended. The history goes on as in integrate().
  double step(double t0, double t_max, Eigen::VectorXd& y);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace CVT_ODE_ABI
}  // namespace cvt
