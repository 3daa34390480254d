// The generic integrators' driver: step-size control, the fixed-step loop, the Jacobian
// colouring and finite differences, the spectral-radius estimate (docs/integrators.md).
#include <algorithm>
#include <cmath>
#include <sstream>

#include "engine/ode/ode_impl.hpp"

namespace cvt {
inline namespace CVT_ODE_ABI {

namespace {
constexpr double kEps = std::numeric_limits<double>::epsilon();
}

void OdeSystem::set_sparsity(const std::vector<std::pair<int, int>>& nonzeros) {
  std::vector<Eigen::Triplet<double>> triplets;
  triplets.reserve(nonzeros.size());
  for (auto [r, c] : nonzeros) triplets.emplace_back(r, c, 1.0);
  sparsity.resize(size, size);
  // Duplicates sum, which does not matter: only the pattern is used.
  sparsity.setFromTriplets(triplets.begin(), triplets.end());
  sparsity.makeCompressed();
}

const char* to_string(OdeMethod method) {
  switch (method) {
    case OdeMethod::Rk4: return "rk4";
    case OdeMethod::Dopri5: return "dopri5";
    case OdeMethod::Rkc: return "rkc";
    case OdeMethod::Trapezoid: return "trapezoid";
    case OdeMethod::TrBdf2: return "trbdf2";
    case OdeMethod::Esdirk3: return "esdirk3";
    case OdeMethod::Ros2: return "ros2";
    case OdeMethod::Ros34pw2: return "ros34pw2";
    case OdeMethod::Ros34prw: return "ros34prw";
    case OdeMethod::Dumka3: return "dumka3";
    case OdeMethod::Cvode: return "cvode";
    case OdeMethod::Arkode: return "arkode";
  }
  return "?";
}

OdeMethod parse_ode_method(const std::string& name) {
  for (OdeMethod m : {OdeMethod::Rk4, OdeMethod::Dopri5, OdeMethod::Rkc, OdeMethod::Dumka3, OdeMethod::Trapezoid,
                      OdeMethod::TrBdf2, OdeMethod::Esdirk3, OdeMethod::Ros2, OdeMethod::Ros34pw2, OdeMethod::Ros34prw,
                      OdeMethod::Cvode, OdeMethod::Arkode})
    if (name == to_string(m)) return m;
  throw std::invalid_argument("unknown method '" + name +
                              "' (rk4, dopri5, rkc, dumka3, trapezoid, trbdf2, esdirk3, ros2, ros34pw2, ros34prw, "
                              "cvode, arkode)");
}

static std::string ode_error_text(double t, double h, const std::string& reason) {
  std::ostringstream s;
  s.precision(17);
  s << "integration stopped at t = " << t << " (step h = " << h << "): " << reason;
  return s.str();
}

OdeError::OdeError(double t_, double h_, const std::string& reason)
    : std::runtime_error(ode_error_text(t_, h_, reason)), t(t_), h(h_) {}

// ---------------------------------------------------------------------------------------
// Colouring and finite differences

std::vector<int> color_columns(const Eigen::SparseMatrix<double>& pattern_in, int* n_colors) {
  Eigen::SparseMatrix<double> pattern = pattern_in;  // column-major, compressed
  pattern.makeCompressed();
  const int n = static_cast<int>(pattern.cols());
  // Rows -> columns, so that the columns sharing a row with column j are found directly.
  Eigen::SparseMatrix<double, Eigen::RowMajor> rows = pattern;
  rows.makeCompressed();
  std::vector<int> color(n, -1);
  std::vector<int> stamp;  // stamp[c] == j: colour c is taken by a neighbour of column j
  int used = 0;
  for (int j = 0; j < n; ++j) {
    for (Eigen::SparseMatrix<double>::InnerIterator it(pattern, j); it; ++it) {
      for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator jt(rows, it.row()); jt; ++jt) {
        const int c = color[jt.col()];
        if (c >= 0) stamp[c] = j;
      }
    }
    int c = 0;
    while (c < used && stamp[c] == j) ++c;
    if (c == used) stamp.push_back(-1), ++used;
    color[j] = c;
  }
  if (n_colors) *n_colors = used;
  return color;
}

FdJacobian::FdJacobian(const OdeSystem& sys)
    : sys_(sys), y_pert_(sys.size), f_pert_(sys.size), delta_(sys.size) {
  if (sys.is_sparse()) {
    color_ = color_columns(sys.sparsity, &n_colors_);
    columns_of_color_.resize(n_colors_);
    for (int j = 0; j < sys.size; ++j) columns_of_color_[color_[j]].push_back(j);
  }
}

// RADAU5's increment: sqrt(uround * max(1e-5, |y_j|)), half the digits of y_j.
static double fd_increment(double yj) { return std::sqrt(kEps * std::max(1e-5, std::abs(yj))); }

void FdJacobian::dense(double t, const Eigen::VectorXd& y, const Eigen::VectorXd& f_y, Eigen::MatrixXd& jac) {
  y_pert_ = y;
  for (int j = 0; j < sys_.size; ++j) {
    const double d = fd_increment(y[j]);
    y_pert_[j] = y[j] + d;
    const double dj = y_pert_[j] - y[j];  // the increment actually represented
    sys_.rhs(t, y_pert_.data(), f_pert_.data());
    ++rhs_evals_;
    jac.col(j) = (f_pert_ - f_y) / dj;
    y_pert_[j] = y[j];
  }
}

void FdJacobian::sparse(double t, const Eigen::VectorXd& y, const Eigen::VectorXd& f_y,
                        Eigen::SparseMatrix<double>& jac) {
  y_pert_ = y;
  for (const auto& cols : columns_of_color_) {
    for (int j : cols) {
      y_pert_[j] = y[j] + fd_increment(y[j]);
      delta_[j] = y_pert_[j] - y[j];
    }
    sys_.rhs(t, y_pert_.data(), f_pert_.data());
    ++rhs_evals_;
    // Columns of one colour share no row: each changed f_i belongs to exactly one of them.
    for (int j : cols) {
      const double d = delta_[j];
      for (Eigen::SparseMatrix<double>::InnerIterator it(jac, j); it; ++it)
        it.valueRef() = (f_pert_[it.row()] - f_y[it.row()]) / d;
      y_pert_[j] = y[j];
    }
  }
}

// ---------------------------------------------------------------------------------------
// Spectral radius (rkcrho of rkc.f, Sommeijer, Shampine & Verwer 1997)

SpectralRadius::SpectralRadius(int size)
    : direction_(Eigen::VectorXd::Zero(size)), y_pert_(size), f_pert_(size) {}

double SpectralRadius::estimate(const OdeSystem& sys, double t, const Eigen::VectorXd& y,
                                const Eigen::VectorXd& f_y, int* rhs_evals, int max_iter) {
  const int n = sys.size;
  const double sqrtu = std::sqrt(kEps);
  const double ynrm = y.norm();
  if (direction_.squaredNorm() == 0) {
    // First call: start along f, plus a little of every direction. f alone can be an
    // eigenvector (a smooth initial state of a diffusion problem is one), and the power
    // method would then never see the top of the spectrum.
    const double fn = f_y.norm();
    const double amp = fn > 0 ? 1e-3 * fn / std::sqrt(static_cast<double>(n)) : 1.0;
    std::uint64_t state = 0x9E3779B97F4A7C15ull;
    for (int i = 0; i < n; ++i) {
      state = state * 6364136223846793005ull + 1442695040888963407ull;  // Knuth's MMIX LCG
      const double u = static_cast<double>(state >> 11) * 0x1.0p-53 - 0.5;
      direction_[i] = f_y[i] + amp * u;
    }
  }
  const double vnrm = direction_.norm();
  // The perturbation is relative to |y| so that the difference quotient keeps half the digits.
  double dynrm;
  if (ynrm != 0 && vnrm != 0) {
    dynrm = ynrm * sqrtu;
    y_pert_ = y + direction_ * (dynrm / vnrm);
  } else if (ynrm != 0) {
    dynrm = ynrm * sqrtu;
    y_pert_ = y * (1 + sqrtu);
  } else if (vnrm != 0) {
    dynrm = kEps;
    y_pert_ = direction_ * (dynrm / vnrm);
  } else {
    dynrm = kEps;
    y_pert_.setConstant(dynrm);
  }
  double sigma = 0;
  converged_ = false;
  for (int iter = 1; iter <= max_iter; ++iter) {
    sys.rhs(t, y_pert_.data(), f_pert_.data());
    if (rhs_evals) ++*rhs_evals;
    const double dfnrm = (f_pert_ - f_y).norm();
    const double sigmal = sigma;
    sigma = dfnrm / dynrm;
    if (iter >= 2 && std::abs(sigma - sigmal) <= std::max(sigma, std::numeric_limits<double>::min()) * 0.01) {
      converged_ = true;
      break;
    }
    if (dfnrm != 0) {
      y_pert_ = y + (f_pert_ - f_y) * (dynrm / dfnrm);
    } else {
      // f did not move: flip one component to leave the null direction.
      const int ind = iter % n;
      y_pert_[ind] = y[ind] - (y_pert_[ind] - y[ind]);
    }
  }
  direction_ = y_pert_ - y;
  return sigma;
}

// ---------------------------------------------------------------------------------------
// Driver

OdeSolverImpl::OdeSolverImpl(const OdeSystem& sys, OdeMethod method, const OdeOptions& options)
    : sys_(sys), method_(method), opt_(options), n_(sys.size) {
  if (n_ <= 0 || !sys.rhs) throw std::invalid_argument("OdeSystem: size must be positive and rhs set");
  if (sys.is_sparse() && (sys.sparsity.rows() != n_ || sys.sparsity.cols() != n_))
    throw std::invalid_argument("OdeSystem: sparsity pattern must be size x size");
  f0_.setZero(n_), f_new_.setZero(n_), y_new_.setZero(n_), err_vec_.setZero(n_), tmp_.setZero(n_), atol_.setZero(n_);
  switch (method_) {
    case OdeMethod::Rk4:
      rk4_.emplace(n_);
      for (auto* k : {&k2_, &k3_, &k4_, &k5_, &k6_}) k->setZero(n_);  // adaptive: step doubling
      break;
    case OdeMethod::Dopri5:
      for (auto* k : {&k2_, &k3_, &k4_, &k5_, &k6_}) k->setZero(n_);
      break;
    case OdeMethod::Rkc:
      rho_est_.emplace(n_);
      yjm1_.setZero(n_), yjm2_.setZero(n_);
      break;
    case OdeMethod::Dumka3:
      rho_est_.emplace(n_);
      for (auto* k : {&k2_, &k3_, &k4_}) k->setZero(n_);
      break;
    case OdeMethod::Trapezoid:
    case OdeMethod::TrBdf2:
    case OdeMethod::Esdirk3:
      if (method_ == OdeMethod::Esdirk3) k2_.setZero(n_), k3_.setZero(n_);
      newton_.emplace(sys_);
      for (auto* v : {&z_, &zg_, &fg_, &psi_, &delta_, &scale_, &f_prev_}) v->setZero(n_);
      stats.colors = sys.is_sparse() && !sys.sparse_jacobian ? newton_->colors() : 0;
      break;
    case OdeMethod::Ros2:
    case OdeMethod::Ros34pw2:
    case OdeMethod::Ros34prw:
      if (static_cast<bool>(sys.w_factor) != static_cast<bool>(sys.w_solve))
        throw std::invalid_argument("OdeSystem: w_factor and w_solve go together");
      if (!sys.w_factor) {
        newton_.emplace(sys_);
        stats.colors = sys.is_sparse() && !sys.sparse_jacobian ? newton_->colors() : 0;
      }
      k2_.setZero(n_);
      z_.setZero(n_);
      if (sys.time_derivative) dfdt_.setZero(n_);
      wv_.resize(n_);
      break;
    case OdeMethod::Cvode:
    case OdeMethod::Arkode:
      sundials_ = std::make_unique<SundialsSolver>(sys_, method_, opt_, stats);
      break;
  }
}

int OdeSolverImpl::order() const {
  switch (method_) {
    case OdeMethod::Rk4: return 4;  // adaptive: the estimate is that of the two half steps
    case OdeMethod::Dopri5: return 4;  // the error estimate is that of the 4th-order embedded solution
    case OdeMethod::Ros2: return 1;  // the estimate is that of the embedded first-order solution
    case OdeMethod::Ros34pw2:
    case OdeMethod::Ros34prw: return 2;  // and here of the embedded second-order one
    case OdeMethod::Dumka3: return 2;  // third order, but its estimate goes like h^3 (dumka3.f's exponent 1/3)
    default: return 2;  // RKC, trapezoid, TR-BDF2; ESDIRK3's estimate is its 2nd-order embedding
  }
}

// The system's norm if it has one; else Hairer's RMS norm of err weighted by atol_i + rtol max(|y0_i|, |y1_i|): 1 is the tolerance.
double OdeSolverImpl::error_norm(const Eigen::VectorXd& err, const Eigen::VectorXd& y0,
                                 const Eigen::VectorXd& y1) const {
  if (sys_.error_norm) return sys_.error_norm(err.data(), y0.data(), y1.data());
  double sum = 0, worst = 0;
  for (int i = 0; i < n_; ++i) {
    const double sk = atol_[i] + opt_.rtol * std::max(std::abs(y0[i]), std::abs(y1[i]));
    const double e = err[i] / sk;
    sum += e * e;
    worst = std::max(worst, std::abs(e));
  }
  return opt_.max_norm ? worst : std::sqrt(sum / n_);
}

// Hairer & Wanner's starting step (HINIT of dopri5.f): the explicit Euler step whose
// local error would be about 1 % of the tolerance; f0_ holds f(t0, y0).
double OdeSolverImpl::initial_step(double t0, const Eigen::VectorXd& y0, double t1) {
  const double span = t1 - t0;
  double d0 = 0, d1 = 0;
  for (int i = 0; i < n_; ++i) {
    const double sk = atol_[i] + opt_.rtol * std::abs(y0[i]);
    d0 += (y0[i] / sk) * (y0[i] / sk);
    d1 += (f0_[i] / sk) * (f0_[i] / sk);
  }
  d0 = std::sqrt(d0 / n_), d1 = std::sqrt(d1 / n_);
  double h = (d0 <= 1e-10 || d1 <= 1e-10) ? 1e-6 : 0.01 * d0 / d1;
  h = std::min({h, opt_.h_max, span});
  y_new_ = y0 + h * f0_;
  eval(t0 + h, y_new_, f_new_);
  double d2 = 0;
  for (int i = 0; i < n_; ++i) {
    const double sk = atol_[i] + opt_.rtol * std::abs(y0[i]);
    const double e = (f_new_[i] - f0_[i]) / sk;
    d2 += e * e;
  }
  d2 = std::sqrt(d2 / n_) / h;
  const double der = std::max(d1, d2);
  const double h1 = der <= 1e-15 ? std::max(1e-6, h * 1e-3) : std::pow(0.01 / der, 1.0 / (order() + 1));
  return std::min({100 * h, h1, opt_.h_max, span});
}

OdeSolverImpl::Attempt OdeSolverImpl::attempt(double t, double& h, const Eigen::VectorXd& y, double* err) {
  switch (method_) {
    case OdeMethod::Dopri5: step_dopri5(t, h, y, err); return Attempt::Ok;
    case OdeMethod::Rkc: step_rkc(t, h, y, err); return Attempt::Ok;
    case OdeMethod::Trapezoid: return step_trapezoid(t, h, y, err);
    case OdeMethod::TrBdf2: return step_trbdf2(t, h, y, err);
    case OdeMethod::Esdirk3: return step_esdirk3(t, h, y, err);
    case OdeMethod::Ros2: step_ros2(t, h, y, err); return Attempt::Ok;
    case OdeMethod::Ros34pw2:
    case OdeMethod::Ros34prw: step_w4(t, h, y, err); return Attempt::Ok;
    case OdeMethod::Rk4: step_rk4_doubling(t, h, y, err); return Attempt::Ok;
    case OdeMethod::Dumka3: step_dumka3(t, h, y, err); return Attempt::Ok;
    case OdeMethod::Cvode:
    case OdeMethod::Arkode: break;  // SundialsSolver takes their steps
  }
  throw std::logic_error("OdeSolver: unknown method");
}

void OdeSolverImpl::accepted(double t, double h) {
  ++stats.steps;
  stats.h_last = h;
  if (stabilized()) {
    ++steps_since_rho_;
    rho_fresh_ = false;
    if (opt_.rkc_rho_every > 0 && steps_since_rho_ >= opt_.rkc_rho_every) need_rho_ = true;
  }
  if (implicit()) {
    // The previous point feeds the trapezoid's third-derivative estimate.
    std::swap(f_prev_, f0_);
    f0_ = f_new_;
    t_prev_ = t;
    have_prev_ = true;
    jac_fresh_ = false;
    if (theta_max_ > opt_.jac_theta) need_jac_ = true;  // slow convergence: J is stale
  } else {
    std::swap(f0_, f_new_);
  }
}

void OdeSolverImpl::rejected() {
  ++stats.rejected;
  // RKC, DUMKA3: a rejected step may come from a stale radius; re-estimate unless just done.
  if (stabilized() && !rho_fresh_) need_rho_ = true;
}

double OdeSolverImpl::step(double t0, double t_max, Eigen::VectorXd& y) {
  if (!sundials_) throw std::logic_error(std::string("OdeSolver::step: ") + to_string(method_) + " takes steps in integrate()");
  return sundials_->step(t0, t_max, y);
}

void OdeSolverImpl::integrate(double t0, double t1, Eigen::VectorXd& y, const OdeObserver& observer) {
  if (y.size() != n_) throw std::invalid_argument("OdeSolver::integrate: y has the wrong size");
  if (!(t1 > t0)) throw std::invalid_argument("OdeSolver::integrate: t1 must be greater than t0");
  // The tolerances of this call (options may change between calls).
  if (opt_.atol_vector.empty()) {
    atol_.setConstant(opt_.atol);
  } else {
    if (static_cast<int>(opt_.atol_vector.size()) != n_)
      throw std::invalid_argument("OdeOptions: atol_vector must be empty or have one entry per component");
    for (int i = 0; i < n_; ++i) {
      if (!(opt_.atol_vector[i] >= 0)) throw std::invalid_argument("OdeOptions: atol_vector entries must be >= 0");
      atol_[i] = opt_.atol_vector[i];
    }
  }
  if (sundials_) return sundials_->integrate(t0, t1, y, observer);
  have_prev_ = false;
  // A new call may start anywhere: the Jacobian of the last call is not to be trusted.
  if (!opt_.keep_jacobian_across_calls || !newton_ || !newton_->factored()) need_jac_ = true, faccon_ = 1;
  if (observer) observer(t0, y);
  // RK4 with a step h0 and no fixed_step keeps the fixed steps it always took with one
  // (engine/wmethod's OdeDriver relies on it); without h0 it is adaptive like the others.
  if (opt_.fixed_step || (method_ == OdeMethod::Rk4 && opt_.h0 > 0))
    integrate_fixed(t0, t1, y, observer);
  else
    integrate_adaptive(t0, t1, y, observer);
}

void OdeSolverImpl::integrate_fixed(double t0, double t1, Eigen::VectorXd& y, const OdeObserver& observer) {
  fixed_ = true;
  if (!(opt_.h0 > 0)) throw std::invalid_argument("OdeOptions: fixed-step mode needs h0 > 0");
  const double span = t1 - t0;
  const std::int64_t steps = std::max<std::int64_t>(1, static_cast<std::int64_t>(std::ceil(span / opt_.h0 - 1e-9)));
  if (steps > opt_.max_steps) throw OdeError(t0, opt_.h0, "more fixed steps than max_steps");
  const double h = span / static_cast<double>(steps);
  if (method_ != OdeMethod::Rk4 && !is_w_method(method_)) eval(t0, y, f0_);  // W-methods evaluate it per step
  for (std::int64_t i = 0; i < steps; ++i) {
    const double t = t0 + static_cast<double>(i) * h;
    const double t_next = i + 1 == steps ? t1 : t0 + static_cast<double>(i + 1) * h;
    if (method_ == OdeMethod::Rk4) {
      auto f = [this](double tt, const double* yy, double* dy) {
        sys_.rhs(tt, yy, dy);
        ++stats.rhs_evals;
      };
      rk4_->step(f, t, h, y);
      ++stats.steps;
      stats.h_last = h;
    } else {
      double err = 0, hh = h;
      Attempt a = attempt(t, hh, y, &err);
      if (a == Attempt::NewtonFailed) {
        // One retry with a Jacobian taken here; fixed mode cannot shrink the step.
        ++stats.newton_failures;
        need_jac_ = true;
        a = attempt(t, hh, y, &err);
        if (a == Attempt::NewtonFailed) {
          ++stats.newton_failures;
          throw OdeError(t, h, "Newton iteration did not converge in fixed-step mode");
        }
      }
      y = y_new_;
      accepted(t, h);
    }
    if (!y.allFinite()) throw OdeError(t, h, "solution is not finite");
    if (observer) observer(t_next, y);
  }
}

void OdeSolverImpl::integrate_adaptive(double t0, double t1, Eigen::VectorXd& y, const OdeObserver& observer) {
  fixed_ = false;
  if (!is_w_method(method_) || !(opt_.h0 > 0)) eval(t0, y, f0_);  // W-methods evaluate it per step
  if (stabilized()) need_rho_ = true;
  dk_err_prev_ = dk_h_prev_ = 0;
  double h = opt_.h0 > 0 ? std::min({opt_.h0, opt_.h_max, t1 - t0}) : initial_step(t0, y, t1);
  // Controller (Hairer & Wanner I, II.4): h_new = h * safe / err^(1/(q+1)) * err_old^beta,
  // beta = 0.04 (the PI part) for DOPRI5 as in dopri5.f, 0 for the others. The step grows
  // at most 10x per step for the explicit methods (dopri5.f, rkc.f) and 2x (as DASSL) for the
  // implicit and W-methods: their estimates hold only where the step is small against the
  // solution's own time scales, and a step that jumps far past the last one that was
  // checked can be accepted with a small estimate and a large error (ESDIRK3 on VDPOL at
  // tol 1e-4 grew 5x into a step with a true error 7600 times the tolerance). DUMKA3 takes
  // dumka3.f's own controller instead (dumka3.cpp), which starts each call without history.
  const double beta = method_ == OdeMethod::Dopri5 ? 0.04 : 0.0;
  const double expo = 1.0 / (order() + 1) - 0.75 * beta;
  const double safe = 0.9, fac_min = 0.2, fac_max = implicit() || is_w_method(method_) ? 2.0 : 10.0;
  double err_old = 1e-4;
  bool last_rejected = false, last_newton_failed = false, first_attempt = true;
  double t = t0;
  while (t < t1) {
    if (stats.steps + stats.rejected >= opt_.max_steps) throw OdeError(t, h, "max_steps reached");
    const double h_min = std::max(opt_.h_min, 16 * kEps * std::abs(t));
    if (h < h_min) {
      std::ostringstream why;
      why << "step size underflow: h < h_min = " << h_min << " after "
          << (last_newton_failed ? "repeated Newton failures (singular or stiff beyond the Jacobian's reach?)"
                                 : "repeated error test failures (a singularity or a discontinuity?)");
      throw OdeError(t, h, why.str());
    }
    bool last = false;
    // Stretch a step that would leave a sliver of less than 1 % before t1.
    if (t + 1.01 * h >= t1) h = t1 - t, last = true;
    double err = 0;
    const double h_tried = h;
    const Attempt a = attempt(t, h, y, &err);
    if (h != h_tried) last = false;  // RKC or DUMKA3 shortened it
    last_newton_failed = a == Attempt::NewtonFailed;
    if (a == Attempt::NewtonFailed) {
      ++stats.newton_failures;
      ++stats.rejected;
      h *= 0.25;
      last_rejected = true;
      continue;
    }
    if (!std::isfinite(err)) err = 1e10;
    if (err <= 1.0) {
      const double t_new = last ? t1 : t + h;
      y = y_new_;
      accepted(t, h);
      stats.err_last = err;
      t = t_new;
      if (observer) observer(t, y);
      double fac = std::pow(std::max(err, 1e-10), expo) / std::pow(err_old, beta) / safe;
      fac = std::clamp(fac, 1.0 / fac_max, 1.0 / fac_min);
      double h_new = h / fac;
      if (last_rejected) h_new = std::min(h_new, h);  // no growth right after a rejection
      if (method_ == OdeMethod::Dumka3) h_new = dumka3_step_accepted(h, err);  // its own controller
      // Implicit methods: a small increase is not worth a new LU (RADAU5's quot1/quot2).
      if (implicit() && h_new >= h && h_new <= opt_.keep_h_ratio * h) h_new = h;
      err_old = std::max(err, 1e-4);
      last_rejected = false;
      h = std::min(h_new, opt_.h_max);
      stats.h_next = h;
    } else {
      rejected();
      const double fac = std::min(1.0 / fac_min, std::pow(err, expo + 0.75 * beta) / safe);
      h = method_ == OdeMethod::Dumka3 ? dumka3_step_rejected(h, err, first_attempt) : h / fac;
      last_rejected = true;
    }
    first_attempt = false;
  }
}

// ---------------------------------------------------------------------------------------

OdeSolver::OdeSolver(const OdeSystem& sys, OdeMethod method, const OdeOptions& options)
    : impl_(std::make_unique<OdeSolverImpl>(sys, method, options)) {}
OdeSolver::~OdeSolver() = default;
void OdeSolver::integrate(double t0, double t1, Eigen::VectorXd& y, const OdeObserver& observer) {
  impl_->integrate(t0, t1, y, observer);
}
double OdeSolver::step(double t0, double t_max, Eigen::VectorXd& y) { return impl_->step(t0, t_max, y); }
const OdeStats& OdeSolver::stats() const { return impl_->stats; }
OdeStats& OdeSolver::stats() { return impl_->stats; }
OdeOptions& OdeSolver::options() { return impl_->options(); }

OdeStats integrate(const OdeSystem& sys, OdeMethod method, double t0, double t1, Eigen::VectorXd& y,
                   const OdeOptions& options, const OdeObserver& observer) {
  OdeSolver solver(sys, method, options);
  solver.integrate(t0, t1, y, observer);
  return solver.stats();
}

}  // namespace CVT_ODE_ABI
}  // namespace cvt
