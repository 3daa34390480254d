// Internals of the generic integrators (engine/ode/ode.hpp): one workspace class whose step
// functions live in explicit.cpp, dumka3.cpp, implicit.cpp and rosenbrock.cpp, and whose
// driver (step-size control, fixed-step loop) lives in ode.cpp. Not part of the public
// interface.
#pragma once

#include <optional>

#include <Eigen/SparseLU>

#include "engine/ode/rk4.hpp"
#include "engine/ode/ode.hpp"
#include "engine/ode/sundials.hpp"
#include "engine/ode/w_stages.hpp"

namespace cvt {
inline namespace CVT_ODE_ABI {

// The iteration matrix M = I - dh J of the implicit methods, with J dense or sparse, its LU
// and the Jacobian's provenance. Everything is sized in the constructor; SparseLU's
// numerical factorization allocates its own supernodes (a documented limitation).
class NewtonMatrix {
 public:
  explicit NewtonMatrix(const OdeSystem& sys);
  // J at (t, y) with f_y = f(t, y): analytic if given, else (coloured) finite differences.
  void evaluate_jacobian(double t, const Eigen::VectorXd& y, const Eigen::VectorXd& f_y, OdeStats& stats);
  void factorize(double dh, OdeStats& stats);  // M = I - dh J; throws nothing, returns via ok()
  bool ok() const { return ok_; }
  void solve_in_place(Eigen::VectorXd& x);  // x <- M^-1 x
  void jacobian_times(const Eigen::VectorXd& x, Eigen::VectorXd& out) const;  // out = J x
  double factored_dh() const { return dh_; }
  bool factored() const { return factored_; }
  int colors() const { return fd_.colors(); }
  bool finite_differences() const { return sparse_ ? !sys_.sparse_jacobian : !sys_.dense_jacobian; }

 private:
  const OdeSystem& sys_;
  bool sparse_;
  FdJacobian fd_;
  Eigen::MatrixXd j_dense_, m_dense_;
  Eigen::PartialPivLU<Eigen::MatrixXd> lu_dense_;
  Eigen::SparseMatrix<double> j_sparse_, m_sparse_;
  std::vector<int> j_to_m_, diag_;  // value index of J's entries and of the diagonal in M
  Eigen::SparseLU<Eigen::SparseMatrix<double>, Eigen::COLAMDOrdering<int>> lu_sparse_;
  bool analyzed_ = false, factored_ = false, ok_ = true;
  double dh_ = 0;
  Eigen::VectorXd tmp_;
};

class OdeSolverImpl {
 public:
  OdeSolverImpl(const OdeSystem& sys, OdeMethod method, const OdeOptions& options);
  void integrate(double t0, double t1, Eigen::VectorXd& y, const OdeObserver& observer);
  double step(double t0, double t_max, Eigen::VectorXd& y);  // SUNDIALS' methods
  OdeStats stats;
  OdeOptions& options() { return opt_; }

 private:
  enum class Attempt { Ok, NewtonFailed };

  // ode.cpp: the drivers and shared pieces
  void integrate_fixed(double t0, double t1, Eigen::VectorXd& y, const OdeObserver& observer);
  void integrate_adaptive(double t0, double t1, Eigen::VectorXd& y, const OdeObserver& observer);
  void eval(double t, const Eigen::VectorXd& y, Eigen::VectorXd& dy) {
    sys_.rhs(t, y.data(), dy.data());
    ++stats.rhs_evals;
  }
  double error_norm(const Eigen::VectorXd& err, const Eigen::VectorXd& y0, const Eigen::VectorXd& y1) const;
  double initial_step(double t0, const Eigen::VectorXd& y0, double t1);
  int order() const;  // of the propagated solution; err ~ h^(order+1)
  bool implicit() const { return is_implicit_method(method_); }
  // The stabilized explicit methods, whose stage count follows the spectral radius.
  bool stabilized() const { return method_ == OdeMethod::Rkc || method_ == OdeMethod::Dumka3; }

  // One step attempt from (t, y) with f0_ = f(t, y) valid: writes y_new_, f_new_ and the
  // scaled error (<= 1: acceptable). RKC and DUMKA3 may shorten h (stage count limit).
  Attempt attempt(double t, double& h, const Eigen::VectorXd& y, double* err);
  void accepted(double t, double h);  // bookkeeping after an accepted step, before f0_ moves on
  void rejected();

  // ode_explicit.cpp
  void step_dopri5(double t, double h, const Eigen::VectorXd& y, double* err);
  void step_rkc(double t, double& h, const Eigen::VectorXd& y, double* err);
  void update_spectral_radius(double t, const Eigen::VectorXd& y);  // RKC, DUMKA3: when need_rho_
  void step_rk4_doubling(double t, double h, const Eigen::VectorXd& y, double* err);
  // One classical RK4 step of h from (t, y) with k1 = f(t, y) given; out must not alias y or k1.
  void rk4_from(double t, double h, const Eigen::VectorXd& y, const Eigen::VectorXd& k1, Eigen::VectorXd& out);
  // dumka3.cpp: one step (h may be shortened to the stability limit in adaptive mode), the
  // choice of its polynomial, and dumka3.f's controller: the next step after an accepted or a
  // rejected attempt of h with scaled error err.
  void step_dumka3(double t, double& h, const Eigen::VectorXd& y, double* err);
  int dumka3_polynomial(double t, double& h) const;
  double dumka3_step_accepted(double h, double err);
  double dumka3_step_rejected(double h, double err, bool first_attempt) const;
  double dk_err_prev_ = 0, dk_h_prev_ = 0;  // the last accepted step's error and size (its controller)
  // ode_implicit.cpp
  Attempt step_trapezoid(double t, double h, const Eigen::VectorXd& y, double* err);
  Attempt newton_failed();
  Attempt filtered_error(const Eigen::VectorXd& y, double* err);
  Attempt step_trbdf2(double t, double h, const Eigen::VectorXd& y, double* err);
  Attempt step_esdirk3(double t, double h, const Eigen::VectorXd& y, double* err);
  // rosenbrock.cpp
  void step_ros2(double t, double h, const Eigen::VectorXd& y, double* err);
  void step_w4(double t, double h, const Eigen::VectorXd& y, double* err);  // ROS34PW2, ROS34PRW
  void prepare_w(double t, double h, const Eigen::VectorXd& y, double gh);  // W = I - gh J~ (after f0_ = f(t, y))
  void solve_w(Eigen::VectorXd& x);                                 // x <- W^-1 x
  // Adaptive W-step from (t, y) to y_new_ with f0_ = f(t, y): the norm of W^-1 h (f(t, y_new)
  // - f0 - J (y_new - y)), or 0 when the system supplies W or the test is off.
  double linearization_error(double t, double h, const Eigen::VectorXd& y);
  double w_nonlinearity(double t, double h, const Eigen::VectorXd& y);
  int w_age_ = 0;  // W-methods: steps since their Jacobian was taken (OdeOptions::w_reuse_steps)
  WStageVectors wv_;  // the W-methods' stages (engine/ode/w_stages.hpp)
  void w_stages(OdeMethod m, double t, double h, const Eigen::VectorXd& y, double* err);
  Eigen::VectorXd dfdt_;       // df/dt at the step's start (systems with time_derivative)
  // Solves z = psi + dh f(tz, z) by simplified Newton from the initial z; on success fz
  // holds f(tz, z) as the stage formula implies, (z - psi) / dh.
  bool newton(double tz, double dh, const Eigen::VectorXd& psi, const Eigen::VectorXd& y_scale, Eigen::VectorXd& z,
              Eigen::VectorXd& fz);
  void prepare_newton(double t, double dh, const Eigen::VectorXd& y);  // fresh J / LU as flagged
  // OdeOptions::newton_uses_w with a system W: Newton's matrix is the system's.
  bool newton_on_w() const { return opt_.newton_uses_w && sys_.w_factor && sys_.w_solve; }
  void newton_solve(Eigen::VectorXd& x);  // x <- (Newton's matrix)^-1 x

  const OdeSystem& sys_;
  OdeMethod method_;
  OdeOptions opt_;
  int n_;
  bool fixed_ = false;

  Eigen::VectorXd f0_, f_new_, y_new_, err_vec_, tmp_;
  Eigen::VectorXd atol_;  // the absolute tolerance of each component (OdeOptions::atol or atol_vector)
  // DOPRI5 stages (k2_, k3_ also ESDIRK3's; k2_..k6_ adaptive RK4's; k2_..k4_ DUMKA3's)
  Eigen::VectorXd k2_, k3_, k4_, k5_, k6_;
  // RK4
  std::optional<Rk4> rk4_;
  // RKC (rho_est_ and the fields after yjm2_ also DUMKA3's)
  std::optional<SpectralRadius> rho_est_;
  Eigen::VectorXd yjm1_, yjm2_;
  double rho_ = 0;
  bool need_rho_ = true, rho_fresh_ = false;
  int steps_since_rho_ = 0;
  // implicit
  std::optional<NewtonMatrix> newton_;
  std::unique_ptr<SundialsSolver> sundials_;  // Cvode, Arkode: the whole integration
  Eigen::VectorXd z_, zg_, fg_, psi_, delta_, scale_, f_prev_;
  bool need_jac_ = true, jac_fresh_ = false;
  double theta_max_ = 0;  // worst contraction rate seen in the current step
  double faccon_ = 1;     // RADAU5's eta = theta / (1 - theta), carried across steps
  bool have_prev_ = false;
  double t_prev_ = 0;
};

}  // namespace CVT_ODE_ABI
}  // namespace cvt
