#include "engine/wmethod/model_ode.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <set>
#include <stdexcept>

#include <tbb/blocked_range.h>
#include <tbb/parallel_invoke.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>

#include "engine/rhs/rhs.hpp"
#include "modules/chain_forces.hpp"
#include "modules/inertia.hpp"
#include "modules/pulley_contact.hpp"

namespace cvt {

namespace {
// The block LU's two sweeps (CyclicBlockLU): concurrent on the schedule's threads (inside its
// arena), one after the other without; the same arithmetic, so the same bits, either way.
struct TwoTasks {
  bool parallel;
  template <class F, class G>
  void operator()(const F& f, const G& g) const {
    if (parallel)
      tbb::parallel_invoke(f, g);
    else
      f(), g();
  }
};
}  // namespace

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
    : m_(m), ws_(ws), schedule_(schedule), opt_(opt), fjac_(m) {
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
  w_rhs_.resize(N), w_g_.resize(N), w_cps_.resize(N), w_cps_on_.assign(N, 0);
  a0_row_.assign(1, 0);
  for (int r = 0; r < kLinkDim; ++r) {
    for (int c = 0; c < kLinkDim; ++c)
      if (a0_link_(r, c) != 0) a0_entries_.push_back({c, a0_link_(r, c)});
    a0_row_.push_back(static_cast<int>(a0_entries_.size()));
  }
  w_k_diag_.assign(N, LinkBlock::Zero()), w_k_sub_ = w_k_diag_, w_k_super_ = w_k_diag_;
  w_k_packed_.resize(N);
  w_delta_.assign(N, 0.0);
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
  if (opt.w_blocks) {
    sys_.w_factor = [this](double t, const double* y, double gh) { w_factor(t, y, gh); };
    sys_.w_solve = [this](double* x) { w_solve(x); };
  }
  f0_.resize(ns), f1_.resize(ns), yp_.resize(ns), delta_.resize(ns);
  shaft0_.resize(static_cast<size_t>(N) * 2 * kShaftSize), shaft1_ = shaft0_;
  pdiss0_.resize(N), pdiss1_ = pdiss0_;
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

void ModelOde::w_factor(double t, const double* y, double gh) {
  // The matrix is rebuilt at the steps whose index is a multiple of w_every (so a run
  // resumed at such a step repeats the bits), and whenever gh changed or none exists yet
  // (a fixed step taken as t1 - t0 varies in its last bits: that is no change of gh); in
  // between, the stale one is kept. The friction blocks come from the evaluation that starts
  // a rebuilding step: OdeDriver asks for them (ask_friction_jacobian) and eval() hands the request
  // to that evaluation only
  // (within an integrate() call of several steps only the first is armed; later rebuilds
  // use the blocks last recorded). The stiffness blocks are dearer (finite differences):
  // they are taken at the rebuilding steps whose index is a multiple of w_k_every.
  const long index = w_index_;
  const bool first = w_gh_ == 0 || w_invalid_;
  const bool rebuild = w_due() || std::abs(gh / w_gh_ - 1) > 1e-9;
  ++w_index_;
  Profiler* prof = schedule_.profiler();
  // Times f as section s of the profile (wall time on the master).
  const auto timed = [prof](Section s, auto&& f) {
    const std::uint64_t t0 = prof ? Profiler::ticks() : 0;
    f();
    if (prof) prof->add_master(s, Profiler::ticks() - t0), prof->call(s);
  };
  if (!rebuild) {
    if (w_fresh_on() && wf_recorded_) timed(Section::w_assembly, [&] { wf_update(w_gh_); });
    return;
  }
  if (wf_force_ && !(opt_.w_every <= 1 || index % opt_.w_every == 0)) ++wf_rebuilds_;
  wf_force_ = false;
  if (opt_.w_stiffness && (first || opt_.w_k_every <= 1 || index % opt_.w_k_every == 0))
    timed(Section::w_stiffness, [&] { w_stiffness(t, y); });
  if (w_invalid_) ++w_status_rebuilds_;
  w_invalid_ = false;
  w_gh_ = gh;
  timed(Section::w_assembly, [&] { for_joints([this, gh](int l) { w_assemble_link(l, gh); }); });
  bool ok = false;
  timed(Section::w_factor, [&] { ok = w_lu_.factor(TwoTasks{schedule_.threads() > 1}); });
  if (!ok) throw std::runtime_error("W-method: the W matrix is singular");
  if (w_fresh_on()) {
    wf_clear();
    fjac_.mu_tol = opt_.w_fresh * m_.cfg.pin.mass / gh;
  }
}

// ---- w_fresh: the friction blocks kept current by a low-rank correction ------------------
//
// The factorized W holds each contact's block as mu_w U U^T (the secant slope: D = mu P on
// the tangent plane, P = t t^T + s s^T for any tangent basis). At a later step the contact
// has mu, so W' = W + gh (mu - mu_w) U U^T, U taken when the contact was recorded (its
// geometry changes little over a few steps; a W-method needs no exact matrix). With the
// contacts whose mu moved most in the correction, W' x = r - gh dC_ps x_s (the sheaves'
// part of the same contacts, as the right side's C_ps term) by Woodbury:
//   x = y0 - Z (p + (I + D G)^-1 D (U^T y0 - G p)),  y0 = W^-1 r, p = D V^T x_s.

void ModelOde::wf_clear() {
  for (const FreshContact& c : wf_set_) c.kind->in_correction[c.idx] = 0;
  wf_set_.clear();
}

const double* ModelOde::FreshContact::columns() const {
  return kind->cols.data() + static_cast<std::size_t>(idx) * 2 * FrictionJacobian::kDim;
}

double ModelOde::wf_dot(const FreshContact& c, int col, const double* z) const {
  constexpr int kH = 2 * half::kSize, kD = FrictionJacobian::kDim;
  const double* u = c.columns() + col * kD;
  const double* zp = z + static_cast<std::size_t>(m_.wrap(c.joint - 1)) * kLinkDim;
  const double* zc = z + static_cast<std::size_t>(c.joint) * kLinkDim;
  double a = 0;
  for (int r = 0; r < kH; ++r) a += u[r] * zp[r] + u[kH + r] * zc[r];
  return a;
}

void ModelOde::wf_join(const FreshContact& c) {
  constexpr int kH = 2 * half::kSize, kD = FrictionJacobian::kDim;
  const int col = 2 * static_cast<int>(wf_set_.size());
  const int lp = m_.wrap(c.joint - 1), lc = c.joint;
  LinkVector* v = w_rhs_.data();
  for (int a = 0; a < 2; ++a) {
    const double* u = c.columns() + a * kD;
    double* z = wf_z_.col(col + a).data();
    const auto prepare = [&](int l) {
      v[l].setZero();
      if (l == lp)
        for (int r = 0; r < kH; ++r) v[l][r] += u[r];
      if (l == lc)
        for (int r = 0; r < kH; ++r) v[l][r] += u[kH + r];
    };
    const auto finish = [&](int l) { Eigen::Map<LinkVector>(z + static_cast<std::size_t>(l) * kLinkDim) = v[l]; };
    w_lu_.solve(v, TwoTasks{schedule_.threads() > 1}, prepare, finish);
  }
  wf_set_.push_back(c);
  c.kind->in_correction[c.idx] = 1;
  ++wf_joined_;
  const int k = col + 2;
  for (int i = 0; i < k; ++i)
    for (int a = 0; a < 2; ++a) {
      wf_g_(col + a, i) = wf_dot(c, a, wf_z_.col(i).data());
      if (i < col) wf_g_(i, col + a) = wf_dot(wf_set_[i / 2], i % 2, wf_z_.col(col + a).data());
    }
}

void ModelOde::wf_update(double gh) {
  const double tol = fjac_.mu_tol;
  // The contacts not yet in whose mu moved by more than tol, the largest change first (ties
  // by index): a deterministic order, the same on any number of threads.
  // Rocker stations first, then pin ends (rank: the rocker count plus the pin end's index).
  wf_cand_.clear();
  FrictionJacobian::FreshMu* kinds[2] = {&fjac_.rocker_fresh, &fjac_.pulley_fresh};
  for (int kind = 0, rank0 = 0; kind < 2; rank0 += static_cast<int>(kinds[kind]->mu.size()), ++kind) {
    const FrictionJacobian::FreshMu& f = *kinds[kind];
    for (int i = 0; i < static_cast<int>(f.mu.size()); ++i) {
      const double d = std::abs(f.mu[i] - f.mu_w[i]);
      if (d > tol && !f.in_correction[i] && f.cols_set[i]) wf_cand_.push_back({d, rank0 + i, kind, i});
    }
  }
  std::sort(wf_cand_.begin(), wf_cand_.end(), [](const FreshCandidate& a, const FreshCandidate& b) {
    return a.dmu > b.dmu || (a.dmu == b.dmu && a.rank < b.rank);
  });
  for (const FreshCandidate& x : wf_cand_) {
    if (static_cast<int>(wf_set_.size()) >= opt_.w_fresh_max) {
      wf_force_ = true;  // the next step rebuilds the friction blocks
      break;
    }
    FreshContact c{kinds[x.kind], x.idx, 0, -1};
    if (x.kind == 0)
      c.joint = x.idx / m_.cfg.rocker.stations;
    else
      c.joint = x.idx / ContactStatus::kPulleyPerJoint, c.shaft = x.idx % 2;  // ContactStatus::pulley_index
    wf_join(c);
  }
  const int k = 2 * static_cast<int>(wf_set_.size());
  if (k == 0) return;
  for (int i = 0; i < k; i += 2) {
    const FreshContact& c = wf_set_[i / 2];
    wf_d_[i] = wf_d_[i + 1] = gh * (c.kind->mu[c.idx] - c.kind->mu_w[c.idx]);
  }
  Eigen::MatrixXd& cap = wf_cap_m_[k / 2 - 1];
  cap.noalias() = wf_d_.head(k).asDiagonal() * wf_g_.topLeftCorner(k, k);
  cap.diagonal().array() += 1.0;
  wf_cap_[k / 2 - 1].compute(cap);
}

void ModelOde::wf_correct(double* x) const {
  const int k = 2 * static_cast<int>(wf_set_.size());
  if (k == 0) return;
  static_assert(sizeof(LinkVector) == kLinkDim * sizeof(double), "link vectors must be contiguous");
  const int n = m_.ndof;
  const double gh = w_gh_;
  const double* y0 = w_rhs_[0].data();  // W^-1 r, physical, link order
  auto p = wf_p_.head(k);
  auto t = wf_t_.head(k);
  for (int i = 0; i < k; ++i) {
    const FreshContact& c = wf_set_[i / 2];
    double w = 0;
    if (c.shaft >= 0) {
      const double* v = fjac_.pulley_shaft_cols.data() + (static_cast<std::size_t>(c.idx) * 2 + i % 2) * kShaftSize;
      for (int s = 0; s < kShaftSize; ++s) {
        const int r = n + m_.shaft(c.shaft) + s;
        w += v[s] * (opt_.scaled ? x[r] * unit_[r] : x[r]);
      }
    }
    p[i] = wf_d_[i] * w;
    t[i] = wf_dot(c, i % 2, y0);
  }
  t.noalias() -= wf_g_.topLeftCorner(k, k) * p;
  // s = p + (I + D G)^-1 D t, formed in preallocated vectors (the sum in either order is
  // the same number).
  auto b = wf_b_.head(k);
  auto s = wf_s_.head(k);
  b = wf_d_.head(k).cwiseProduct(t);
  s = wf_cap_[k / 2 - 1].solve(b);
  s += p;
  Eigen::VectorXd& corr = wf_corr_;
  corr.noalias() = wf_z_.leftCols(k) * s;
  const double* uv = w_unit_v_.data();
  const double* ratio = w_unit_ratio_.data();
  for (int j = 0; j < m_.links * kLinkDim; ++j) {
    const int c = w_coord_[j];
    const double dv = corr[j] / uv[j];
    x[n + c] -= dv;
    x[c] -= gh * dv * ratio[c];
  }
}

void ModelOde::w_stiffness(double t, const double* y) {
  // K = -dF/dq on the chain by finite differences of the generalized forces (ws.force), in
  // link order: a link's coordinates reach the forces of itself and its two neighbours
  // only, so the links of one colour (3 or more apart) are perturbed together, one link
  // coordinate at a time: 21 evaluations per colour.
  const auto t0 = std::chrono::steady_clock::now();
  const int n = m_.ndof, N = m_.links;
  const double eps = std::numeric_limits<double>::epsilon();
  Eigen::VectorXd& yp = yp_;
  if (opt_.scaled)
    to_y(Eigen::Map<const Eigen::VectorXd>(y, m_.nstate), yp);
  else
    yp = Eigen::Map<const Eigen::VectorXd>(y, m_.nstate);
  ys_ = yp;  // the unperturbed physical state
  chain_forces_at(t, ys_.data());
  std::vector<double>& F0 = w_force0_;
  F0.assign(ws_.force.begin(), ws_.force.begin() + n);
  w_chain0_ = ws_.chain_slots, w_pulley0_ = ws_.pulley_slots;  // the joints a colour leaves alone
  for (int color = 0; color < w_colors_; ++color) {
    for (int i = 0; i < kLinkDim; ++i) {
      for (int l = 0; l < N; ++l) {
        if (w_color_[l] != color) continue;
        const int c = coord(l, i);
        w_delta_[l] = std::sqrt(eps * std::max(1e-5, std::abs(ys_[c])));
        yp[c] = ys_[c] + w_delta_[l];
      }
      chain_forces_at(t, yp.data(), color);
      const double* F1 = ws_.force.data();
      for_joints([&](int l) {
        if (w_color_[l] != color) return;
        const double inv = 1.0 / w_delta_[l];
        // Column i of link l: rows of links l-1 (sub of l, as M(l-1, l): super(l)), l, l+1.
        for (int r = 0; r < kLinkDim; ++r) {
          const int rp = coord(m_.wrap(l - 1), r), ro = coord(l, r), rn = coord(m_.wrap(l + 1), r);
          w_k_super_[l](r, i) = -(F1[rp] - F0[rp]) * inv;
          w_k_diag_[l](r, i) = -(F1[ro] - F0[ro]) * inv;
          w_k_sub_[m_.wrap(l + 1)](r, i) = -(F1[rn] - F0[rn]) * inv;
        }
      });
      for (int l = 0; l < N; ++l)
        if (w_color_[l] == color) yp[coord(l, i)] = ys_[coord(l, i)];
    }
  }
  for_joints([this](int l) {
    pack_columns(w_k_sub_[l], w_k_packed_[l][0]);
    pack_columns(w_k_super_[l], w_k_packed_[l][1]);
  });
  ++jac_evals_;
  w_k_seconds_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

void ModelOde::chain_forces_at(double t, const double* y, int color) {
  // The passes of an evaluation that the chain's generalized forces need: the link angles,
  // the chain and pulley kernels, the gather. The inertia's velocity terms keep the values of
  // the last full evaluation (a constant, which the differences cancel). With a colour: a
  // joint touches only links j-1 and j (docs/model.md 4: its halves a_j, b_j, the plates of
  // link j, the directions of links j-1 and j), so a joint next to no perturbed link keeps
  // the slots of the unperturbed state (w_chain0_, w_pulley0_), which its kernels would
  // reproduce bit for bit; only the others are computed (2 of 3 joints with 3 colours).
  set_stage_input(m_, ws_, t, y);
  for_ranges([this](int b, int e) { link_kinematics(m_, ws_, b, e); });
  if (color < 0) {
    for_ranges([this](int b, int e) {
      chain_forces(m_, ws_, b, e);
      pulley_contact(m_, ws_, b, e);
    });
  } else {
    // Joint j is next to a perturbed link when link j-1 or link j has the colour.
    const auto touched = [this, color](int j) { return w_color_[m_.wrap(j - 1)] == color || w_color_[j] == color; };
    for_ranges([this, &touched](int b, int e) {
      for (int j = b; j < e;) {
        if (!touched(j)) {
          ws_.chain_slots[j] = w_chain0_[j], ws_.pulley_slots[j] = w_pulley0_[j];
          ++j;
          continue;
        }
        int k = j + 1;
        while (k < e && touched(k)) ++k;
        chain_forces(m_, ws_, j, k);
        pulley_contact(m_, ws_, j, k);
        j = k;
      }
    });
  }
  for_ranges([this](int b, int e) { gather_joints(m_, ws_, b, e); });
  ++rhs_evals_;  // counted as an evaluation (about 3/4 of one)
}

template <class F>
void ModelOde::for_ranges(const F& f) const {
  if (schedule_.threads() <= 1) return f(0, m_.links);
  // Inside the schedule's arena (OdeDriver runs in Schedule::within): its threads share them.
  tbb::parallel_for(
      tbb::blocked_range<int>(0, m_.links), [&](const tbb::blocked_range<int>& r) { f(r.begin(), r.end()); },
      tbb::static_partitioner());
}

// Each joint's block is independent of the others: any split over threads gives the same bits.
template <class F>
void ModelOde::for_joints(const F& f) const {
  for_ranges([&](int b, int e) {
    for (int j = b; j < e; ++j) f(j);
  });
}

void ModelOde::link_gradient(int l, LinkVector& g) const {
  // d psi_l / d(b_l, a_{l+1}, s_l) (modules/inertia.hpp link_g): -+ n/(2|Delta|) on both
  // ends' x, y; 0 on the pack.
  double gx, gy;
  link_g(ws_.kin, l, gx, gy);
  g.setZero();
  for (int e = 0; e < 2; ++e) {
    g[e * half::kEnd + half::kX] = -gx, g[e * half::kEnd + half::kY] = -gy;
    g[half::kSize + e * half::kEnd + half::kX] = gx, g[half::kSize + e * half::kEnd + half::kY] = gy;
  }
}

void ModelOde::w_assemble_link(int l, double gh) {
  // Link l's coordinates: b_l, a_{l+1}, pack s_l. Joint j's 40 x 40 friction blocks are over
  // links j-1 (rows 0..19) and j (20..39), lower triangle only: link l's diagonal block is
  // the lower-right of joint l's plus the upper-left of joint l+1's; M(l, l-1) is joint l's
  // lower-left, M(l-1, l) its transpose.
  constexpr int kD = FrictionJacobian::kDim, kH = 2 * half::kSize;
  const double* kr = fjac_.rocker_damping.data() + static_cast<std::size_t>(l) * kD * kD;
  const double* kp = fjac_.pulley_damping.data() + static_cast<std::size_t>(l) * kD * kD;
  const double* nr = fjac_.rocker_damping.data() + static_cast<std::size_t>(m_.wrap(l + 1)) * kD * kD;
  const double* np = fjac_.pulley_damping.data() + static_cast<std::size_t>(m_.wrap(l + 1)) * kD * kD;
  LinkBlock& D = w_lu_.diag(l);
  LinkBlock& S = w_lu_.sub(l);
  LinkBlock& P = w_lu_.super(l);
  // Row r of the joint blocks (row-major, lower triangle) into column r of F and P, so that
  // reads and writes run along memory; then mirrored. Each entry is the same sum as before.
  Eigen::Matrix<double, kH, kH> F;
  P.setZero();
  for (int r = 0; r < kH; ++r) {
    const double* a = kr + (r + kH) * kD;  // joint l's lower rows (link l)
    const double* b = kp + (r + kH) * kD;
    const double* c2 = nr + r * kD;  // joint l+1's upper-left (link l)
    const double* d = np + r * kD;
    double* f = F.col(r).data();
    for (int c = 0; c <= r; ++c) f[c] = gh * (a[c + kH] + b[c + kH] + c2[c] + d[c]);
    double* p = P.col(r).data();
    for (int c = 0; c < kH; ++c) p[c] = gh * (a[c] + b[c]);  // M(l-1, l) = M(l, l-1)^T
  }
  for (int c = 0; c < kH; ++c)
    for (int r = c + 1; r < kH; ++r) F(r, c) = F(c, r);
  D = a0_link_;
  D.topLeftCorner<kH, kH>() += F;
  S = P.transpose();
  // + J g g^T of A(q) (docs/model.md 3): psi_l turns with the mid-points of b_l (-) and a_{l+1} (+).
  LinkVector& g = w_g_[l];
  link_gradient(l, g);
  D.noalias() += m_.cfg.chain.link_inertia * g * g.transpose();
  // The pins' rows of K_ps for this link: rows 20..39 of joint l's blocks, 0..19 of joint l+1's.
  constexpr int kX = 2 * kD * kShaftSize;
  const double* here = fjac_.pulley_shaft_damping.data() + static_cast<std::size_t>(l) * kX;
  const double* next = fjac_.pulley_shaft_damping.data() + static_cast<std::size_t>(m_.wrap(l + 1)) * kX;
  auto& X = w_cps_[l];
  for (int k = 0; k < 2; ++k)
    for (int i = 0; i < kH; ++i)
      for (int c = 0; c < kShaftSize; ++c)
        X(i, k * kShaftSize + c) = here[(k * kD + kH + i) * kShaftSize + c] + next[(k * kD + i) * kShaftSize + c];
  X.row(kH).setZero();  // the pack
  w_cps_on_[l] = X.cwiseAbs().maxCoeff() > 0;
  if (opt_.w_stiffness) {
    const double gh2 = gh * gh;
    D += gh2 * w_k_diag_[l];
    S += gh2 * w_k_sub_[l];
    P += gh2 * w_k_super_[l];
  }
}

void ModelOde::pack_columns(const LinkBlock& b, PackedColumns& p) {
  p.n = 0;
  for (int c = 0; c < kLinkDim; ++c)
    if (b.col(c).cwiseAbs().maxCoeff() != 0) p.index[p.n] = c, p.cols.col(p.n++) = b.col(c);
}

void ModelOde::w_solve(double* x) const {
  Profiler* prof = schedule_.profiler();
  const std::uint64_t t0 = prof ? Profiler::ticks() : 0;
  w_solve_untimed(x);
  if (prof) prof->add_master(Section::w_solve, Profiler::ticks() - t0), prof->call(Section::w_solve);
}

void ModelOde::w_solve_untimed(double* x) const {
  // W = [I, -gh I; gh A^-1 K, I + gh A^-1 C] on the chain (identity on the other
  // velocities): (A + gh C + gh^2 K) x_v = A b_v - gh K b_q, then x_q = b_q + gh x_v.
  // (Scaled: the chain's entries through w_unit_q_ / w_unit_v_, tables in link order.)
  // The right side of each link and the write-back of its solution run inside the block
  // LU's two tasks (CyclicBlockLU::solve's prepare / finish): one fork and join per phase.
  const int n = m_.ndof;
  const double gh = w_gh_;
  const double* uq = w_unit_q_.data();
  const double* uv = w_unit_v_.data();
  const double* ratio = w_unit_ratio_.data();
  LinkVector* v = w_rhs_.data();
  // Entry i of b_q in link l's coordinates.
  const auto position = [&](int l, int i) { return x[w_coord_[l * kLinkDim + i]] * uq[l * kLinkDim + i]; };
  const auto prepare = [&](int l) {
    const int o = l * kLinkDim;
    LinkVector b;
    for (int i = 0; i < kLinkDim; ++i) b[i] = x[n + w_coord_[o + i]] * uv[o + i];
    LinkVector& y = v[l];
    // A0 b (73 nonzeros of 441), row by row (each row's sum in a register).
    for (int r = 0; r < kLinkDim; ++r) {
      double acc = 0;
      for (int k = a0_row_[r]; k < a0_row_[r + 1]; ++k) acc += a0_entries_[k].v * b[a0_entries_[k].c];
      y[r] = acc;
    }
    y += (m_.cfg.chain.link_inertia * w_g_[l].dot(b)) * w_g_[l];  // + J g g^T b
    if (opt_.w_stiffness) {
      const int lp = m_.wrap(l - 1), ln = m_.wrap(l + 1);
      LinkVector bq;
      for (int i = 0; i < kLinkDim; ++i) bq[i] = position(l, i);
      // K b_q over link l's row: the dense diagonal block, the couplings by their nonzero
      // columns (exact zeros skipped; the neighbours' b_q read at those columns only).
      LinkVector kb;
      block_times(w_k_diag_[l], bq, kb);
      const PackedColumns& sub = w_k_packed_[l][0];
      const PackedColumns& sup = w_k_packed_[ln][1];
      for (int c = 0; c < sub.n; ++c) kb += sub.cols.col(c) * position(lp, sub.index[c]);
      for (int c = 0; c < sup.n; ++c) kb += sup.cols.col(c) * position(ln, sup.index[c]);
      y.noalias() -= gh * kb;
    }
    if (w_cps_on_[l]) {
      // - gh K_ps x_s: the sheaves' velocity increments (x_s = b_s) drag the pins in contact.
      Eigen::Matrix<double, 2 * kShaftSize, 1> xs;
      for (int k = 0; k < 2; ++k)
        for (int i = 0; i < kShaftSize; ++i) {
          const int r = n + m_.shaft(k) + i;
          xs[k * kShaftSize + i] = opt_.scaled ? x[r] * unit_[r] : x[r];
        }
      y.noalias() -= gh * (w_cps_[l] * xs);
    }
  };
  // x_v, then x_q = b_q + gh x_v (dq/dt = v exactly: W's position rows [I, -gh I]; scaled:
  // times the ratio of the units, w_unit_ratio_).
  const auto finish = [&](int l) {
    const int o = l * kLinkDim;
    for (int i = 0; i < kLinkDim; ++i) {
      const int c = w_coord_[o + i];
      x[n + c] = v[l][i] / uv[o + i];
      x[c] += gh * x[n + c] * ratio[c];
    }
  };
  w_lu_.solve(v, TwoTasks{schedule_.threads() > 1}, prepare, finish);
  wf_correct(x);
  for (int c : w_other_coord_) x[c] += gh * x[n + c] * ratio[c];  // the shafts' and load's
}

OdeMethod parse_ode_method(const std::string& name) {
  for (OdeMethod m : {OdeMethod::Rk4, OdeMethod::Dopri5, OdeMethod::Rkc, OdeMethod::Trapezoid, OdeMethod::TrBdf2,
                      OdeMethod::Esdirk3, OdeMethod::Ros2, OdeMethod::Ros34pw2})
    if (name == to_string(m)) return m;
  throw std::invalid_argument("unknown method '" + name +
                              "' (rk4, dopri5, rkc, trapezoid, trbdf2, esdirk3, ros2, ros34pw2)");
}

OdeRunOptions w_run_options(const Config& c, double h, bool startup) {
  const Config::Integrator& in = c.integrator;
  OdeRunOptions ro;
  ro.method = startup || in.method == IntegratorMethod::ros2 ? OdeMethod::Ros2 : OdeMethod::Ros34pw2;
  ro.ode.fixed_step = true;
  ro.ode.h0 = h;
  ro.jac.scaled = false;
  ro.jac.w_every = in.w_every;
  ro.jac.w_k_every = in.w_k_every;
  ro.jac.w_secant = in.w_secant;
  ro.jac.w_fresh = in.w_fresh;  // ModelOde leaves it off without the secant
  ro.jac.w_fresh_max = in.w_fresh_max;
  return ro;
}

OdeDriver::OdeDriver(const Model& m, Workspace& ws, Schedule& schedule, const OdeRunOptions& opt)
    : m_(m), ws_(ws), schedule_(schedule), opt_(opt), ode_(m, ws, schedule, opt.jac),
      solver_(ode_.system(), opt.method, opt.ode) {
  solver_.options().keep_jacobian_across_calls = true;
  if (!(opt.ode.h0 > 0)) throw std::invalid_argument("OdeRunOptions: ode.h0 (first or fixed step) must be > 0");
  h_next_ = opt.ode.h0;
}

long OdeDriver::advance(double t, Eigen::VectorXd& y, double t1, long first_step) {
  const std::int64_t steps0 = solver_.stats().steps;
  const bool fixed = opt_.method == OdeMethod::Rk4 || opt_.ode.fixed_step;
  // Fixed steps: their times from a clock of the driver's own that starts here.
  const StepClock grid = StepClock::at(t, 0);
  std::int64_t k = 0;
  const bool freeze = opt_.jac.freeze_friction && m_.cfg.friction.law == FrictionLaw::nonsmooth &&
                      (opt_.method == OdeMethod::Trapezoid || opt_.method == OdeMethod::TrBdf2 ||
                       opt_.method == OdeMethod::Esdirk3);
  // The production RK4 path (Simulation::step) shares this workspace: leave the law plain.
  struct Plain {
    Workspace& ws;
    ~Plain() { ws.friction_branch = Workspace::FrictionBranch::off; }
  } plain{ws_};
  const bool w_blocks = is_w_method(opt_.method) && opt_.jac.w_blocks;
  schedule_.within([&] {
    while (t < t1) {
      const double H = fixed ? opt_.ode.h0 : opt_.status_interval > 0 ? opt_.status_interval : h_next_;
      double t_end = fixed ? grid.time_after(k + 1, H) : t + H;
      // No sliver shorter than 1 % of a macro step before t1.
      if (t_end > t1 || t1 - t_end < 0.01 * H) t_end = t1;
      if (!fixed) solver_.options().h0 = std::min(h_next_, t_end - t);
      if (freeze) ws_.friction_branch = Workspace::FrictionBranch::record;
      if (w_blocks) ode_.ask_friction_jacobian(first_step + static_cast<long>(solver_.stats().steps - steps0));
      if (opt_.jac.scaled) {
        ode_.offset() = y;
        ode_.to_z(y, z_);
        solver_.integrate(t, t_end, z_);
        ode_.to_y(z_, y);
      } else {
        solver_.integrate(t, t_end, y);
      }
      if (!fixed && solver_.stats().h_next > 0) h_next_ = solver_.stats().h_next;
      t = t_end;
      ++k;
      const bool watch = w_blocks && opt_.jac.w_status_rebuild;
      if (watch) rocker0_ = ws_.status.rocker, pulley0_ = ws_.status.pulley;
      update_statuses_after_step(m_, schedule_, ws_, t, y);
      if (watch && (rocker0_ != ws_.status.rocker || pulley0_ != ws_.status.pulley)) ode_.w_invalidate();
      ++macro_;
    }
  });
  return static_cast<long>(solver_.stats().steps - steps0);
}

}  // namespace cvt
