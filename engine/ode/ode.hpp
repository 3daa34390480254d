// Generic integrators for any first-order system y' = f(t, y) (docs/integrators.md).
//
// The engine's production path keeps the fixed-step Rk4 of engine/ode/rk4.hpp, whose
// fused stage update the parallel runtime relies on bit for bit. This library sits beside
// it: explicit (RK4, DOPRI5(4), RKC, DUMKA3) and implicit (trapezoid, TR-BDF2, ESDIRK3) methods
// behind one driver, with error control, Newton with a reused Jacobian and factorization,
// and a finite-difference Jacobian that needs one right-hand side per column colour when
// the sparsity pattern is known.
#pragma once

#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Dense>
#include <Eigen/Sparse>

// The library's names live in an inline namespace named after Eigen's heap and static
// alignment (cvt::eigen_align_32_32 under AVX): Eigen objects cross this interface and the
// linker shares Eigen's template instances between a program and the library, so a program
// whose Eigen aligns differently (one built with the compiler's default flags: 16 bytes) would
// free with one allocator what the other allocated, and crash. With the namespace such a
// program fails to link, naming the alignment it expected, and a pimpl could not help: the
// state vector, the sparsity pattern and the Jacobians are Eigen objects of the interface
// itself. CMake targets that link cvt_ode receive the library's values as PUBLIC definitions
// (EIGEN_MAX_ALIGN_BYTES, EIGEN_MAX_STATIC_ALIGN_BYTES); a program built otherwise passes
// the same two (docs/integrators.md 1). Spelled out as cvt::OdeSolver etc. everywhere else.
#define CVT_ODE_ABI_NAME_(heap, stat) eigen_align_##heap##_##stat
#define CVT_ODE_ABI_NAME(heap, stat) CVT_ODE_ABI_NAME_(heap, stat)
#define CVT_ODE_ABI CVT_ODE_ABI_NAME(EIGEN_MAX_ALIGN_BYTES, EIGEN_MAX_STATIC_ALIGN_BYTES)

