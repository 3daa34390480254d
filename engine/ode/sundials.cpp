#include "engine/ode/sundials.hpp"

#include <chrono>
#include <cmath>
#include <exception>
#include <string>

#ifdef CVT_WITH_SUNDIALS
#include <arkode/arkode_arkstep.h>
#include <cvode/cvode.h>
#include <nvector/nvector_serial.h>
#include <sundials/sundials_context.h>
#include <sundials/sundials_linearsolver.h>
#include <sunlinsol/sunlinsol_dense.h>
#include <sunmatrix/sunmatrix_dense.h>
#endif

namespace cvt {
inline namespace CVT_ODE_ABI {

bool sundials_available() {
#ifdef CVT_WITH_SUNDIALS
  return true;
#else
  return false;
#endif
}

#ifndef CVT_WITH_SUNDIALS

struct SundialsSolver::Impl {};

SundialsSolver::SundialsSolver(const OdeSystem&, OdeMethod method, const OdeOptions&, OdeStats&) {
  throw std::invalid_argument(std::string(to_string(method)) +
                              ": this build has no SUNDIALS (install libsundials-dev and build again; docs/install.md)");
}
SundialsSolver::~SundialsSolver() = default;
void SundialsSolver::integrate(double, double, Eigen::VectorXd&, const OdeObserver&) {}
double SundialsSolver::step(double t0, double, Eigen::VectorXd&) { return t0; }

#else

namespace {
double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}
}  // namespace

// The two integrators differ only in their calls; everything else is shared.
struct SundialsSolver::Impl {
  const OdeSystem& sys;
  OdeMethod method;
  const OdeOptions& opt;
  OdeStats& stats;
  int n;
  SUNContext ctx = nullptr;
  void* mem = nullptr;
  N_Vector y = nullptr, atol = nullptr;
  SUNMatrix dense = nullptr;
  SUNLinearSolver ls = nullptr;
  bool embedded = false;   // the system's W solver is the linear solver
  bool started = false;    // mem holds a history that a call may continue
  double t_last = 0;
  Eigen::VectorXd y_last, f_tmp;
  Eigen::VectorXd passive_add;  // the caller's additions to the passive components since the start
  std::exception_ptr error;  // thrown inside a callback, rethrown after SUNDIALS returns
  std::string message;       // SUNDIALS' last error message
  // The counters of mem when the current history began (a ReInit zeroes them).
  long steps0 = 0, fails0 = 0, setups0 = 0, iters0 = 0, conv0 = 0;

  Impl(const OdeSystem& s, OdeMethod m, const OdeOptions& o, OdeStats& st)
      : sys(s), method(m), opt(o), stats(st), n(s.size) {}
  ~Impl() {
    if (mem) method == OdeMethod::Cvode ? CVodeFree(&mem) : ARKStepFree(&mem);
    if (ls) embedded ? SUNLinSolFreeEmpty(ls) : static_cast<void>(SUNLinSolFree(ls));
    if (dense) SUNMatDestroy(dense);
    if (y) N_VDestroy(y);
    if (atol) N_VDestroy(atol);
    if (ctx) SUNContext_Free(&ctx);
  }
  const char* name() const { return to_string(method); }
  void begin(double t0, double t1, const Eigen::VectorXd& y_in);
  double one_step(double t, Eigen::VectorXd& y_out);
  bool cvode() const { return method == OdeMethod::Cvode; }

