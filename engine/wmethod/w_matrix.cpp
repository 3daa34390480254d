// The W-method's iteration matrix on the model (docs/integrators.md 12): when to rebuild
// it, the chain's stiffness by finite differences over link colours, the link blocks'
// assembly, the block-cyclic factorization and the solves.
#include "engine/wmethod/model_ode.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "engine/rhs/rhs.hpp"
#include "engine/wmethod/parallel.hpp"
#include "modules/chain_forces.hpp"
#include "modules/inertia.hpp"
#include "modules/pulley_contact.hpp"

namespace cvt {

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
  // A new gh refactorizes outside the band of ModelOdeOptions::w_h_grow / w_h_shrink (with
  // the defaults, at any change beyond rounding: a fixed step taken as t1 - t0 varies in its
  // last bits).
  const bool gh_out = gh > w_gh_ * opt_.w_h_grow * (1 + 1e-9) || gh * opt_.w_h_shrink * (1 + 1e-9) < w_gh_;
  const bool rebuild = w_due() || gh_out;
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
  timed(Section::w_factor, [&] {
    ok = w_lu_.factor(TwoTasks{schedule_.threads() > 1});
    if (ok && opt_.w_shafts) w_shaft_factor(gh);
  });
  if (!ok) throw std::runtime_error("W-method: the W matrix is singular");
  if (w_fresh_on()) {
    wf_clear();
    fjac_.mu_tol = opt_.w_fresh * m_.cfg.pin.mass / gh;
  }
}


