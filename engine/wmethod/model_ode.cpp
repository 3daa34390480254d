#include "engine/wmethod/model_ode.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <set>
#include <stdexcept>

#include "engine/rhs/rhs.hpp"
#include "modules/chain_forces.hpp"
#include "modules/inertia.hpp"
#include "modules/pulley_contact.hpp"

namespace cvt {

std::vector<std::pair<int, int>> model_jacobian_pattern(const Model& m, int band, bool pin_to_tail) {
  const int n = m.ndof, N = m.links, tail0 = m.shaft(0), pins = kJointSize * N;
  std::vector<std::pair<int, int>> nz;
  // Position rows: q' = v.
  for (int i = 0; i < n; ++i) nz.emplace_back(i, n + i);
  // Pin acceleration rows: the joints within the band, and the shafts (contact geometry
  // and sheave velocities at every pin end).
  std::set<int> near;
  for (int j = 0; j < N; ++j) {
    near.clear();
    for (int d = -band; d <= band; ++d) near.insert(m.wrap(j + d));
    for (int r = m.joint(j); r < m.joint(j) + kJointSize; ++r) {
      for (int k : near)
        for (int c = m.joint(k); c < m.joint(k) + kJointSize; ++c) nz.emplace_back(n + r, c), nz.emplace_back(n + r, n + c);
      for (int c = tail0; c < tail0 + 2 * kShaftSize; ++c) nz.emplace_back(n + r, c), nz.emplace_back(n + r, n + c);
    }
  }
  // Tail rows (shaft and load accelerations, the work integrals): all tail columns, and
  // with pin_to_tail every pin column where the pins act (shafts, dissipated power).
  std::vector<int> tail_rows, tail_cols;
  for (int i = tail0; i < n; ++i) tail_rows.push_back(n + i), tail_cols.push_back(i), tail_cols.push_back(n + i);
  for (int a = 0; a < kAuxSize; ++a) tail_rows.push_back(2 * n + a), tail_cols.push_back(2 * n + a);
  for (int r : tail_rows)
    for (int c : tail_cols) nz.emplace_back(r, c);
  if (pin_to_tail) {
    std::vector<int> dense_rows;
    for (int i = tail0; i < tail0 + 2 * kShaftSize; ++i) dense_rows.push_back(n + i);
    dense_rows.push_back(2 * n + kWorkDiss);
    for (int r : dense_rows)
      for (int c = 0; c < pins; ++c) nz.emplace_back(r, c), nz.emplace_back(r, n + c);
  }
  return nz;
}

Eigen::VectorXd model_state_units(const Model& m, const ModelOdeOptions& opt) {
  Eigen::VectorXd s = Eigen::VectorXd::Ones(m.nstate);
  if (!opt.scaled) return s;
  const int n = m.ndof;
  const double r = 0.05;  // lever arm turning an angle into a length [m]
  for (int j = 0; j < m.links; ++j)
    for (int i = 0; i < kJointSize; ++i) {
      const int c = i % half::kEnd;
      const bool slope = i < 2 * half::kSize && (c == half::kSx || c == half::kSy);
      s[m.joint(j) + i] = slope ? opt.length_unit / r : opt.length_unit;
      s[n + m.joint(j) + i] = slope ? opt.velocity_unit / r : opt.velocity_unit;
    }
  for (int k = 0; k < 2; ++k)
    for (int i = 0; i < kShaftSize; ++i) {
      const bool angle = i == kTx || i == kTy || i == kPhi;
      s[m.shaft(k) + i] = angle ? opt.length_unit / r : opt.length_unit;
      s[n + m.shaft(k) + i] = angle ? opt.velocity_unit / r : opt.velocity_unit;
    }
  s[m.load_index()] = opt.length_unit / r;
  s[n + m.load_index()] = opt.velocity_unit / r;
  for (int a = 0; a < kAuxSize; ++a) s[2 * n + a] = opt.energy_unit;
  return s;
}

void ModelOde::eval_scaled(double t, const double* z, double* dz) {
  const int ns = m_.nstate;
  for (int i = 0; i < ns; ++i) ys_[i] = offset_[i] + z[i] * unit_[i];
  eval(t, ys_.data(), dz);
  for (int i = 0; i < ns; ++i) dz[i] /= unit_[i];
}

ModelOde::ModelOde(const Model& m, Workspace& ws, Schedule& schedule, const ModelOdeOptions& opt)
    : m_(m), ws_(ws), schedule_(schedule), opt_(opt), frozen_(m), unit_(model_state_units(m, opt)),
      offset_(Eigen::VectorXd::Zero(m.nstate)), w_(m, ws, schedule, opt, unit_, offset_) {
  const int ns = m.nstate, N = m.links;
  if (opt.band < 1 || 2 * opt.band + 1 > N) throw std::invalid_argument("ModelOdeOptions::band must be in [1, (links - 1) / 2]");
  if (!(opt.w_h_grow >= 1 && opt.w_h_shrink >= 1))
    throw std::invalid_argument("ModelOdeOptions: w_h_grow and w_h_shrink must be >= 1");
  sys_.size = ns;
  ys_.resize(ns);
  if (opt.scaled)
    sys_.rhs = [this](double t, const double* z, double* dz) { eval_scaled(t, z, dz); };
  else
    sys_.rhs = [this](double t, const double* y, double* dy) { eval(t, y, dy); };
  if (opt.sparsity) sys_.set_sparsity(model_jacobian_pattern(m, opt.band, opt.exact_dense_rows));
  sys_.sparse_jacobian = [this](double t, const double* z, Eigen::SparseMatrix<double>& jac) {
    if (!opt_.scaled) return jacobian(t, z, jac);
    // J_z = S^-1 J_y S.
    for (int i = 0; i < m_.nstate; ++i) ys_[i] = offset_[i] + z[i] * unit_[i];
    jacobian(t, ys_.data(), jac);  // evaluates through eval(), which leaves ys_ alone
    for (int c = 0; c < jac.outerSize(); ++c)
      for (Eigen::SparseMatrix<double>::InnerIterator it(jac, c); it; ++it) it.valueRef() *= unit_[c] / unit_[it.row()];
  };
  a0_shaft_inv_ = a0_shaft_inverse(m);
  if (opt.w_blocks) {  // the linear solver module's setup and solve
    sys_.w_factor = [this](double t, const double* y, double gh) { w_.factor(t, y, gh); };
    sys_.w_solve = [this](double* x) { w_.solve(x); };
    sys_.w_refresh = [this] {
      w_.retake();
      w_.ask(w_.index());
    };
  }
  // The switching work, which update_statuses_after_step adds to between steps, is read by no force.
  sys_.passive = {2 * m.ndof + kWorkSwitch};
  set_error_norm();
  f0_.resize(ns), f1_.resize(ns), yp_.resize(ns), delta_.resize(ns);
  shaft0_.resize(static_cast<size_t>(N) * 2 * kShaftSize), shaft1_ = shaft0_;
  pdiss0_.resize(N), pdiss1_ = pdiss0_;
}

// ModelOdeOptions::error_tol > 0: the system's error norm per joint, shaft and the load.
void ModelOde::set_error_norm() {
  if (opt_.error_tol < 0) throw std::invalid_argument("ModelOdeOptions: error_tol must be >= 0");
  if (opt_.error_tol == 0) return;
  ModelOdeOptions units = opt_;
  units.scaled = true;
  const Eigen::VectorXd u = model_state_units(m_, units);
  norm_weight_.assign(m_.nstate, 0.0);
  for (int i = 0; i < 2 * m_.ndof; ++i) norm_weight_[i] = unit_[i] / (opt_.error_tol * u[i]);
  for (int j = 0; j < m_.links; ++j) norm_group_.push_back(m_.joint(j));
  norm_group_.insert(norm_group_.end(), {m_.shaft(0), m_.shaft(1), m_.load_index(), m_.ndof});
  sys_.error_norm = [this](const double* err, const double*, const double*) { return chain_error_norm(err); };
}

// The largest, over the joints, shafts and load, of the RMS of a group's error (its
// positions and their velocities) in units of error_tol * (1 um, 1 mm/s).
double ModelOde::chain_error_norm(const double* err) const {
  const int n = m_.ndof;
  double worst = 0;
  for (size_t g = 0; g + 1 < norm_group_.size(); ++g) {
    double sum = 0;
    const int b = norm_group_[g], e = norm_group_[g + 1];
    for (int i = b; i < e; ++i) {
      const double q = err[i] * norm_weight_[i], v = err[n + i] * norm_weight_[n + i];
      sum += q * q + v * v;
    }
    worst = std::max(worst, sum / (2 * (e - b)));
  }
  return std::sqrt(worst);
}

void ModelOde::read_slots(std::vector<double>& shaft, std::vector<double>& pdiss) const {
  for (int j = 0; j < m_.links; ++j) {
    const JointSlot& s = ws_.pulley_slots[j];
    for (int i = 0; i < 2 * kShaftSize; ++i) shaft[static_cast<size_t>(j) * 2 * kShaftSize + i] = s.shaft[i];
    pdiss[j] = s.p_diss + ws_.chain_slots[j].p_diss;
  }
}

// The colouring of the finite-difference Jacobian, made at its first use: a W-method with
// the chain's matrix never needs it (it cost each driver about 0.1 s).
void ModelOde::ensure_colors() const {
  if (colored_) return;
  colored_ = true;
  const Model& m = m_;
  const ModelOdeOptions& opt = opt_;
  const int ns = m.nstate, N = m.links;
  // Colours: the pin columns by the reduced pattern (no pin -> tail entries); every tail
  // column (shafts, load, work integrals) a colour of its own, since the tail rows see
  // every pin column and so could not tell a tail column from the pins beside it.
  std::vector<std::pair<int, int>> pin_nz;
  for (const auto& rc : model_jacobian_pattern(m, opt.band, false))
    if (is_pin(rc.second)) pin_nz.push_back(rc);
  OdeSystem reduced;
  reduced.size = ns;
  reduced.set_sparsity(pin_nz);
  std::vector<int> color = color_columns(reduced.sparsity, &n_colors_);
  for (int c = 0; c < ns; ++c)
    if (!is_pin(c)) color[c] = n_colors_++;
  columns_of_color_.assign(n_colors_, {});
  for (int c = 0; c < ns; ++c) columns_of_color_[color[c]].push_back(c);
  owner_.assign(static_cast<size_t>(n_colors_) * N, -1);
  size_t widest = 0;
  for (int k = 0; k < n_colors_; ++k) {
    const auto& cols = columns_of_color_[k];
    widest = std::max(widest, cols.size());
    for (int idx = 0; idx < static_cast<int>(cols.size()); ++idx) {
      if (!is_pin(cols[idx])) continue;
      for (int d = -opt.band; d <= opt.band; ++d) {
        int& o = owner_[static_cast<size_t>(k) * N + m.wrap(joint_of(cols[idx]) + d)];
        if (o >= 0 && o != idx) throw std::logic_error("ModelOde: two pin columns of one colour near one joint");
        o = idx;
      }
    }
  }
  acc_shaft_.resize(2 * kShaftSize, static_cast<Eigen::Index>(widest));
  acc_p_.resize(static_cast<Eigen::Index>(widest));
}

void ModelOde::jacobian(double t, const double* y, Eigen::SparseMatrix<double>& jac) {
  ensure_colors();
  ++jac_evals_;
  const int n = m_.ndof, N = m_.links, ns = m_.nstate;
  const int shaft_row0 = n + m_.shaft(0), diss_row = 2 * n + kWorkDiss;
  const bool exact = opt_.exact_dense_rows;
  const double eps = std::numeric_limits<double>::epsilon();
  eval(t, y, f0_.data());
  if (exact) read_slots(shaft0_, pdiss0_);
  for (int i = 0; i < ns; ++i) yp_[i] = y[i];
  jac.coeffs().setZero();
  for (int k = 0; k < n_colors_; ++k) {
    const auto& cols = columns_of_color_[k];
    for (int c : cols) {
      delta_[c] = std::sqrt(eps * std::max(1e-5, std::abs(y[c])));
      yp_[c] = y[c] + delta_[c];
    }
    eval(t, yp_.data(), f1_.data());
    if (exact) {
      read_slots(shaft1_, pdiss1_);
      acc_shaft_.setZero();
      acc_p_.setZero();
      for (int j = 0; j < N; ++j) {
        const int o = owner_[static_cast<size_t>(k) * N + j];
        if (o < 0) continue;
        for (int i = 0; i < 2 * kShaftSize; ++i) {
          const size_t s = static_cast<size_t>(j) * 2 * kShaftSize + i;
          acc_shaft_(i, o) += shaft1_[s] - shaft0_[s];
        }
        acc_p_[o] += pdiss1_[j] - pdiss0_[j];
      }
    }
    for (int idx = 0; idx < static_cast<int>(cols.size()); ++idx) {
      const int c = cols[idx];
      const bool pin = exact && is_pin(c);
      const double inv = 1.0 / delta_[c];
      for (Eigen::SparseMatrix<double>::InnerIterator it(jac, c); it; ++it) {
        const int r = static_cast<int>(it.row());
        if (pin && r >= shaft_row0 && r < shaft_row0 + 2 * kShaftSize)
          it.valueRef() = a0_shaft_inv_.row(r - shaft_row0).dot(acc_shaft_.col(idx)) * inv;
        else if (pin && r == diss_row)
          it.valueRef() = acc_p_[idx] * inv;
        else
          it.valueRef() = (f1_[r] - f0_[r]) * inv;
      }
      yp_[c] = y[c];
    }
  }
}


}  // namespace cvt