  // Callbacks: C++ exceptions stop at the C boundary.
  static int rhs(double t, N_Vector yv, N_Vector dyv, void* data) {
    auto* s = static_cast<Impl*>(data);
    try {
      s->sys.rhs(t, N_VGetArrayPointer(yv), N_VGetArrayPointer(dyv));
      ++s->stats.rhs_evals;
      // A non-finite derivative is recoverable: the integrator retries with a shorter step.
      const double* d = N_VGetArrayPointer(dyv);
      for (int i = 0; i < s->n; ++i)
        if (!std::isfinite(d[i])) return 1;
      return 0;
    } catch (...) {
      s->error = std::current_exception();
      return -1;
    }
  }
  static int dense_jacobian(double t, N_Vector yv, N_Vector, SUNMatrix J, void* data, N_Vector, N_Vector, N_Vector) {
    auto* s = static_cast<Impl*>(data);
    try {
      Eigen::MatrixXd jac(s->n, s->n);
      s->sys.dense_jacobian(t, N_VGetArrayPointer(yv), jac);
      Eigen::Map<Eigen::MatrixXd>(SM_DATA_D(J), s->n, s->n) = jac;  // both column-major
      ++s->stats.jac_evals;
      return 0;
    } catch (...) {
      s->error = std::current_exception();
      return -1;
    }
  }
  static void on_error(int, const char*, const char*, char* msg, void* data) {
    static_cast<Impl*>(data)->message = msg ? msg : "";
  }

  // The matrix-embedded linear solver. SUNDIALS leaves such a solver its own setups (it
  // calls no lsetup for it, cvode_ls.c), so the solve decides as CVODE's and ARKODE's own
  // lsetup heuristics do: W = I - gamma J~ is built afresh at the integrator's current (t, y)
  // (after an evaluation there that records what the matrix needs, OdeSystem::w_refresh) at
  // the first solve, when gamma moved by more than kGammaChange from the factorized one, when
  // kSetupSteps steps passed, and after a Newton failure; else the factorized W serves.
  static constexpr double kGammaChange = 0.2;  // ARKODE's dgmax (CVODE's: 0.3)
  static constexpr long kSetupSteps = 20;      // both integrators' msbp
  double gamma_f = 0;                          // gamma of the factorized W (0: none)
  long steps_f = 0, conv_f = 0;                // the steps and Newton failures at its setup
  static SUNLinearSolver_Type ls_type(SUNLinearSolver) { return SUNLINEARSOLVER_MATRIX_EMBEDDED; }
  static SUNLinearSolver_ID ls_id(SUNLinearSolver) { return SUNLINEARSOLVER_CUSTOM; }
  void setup_if_stale() {
    double gamma = 0, t = 0;
    long nst = 0, ncf = 0;
    N_Vector yc = nullptr;
    if (cvode()) {
      CVodeGetCurrentGamma(mem, &gamma), CVodeGetCurrentTime(mem, &t), CVodeGetCurrentState(mem, &yc);
      CVodeGetNumSteps(mem, &nst), CVodeGetNumNonlinSolvConvFails(mem, &ncf);
    } else {
      ARKStepGetCurrentGamma(mem, &gamma), ARKStepGetCurrentTime(mem, &t), ARKStepGetCurrentState(mem, &yc);
      ARKStepGetNumSteps(mem, &nst), ARKStepGetNumNonlinSolvConvFails(mem, &ncf);
    }
    const bool stale = gamma_f == 0 || std::abs(gamma / gamma_f - 1) > kGammaChange || nst >= steps_f + kSetupSteps ||
                       nst < steps_f || ncf != conv_f;
    if (!stale) return;
    const auto c0 = std::chrono::steady_clock::now();
    if (sys.w_refresh) sys.w_refresh();
    sys.rhs(t, N_VGetArrayPointer(yc), f_tmp.data());
    ++stats.rhs_evals;
    sys.w_factor(t, N_VGetArrayPointer(yc), gamma);
    ++stats.jac_evals, ++stats.lu_factorizations;
    stats.lu_seconds += seconds_since(c0);
    gamma_f = gamma, steps_f = nst, conv_f = ncf;
  }
  static int ls_solve(SUNLinearSolver S, SUNMatrix, N_Vector x, N_Vector b, double) {
    auto* s = static_cast<Impl*>(S->content);
    try {
      s->setup_if_stale();
      const auto c0 = std::chrono::steady_clock::now();
      N_VScale(1.0, b, x);
      double* xs = N_VGetArrayPointer(x);
      s->sys.w_solve(xs);
      s->stats.solve_seconds += seconds_since(c0);
      // A non-finite solution is recoverable: the integrator shortens the step.
      for (int i = 0; i < s->n; ++i)
        if (!std::isfinite(xs[i])) return SUNLS_PACKAGE_FAIL_REC;
      return SUNLS_SUCCESS;
    } catch (const std::exception&) {
      // A singular or failed matrix (the W solver throws) is recoverable too.
      s->gamma_f = 0;
      return SUNLS_PACKAGE_FAIL_REC;
    }
  }

