#include "engine/wmethod/fresh_friction.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "engine/wmethod/parallel.hpp"
#include "engine/wmethod/w_solver.hpp"

namespace cvt {

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

FreshFriction::FreshFriction(const Model& m, const ModelOdeOptions& opt, WSolver& w, FrictionJacobian& fjac, bool on)
    : m_(m), opt_(opt), w_(w), fjac_(fjac) {
  const int N = m.links;
  pair_.resize(N), rhs2_.resize(N), bz2_.resize(N);
  if (!on) return;
  if (opt.w_fresh_max < 1) throw std::invalid_argument("ModelOdeOptions: w_fresh_max must be >= 1");
  const int k = 2 * opt.w_fresh_max;
  z_.setZero(static_cast<Eigen::Index>(N) * kLinkDim, k);
  if (opt.w_shafts) zs_.setZero(2 * kShaftSize, k);
  g_.setZero(k, k);
  for (Eigen::VectorXd* v : {&d_, &p_, &t_, &s_, &b_}) v->setZero(k);
  for (int i = 1; i <= opt.w_fresh_max; ++i) {
    cap_m_.emplace_back(Eigen::MatrixXd::Zero(2 * i, 2 * i));
    cap_.emplace_back(2 * i);
  }
  set_.reserve(opt.w_fresh_max);
  cand_.reserve(fjac.rocker_fresh.mu.size() + fjac.pulley_fresh.mu.size());
  corr_.setZero(static_cast<Eigen::Index>(N) * kLinkDim);
}

void FreshFriction::clear() {
  for (const Contact& c : set_) c.kind->in_correction[c.idx] = 0;
  set_.clear();
}

const double* FreshFriction::Contact::columns() const {
  return kind->cols.data() + static_cast<std::size_t>(idx) * 2 * FrictionJacobian::kDim;
}

const double* FreshFriction::Contact::sheave_columns(const FrictionJacobian& f) const {
  return shaft < 0 ? nullptr : f.pulley_shaft_cols.data() + static_cast<std::size_t>(idx) * 2 * kShaftSize;
}

double FreshFriction::dot(const Contact& c, int col, const double* z, const double* zs) const {
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

void FreshFriction::join(const Contact& c) {
  // Z's two new columns, W^-1 [U; V]: the chain's block solve of both at once (the same bits
  // as one solve per column), then (w_shafts) each column's shafts' step and z - Y x_s.
  constexpr int kH = 2 * half::kSize, kD = FrictionJacobian::kDim;
  const int col = 2 * static_cast<int>(set_.size());
  const int lp = m_.wrap(c.joint - 1), lc = c.joint;
  LinkPair* v = pair_.data();
  for (int l = 0; l < m_.links; ++l) v[l].setZero();
  for (int a = 0; a < 2; ++a) {
    const double* u = c.columns() + a * kD;
    for (int r = 0; r < kH; ++r) v[lp](r, a) += u[r];
    for (int r = 0; r < kH; ++r) v[lc](r, a) += u[kH + r];
  }
  double* z[2] = {z_.col(col).data(), z_.col(col + 1).data()};
  const auto z_of = [&](int a, int l) { return Eigen::Map<LinkVector>(z[a] + static_cast<std::size_t>(l) * kLinkDim); };
  if (opt_.w_shafts) {
    // Within the solve's one fork: per link each column's chain part and its shafts' product
    // (after the backward sweep), the two shaft steps, then each column's z - Y x_s.
    LinkVectors* w[2] = {&w_.rhs_, &rhs2_};
    ShaftVectors* bz[2] = {&w_.bz_, &bz2_};
    ShaftVector xs[2];
    w_.lu_.solve_columns(
        v, w_.threads(),
        [&](int l) {
          for (int a = 0; a < 2; ++a) (*w[a])[l] = v[l].col(a), w_.shaft_product(l, *w[a], *bz[a]);
        },
        [&] {
          for (int a = 0; a < 2; ++a) {
            ShaftVector rs = ShaftVector::Zero();
            if (c.shaft >= 0)
              for (int s = 0; s < kShaftSize; ++s) rs[c.shaft * kShaftSize + s] = c.sheave_columns(fjac_)[a * kShaftSize + s];
            xs[a] = w_.shaft_unknowns(rs, *bz[a]);
            zs_.col(col + a) = xs[a];
          }
        },
        [&](int l) {
          for (int a = 0; a < 2; ++a) {
            w_.shaft_back(l, xs[a], (*w[a])[l]);
            z_of(a, l) = (*w[a])[l];
          }
        });
  } else {
    w_.lu_.solve_columns(v, w_.threads());
    for (int a = 0; a < 2; ++a)
      for (int l = 0; l < m_.links; ++l) z_of(a, l) = v[l].col(a);
  }
  set_.push_back(c);
  c.kind->in_correction[c.idx] = 1;
  ++joined_;
  const int k = col + 2;
  const auto zs = [this](int i) { return opt_.w_shafts ? zs_.col(i).data() : nullptr; };
  for (int i = 0; i < k; ++i)
    for (int a = 0; a < 2; ++a) {
      g_(col + a, i) = dot(c, a, z_.col(i).data(), zs(i));
      if (i < col) g_(i, col + a) = dot(set_[i / 2], i % 2, z_.col(col + a).data(), zs(col + a));
    }
}

void FreshFriction::update(double gh) {
  const double tol = fjac_.mu_tol;
  // The contacts not yet in whose mu moved by more than tol, the largest change first (ties
  // by index): a deterministic order, the same on any number of threads.
  // Rocker stations first, then pin ends (rank: the rocker count plus the pin end's index).
  cand_.clear();
  FrictionJacobian::FreshMu* kinds[2] = {&fjac_.rocker_fresh, &fjac_.pulley_fresh};
  for (int kind = 0, rank0 = 0; kind < 2; rank0 += static_cast<int>(kinds[kind]->mu.size()), ++kind) {
    const FrictionJacobian::FreshMu& f = *kinds[kind];
    for (int i = 0; i < static_cast<int>(f.mu.size()); ++i) {
      const double d = std::abs(f.mu[i] - f.mu_w[i]);
      if (d > tol && !f.in_correction[i] && f.cols_set[i]) cand_.push_back({d, rank0 + i, kind, i});
    }
  }
  std::sort(cand_.begin(), cand_.end(), [](const Candidate& a, const Candidate& b) {
    return a.dmu > b.dmu || (a.dmu == b.dmu && a.rank < b.rank);
  });
  for (const Candidate& x : cand_) {
    if (static_cast<int>(set_.size()) >= opt_.w_fresh_max) {
      force_ = true;  // the next step rebuilds the friction blocks
      break;
    }
    Contact c{kinds[x.kind], x.idx, 0, -1};
    if (x.kind == 0)
      c.joint = x.idx / m_.cfg.rocker.stations;
    else
      c.joint = x.idx / ContactStatus::kPulleyPerJoint, c.shaft = x.idx % 2;  // ContactStatus::pulley_index
    join(c);
  }
  const int k = 2 * static_cast<int>(set_.size());
  if (k == 0) return;
  for (int i = 0; i < k; i += 2) {
    const Contact& c = set_[i / 2];
    d_[i] = d_[i + 1] = gh * (c.kind->mu[c.idx] - c.kind->mu_w[c.idx]);
  }
  Eigen::MatrixXd& cap = cap_m_[k / 2 - 1];
  cap.noalias() = d_.head(k).asDiagonal() * g_.topLeftCorner(k, k);
  cap.diagonal().array() += 1.0;
  cap_[k / 2 - 1].compute(cap);
}

void FreshFriction::correct(double* x) const {
  const int k = 2 * static_cast<int>(set_.size());
  if (k == 0) return;
  static_assert(sizeof(LinkVector) == kLinkDim * sizeof(double), "link vectors must be contiguous");
  const int n = m_.ndof;
  const double gh = w_.gh_;
  const double* y0 = w_.rhs_[0].data();  // W^-1 r, physical, link order
  auto p = p_.head(k);
  auto t = t_.head(k);
  // The shafts' velocities, physical: w_shafts, their part of y0; else the right side's b_s.
  const ShaftVector xs = w_.shaft_velocities(x);
  for (int i = 0; i < k; ++i) {
    const Contact& c = set_[i / 2];
    double w = 0;
    if (opt_.w_shafts) {
      p[i] = 0;
      t[i] = dot(c, i % 2, y0, xs.data());
      continue;
    }
    if (c.shaft >= 0) {
      const double* v = fjac_.pulley_shaft_cols.data() + (static_cast<std::size_t>(c.idx) * 2 + i % 2) * kShaftSize;
      for (int s = 0; s < kShaftSize; ++s) w += v[s] * xs[c.shaft * kShaftSize + s];
    }
    p[i] = d_[i] * w;
    t[i] = dot(c, i % 2, y0);
  }
  if (!opt_.w_shafts) t.noalias() -= g_.topLeftCorner(k, k) * p;
  // s = p + (I + D G)^-1 D t, formed in preallocated vectors (the sum in either order is
  // the same number).
  auto b = b_.head(k);
  auto s = s_.head(k);
  b = d_.head(k).cwiseProduct(t);
  s = cap_[k / 2 - 1].solve(b);
  s += p;
  Eigen::VectorXd& corr = corr_;
  corr.noalias() = z_.leftCols(k) * s;
  const double* uv = w_.unit_v_.data();
  const double* ratio = w_.unit_ratio_.data();
  for (int j = 0; j < m_.links * kLinkDim; ++j) {
    const int c = w_.coord_[j];
    const double dv = corr[j] / uv[j];
    x[n + c] -= dv;
    x[c] -= gh * dv * ratio[c];
  }
  if (opt_.w_shafts) {
    const ShaftVector ds = zs_.leftCols(k) * s;
    for (int k2 = 0; k2 < 2; ++k2)
      for (int i = 0; i < kShaftSize; ++i) {
        const int r = n + m_.shaft(k2) + i;
        x[r] -= opt_.scaled ? ds[k2 * kShaftSize + i] / w_.unit_[r] : ds[k2 * kShaftSize + i];
      }
  }
}

}  // namespace cvt
