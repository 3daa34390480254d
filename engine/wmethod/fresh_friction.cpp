#include "engine/wmethod/model_ode.hpp"

#include <algorithm>
#include <cmath>

#include "engine/wmethod/parallel.hpp"

namespace cvt {

// ---- w_fresh: the friction blocks kept current by a low-rank correction ------------------
//
// The factorized W holds each contact's block as mu_w U U^T (the secant slope: D = mu P on
// the tangent plane, P = t t^T + s s^T for any tangent basis). At a later step the contact
// has mu, so W' = W + gh (mu - mu_w) U U^T, U taken when the contact was recorded (its
// geometry changes little over a few steps; a W-method needs no exact matrix). With the
// contacts whose mu moved most in the correction, W' x = r - gh dC_ps x_s (the sheaves'
// part of the same contacts, as the right side's C_ps term) by Woodbury:
//   x = y0 - Z (p + (I + D G)^-1 D (U^T y0 - G p)),  y0 = W^-1 r, p = D V^T x_s.
// With the shafts' rows in W (w_shafts) a contact's column is [U; V] over the chain and the
// shafts, W the bordered matrix, and x = y0 - Z (I + D G)^-1 D [U; V]^T y0 with
// Z = W^-1 [U; V], G = [U; V]^T Z (p = 0: the sheaves are unknowns, not a right side).

void ModelOde::wf_clear() {
  for (const FreshContact& c : wf_set_) c.kind->in_correction[c.idx] = 0;
  wf_set_.clear();
}

const double* ModelOde::FreshContact::columns() const {
  return kind->cols.data() + static_cast<std::size_t>(idx) * 2 * FrictionJacobian::kDim;
}

const double* ModelOde::FreshContact::sheave_columns(const FrictionJacobian& f) const {
  return shaft < 0 ? nullptr : f.pulley_shaft_cols.data() + static_cast<std::size_t>(idx) * 2 * kShaftSize;
}

double ModelOde::wf_dot(const FreshContact& c, int col, const double* z, const double* zs) const {
  constexpr int kH = 2 * half::kSize, kD = FrictionJacobian::kDim;
  const double* u = c.columns() + col * kD;
  const double* zp = z + static_cast<std::size_t>(m_.wrap(c.joint - 1)) * kLinkDim;
  const double* zc = z + static_cast<std::size_t>(c.joint) * kLinkDim;
  double a = 0;
  for (int r = 0; r < kH; ++r) a += u[r] * zp[r] + u[kH + r] * zc[r];
  if (zs && c.shaft >= 0) {
    const double* v = c.sheave_columns(fjac_) + col * kShaftSize;
    for (int s = 0; s < kShaftSize; ++s) a += v[s] * zs[c.shaft * kShaftSize + s];
  }
  return a;
}

void ModelOde::wf_join(const FreshContact& c) {
  // Z's two new columns, W^-1 [U; V]: the chain's block solve of both at once (the same bits
  // as one solve per column), then (w_shafts) each column's shafts' step and z - Y x_s.
  constexpr int kH = 2 * half::kSize, kD = FrictionJacobian::kDim;
  const int col = 2 * static_cast<int>(wf_set_.size());
  const int lp = m_.wrap(c.joint - 1), lc = c.joint;
  LinkPair* v = wf_rhs_.data();
  for (int l = 0; l < m_.links; ++l) v[l].setZero();
  for (int a = 0; a < 2; ++a) {
    const double* u = c.columns() + a * kD;
    for (int r = 0; r < kH; ++r) v[lp](r, a) += u[r];
    for (int r = 0; r < kH; ++r) v[lc](r, a) += u[kH + r];
  }
  double* z[2] = {wf_z_.col(col).data(), wf_z_.col(col + 1).data()};
  const auto z_of = [&](int a, int l) { return Eigen::Map<LinkVector>(z[a] + static_cast<std::size_t>(l) * kLinkDim); };
  if (opt_.w_shafts) {
    // Within the solve's one fork: per link each column's chain part and its shafts' product
    // (after the backward sweep), the two shaft steps, then each column's z - Y x_s.
    LinkVectors* w[2] = {&w_rhs_, &wf_rhs2_};
    ShaftVectors* bz[2] = {&w_bz_, &wf_bz2_};
    ShaftVector xs[2];
    w_lu_.solve_columns(
        v, TwoTasks{schedule_.threads() > 1},
        [&](int l) {
          for (int a = 0; a < 2; ++a) (*w[a])[l] = v[l].col(a), w_shaft_product(l, *w[a], *bz[a]);
        },
        [&] {
          for (int a = 0; a < 2; ++a) {
            ShaftVector rs = ShaftVector::Zero();
            if (c.shaft >= 0)
              for (int s = 0; s < kShaftSize; ++s)
                rs[c.shaft * kShaftSize + s] = c.sheave_columns(fjac_)[a * kShaftSize + s];
            xs[a] = w_shaft_unknowns(rs, *bz[a]);
            wf_zs_.col(col + a) = xs[a];
          }
        },
        [&](int l) {
          for (int a = 0; a < 2; ++a) {
            w_shaft_back(l, xs[a], (*w[a])[l]);
            z_of(a, l) = (*w[a])[l];
          }
        });
  } else {
    w_lu_.solve_columns(v, TwoTasks{schedule_.threads() > 1});
    for (int a = 0; a < 2; ++a)
      for (int l = 0; l < m_.links; ++l) z_of(a, l) = v[l].col(a);
  }
  wf_set_.push_back(c);
  c.kind->in_correction[c.idx] = 1;
  ++wf_joined_;
  const int k = col + 2;
  const auto zs = [this](int i) { return opt_.w_shafts ? wf_zs_.col(i).data() : nullptr; };
  for (int i = 0; i < k; ++i)
    for (int a = 0; a < 2; ++a) {
      wf_g_(col + a, i) = wf_dot(c, a, wf_z_.col(i).data(), zs(i));
      if (i < col) wf_g_(i, col + a) = wf_dot(wf_set_[i / 2], i % 2, wf_z_.col(col + a).data(), zs(col + a));
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
  // The shafts' velocities, physical: w_shafts, their part of y0; else the right side's b_s.
  const ShaftVector xs = shaft_velocities(x);
  for (int i = 0; i < k; ++i) {
    const FreshContact& c = wf_set_[i / 2];
    double w = 0;
    if (opt_.w_shafts) {
      p[i] = 0;
      t[i] = wf_dot(c, i % 2, y0, xs.data());
      continue;
    }
    if (c.shaft >= 0) {
      const double* v = fjac_.pulley_shaft_cols.data() + (static_cast<std::size_t>(c.idx) * 2 + i % 2) * kShaftSize;
      for (int s = 0; s < kShaftSize; ++s) w += v[s] * xs[c.shaft * kShaftSize + s];
    }
    p[i] = wf_d_[i] * w;
    t[i] = wf_dot(c, i % 2, y0);
  }
  if (!opt_.w_shafts) t.noalias() -= wf_g_.topLeftCorner(k, k) * p;
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
  if (opt_.w_shafts) {
    const ShaftVector ds = wf_zs_.leftCols(k) * s;
    for (int k2 = 0; k2 < 2; ++k2)
      for (int i = 0; i < kShaftSize; ++i) {
        const int r = n + m_.shaft(k2) + i;
        x[r] -= opt_.scaled ? ds[k2 * kShaftSize + i] / unit_[r] : ds[k2 * kShaftSize + i];
      }
  }
}

}  // namespace cvt