  void check(int flag, const char* call) {
    if (flag >= 0) return;
    throw std::runtime_error(std::string(name()) + ": " + call + " failed (flag " + std::to_string(flag) + ")" +
                             (message.empty() ? "" : ": " + message));
  }

  // The integrator's memory, its tolerances, limits and linear solver, from (t0, y).
  void start(double t0) {
    if (!mem) {
      if (cvode()) {
        mem = CVodeCreate(CV_BDF, ctx);
        check(mem ? 0 : -1, "CVodeCreate");
        check(CVodeInit(mem, rhs, t0, y), "CVodeInit");
        check(CVodeSetUserData(mem, this), "CVodeSetUserData");
        check(CVodeSetErrHandlerFn(mem, on_error, this), "CVodeSetErrHandlerFn");
        check(CVodeSetLinearSolver(mem, ls, dense), "CVodeSetLinearSolver");
        if (!embedded && sys.dense_jacobian) check(CVodeSetJacFn(mem, dense_jacobian), "CVodeSetJacFn");
      } else {
        mem = ARKStepCreate(nullptr, rhs, t0, y, ctx);
        check(mem ? 0 : -1, "ARKStepCreate");
        check(ARKStepSetUserData(mem, this), "ARKStepSetUserData");
        check(ARKStepSetErrHandlerFn(mem, on_error, this), "ARKStepSetErrHandlerFn");
        // Kvaerno's and Kennedy & Carpenter's ESDIRK 3(2) with 4 stages, L-stable: the
        // counterpart of the library's own ESDIRK3.
        check(ARKStepSetTableNum(mem, ARKODE_ARK324L2SA_DIRK_4_2_3, ARKODE_ERK_NONE), "ARKStepSetTableNum");
        check(ARKStepSetLinearSolver(mem, ls, dense), "ARKStepSetLinearSolver");
        if (!embedded && sys.dense_jacobian) check(ARKStepSetJacFn(mem, dense_jacobian), "ARKStepSetJacFn");
      }
    } else {
      check(cvode() ? CVodeReInit(mem, t0, y) : ARKStepReInit(mem, nullptr, rhs, t0, y), "ReInit");
    }
    steps0 = fails0 = setups0 = iters0 = conv0 = 0;
    gamma_f = 0, steps_f = conv_f = 0;
    // Tolerances: rtol and atol (or atol_vector) of the options, SUNDIALS' weighted RMS norm.
    if (opt.atol_vector.empty()) {
      N_VConst(opt.atol, atol);
    } else {
      if (static_cast<int>(opt.atol_vector.size()) != n)
        throw std::invalid_argument("OdeOptions: atol_vector must be empty or have one entry per component");
      for (int i = 0; i < n; ++i) NV_Ith_S(atol, i) = opt.atol_vector[i];
    }
    check(cvode() ? CVodeSVtolerances(mem, opt.rtol, atol) : ARKStepSVtolerances(mem, opt.rtol, atol), "tolerances");
    const long max_steps = static_cast<long>(std::min<std::int64_t>(opt.max_steps, 1L << 40));
    check(cvode() ? CVodeSetMaxNumSteps(mem, max_steps) : ARKStepSetMaxNumSteps(mem, max_steps), "SetMaxNumSteps");
    // A step whose error test or Newton iteration fails is retried with a shorter one up to
    // 20 times (SUNDIALS' defaults, 7 and 10, end ARKODE's ESDIRK on Van der Pol at mu = 1e3
    // and tol 1e-5 in its first relaxation jump).
    check(cvode() ? CVodeSetMaxErrTestFails(mem, 20) : ARKStepSetMaxErrTestFails(mem, 20), "SetMaxErrTestFails");
    check(cvode() ? CVodeSetMaxConvFails(mem, 20) : ARKStepSetMaxConvFails(mem, 20), "SetMaxConvFails");
    if (opt.h0 > 0) check(cvode() ? CVodeSetInitStep(mem, opt.h0) : ARKStepSetInitStep(mem, opt.h0), "SetInitStep");
    if (std::isfinite(opt.h_max))
      check(cvode() ? CVodeSetMaxStep(mem, opt.h_max) : ARKStepSetMaxStep(mem, opt.h_max), "SetMaxStep");
    if (opt.h_min > 0) check(cvode() ? CVodeSetMinStep(mem, opt.h_min) : ARKStepSetMinStep(mem, opt.h_min), "SetMinStep");
  }

