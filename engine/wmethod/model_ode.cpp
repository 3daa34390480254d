#include "engine/wmethod/model_ode.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <set>
#include <stdexcept>

#include "engine/rhs/rhs.hpp"
#include "engine/wmethod/parallel.hpp"
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

void ModelOde::eval_ahead(double t, const double* y, double* dy) {
  ahead_ = false;
  eval(t, y, dy);
  // A scaled system's steps evaluate at offset + z * unit, which need not repeat y's bits.
  if (opt_.scaled || freeze_) return;
  const int ns = m_.nstate;
  ahead_ = true;
  ahead_t_ = t;
  ahead_index_ = w_index_;
  ahead_y_.assign(y, y + ns);
  ahead_dy_.assign(dy, dy + ns);
  ahead_status_ = ws_.status;
}

bool ModelOde::take_ahead(double t, const double* y, double* dy) {
  ahead_ = false;
  const int ns = m_.nstate;
  if (t != ahead_t_ || fjac_.requested() || freeze_ || ws_.status.rocker != ahead_status_.rocker ||
      ws_.status.pulley != ahead_status_.pulley ||
      std::memcmp(y, ahead_y_.data(), sizeof(double) * static_cast<std::size_t>(ns)) != 0)
    return false;
  std::copy(ahead_dy_.begin(), ahead_dy_.end(), dy);
  set_stage_input(m_, ws_, t, y);  // the workspace as this evaluation would leave it: same values, this y
  return true;
}

void ModelOde::eval_scaled(double t, const double* z, double* dz) {
  const int ns = m_.nstate;
  for (int i = 0; i < ns; ++i) ys_[i] = offset_[i] + z[i] * unit_[i];
  eval(t, ys_.data(), dz);
  for (int i = 0; i < ns; ++i) dz[i] /= unit_[i];
}

