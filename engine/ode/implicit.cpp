#include <chrono>
// Implicit steps of the generic integrators: the trapezoidal rule and TR-BDF2, with
// simplified Newton on (I - dh J) (docs/integrators.md 5, 6).
#include <algorithm>
#include <cmath>

#include "engine/base/timing.hpp"
#include "engine/ode/ode_impl.hpp"

namespace cvt {
inline namespace CVT_ODE_ABI {

namespace {
constexpr double kEps = std::numeric_limits<double>::epsilon();
// TR-BDF2 (Bank et al. 1985; Hosea & Shampine, Appl. Numer. Math. 20 (1996) 21-37):
// gamma = 2 - sqrt 2 makes both stages use the same matrix I - d h J with d = gamma / 2.
const double kGamma = 2 - std::sqrt(2.0);
const double kD = kGamma / 2;
const double kW = 1 / (kGamma * (2 - kGamma));                             // weight of y_gamma
const double kW0 = (1 - kGamma) * (1 - kGamma) / (kGamma * (2 - kGamma));  // weight of y_n
// |local error| = C h^3 |y'''|, C = (3 gamma^2 - 4 gamma + 2) / (12 (2 - gamma)) = 0.0404
// (Hosea & Shampine 1996, eq. for the TR-BDF2 error constant).
const double kErrC = (3 * kGamma * kGamma - 4 * kGamma + 2) / (12 * (2 - kGamma));
// Kvaerno's ESDIRK 3(2) with 4 stages (A. Kvaerno, "Singly diagonally implicit
// Runge-Kutta methods with an explicit first stage", BIT 44 (2004) 489-502): c = (0, 2g,
// 1, 1), stiffly accurate (y_n+1 is the last stage), the third stage is the embedded
// second-order solution. g is the root of 6 g^3 - 18 g^2 + 9 g - 1 = 0 that makes the
// method L-stable (the same as Alexander's 3rd-order SDIRK).
const double kKg = 0.43586652150845899941601945;
const double kKa31 = (-4 * kKg * kKg + 6 * kKg - 1) / (4 * kKg);
const double kKa32 = (-2 * kKg + 1) / (4 * kKg);
const double kKa41 = (6 * kKg - 1) / (12 * kKg);
const double kKa42 = -1 / ((24 * kKg - 12) * kKg);
const double kKa43 = (-6 * kKg * kKg + 6 * kKg - 1) / (6 * kKg - 3);
}  // namespace

NewtonMatrix::NewtonMatrix(const OdeSystem& sys) : sys_(sys), sparse_(sys.is_sparse()), fd_(sys), tmp_(sys.size) {
  const int n = sys.size;
  if (!sparse_) {
    j_dense_.setZero(n, n), m_dense_.setZero(n, n);
    lu_dense_ = Eigen::PartialPivLU<Eigen::MatrixXd>(n);  // its storage too: no allocation in a step
    return;
  }
  j_sparse_ = sys.sparsity;
  j_sparse_.makeCompressed();
  j_sparse_.coeffs().setZero();
  // M's pattern: J's plus the diagonal.
  std::vector<Eigen::Triplet<double>> triplets;
  triplets.reserve(j_sparse_.nonZeros() + n);
  for (int c = 0; c < n; ++c) {
    triplets.emplace_back(c, c, 0.0);
    for (Eigen::SparseMatrix<double>::InnerIterator it(j_sparse_, c); it; ++it) triplets.emplace_back(it.row(), c, 0.0);
  }
  m_sparse_.resize(n, n);
  m_sparse_.setFromTriplets(triplets.begin(), triplets.end());
  m_sparse_.makeCompressed();
  // Where each of J's values and each diagonal entry sit in M's value array, so that
  // forming M is one pass over the values.
  j_to_m_.resize(j_sparse_.nonZeros());
  diag_.resize(n);
  const int* m_outer = m_sparse_.outerIndexPtr();
  const int* m_inner = m_sparse_.innerIndexPtr();
  const int* j_outer = j_sparse_.outerIndexPtr();
  const int* j_inner = j_sparse_.innerIndexPtr();
  for (int c = 0; c < n; ++c) {
    auto find = [&](int row) {
      const int* b = m_inner + m_outer[c];
      const int* e = m_inner + m_outer[c + 1];
      return static_cast<int>(std::lower_bound(b, e, row) - m_inner);
    };
    diag_[c] = find(c);
    for (int k = j_outer[c]; k < j_outer[c + 1]; ++k) j_to_m_[k] = find(j_inner[k]);
  }
}

void NewtonMatrix::evaluate_jacobian(double t, const Eigen::VectorXd& y, const Eigen::VectorXd& f_y,
                                     OdeStats& stats) {
  ++stats.jac_evals;
  const int before = fd_.rhs_evals();
  if (sparse_) {
    if (sys_.sparse_jacobian)
      sys_.sparse_jacobian(t, y.data(), j_sparse_);
    else
      fd_.sparse(t, y, f_y, j_sparse_);
  } else {
    if (sys_.dense_jacobian)
      sys_.dense_jacobian(t, y.data(), j_dense_);
    else
      fd_.dense(t, y, f_y, j_dense_);
  }
  stats.rhs_evals += fd_.rhs_evals() - before;
  factored_ = false;
}

void NewtonMatrix::factorize(double dh, OdeStats& stats) {
  ++stats.lu_factorizations;
  dh_ = dh;
  factored_ = true;
  if (!sparse_) {
    m_dense_ = -dh * j_dense_;
    m_dense_.diagonal().array() += 1.0;
    lu_dense_.compute(m_dense_);
    // PartialPivLU does not report singularity: a zero or non-finite pivot shows in the diagonal.
    const auto d = lu_dense_.matrixLU().diagonal();
    ok_ = d.allFinite() && (d.array() != 0).all();
    return;
  }
  double* mv = m_sparse_.valuePtr();
  const double* jv = j_sparse_.valuePtr();
  std::fill(mv, mv + m_sparse_.nonZeros(), 0.0);
  for (int k = 0; k < static_cast<int>(j_to_m_.size()); ++k) mv[j_to_m_[k]] = -dh * jv[k];
  for (int c = 0; c < static_cast<int>(diag_.size()); ++c) mv[diag_[c]] += 1.0;
  if (!analyzed_) lu_sparse_.analyzePattern(m_sparse_), analyzed_ = true;
  lu_sparse_.factorize(m_sparse_);
  ok_ = lu_sparse_.info() == Eigen::Success;
}

void NewtonMatrix::jacobian_times(const Eigen::VectorXd& x, Eigen::VectorXd& out) const {
  if (sparse_)
    out.noalias() = j_sparse_ * x;
  else
    out.noalias() = j_dense_ * x;
}

void NewtonMatrix::solve_in_place(Eigen::VectorXd& x) {
  if (sparse_)
    tmp_ = lu_sparse_.solve(x);
  else
    tmp_ = lu_dense_.solve(x);
  x.swap(tmp_);
}

// A Jacobian at the step's start when flagged (first step, slow convergence, Newton
// failure), and an LU whenever J or dh changed.
void OdeSolverImpl::prepare_newton(double t, double dh, const Eigen::VectorXd& y) {
  theta_max_ = 0;
  if (newton_on_w()) {
    // The system's matrix I - dh J~, prepared right after a fresh f(t, y) as w_factor asks.
    eval(t, y, tmp_);
    const auto c0 = std::chrono::steady_clock::now();
    sys_.w_factor(t, y.data(), dh);
    ++stats.lu_factorizations;
    stats.lu_seconds += seconds_since(c0);
    return;
  }
  if (need_jac_) {
    // Finite differences need f(t, y) to full precision: f0_ of an implicit step is the
    // stage formula's (z - psi) / dh, off by the Newton error over dh, which divided by a
    // difference increment of sqrt(eps) |y| would ruin the Jacobian.
    if (newton_->finite_differences()) eval(t, y, tmp_);
    const auto c0 = std::chrono::steady_clock::now();
    newton_->evaluate_jacobian(t, y, tmp_, stats);
    stats.jac_seconds += seconds_since(c0);
    need_jac_ = false, jac_fresh_ = true;
  }
  // Simplified Newton converges with a matrix for a somewhat different dh, only a little
  // slower: refactorize when dh moved by more than lu_rel_change (or J is new).
  if (!newton_->factored() || std::abs(dh / newton_->factored_dh() - 1) > opt_.lu_rel_change) {
    const auto c0 = std::chrono::steady_clock::now();
    newton_->factorize(dh, stats);
    stats.lu_seconds += seconds_since(c0);
  }
}

void OdeSolverImpl::newton_solve(Eigen::VectorXd& x) {
  const auto c0 = std::chrono::steady_clock::now();
  if (newton_on_w())
    sys_.w_solve(x.data());
  else
    newton_->solve_in_place(x);
  stats.solve_seconds += seconds_since(c0);
}

// Simplified Newton with RADAU5's convergence control (Hairer & Wanner II, IV.8): the rate
// theta = |dz_k| / |dz_k-1| predicts the remaining error eta |dz_k| with eta = theta /
// (1 - theta); stop when that is below fnewt (a fraction of the tolerance), give up when
// theta >= 1 or when the prediction says max_iter will not be enough.
bool OdeSolverImpl::newton(double tz, double dh, const Eigen::VectorXd& psi, const Eigen::VectorXd& y_scale,
                           Eigen::VectorXd& z, Eigen::VectorXd& fz) {
  if (!newton_on_w() && !newton_->ok()) return false;
  const double fnewt = std::max(10 * kEps / opt_.rtol, std::min(0.03, std::sqrt(opt_.rtol)));
  for (int i = 0; i < n_; ++i) scale_[i] = atol_[i] + opt_.rtol * std::abs(y_scale[i]);
  double faccon = std::pow(std::max(faccon_, kEps), 0.8);
  double dyold = 0;
  const int max_iter = opt_.newton_max_iter;
  for (int it = 0; it < max_iter; ++it) {
    eval(tz, z, fz);
    ++stats.newton_iterations;
    delta_ = psi + dh * fz - z;  // -G(z)
    newton_solve(delta_);
    const double dyno = opt_.max_norm ? (delta_.array() / scale_.array()).abs().maxCoeff()
                                      : std::sqrt((delta_.array() / scale_.array()).square().sum() / n_);
    if (!std::isfinite(dyno)) return false;
    if (it >= 1) {
      const double theta = dyno / dyold;
      theta_max_ = std::max(theta_max_, theta);
      if (theta >= 0.99) return false;
      faccon = theta / (1 - theta);
      // Will the remaining iterations bring the error below fnewt at this rate?
      if (it + 1 < max_iter && faccon * dyno * std::pow(theta, max_iter - 1 - it) > fnewt) return false;
    }
    dyold = std::max(dyno, kEps);
    z += delta_;
    // After one iteration the rate is only a guess from the last step: trust it only when
    // the correction itself is already below fnewt (a good predictor).
    if (faccon * dyno <= fnewt && (it >= 1 || dyno <= fnewt)) {
      faccon_ = faccon;
      fz = (z - psi) / dh;  // f(z) as the converged stage equation says, without an evaluation
      return true;
    }
  }
  return false;
}

// A failed Newton iteration: the next attempt takes a fresh Jacobian unless this one was.
OdeSolverImpl::Attempt OdeSolverImpl::newton_failed() {
  if (!jac_fresh_) need_jac_ = true;
  return Attempt::NewtonFailed;
}

// The error estimate err_vec_ filtered by the Newton matrix (I - dh J)^-1, as its norm.
OdeSolverImpl::Attempt OdeSolverImpl::filtered_error(const Eigen::VectorXd& y, double* err) {
  newton_solve(err_vec_);
  *err = error_norm(err_vec_, y, y_new_);
  return Attempt::Ok;
}

// The trapezoidal rule y1 = y0 + h/2 (f0 + f1). Its local error -h^3/12 y''' is estimated
// from the second divided difference of f over the previous, current and new points,
// y''' ~ 2 f[t_-1, t0, t1], and filtered by (I - h/2 J)^-1 as Shampine suggests for stiff
// components. The first step takes its third point from an explicit Euler step backwards.
OdeSolverImpl::Attempt OdeSolverImpl::step_trapezoid(double t, double h, const Eigen::VectorXd& y, double* err) {
  const double dh = 0.5 * h;
  prepare_newton(t, dh, y);
  psi_ = y + dh * f0_;
  z_ = y;
  if (!newton(t + h, dh, psi_, y, z_, f_new_)) return newton_failed();
  y_new_ = z_;
  if (fixed_) return Attempt::Ok;
  double tp = t_prev_;
  if (!have_prev_) {
    tp = t - h;
    tmp_ = y - h * f0_;
    eval(tp, tmp_, f_prev_);
  }
  const double hp = t - tp;
  // (h^3 / 12) * 2 f[tp, t, t + h]
  err_vec_ = ((f_new_ - f0_) / h - (f0_ - f_prev_) / hp) * (h * h * h / 6.0 / (h + hp));
  return filtered_error(y, err);
}

// TR-BDF2: a trapezoidal stage to t + gamma h, then BDF2 through y_n, y_gamma, y_n+1:
//   y_g = y_n + d h (f_n + f(y_g)),   y_n+1 = kW y_g - kW0 y_n + d h f(y_n+1),
// both with the matrix I - d h J. Error: C h^3 y''' with y''' from the divided difference
// of f_n, f_g, f_n+1 over the step, filtered by (I - d h J)^-1 (Hosea & Shampine 1996).
OdeSolverImpl::Attempt OdeSolverImpl::step_trbdf2(double t, double h, const Eigen::VectorXd& y, double* err) {
  const double dh = kD * h;
  prepare_newton(t, dh, y);
  psi_ = y + dh * f0_;
  // Explicit Euler predictor: f0_ comes from the last stage formula, so on a smooth
  // (slow-manifold) solution its stiff components are small; it halves Newton failures on
  // the test set against starting from y_n.
  zg_ = y + (kGamma * h) * f0_;
  bool ok = newton(t + kGamma * h, dh, psi_, y, zg_, fg_);
  if (ok) {
    psi_ = kW * zg_ - kW0 * y;
    z_ = y + (zg_ - y) / kGamma;  // linear extrapolation through y_n and y_g
    ok = newton(t + h, dh, psi_, y, z_, f_new_);
  }
  if (!ok) return newton_failed();
  y_new_ = z_;
  if (fixed_) return Attempt::Ok;
  err_vec_ = (kErrC * 2 * h) * (f0_ / kGamma - fg_ / (kGamma * (1 - kGamma)) + f_new_ / (1 - kGamma));
  return filtered_error(y, err);
}

// ESDIRK3: stage i solves Z_i = psi_i + g h f(Z_i) with psi_i = y_n + h sum_j<i a_ij k_j,
// all with the matrix I - g h J; k_i = (Z_i - psi_i) / (g h). The error estimate is
// y_n+1 - Z_3, the difference with the embedded 2nd-order solution, filtered by
// (I - g h J)^-1: the embedding is not L-stable (R(inf) = -0.957), and unfiltered its
// estimate would be all stiff noise.
OdeSolverImpl::Attempt OdeSolverImpl::step_esdirk3(double t, double h, const Eigen::VectorXd& y, double* err) {
  const double dh = kKg * h;
  prepare_newton(t, dh, y);
  const Eigen::VectorXd& k1 = f0_;
  // Stage 2 at c = 2g: the trapezoid over 2 g h.
  psi_ = y + dh * k1;
  zg_ = y + (2 * kKg * h) * k1;
  bool ok = newton(t + 2 * kKg * h, dh, psi_, y, zg_, k2_);
  if (ok) {
    // Stage 3 at c = 1; predictor: the integral over the step of k interpolated linearly
    // through k1 (c = 0) and k2 (c = 2g).
    psi_ = y + h * (kKa31 * k1 + kKa32 * k2_);
    z_ = y + h * (k1 + (k2_ - k1) / (4 * kKg));
    ok = newton(t + h, dh, psi_, y, z_, k3_);
  }
  if (ok) {
    zg_ = z_;  // the embedded solution Z_3, also the predictor of stage 4
    psi_ = y + h * (kKa41 * k1 + kKa42 * k2_ + kKa43 * k3_);
    ok = newton(t + h, dh, psi_, y, z_, f_new_);
  }
  if (!ok) return newton_failed();
  y_new_ = z_;
  if (fixed_) return Attempt::Ok;
  err_vec_ = z_ - zg_;
  return filtered_error(y, err);
}

}  // namespace CVT_ODE_ABI
}  // namespace cvt