  // Adds the counters' growth since the last call to the statistics.
  void take_counts() {
    long st = 0, fails = 0, nsetups = 0, iters = 0, conv = 0;
    double h_last = 0, h_next = 0;
    if (cvode()) {
      CVodeGetNumSteps(mem, &st), CVodeGetNumErrTestFails(mem, &fails), CVodeGetNumLinSolvSetups(mem, &nsetups);
      CVodeGetNumNonlinSolvIters(mem, &iters), CVodeGetNumNonlinSolvConvFails(mem, &conv);
      CVodeGetLastStep(mem, &h_last), CVodeGetCurrentStep(mem, &h_next);
    } else {
      ARKStepGetNumSteps(mem, &st), ARKStepGetNumErrTestFails(mem, &fails), ARKStepGetNumLinSolvSetups(mem, &nsetups);
      ARKStepGetNumNonlinSolvIters(mem, &iters), ARKStepGetNumNonlinSolvConvFails(mem, &conv);
      ARKStepGetLastStep(mem, &h_last), ARKStepGetCurrentStep(mem, &h_next);
    }
    stats.steps += st - steps0;
    stats.rejected += (fails - fails0) + (conv - conv0);
    stats.newton_iterations += iters - iters0;
    stats.newton_failures += conv - conv0;
    if (!embedded) {
      // SUNDIALS' own Jacobians (their difference quotients' evaluations pass through rhs),
      // one LU per setup.
      stats.lu_factorizations += nsetups - setups0;
      if (!sys.dense_jacobian) stats.jac_evals += nsetups - setups0;
    }
    steps0 = st, fails0 = fails, setups0 = nsetups, iters0 = iters, conv0 = conv;
    stats.h_last = h_last, stats.h_next = h_next;
  }
};

SundialsSolver::SundialsSolver(const OdeSystem& sys, OdeMethod method, const OdeOptions& opt, OdeStats& stats)
    : impl_(std::make_unique<Impl>(sys, method, opt, stats)) {
  Impl& s = *impl_;
  if (method != OdeMethod::Cvode && method != OdeMethod::Arkode)
    throw std::invalid_argument("SundialsSolver: not a SUNDIALS method");
  if (static_cast<bool>(sys.w_factor) != static_cast<bool>(sys.w_solve))
    throw std::invalid_argument("OdeSystem: w_factor and w_solve go together");
  for (int i : sys.passive)
    if (i < 0 || i >= sys.size) throw std::invalid_argument("OdeSystem: a passive component is out of range");
  if (SUNContext_Create(nullptr, &s.ctx) != 0) throw std::runtime_error("SUNContext_Create failed");
  s.y = N_VNew_Serial(s.n, s.ctx);
  s.atol = N_VNew_Serial(s.n, s.ctx);
  s.f_tmp.setZero(s.n);
  s.embedded = static_cast<bool>(sys.w_factor);
  if (s.embedded) {
    s.ls = SUNLinSolNewEmpty(s.ctx);
    s.ls->content = &s;
    s.ls->ops->gettype = Impl::ls_type;
    s.ls->ops->getid = Impl::ls_id;
    s.ls->ops->solve = Impl::ls_solve;
  } else {
    s.dense = SUNDenseMatrix(s.n, s.n, s.ctx);
    s.ls = SUNLinSol_Dense(s.y, s.dense, s.ctx);
  }
  if (!s.y || !s.atol || !s.ls || (!s.embedded && !s.dense)) throw std::runtime_error("SUNDIALS: out of memory");
}

SundialsSolver::~SundialsSolver() = default;

// Continues the history where the call starts at the last one's end with the same state
// (but for what the caller added to the passive components, carried in passive_add), else
// starts afresh from (t0, y); then sets the stop time t1.
void SundialsSolver::Impl::begin(double t0, double t1, const Eigen::VectorXd& y_in) {
  if (opt.fixed_step) throw std::invalid_argument(std::string(name()) + ": SUNDIALS' methods take no fixed step");
  if (y_in.size() != n) throw std::invalid_argument("OdeSolver: y has the wrong size");
  if (!(t1 > t0)) throw std::invalid_argument("OdeSolver: t1 must be greater than t0");
  double* yv = N_VGetArrayPointer(y);
  bool same = started && t0 == t_last;
  if (same) {
    y_last(sys.passive) = y_in(sys.passive);  // (y_last is set anew before it is read again)
    same = std::equal(y_in.data(), y_in.data() + n, y_last.data());
  }
  started = false;  // until the call ends well
  if (!same) {
    std::copy(y_in.data(), y_in.data() + n, yv);
    passive_add.setZero(n);
    start(t0);
  } else {
    for (int i : sys.passive) passive_add[i] = y_in[i] - yv[i];
    if (std::isfinite(opt.h_max))
      check(cvode() ? CVodeSetMaxStep(mem, opt.h_max) : ARKStepSetMaxStep(mem, opt.h_max), "SetMaxStep");
  }
  check(cvode() ? CVodeSetStopTime(mem, t1) : ARKStepSetStopTime(mem, t1), "SetStopTime");
}

// One step of the integrator's own choice from t, not past the stop time: returns the new
// time, with y_out the state there.
double SundialsSolver::Impl::one_step(double t, Eigen::VectorXd& y_out) {
  error = nullptr, message.clear();
  const double far = t + 1.0;  // a target past the stop time: the stop time ends the call
  const int flag = cvode() ? CVode(mem, far, y, &t, CV_ONE_STEP) : ARKStepEvolve(mem, far, y, &t, ARK_ONE_STEP);
  take_counts();
  if (error) std::rethrow_exception(error);
  if (flag < 0)
    throw OdeError(t, stats.h_next, std::string(name()) + ": " + (message.empty() ? "flag " + std::to_string(flag) : message));
  const double* yv = N_VGetArrayPointer(y);
  std::copy(yv, yv + n, y_out.data());
  for (int i : sys.passive) y_out[i] += passive_add[i];
  return t;
}

void SundialsSolver::integrate(double t0, double t1, Eigen::VectorXd& y, const OdeObserver& observer) {
  Impl& s = *impl_;
  s.begin(t0, t1, y);
  if (observer) observer(t0, y);
  double t = t0;
  while (t < t1) {
    t = s.one_step(t, y);
    if (observer) observer(t, y);
  }
  s.t_last = t1, s.y_last = y, s.started = true;
}

double SundialsSolver::step(double t0, double t_max, Eigen::VectorXd& y) {
  Impl& s = *impl_;
  s.begin(t0, t_max, y);
  const double t = s.one_step(t0, y);
  s.t_last = t, s.y_last = y, s.started = true;
  return t;
}

#endif

}  // namespace CVT_ODE_ABI
}  // namespace cvt