void ModelOde::w_stiffness(double t, const double* y) {
  // K = -dF/dq on the chain by finite differences of the generalized forces (ws.force), in
  // link order: a link's coordinates reach the forces of itself and its two neighbours
  // only, so the links of one colour (3 or more apart) are perturbed together, one link
  // coordinate at a time: 21 evaluations per colour. On more than one thread the
  // evaluations are split in two halves, each run serially on a workspace of its own (no
  // synchronization per evaluation); the second half runs on ws_, so that ws_ ends as the
  // serial loop leaves it (the assembly reads its link directions), and every column is
  // the same number whichever thread takes it.
  const auto t0 = std::chrono::steady_clock::now();
  Eigen::VectorXd& yp = yp_;
  if (opt_.scaled)
    to_y(Eigen::Map<const Eigen::VectorXd>(y, m_.nstate), yp);
  else
    yp = Eigen::Map<const Eigen::VectorXd>(y, m_.nstate);
  ys_ = yp;  // the unperturbed physical state
  chain_forces_at(t, ys_.data());
  w_force0_.assign(ws_.force.begin(), ws_.force.begin() + m_.ndof);
  w_chain0_ = ws_.chain_slots, w_pulley0_ = ws_.pulley_slots;  // the joints a colour leaves alone
  const int items = w_colors_ * kLinkDim;
  if (schedule_.threads() > 1) {  // w_ws2_ exists (the constructor makes it for more than one thread)
    *w_ws2_ = ws_;
    w_yp2_ = yp;
    const int half = items / 2;
    const auto first = [&] { w_stiffness_items(*w_ws2_, w_yp2_, w_delta2_, t, 0, half); };
    const auto second = [&] { w_stiffness_items(ws_, yp, w_delta_, t, half, items); };
    TwoTaskPhases ph;
    TwoTasks{true}([&] { ph.two(0, 0, first, second); }, [&] { ph.two(0, 1, first, second); });
  } else {
    w_stiffness_items(ws_, yp, w_delta_, t, 0, items);
  }
  rhs_evals_ += items;  // each counted as an evaluation (about 3/4 of one)
  for_joints([this](int l) {
    pack_columns(w_k_sub_[l], w_k_packed_[l][0]);
    pack_columns(w_k_super_[l], w_k_packed_[l][1]);
  });
  ++jac_evals_;
  w_k_seconds_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

void ModelOde::w_stiffness_items(Workspace& w, Eigen::VectorXd& yp, std::vector<double>& delta, double t, int k0,
                                 int k1) {
  const int N = m_.links;
  const double eps = std::numeric_limits<double>::epsilon();
  const std::vector<double>& F0 = w_force0_;
  for (int k = k0; k < k1; ++k) {
    const int color = k / kLinkDim, i = k % kLinkDim;
    for (int l = 0; l < N; ++l) {
      if (w_color_[l] != color) continue;
      const int c = coord(l, i);
      delta[l] = std::sqrt(eps * std::max(1e-5, std::abs(ys_[c])));
      yp[c] = ys_[c] + delta[l];
    }
    chain_forces_on(w, t, yp.data(), color, false);
    const double* F1 = w.force.data();
    for (int l = 0; l < N; ++l) {
      if (w_color_[l] != color) continue;
      const double inv = 1.0 / delta[l];
      // Column i of link l: rows of links l-1 (sub of l, as M(l-1, l): super(l)), l, l+1.
      for (int r = 0; r < kLinkDim; ++r) {
        const int rp = coord(m_.wrap(l - 1), r), ro = coord(l, r), rn = coord(m_.wrap(l + 1), r);
        w_k_super_[l](r, i) = -(F1[rp] - F0[rp]) * inv;
        w_k_diag_[l](r, i) = -(F1[ro] - F0[ro]) * inv;
        w_k_sub_[m_.wrap(l + 1)](r, i) = -(F1[rn] - F0[rn]) * inv;
      }
    }
    for (int l = 0; l < N; ++l)
      if (w_color_[l] == color) yp[coord(l, i)] = ys_[coord(l, i)];
  }
}

void ModelOde::chain_forces_at(double t, const double* y, int color) {
  chain_forces_on(ws_, t, y, color, schedule_.threads() > 1);
  ++rhs_evals_;  // counted as an evaluation (about 3/4 of one)
}

void ModelOde::chain_forces_on(Workspace& w, double t, const double* y, int color, bool threads) {
  // The passes of an evaluation that the chain's generalized forces need: the link angles,
  // the chain and pulley kernels, the gather. The inertia's velocity terms keep the values of
  // the last full evaluation (a constant, which the differences cancel). With a colour: a
  // joint touches only links j-1 and j (docs/model.md 4: its halves a_j, b_j, the plates of
  // link j, the directions of links j-1 and j), so a joint next to no perturbed link keeps
  // the slots of the unperturbed state (w_chain0_, w_pulley0_), which its kernels would
  // reproduce bit for bit; only the others are computed (2 of 3 joints with 3 colours).
  const auto ranges = [this, threads](const auto& f) {
    if (threads)
      for_ranges(f);
    else
      f(0, m_.links);
  };
  set_stage_input(m_, w, t, y);
  ranges([this, &w](int b, int e) { link_kinematics(m_, w, b, e); });
  if (color < 0) {
    ranges([this, &w](int b, int e) {
      chain_forces(m_, w, b, e);
      pulley_contact(m_, w, b, e);
    });
  } else {
    // Joint j is next to a perturbed link when link j-1 or link j has the colour.
    const auto touched = [this, color](int j) { return w_color_[m_.wrap(j - 1)] == color || w_color_[j] == color; };
    ranges([this, &w, &touched](int b, int e) {
      for (int j = b; j < e;) {
        if (!touched(j)) {
          w.chain_slots[j] = w_chain0_[j], w.pulley_slots[j] = w_pulley0_[j];
          ++j;
          continue;
        }
        int k = j + 1;
        while (k < e && touched(k)) ++k;
        chain_forces(m_, w, j, k);
        pulley_contact(m_, w, j, k);
        j = k;
      }
    });
  }
  ranges([this, &w](int b, int e) { gather_joints(m_, w, b, e); });
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

void ModelOde::w_shaft_factor(double gh) {
  // The bordered matrix [Wc, B; B^T, Ds] over (chain velocities, shaft velocities), Wc the
  // factorized chain block, B = gh K_ps, Ds = M_s + gh C_ss: Y = Wc^-1 B by 14 solves and the
  // Schur complement S = Ds - B^T Y (the 14 columns solved together, as block products).
  // C_ss sums the joints' sheave blocks (block-diagonal).
  constexpr int kS = kShaftSize * kShaftSize;
  ShaftMatrix S = w_ms_;
  for (int j = 0; j < m_.links; ++j)
    for (int k = 0; k < 2; ++k) {
      const double* c = fjac_.pulley_shaft_self.data() + (static_cast<std::size_t>(j) * 2 + k) * kS;
      for (int r = 0; r < kShaftSize; ++r)
        for (int q = 0; q < kShaftSize; ++q) S(k * kShaftSize + r, k * kShaftSize + q) += gh * c[r * kShaftSize + q];
    }
  for (int l = 0; l < m_.links; ++l) {
    if (w_cps_on_[l])
      w_y_[l] = gh * w_cps_[l];
    else
      w_y_[l].setZero();
  }
  w_lu_.solve_columns(w_y_.data(), TwoTasks{schedule_.threads() > 1});
  for (int l = 0; l < m_.links; ++l)
    if (w_cps_on_[l]) S.noalias() -= (gh * w_cps_[l]).transpose() * w_y_[l];
  w_schur_.compute(S);
}

ModelOde::ShaftVector ModelOde::w_shaft_unknowns(const ShaftVector& rs, const ShaftVectors& bz) const {
  // With z = Wc^-1 r_v: x_s = S^-1 (r_s - B^T z); the chain's x_v is then z - Y x_s.
  const double gh = w_gh_;
  ShaftVector r = rs;
  for (int l = 0; l < m_.links; ++l)
    if (w_cps_on_[l]) r.noalias() -= gh * bz[l];
  return w_schur_.solve(r);
}

void ModelOde::w_shaft_product(int l, const LinkVectors& z, ShaftVectors& bz) const {
  if (w_cps_on_[l]) bz[l].noalias() = w_cps_[l].transpose() * z[l];
}

ModelOde::ShaftVector ModelOde::w_shaft_solve(double* x) const {
  // The bordered solve's shaft step on x's shafts (right side M_s b_s), their x_s into x.
  const int n = m_.ndof;
  const ShaftVector xs = w_shaft_unknowns(w_ms_ * shaft_velocities(x));
  for (int k = 0; k < 2; ++k)
    for (int i = 0; i < kShaftSize; ++i) {
      const int r = n + m_.shaft(k) + i;
      x[r] = opt_.scaled ? xs[k * kShaftSize + i] / unit_[r] : xs[k * kShaftSize + i];
    }
  return xs;
}

void ModelOde::w_shaft_back(int l, const ShaftVector& xs, LinkVector& z) const {
  // z -= Y_l x_s, Y_l's 14 columns summed in registers (Eigen's out-of-line product of a
  // 21 x 14 block with a vector took longer).
  ColumnSum<kLinkDim> sum;
  sum.add(w_y_[l].data(), xs.data(), 2 * kShaftSize);
  LinkVector t;
  sum.get(t);
  z -= t;
}

ModelOde::ShaftVector ModelOde::shaft_velocities(const double* x) const {
  ShaftVector v;
  for (int k = 0; k < 2; ++k)
    for (int i = 0; i < kShaftSize; ++i) {
      const int r = m_.ndof + m_.shaft(k) + i;
      v[k * kShaftSize + i] = opt_.scaled ? x[r] * unit_[r] : x[r];
    }
  return v;
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
  // LU's two tasks (CyclicBlockLU::solve's prepare / finish): one fork and join per solve.
  const int n = m_.ndof;
  const double gh = w_gh_;
  const double* uq = w_unit_q_.data();
  const double* uv = w_unit_v_.data();
  const double* ratio = w_unit_ratio_.data();
  const ShaftVector bs = shaft_velocities(x);  // the shafts' b_s, physical (read once, not per link)
  LinkVector* v = w_rhs_.data();
  // Entry i of b_q in link l's coordinates.
  const auto position = [&](int l, int i) { return x[w_coord_[l * kLinkDim + i]] * uq[l * kLinkDim + i]; };
  const auto prepare = [&](int l) {
    const int o = l * kLinkDim;
    LinkVector b;
    for (int i = 0; i < kLinkDim; ++i) b[i] = x[n + w_coord_[o + i]] * uv[o + i];
    LinkVector& y = v[l];
    // A0 b: the links' common block, dense from L1 (73 nonzeros of 441, but a sparse loop
    // over them with its index loads took longer than the 21 vector columns).
    block_times(a0_link_, b, y);
    y += (m_.cfg.chain.link_inertia * w_g_[l].dot(b)) * w_g_[l];  // + J g g^T b
    if (opt_.w_stiffness) {
      const int lp = m_.wrap(l - 1), ln = m_.wrap(l + 1);
      LinkVector bq;
      for (int i = 0; i < kLinkDim; ++i) bq[i] = position(l, i);
      // K b_q over link l's row, summed in one set of registers: the dense diagonal block,
      // then the couplings by their nonzero columns (exact zeros skipped; the neighbours'
      // b_q read at those columns only).
      const PackedColumns& sub = w_k_packed_[l][0];
      const PackedColumns& sup = w_k_packed_[ln][1];
      double xs[kLinkDim], xn[kLinkDim];
      for (int c = 0; c < sub.n; ++c) xs[c] = position(lp, sub.index[c]);
      for (int c = 0; c < sup.n; ++c) xn[c] = position(ln, sup.index[c]);
      ColumnSum<kLinkDim> sum;
      sum.add(w_k_diag_[l].data(), bq.data(), kLinkDim);
      sum.add(sub.cols.data(), xs, sub.n);
      sum.add(sup.cols.data(), xn, sup.n);
      LinkVector kb;
      sum.get(kb);
      y.noalias() -= gh * kb;
    }
    // - gh K_ps x_s: the sheaves' velocity increments (x_s = b_s) drag the pins in contact.
    if (w_cps_on_[l] && !opt_.w_shafts) y.noalias() -= gh * (w_cps_[l] * bs);
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
  if (opt_.w_shafts) {
    // The chain's solve z, the shafts' x_s from it, then x_v = z - Y x_s per link: one fork
    // and join for the three (CyclicBlockLU::solve's serial and last phases).
    ShaftVector xs;
    w_lu_.solve(
        v, TwoTasks{schedule_.threads() > 1}, prepare, [&](int l) { w_shaft_product(l); },
        [&] { xs = w_shaft_solve(x); },
        [&](int l) {
          w_shaft_back(l, xs, v[l]);
          finish(l);
        });
  } else {
    w_lu_.solve(v, TwoTasks{schedule_.threads() > 1}, prepare, finish);
  }
  wf_correct(x);
  for (int c : w_other_coord_) x[c] += gh * x[n + c] * ratio[c];  // the shafts' and load's
}

}  // namespace cvt