ModelOde::ModelOde(const Model& m, Workspace& ws, Schedule& schedule, const ModelOdeOptions& opt)
    : m_(m), ws_(ws), schedule_(schedule), opt_(opt), fjac_(m), frozen_(m) {
  fjac_.secant = opt.w_secant;
  const int ns = m.nstate, N = m.links, tail0 = m.shaft(0);
  if (opt.band < 1 || 2 * opt.band + 1 > N) throw std::invalid_argument("ModelOdeOptions::band must be in [1, (links - 1) / 2]");
  sys_.size = ns;
  unit_ = model_state_units(m, opt);
  offset_ = Eigen::VectorXd::Zero(ns);
  ys_.resize(ns);
  if (opt.scaled)
    sys_.rhs = [this](double t, const double* z, double* dz) { eval_scaled(t, z, dz); };
  else
    sys_.rhs = [this](double t, const double* y, double* dy) { eval(t, y, dy); };
  sys_.set_sparsity(model_jacobian_pattern(m, opt.band, opt.exact_dense_rows));
  sys_.sparse_jacobian = [this](double t, const double* z, Eigen::SparseMatrix<double>& jac) {
    if (!opt_.scaled) return jacobian(t, z, jac);
    // J_z = S^-1 J_y S.
    for (int i = 0; i < m_.nstate; ++i) ys_[i] = offset_[i] + z[i] * unit_[i];
    jacobian(t, ys_.data(), jac);  // evaluates through eval(), which leaves ys_ alone
    for (int c = 0; c < jac.outerSize(); ++c)
      for (Eigen::SparseMatrix<double>::InnerIterator it(jac, c); it; ++it) it.valueRef() *= unit_[c] / unit_[it.row()];
  };

  // A0^-1 restricted to the shafts and the load (a constant 15 x 14 block).
  a0_shaft_inv_.resize(2 * kShaftSize + 1, 2 * kShaftSize);
  Eigen::VectorXd F = Eigen::VectorXd::Zero(m.ndof), Y = Eigen::VectorXd::Zero(m.ndof);
  for (int k = 0; k < 2 * kShaftSize; ++k) {
    F.setZero();
    F[tail0 + k] = 1.0;
    a0_inverse_shafts(m, F.data(), Y.data());
    for (int r = 0; r < 2 * kShaftSize + 1; ++r) a0_shaft_inv_(r, k) = Y[tail0 + r];
  }
  // W-method: A0 of a link's coordinates (two halves: bending per plane, axial bar; the
  // plate pack's axial mass), and the hooks.
  a0_link_.setZero();
  for (int h = 0; h < 2; ++h) set_half_mass(m, a0_link_, h * half::kSize);
  a0_link_(2 * half::kSize, 2 * half::kSize) = m.pack_mass;
  w_lu_.resize(N);
  w_lu_.set_drop_tolerance(opt_.w_fill_drop);
  // The chain's coordinates in link order, and their units (1 unless scaled).
  w_coord_.resize(static_cast<size_t>(N) * kLinkDim);
  w_unit_q_.assign(w_coord_.size(), 1.0), w_unit_v_.assign(w_coord_.size(), 1.0);
  for (int l = 0; l < N; ++l)
    for (int i = 0; i < kLinkDim; ++i) {
      const int o = l * kLinkDim + i, c = link_coord(l, i);
      w_coord_[o] = c;
      if (opt.scaled) w_unit_q_[o] = unit_[c], w_unit_v_[o] = unit_[m.ndof + c];
    }
  w_unit_ratio_.assign(m.ndof, 1.0);
  if (opt.scaled)
    for (int i = 0; i < m.ndof; ++i) w_unit_ratio_[i] = unit_[m.ndof + i] / unit_[i];
  std::vector<char> in_chain(m.ndof, 0);
  for (int c : w_coord_) in_chain[c] = 1;
  for (int c = 0; c < m.ndof; ++c)
    if (!in_chain[c]) w_other_coord_.push_back(c);
  w_rhs_.resize(N), w_bz_.resize(N), wf_rhs_.resize(N), wf_rhs2_.resize(N), wf_bz2_.resize(N), w_g_.resize(N), w_cps_.resize(N), w_cps_on_.assign(N, 0);
  w_k_diag_.assign(N, LinkBlock::Zero()), w_k_sub_ = w_k_diag_, w_k_super_ = w_k_diag_;
  w_k_packed_.resize(N);
  w_delta_.assign(N, 0.0);
  if (schedule_.threads() > 1) {  // the stiffness's second workspace, sized before any step
    w_ws2_ = std::make_unique<Workspace>(ws_);
    w_yp2_.resize(m.nstate);
    w_delta2_.assign(N, 0.0);
  }
  // Link colours for the stiffness differences: greedy around the cycle, links within two
  // of each other differ (3 colours when 3 divides N, at most 5).
  w_color_.assign(N, -1);
  w_colors_ = 0;
  for (int l = 0; l < N; ++l) {
    int c = 0;
    for (bool clash = true; clash; ++c) {
      clash = false;
      for (int d = -2; d <= 2; ++d)
        if (d != 0 && w_color_[m.wrap(l + d)] == c) clash = true;
      if (!clash) break;
    }
    w_color_[l] = c;
    w_colors_ = std::max(w_colors_, c + 1);
  }
  if (w_fresh_on()) {
    if (opt.w_fresh_max < 1) throw std::invalid_argument("ModelOdeOptions: w_fresh_max must be >= 1");
    const int k = 2 * opt.w_fresh_max;
    wf_z_.setZero(static_cast<Eigen::Index>(N) * kLinkDim, k);
    if (opt.w_shafts) wf_zs_.setZero(2 * kShaftSize, k);
    wf_g_.setZero(k, k);
    // Everything a step's correction uses, sized here: nothing is allocated inside a step.
    // The capacitance matrix and its LU for each number of contacts in the correction.
    for (Eigen::VectorXd* v : {&wf_d_, &wf_p_, &wf_t_, &wf_s_, &wf_b_}) v->setZero(k);
    for (int i = 1; i <= opt.w_fresh_max; ++i) {
      wf_cap_m_.emplace_back(Eigen::MatrixXd::Zero(2 * i, 2 * i));
      wf_cap_.emplace_back(2 * i);
    }
    wf_set_.reserve(opt.w_fresh_max);
    wf_cand_.reserve(fjac_.rocker_fresh.mu.size() + fjac_.pulley_fresh.mu.size());
    wf_corr_.setZero(static_cast<Eigen::Index>(N) * kLinkDim);
  }
  if (opt.w_shafts) {
    // M_s: the inverse of A0^-1 on the shafts (their 14 x 14 block; the load is outside W).
    w_ms_ = a0_shaft_inv_.topRows(2 * kShaftSize).inverse();
    w_y_.resize(N);
  }
  if (opt.w_blocks) {
    sys_.w_factor = [this](double t, const double* y, double gh) { w_factor(t, y, gh); };
    sys_.w_solve = [this](double* x) { w_solve(x); };
  }
  if (opt.error_tol > 0) {
    ModelOdeOptions units = opt;
    units.scaled = true;
    const Eigen::VectorXd u = model_state_units(m, units);
    norm_weight_.assign(ns, 0.0);
    for (int i = 0; i < 2 * m.ndof; ++i) norm_weight_[i] = unit_[i] / (opt.error_tol * u[i]);
    for (int j = 0; j < N; ++j) norm_group_.push_back(m.joint(j));
    norm_group_.insert(norm_group_.end(), {m.shaft(0), m.shaft(1), m.load_index(), m.ndof});
    sys_.error_norm = [this](const double* err, const double*, const double*) { return chain_error_norm(err); };
  } else if (opt.error_tol < 0) {
    throw std::invalid_argument("ModelOdeOptions: error_tol must be >= 0");
  }
  if (!(opt.w_h_grow >= 1 && opt.w_h_shrink >= 1))
    throw std::invalid_argument("ModelOdeOptions: w_h_grow and w_h_shrink must be >= 1");
  f0_.resize(ns), f1_.resize(ns), yp_.resize(ns), delta_.resize(ns);
  shaft0_.resize(static_cast<size_t>(N) * 2 * kShaftSize), shaft1_ = shaft0_;
  pdiss0_.resize(N), pdiss1_ = pdiss0_;
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