namespace cvt {
inline namespace CVT_ODE_ABI {

// y' = f(t, y). `rhs` writes dy (size `size`) and must not allocate: it is called once per
// stage. Raw pointers so that any storage (Eigen, State buffers) can be handed in.
struct OdeSystem {
  using Rhs = std::function<void(double t, const double* y, double* dy)>;
  // Analytic Jacobians (optional). The dense one fills an n x n matrix; the sparse one
  // overwrites the values of a matrix that already has the pattern `sparsity`.
  using DenseJacobian = std::function<void(double t, const double* y, Eigen::MatrixXd& jac)>;
  using SparseJacobian = std::function<void(double t, const double* y, Eigen::SparseMatrix<double>& jac)>;

  int size = 0;
  Rhs rhs;
  DenseJacobian dense_jacobian;
  SparseJacobian sparse_jacobian;
  // Nonzero pattern of df/dy (values ignored). Non-empty: the implicit methods work with a
  // sparse Jacobian (coloured finite differences unless sparse_jacobian is given) and
  // Eigen::SparseLU; empty: dense Jacobian and dense LU.
  Eigen::SparseMatrix<double> sparsity;

  bool is_sparse() const { return sparsity.nonZeros() > 0; }

  // W-methods (is_w_method: Ros2, Ros34pw2, Ros34prw) with a system-supplied approximate Jacobian J~ (optional;
  // without them a W-method takes the Jacobian above and an LU, fresh at every step):
  // w_factor(t, y, gh) prepares W = I - gh J~ at (t, y), and is always called right after
  // rhs(t, y), so a system may take J~ from what that evaluation recorded; w_solve(x)
  // overwrites x with W^-1 x. A W-method keeps its order for any J~; J~ only has to capture
  // the stiff part for the step to be stable.
  using WFactor = std::function<void(double t, const double* y, double gh)>;
  using WSolve = std::function<void(double* x)>;
  WFactor w_factor;
  WSolve w_solve;
  // With w_factor, optional: the next evaluation records what the matrix needs and the next
  // w_factor rebuilds all of it, whatever the system's own schedule of rebuilds. For solvers
  // that decide themselves when their matrix is stale (SUNDIALS' linear-solver setups).
  std::function<void()> w_refresh;
  // df/dt at (t, y), optional: writes size values and must not allocate. With it the
  // W-methods take the t-column of their matrix exactly (the terms gamma_i h^2 df/dt of
  // Hairer & Wanner II, IV.7), which keeps their order on stiff problems driven by an
  // explicit function of t (ROS2 falls to order 1 on Prothero-Robinson without it,
  // docs/integrators.md 12.1). Without it they run exactly as an autonomous W-method whose
  // t-column is zero. The other methods do not use it.
  using TimeDerivative = std::function<void(double t, const double* y, double* dfdt)>;
  TimeDerivative time_derivative;
  // The error test's norm, optional: the scaled size of a step's error estimate err (1 is
  // the tolerance) given the step's start and end states. Without it every adaptive method
  // takes Hairer's weighted RMS norm (or the max norm) over atol / rtol. For systems whose
  // error concentrates in a few groups of many components (the CVT: the pins entering a
  // sheave), a norm per group, maximized over the groups, is not diluted by the others.
  using ErrorNorm = std::function<double(const double* err, const double* y0, const double* y1)>;
  ErrorNorm error_norm;
  // Components the right-hand side does not read (integrals of outputs, like the CVT's
  // contact switching work), optional: a caller may add to them between integrate() calls,
  // and a solver with a history (SUNDIALS' methods) carries the addition over instead of
  // starting afresh.
  std::vector<int> passive;
  // The pattern from a list of (row, column) nonzeros; duplicates are fine.
  void set_sparsity(const std::vector<std::pair<int, int>>& nonzeros);
};

enum class OdeMethod {
  Rk4,        // classical RK4: fixed steps (the same arithmetic as cvt::Rk4) or step doubling
  Dopri5,     // Dormand-Prince 5(4), Hairer's error norm and PI controller
  Rkc,        // Runge-Kutta-Chebyshev, 2nd order, stabilized explicit (Sommeijer et al. 1997)
  Trapezoid,  // implicit trapezoidal rule, A-stable but not L-stable, order 2
  TrBdf2,     // TR-BDF2, gamma = 2 - sqrt 2, L-stable, order 2 (Hosea & Shampine 1996)
  Esdirk3,    // Kvaerno's ESDIRK 3(2), 4 stages, L-stable, stiffly accurate, order 3
  Ros2,       // Verwer et al.'s ROS2 W-method, 2 stages, order 2 for any J~, L-stable for J~ = J
  Ros34pw2,   // Rang & Angermann's ROS34PW2 W-method, 4 stages, order 3 for any J~, stiffly accurate
  // Rang's ROS34PRW: 4 stages, stiffly accurate, the same gamma as ROS34PW2; order 3 with the
  // exact Jacobian and on the Prothero-Robinson problem for any h lambda (where ROS34PW2 is of
  // order 2), second order with a matrix kept over several steps (not a W-method).
  Ros34prw,
  // Medovikov's DUMKA3 (BIT 38 (1998) 372-390, dumka3.f): 3rd order, stabilized explicit, one of
  // 15 optimal stability polynomials of degree 3 ... 576 (the stages of a step) chosen from the
  // spectral radius; real stability interval 2.5 ... 142602 (about 0.3-0.5 s^2). A fixed
  // step with h rho beyond the largest interval throws OdeError.
  Dumka3,
  // SUNDIALS (engine/ode/sundials.hpp; only where the build found it, sundials_available()):
  // CVODE's variable-order BDF (orders 1-5) and ARKODE's ESDIRK 3(2) (ARK324L2SA, 4 stages,
  // L-stable), each with its own step and order control, error test (weighted RMS over
  // rtol, atol) and Newton iteration; the system's w_factor / w_solve as their linear
  // solver where it has them. Adaptive only.
  Cvode,
  Arkode,
};
// Whether this build has SUNDIALS' methods (OdeMethod::Cvode, OdeMethod::Arkode).
bool sundials_available();
inline bool is_sundials_method(OdeMethod m) { return m == OdeMethod::Cvode || m == OdeMethod::Arkode; }

// The linearly implicit methods (Ros2, Ros34pw2, Ros34prw; "W-methods" for short, though
// ROS34PRW keeps its order only with a current Jacobian): one matrix W = I - gamma h J~ per
// step, no Newton iteration; all take a system's w_factor / w_solve.
inline bool is_w_method(OdeMethod m) {
  return m == OdeMethod::Ros2 || m == OdeMethod::Ros34pw2 || m == OdeMethod::Ros34prw;
}
// gamma of a W-method's matrix W = I - gamma h J~ (1 + 1/sqrt 2 for ROS2, 0.4358665215 for
// ROS34PW2 and ROS34PRW); throws std::invalid_argument for the other methods.
double w_method_gamma(OdeMethod m);
// The implicit methods with Newton (trapezoid, TR-BDF2, ESDIRK3).
inline bool is_implicit_method(OdeMethod m) {
  return m == OdeMethod::Trapezoid || m == OdeMethod::TrBdf2 || m == OdeMethod::Esdirk3;
}

const char* to_string(OdeMethod method);
// The inverse of to_string: "rk4" | "dopri5" | "rkc" | "dumka3" | "trapezoid" | "trbdf2" |
// "esdirk3" | "ros2" | "ros34pw2" | "ros34prw" | "cvode" | "arkode"; throws std::invalid_argument otherwise
// (SUNDIALS' names too are parsed in a build without it: the solver then says what is missing).
OdeMethod parse_ode_method(const std::string& name);

struct OdeOptions {
  double rtol = 1e-6;
  double atol = 1e-9;
  // Absolute tolerance per component (size n) in place of atol when not empty: for states
  // whose components live on different scales (ROBER's y2 ~ 1e-5 beside y1, y3 ~ 1). Used
  // wherever atol is: the error norm of every adaptive method, the starting step, Newton's
  // convergence test.
  std::vector<double> atol_vector;
  double h0 = 0;  // first step; 0: chosen from f (Hairer's starting step algorithm)
  double h_max = std::numeric_limits<double>::infinity();
  double h_min = 0;  // 0: 16 ulps of t; a step size below it throws OdeError
  std::int64_t max_steps = 10'000'000;
  // Fixed step h0 (required > 0), shortened uniformly so that the steps end on t1; no error
  // control. Rk4 also runs this way when h0 > 0 without fixed_step (as it always has); with
  // h0 = 0 it is adaptive (step doubling).
  bool fixed_step = false;

  // RKC and DUMKA3: re-estimate the spectral radius after this many accepted steps (and after
  // a rejection); 0 never again after the first.
  int rkc_rho_every = 25;
  // RKC and DUMKA3: a user-supplied bound on the spectral radius of df/dy replaces the power
  // iteration (whose estimate both take times 1.2).
  std::function<double(double t, const double* y)> spectral_radius;

  // Newton (implicit methods). max iterations per stage; recompute the Jacobian at the next
  // step when the observed contraction rate theta exceeds jac_theta; keep h (RADAU5's
  // quot1/quot2 rule) when the controller proposes a ratio in [1, keep_h_ratio] (1: off,
  // since lu_rel_change below already saves the LU and free steps are cheaper).
  int newton_max_iter = 7;
  double jac_theta = 0.3;
  double keep_h_ratio = 1.0;
  // Keep the LU of I - dh' J while |dh / dh' - 1| <= lu_rel_change (0: refactorize at
  // every change of h).
  double lu_rel_change = 0.2;
  // Keep the Jacobian (and LU) of the previous integrate() call instead of taking a fresh
  // one at the start of each call: for callers that integrate one system in short pieces
  // (engine/wmethod/model_ode.hpp). Newton's convergence monitor still asks for a new one when it is
  // stale.
  bool keep_jacobian_across_calls = false;
  // Error test and Newton's convergence test in the max norm instead of the RMS norm: for
  // systems (the CVT) whose error concentrates in a few of many components, which an RMS over
  // all of them dilutes by sqrt(n).
  bool max_norm = false;
  // W-methods without a system W (finite-difference or analytic Jacobian): keep the Jacobian and
  // the LU of W for this many steps (a W-method keeps its order with a stale matrix);
  // rebuilt earlier when gamma h changes.
  int w_reuse_steps = 1;
  // W-methods with the Jacobian above (no system w_factor), adaptive mode: a step passes
  // only if, besides the embedded estimate, the part of f that W's linearization misses,
  // carried over the step, || W^-1 h (f(t, y1) - f(t, y0) - J (y1 - y0)) ||, is within the
  // tolerance (docs/integrators.md 12.5). The embedded estimate alone passes steps over
  // which the Jacobian changes much: HIRES at tol 1e-4, a step of 212 estimated at 0.55 of
  // the tolerance, true error 57 times it. One more evaluation of f per attempt.
  bool w_linearization_test = true;
  // Implicit methods (trapezoid, TR-BDF2, ESDIRK3): simplified Newton with the system's
  // W-method matrix (w_factor(t, y, d h) at each step's start, after a fresh f(t, y); w_solve
  // for every iteration and for the error filter) in place of a Jacobian and an LU of the
  // library's own. The system decides when its matrix is rebuilt; Newton only needs it to
  // contract. Ignored without w_factor / w_solve.
  bool newton_uses_w = false;
};

struct OdeStats {
  std::int64_t steps = 0;  // accepted
  std::int64_t rejected = 0;
  std::int64_t rhs_evals = 0;  // including those of finite-difference Jacobians and rho estimates
  std::int64_t jac_evals = 0;
  std::int64_t lu_factorizations = 0;
  std::int64_t newton_iterations = 0;
  std::int64_t newton_failures = 0;
  std::int64_t rho_estimates = 0;  // RKC, DUMKA3
  int max_stages = 0;              // RKC, DUMKA3: most stages (f-evaluations) used in one step
  int colors = 0;                  // colours of the finite-difference Jacobian (0: dense or analytic)
  double h_last = 0;
  // Adaptive mode: the step the controller proposed for after the last accepted one (a
  // caller that integrates in short pieces passes it on as the next call's h0).
  double h_next = 0;
  // Adaptive mode: the scaled error estimate of the last accepted step (<= 1; 0 in fixed
  // steps), for observers that watch the error control.
  double err_last = 0;
  double rho_last = 0;  // RKC, DUMKA3: last spectral radius used
  // Wall time of the implicit methods' linear algebra [s]: Jacobians (with their f
  // evaluations), LU factorizations, and the Newton iterations' solves.
  double jac_seconds = 0, lu_seconds = 0, solve_seconds = 0;
};

// Thrown when the integration cannot go on: what() names the time, the step and the reason.
class OdeError : public std::runtime_error {
 public:
  OdeError(double t, double h, const std::string& reason);
  double t, h;
};

// Called at t0 and after every accepted step with the new (t, y).
using OdeObserver = std::function<void(double t, const Eigen::VectorXd& y)>;

// Greedy column colouring: columns of one colour share no row, so one RHS evaluation with
// all of them perturbed gives all their Jacobian columns. colors[j] in [0, n_colors).
std::vector<int> color_columns(const Eigen::SparseMatrix<double>& pattern, int* n_colors);

// Estimates the spectral radius of df/dy at (t, y) by the nonlinear power method of RKC's
// rkcrho (Sommeijer, Shampine & Verwer 1997): returns the unsafe estimate sigma (RKC itself
// uses 1.2 sigma). The direction found is kept and starts the next estimate, which then
// converges in a few evaluations. Buffers are sized once.
class SpectralRadius {
 public:
  explicit SpectralRadius(int size);
  // f_y = f(t, y). At most max_iter evaluations of sys.rhs; *rhs_evals counts them.
  double estimate(const OdeSystem& sys, double t, const Eigen::VectorXd& y, const Eigen::VectorXd& f_y,
                  int* rhs_evals, int max_iter = 50);
  bool converged() const { return converged_; }

 private:
  Eigen::VectorXd direction_, y_pert_, f_pert_;
  bool converged_ = false;
};

// Finite-difference Jacobian at (t, y) with f_y = f(t, y): dense (n evaluations) or, with a
// sparsity pattern, coloured (n_colors evaluations). Buffers are sized once.
class FdJacobian {
 public:
  explicit FdJacobian(const OdeSystem& sys);
  int colors() const { return n_colors_; }
  void dense(double t, const Eigen::VectorXd& y, const Eigen::VectorXd& f_y, Eigen::MatrixXd& jac);
  // jac must have the pattern of sys.sparsity (compressed); its values are overwritten.
  void sparse(double t, const Eigen::VectorXd& y, const Eigen::VectorXd& f_y, Eigen::SparseMatrix<double>& jac);
  int rhs_evals() const { return rhs_evals_; }

 private:
  const OdeSystem& sys_;
  std::vector<int> color_;
  std::vector<std::vector<int>> columns_of_color_;
  int n_colors_ = 0;
  int rhs_evals_ = 0;
  Eigen::VectorXd y_pert_, f_pert_, delta_;
};

class OdeSolverImpl;

// Owns the workspace of one method for one system: construct once, integrate many times.
// Keeps a reference to sys, which must outlive it.
class OdeSolver {
 public:
  OdeSolver(const OdeSystem& sys, OdeMethod method, const OdeOptions& options = {});
  ~OdeSolver();
  OdeSolver(const OdeSolver&) = delete;
  OdeSolver& operator=(const OdeSolver&) = delete;

  // Advances y from t0 to t1 (t1 > t0). Statistics accumulate over calls.
  void integrate(double t0, double t1, Eigen::VectorXd& y, const OdeObserver& observer = {});
  // SUNDIALS' methods (is_sundials_method): one step of their own choice from (t0, y), ending
  // at or before t_max; returns where it ended. A call from where the last one ended goes on
  // with their history (order, step). For callers that change something between steps (the
  // CVT's contact statuses) without cutting the method's steps to a length of their own.
  // Other methods throw std::logic_error.
  double step(double t0, double t_max, Eigen::VectorXd& y);
  const OdeStats& stats() const;
  OdeStats& stats();
  // The options in use; changes (e.g. h0 between calls) apply from the next integrate().
  OdeOptions& options();

 private:
  std::unique_ptr<OdeSolverImpl> impl_;
};

// One-shot driver: returns the statistics of the run.
OdeStats integrate(const OdeSystem& sys, OdeMethod method, double t0, double t1, Eigen::VectorXd& y,
                   const OdeOptions& options = {}, const OdeObserver& observer = {});

}  // namespace CVT_ODE_ABI
}  // namespace cvt
