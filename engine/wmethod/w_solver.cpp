#include "engine/wmethod/w_solver.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>

#include "engine/wmethod/parallel.hpp"
#include "modules/inertia.hpp"

namespace cvt {

Eigen::MatrixXd a0_shaft_inverse(const Model& m) {
  Eigen::MatrixXd inv(2 * kShaftSize + 1, 2 * kShaftSize);
  Eigen::VectorXd F = Eigen::VectorXd::Zero(m.ndof), Y = Eigen::VectorXd::Zero(m.ndof);
  const int tail0 = m.shaft(0);
  for (int k = 0; k < 2 * kShaftSize; ++k) {
    F.setZero();
    F[tail0 + k] = 1.0;
    a0_inverse_shafts(m, F.data(), Y.data());
    for (int r = 0; r < 2 * kShaftSize + 1; ++r) inv(r, k) = Y[tail0 + r];
  }
  return inv;
}

WSolver::WSolver(const Model& m, Workspace& ws, Schedule& schedule, const ModelOdeOptions& opt,
                 const Eigen::VectorXd& unit, const Eigen::VectorXd& offset)
    : m_(m), ws_(ws), schedule_(schedule), opt_(opt), unit_(unit), offset_(offset), fjac_(m),
      stiffness_(m, ws, schedule, opt_.w_analytic_stiffness), fresh_(m, opt_, *this, fjac_, fresh_on()) {
  const int N = m.links;
  fjac_.secant = opt.w_secant;
  // A0 of a link's coordinates: two halves (bending per plane, axial bar), the pack's axial mass.
  a0_link_.setZero();
  for (int h = 0; h < 2; ++h) set_half_mass(m, a0_link_, h * half::kSize);
  a0_link_(2 * half::kSize, 2 * half::kSize) = m.pack_mass;
  lu_.resize(N, opt.w_segments, opt.w_fill_drop);
  // The chain's coordinates in link order, and their units (1 unless scaled).
  coord_.resize(static_cast<size_t>(N) * kLinkDim);
  unit_q_.assign(coord_.size(), 1.0), unit_v_.assign(coord_.size(), 1.0);
  for (int l = 0; l < N; ++l)
    for (int i = 0; i < kLinkDim; ++i) {
      const int o = l * kLinkDim + i, c = link_coordinate(m, l, i);
      coord_[o] = c;
      if (opt.scaled) unit_q_[o] = unit[c], unit_v_[o] = unit[m.ndof + c];
    }
  unit_ratio_.assign(m.ndof, 1.0);
  if (opt.scaled)
    for (int i = 0; i < m.ndof; ++i) unit_ratio_[i] = unit[m.ndof + i] / unit[i];
  std::vector<char> in_chain(m.ndof, 0);
  for (int c : coord_) in_chain[c] = 1;
  for (int c = 0; c < m.ndof; ++c)
    if (!in_chain[c]) other_coord_.push_back(c);
  rhs_.resize(N), bz_.resize(N), g_.resize(N), cps_.resize(N), cps_on_.assign(N, 0);
  if (opt.w_shafts) {
    // M_s: the inverse of A0^-1 on the shafts (their 14 x 14 block; the load is outside W).
    ms_ = a0_shaft_inverse(m).topRows(2 * kShaftSize).inverse();
    y_shaft_.resize(N);
  }
  if (opt.scaled) y_.resize(m.nstate);
}

void WSolver::factor(double t, const double* y, double gh) {
  // The matrix is rebuilt at the steps whose index is a multiple of w_every (so a run
  // resumed at such a step repeats the bits), and whenever gh changed or none exists yet
  // (a fixed step taken as t1 - t0 varies in its last bits: that is no change of gh); in
  // between, the stale one is kept. The friction blocks come from the evaluation that starts
  // a rebuilding step (ask(), recording()); within an integrate() call of several steps only
  // the first is armed, later rebuilds use the blocks last recorded. The stiffness blocks are
  // dearer (finite differences): they are taken at the rebuilding steps whose index is a
  // multiple of w_k_every.
  const long index = index_;
  const bool first = gh_ == 0 || invalid_ || retake_;
  // A new gh refactorizes outside the band of ModelOdeOptions::w_h_grow / w_h_shrink (with
  // the defaults, at any change beyond rounding).
  const bool gh_out = gh > gh_ * opt_.w_h_grow * (1 + 1e-9) || gh * opt_.w_h_shrink * (1 + 1e-9) < gh_;
  const bool rebuild = due() || gh_out;
  ++index_;
  Profiler* prof = schedule_.profiler();
  // Times f as section s of the profile (wall time on the master).
  const auto timed = [prof](Section s, auto&& f) {
    const std::uint64_t t0 = prof ? Profiler::ticks() : 0;
    f();
    if (prof) prof->add_master(s, Profiler::ticks() - t0), prof->call(s);
  };
  if (!rebuild) {
    if (fresh_on() && fresh_recorded_) timed(Section::w_assembly, [&] { fresh_.update(gh_); });
    return;
  }
  if (fresh_.take_force() && !(opt_.w_every <= 1 || index % opt_.w_every == 0)) ++fresh_rebuilds_;
  if (opt_.w_stiffness && (first || opt_.w_k_every <= 1 || index % opt_.w_k_every == 0))
    timed(Section::w_stiffness, [&] {
      if (opt_.scaled) {
        y_ = offset_ + Eigen::Map<const Eigen::VectorXd>(y, m_.nstate).cwiseProduct(unit_);
        y = y_.data();
      }
      stiffness_.take(t, y);
    });
  if (invalid_) ++status_rebuilds_;
  invalid_ = retake_ = false;
  gh_ = gh;
  timed(Section::w_assembly, [&] { for_joints(schedule_, m_.links, [this, gh](int l) { assemble_link(l, gh); }); });
  bool ok = false;
  timed(Section::w_factor, [&] {
    ok = lu_.factor(threads());
    if (ok && opt_.w_shafts) shaft_factor(gh);
  });
  if (!ok) throw std::runtime_error(singular_matrix(t, index, gh));
  if (fresh_on()) {
    fresh_.clear();
    fjac_.mu_tol = opt_.w_fresh * m_.cfg.pin.mass / gh;
  }
}

// What a singular W names: the time, the step, the first link whose blocks hold a
// non-finite number and where it came from (the stiffness's differences, the friction
// blocks, the link inertia), and what to change.
std::string WSolver::singular_matrix(double t, long index, double gh) const {
  const auto finite = [](const auto& b) { return b.allFinite(); };
  std::string where = "no block holds a non-finite number: a pivot block is singular";
  for (int l = 0; l < m_.links; ++l) {
    const char* what = nullptr;
    if (opt_.w_stiffness && !(finite(stiffness_.diag(l)) && finite(stiffness_.sub(l)) && finite(stiffness_.super(l))))
      what = "the stiffness K (finite differences of the chain's forces)";
    else if (!finite(g_[l]))
      what = "the link inertia (the link's direction)";
    else if (!finite(cps_[l]))
      what = "the pulley friction's coupling to the shafts";
    if (what) {
      where = "link " + std::to_string(l) + " holds a non-finite number in " + what;
      break;
    }
  }
  char buf[160];
  std::snprintf(buf, sizeof buf, "the W-method's matrix is singular at t = %.9g s (step %ld, gamma h = %.3g s): ", t,
                index, gh);
  return buf + where +
         "; the state the matrix was taken at holds forces that are not finite or not smooth there, and every "
         "retake of the step (the matrix afresh, up to 64 pieces) met it too. RK4 (--method rk4 --step 1e-8) shows "
         "whether the model itself fails there; a smaller integrator.step steps past it";
}

void WSolver::link_gradient(int l, LinkVector& g) const {
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

void WSolver::assemble_link(int l, double gh) {
  // Link l's coordinates: b_l, a_{l+1}, pack s_l. Joint j's 40 x 40 friction blocks are over
  // links j-1 (rows 0..19) and j (20..39), lower triangle only: link l's diagonal block is
  // the lower-right of joint l's plus the upper-left of joint l+1's; M(l, l-1) is joint l's
  // lower-left, M(l-1, l) its transpose.
  constexpr int kD = FrictionJacobian::kDim, kH = 2 * half::kSize;
  const double* kr = fjac_.rocker_damping.data() + static_cast<std::size_t>(l) * kD * kD;
  const double* kp = fjac_.pulley_damping.data() + static_cast<std::size_t>(l) * kD * kD;
  const double* nr = fjac_.rocker_damping.data() + static_cast<std::size_t>(m_.wrap(l + 1)) * kD * kD;
  const double* np = fjac_.pulley_damping.data() + static_cast<std::size_t>(m_.wrap(l + 1)) * kD * kD;
  LinkBlock& D = lu_.diag(l);
  LinkBlock& S = lu_.sub(l);
  LinkBlock& P = lu_.super(l);
  // Row r of the joint blocks (row-major, lower triangle) into column r of F and P, so that
  // reads and writes run along memory; then mirrored.
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
  LinkVector& g = g_[l];
  link_gradient(l, g);
  D.noalias() += m_.cfg.chain.link_inertia * g * g.transpose();
  // The pins' rows of K_ps for this link: rows 20..39 of joint l's blocks, 0..19 of joint l+1's.
  constexpr int kX = 2 * kD * kShaftSize;
  const double* here = fjac_.pulley_shaft_damping.data() + static_cast<std::size_t>(l) * kX;
  const double* next = fjac_.pulley_shaft_damping.data() + static_cast<std::size_t>(m_.wrap(l + 1)) * kX;
  auto& X = cps_[l];
  for (int k = 0; k < 2; ++k)
    for (int i = 0; i < kH; ++i)
      for (int c = 0; c < kShaftSize; ++c)
        X(i, k * kShaftSize + c) = here[(k * kD + kH + i) * kShaftSize + c] + next[(k * kD + i) * kShaftSize + c];
  X.row(kH).setZero();  // the pack
  cps_on_[l] = X.cwiseAbs().maxCoeff() > 0;
  if (opt_.w_stiffness) {
    const double gh2 = gh * gh;
    D += gh2 * stiffness_.diag(l);
    S += gh2 * stiffness_.sub(l);
    P += gh2 * stiffness_.super(l);
  }
}

void WSolver::shaft_factor(double gh) {
  // The bordered matrix [Wc, B; B^T, Ds] over (chain velocities, shaft velocities), Wc the
  // factorized chain block, B = gh K_ps, Ds = M_s + gh C_ss: Y = Wc^-1 B by 14 solves and the
  // Schur complement S = Ds - B^T Y (the 14 columns solved together, as block products).
  // C_ss sums the joints' sheave blocks (block-diagonal).
  constexpr int kS = kShaftSize * kShaftSize;
  ShaftMatrix S = ms_;
  for (int j = 0; j < m_.links; ++j)
    for (int k = 0; k < 2; ++k) {
      const double* c = fjac_.pulley_shaft_self.data() + (static_cast<std::size_t>(j) * 2 + k) * kS;
      for (int r = 0; r < kShaftSize; ++r)
        for (int q = 0; q < kShaftSize; ++q) S(k * kShaftSize + r, k * kShaftSize + q) += gh * c[r * kShaftSize + q];
    }
  for (int l = 0; l < m_.links; ++l) {
    if (cps_on_[l])
      y_shaft_[l] = gh * cps_[l];
    else
      y_shaft_[l].setZero();
  }
  lu_.solve_columns(y_shaft_.data(), threads());
  for (int l = 0; l < m_.links; ++l)
    if (cps_on_[l]) S.noalias() -= (gh * cps_[l]).transpose() * y_shaft_[l];
  schur_.compute(S);
}

WSolver::ShaftVector WSolver::shaft_unknowns(const ShaftVector& rs, const ShaftVectors& bz) const {
  // With z = Wc^-1 r_v: x_s = S^-1 (r_s - B^T z); the chain's x_v is then z - Y x_s.
  const double gh = gh_;
  ShaftVector r = rs;
  for (int l = 0; l < m_.links; ++l)
    if (cps_on_[l]) r.noalias() -= gh * bz[l];
  return schur_.solve(r);
}

void WSolver::shaft_product(int l, const LinkVectors& z, ShaftVectors& bz) const {
  if (cps_on_[l]) bz[l].noalias() = cps_[l].transpose() * z[l];
}

WSolver::ShaftVector WSolver::shaft_solve(double* x) const {
  const int n = m_.ndof;
  const ShaftVector xs = shaft_unknowns(ms_ * shaft_velocities(x));
  for (int k = 0; k < 2; ++k)
    for (int i = 0; i < kShaftSize; ++i) {
      const int r = n + m_.shaft(k) + i;
      x[r] = opt_.scaled ? xs[k * kShaftSize + i] / unit_[r] : xs[k * kShaftSize + i];
    }
  return xs;
}

void WSolver::shaft_back(int l, const ShaftVector& xs, LinkVector& z) const {
  // Y_l's 14 columns summed in registers (Eigen's out-of-line product of a 21 x 14 block
  // with a vector took longer).
  ColumnSum<kLinkDim> sum;
  sum.add(y_shaft_[l].data(), xs.data(), 2 * kShaftSize);
  LinkVector t;
  sum.get(t);
  z -= t;
}

WSolver::ShaftVector WSolver::shaft_velocities(const double* x) const {
  ShaftVector v;
  for (int k = 0; k < 2; ++k)
    for (int i = 0; i < kShaftSize; ++i) {
      const int r = m_.ndof + m_.shaft(k) + i;
      v[k * kShaftSize + i] = opt_.scaled ? x[r] * unit_[r] : x[r];
    }
  return v;
}

void WSolver::solve(double* x) const {
  Profiler* prof = schedule_.profiler();
  const std::uint64_t t0 = prof ? Profiler::ticks() : 0;
  solve_untimed(x);
  if (prof) prof->add_master(Section::w_solve, Profiler::ticks() - t0), prof->call(Section::w_solve);
}

void WSolver::solve_untimed(double* x) const {
  // W = [I, -gh I; gh A^-1 K, I + gh A^-1 C] on the chain (identity on the other
  // velocities): (A + gh C + gh^2 K) x_v = A b_v - gh K b_q, then x_q = b_q + gh x_v.
  // (Scaled: the chain's entries through unit_q_ / unit_v_, tables in link order.)
  // The right side of each link and the write-back of its solution run inside the block
  // LU's two tasks (CyclicBlockLU::solve's prepare / finish): one fork and join per solve.
  const int n = m_.ndof;
  const double gh = gh_;
  const double* uq = unit_q_.data();
  const double* uv = unit_v_.data();
  const double* ratio = unit_ratio_.data();
  const ShaftVector bs = shaft_velocities(x);  // the shafts' b_s, physical (read once, not per link)
  LinkVector* v = rhs_.data();
  // Entry i of b_q in link l's coordinates.
  const auto position = [&](int l, int i) { return x[coord_[l * kLinkDim + i]] * uq[l * kLinkDim + i]; };
  const auto prepare = [&](int l) {
    const int o = l * kLinkDim;
    LinkVector b;
    for (int i = 0; i < kLinkDim; ++i) b[i] = x[n + coord_[o + i]] * uv[o + i];
    LinkVector& y = v[l];
    // A0 b: the links' common block, dense from L1 (73 nonzeros of 441, but a sparse loop
    // over them with its index loads took longer than the 21 vector columns).
    block_times(a0_link_, b, y);
    y += (m_.cfg.chain.link_inertia * g_[l].dot(b)) * g_[l];  // + J g g^T b
    if (opt_.w_stiffness) {
      const int lp = m_.wrap(l - 1), ln = m_.wrap(l + 1);
      LinkVector bq;
      for (int i = 0; i < kLinkDim; ++i) bq[i] = position(l, i);
      // K b_q over link l's row, summed in one set of registers: the dense diagonal block,
      // then the couplings by their nonzero columns (exact zeros skipped; the neighbours'
      // b_q read at those columns only).
      const ChainStiffness::PackedColumns& sub = stiffness_.packed(l)[0];
      const ChainStiffness::PackedColumns& sup = stiffness_.packed(ln)[1];
      double xs[kLinkDim], xn[kLinkDim];
      for (int c = 0; c < sub.n; ++c) xs[c] = position(lp, sub.index[c]);
      for (int c = 0; c < sup.n; ++c) xn[c] = position(ln, sup.index[c]);
      ColumnSum<kLinkDim> sum;
      sum.add(stiffness_.diag(l).data(), bq.data(), kLinkDim);
      sum.add(sub.cols.data(), xs, sub.n);
      sum.add(sup.cols.data(), xn, sup.n);
      LinkVector kb;
      sum.get(kb);
      y.noalias() -= gh * kb;
    }
    // - gh K_ps x_s: the sheaves' velocity increments (x_s = b_s) drag the pins in contact.
    if (cps_on_[l] && !opt_.w_shafts) y.noalias() -= gh * (cps_[l] * bs);
  };
  // x_v, then x_q = b_q + gh x_v (dq/dt = v exactly: W's position rows [I, -gh I]; scaled:
  // times the ratio of the units, unit_ratio_).
  const auto finish = [&](int l) {
    const int o = l * kLinkDim;
    for (int i = 0; i < kLinkDim; ++i) {
      const int c = coord_[o + i];
      x[n + c] = v[l][i] / uv[o + i];
      x[c] += gh * x[n + c] * ratio[c];
    }
  };
  if (opt_.w_shafts) {
    // The chain's solve z, the shafts' x_s from it, then x_v = z - Y x_s per link: one fork
    // and join for the three (CyclicBlockLU::solve's serial and last phases).
    ShaftVector xs;
    lu_.solve(
        v, threads(), prepare, [&](int l) { shaft_product(l); }, [&] { xs = shaft_solve(x); },
        [&](int l) {
          shaft_back(l, xs, v[l]);
          finish(l);
        });
  } else {
    lu_.solve(v, threads(), prepare, finish);
  }
  fresh_.correct(x);
  for (int c : other_coord_) x[c] += gh * x[n + c] * ratio[c];  // the shafts' and load's
}

}  // namespace cvt
