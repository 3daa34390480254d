#include "engine/wmethod/chain_stiffness.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

#include "engine/rhs/rhs.hpp"
#include "engine/rhs/stages.hpp"
#include "engine/wmethod/parallel.hpp"
#include "modules/chain_forces.hpp"
#include "modules/inertia.hpp"
#include "modules/pulley_contact.hpp"

namespace cvt {

ChainStiffness::ChainStiffness(const Model& m, Workspace& ws, Schedule& schedule, bool analytic)
    : m_(m), ws_(ws), schedule_(schedule), analytic_(analytic) {
  const int N = m.links;
  coord_.resize(static_cast<size_t>(N) * kLinkDim);
  for (int l = 0; l < N; ++l)
    for (int i = 0; i < kLinkDim; ++i) coord_[l * kLinkDim + i] = link_coordinate(m, l, i);
  // Link colours: greedy around the cycle, links within two of each other differ (3 colours
  // when 3 divides N, at most 5).
  color_.assign(N, -1);
  for (int l = 0; l < N; ++l) {
    int c = 0;
    for (bool clash = true; clash; ++c) {
      clash = false;
      for (int d = -2; d <= 2; ++d)
        if (d != 0 && color_[m.wrap(l + d)] == c) clash = true;
      if (!clash) break;
    }
    color_[l] = c;
    colors_ = std::max(colors_, c + 1);
  }
  ys_.resize(m.nstate), yp_.resize(m.nstate);
  diag_.assign(N, LinkBlock::Zero()), sub_ = diag_, super_ = diag_;
  packed_.resize(N);
  delta_.assign(N, 0.0);
  if (analytic_) joints_.resize(N);
  if (schedule_.threads() > 1 && !analytic_) {  // the second workspace, sized before any step
    ws2_ = std::make_unique<Workspace>(ws_);
    yp2_.resize(m.nstate);
    delta2_.assign(N, 0.0);
  }
}

void ChainStiffness::take(double t, const double* y) {
  // K = -dF/dq on the chain by finite differences of the generalized forces (ws.force), in
  // link order: a link's coordinates reach the forces of itself and its two neighbours
  // only, so the links of one colour (3 or more apart) are perturbed together, one link
  // coordinate at a time: 21 evaluations per colour. On more than one thread the
  // evaluations are split in two halves, each run serially on a workspace of its own (no
  // synchronization per evaluation); the second half runs on ws_, so that ws_ ends as the
  // serial loop leaves it (the assembly reads its link directions), and every column is
  // the same number whichever thread takes it.
  const auto t0 = std::chrono::steady_clock::now();
  if (analytic_) {
    hessian(t, y);
    for_joints(schedule_, m_.links, [this](int l) {
      pack_columns(sub_[l], packed_[l][0]);
      pack_columns(super_[l], packed_[l][1]);
    });
    ++takes_;
    seconds_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return;
  }
  yp_ = Eigen::Map<const Eigen::VectorXd>(y, m_.nstate);
  ys_ = yp_;
  forces(ws_, t, ys_.data(), -1, schedule_.threads() > 1);
  force0_.assign(ws_.force.begin(), ws_.force.begin() + m_.ndof);
  chain0_ = ws_.chain_slots, pulley0_ = ws_.pulley_slots;  // the joints a colour leaves alone
  const int n_items = colors_ * kLinkDim;
  if (schedule_.threads() > 1) {  // ws2_ exists (the constructor makes it for more than one thread)
    *ws2_ = ws_;
    yp2_ = yp_;
    const int half = n_items / 2;
    const auto first = [&] { items(*ws2_, yp2_, delta2_, t, 0, half); };
    const auto second = [&] { items(ws_, yp_, delta_, t, half, n_items); };
    TwoTaskPhases ph;
    TwoTasks{true}([&] { ph.two(0, 0, first, second); }, [&] { ph.two(0, 1, first, second); });
  } else {
    items(ws_, yp_, delta_, t, 0, n_items);
  }
  evaluations_ += 1 + n_items;
  for_joints(schedule_, m_.links, [this](int l) {
    pack_columns(sub_[l], packed_[l][0]);
    pack_columns(super_[l], packed_[l][1]);
  });
  ++takes_;
  seconds_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

void ChainStiffness::items(Workspace& w, Eigen::VectorXd& yp, std::vector<double>& delta, double t, int k0, int k1) {
  const int N = m_.links;
  const double eps = std::numeric_limits<double>::epsilon();
  const std::vector<double>& F0 = force0_;
  for (int k = k0; k < k1; ++k) {
    const int color = k / kLinkDim, i = k % kLinkDim;
    for (int l = 0; l < N; ++l) {
      if (color_[l] != color) continue;
      const int c = coord(l, i);
      delta[l] = std::sqrt(eps * std::max(1e-5, std::abs(ys_[c])));
      yp[c] = ys_[c] + delta[l];
    }
    forces(w, t, yp.data(), color, false);
    const double* F1 = w.force.data();
    for (int l = 0; l < N; ++l) {
      if (color_[l] != color) continue;
      const double inv = 1.0 / delta[l];
      // Column i of link l: rows of links l-1 (sub of l, as M(l-1, l): super(l)), l, l+1.
      for (int r = 0; r < kLinkDim; ++r) {
        const int rp = coord(m_.wrap(l - 1), r), ro = coord(l, r), rn = coord(m_.wrap(l + 1), r);
        super_[l](r, i) = -(F1[rp] - F0[rp]) * inv;
        diag_[l](r, i) = -(F1[ro] - F0[ro]) * inv;
        sub_[m_.wrap(l + 1)](r, i) = -(F1[rn] - F0[rn]) * inv;
      }
    }
    for (int l = 0; l < N; ++l)
      if (color_[l] == color) yp[coord(l, i)] = ys_[coord(l, i)];
  }
}

void ChainStiffness::forces(Workspace& w, double t, const double* y, int color, bool threads) {
  // The stages of an evaluation that the chain's generalized forces need (kChainForceStages
  // of the stage table): the link angles, the chain and pulley kernels, the gather. The inertia's velocity terms keep the values of
  // the last full evaluation (a constant, which the differences cancel). With a colour: a
  // joint touches only links j-1 and j (docs/model.md 4: its halves a_j, b_j, the plates of
  // link j, the directions of links j-1 and j), so a joint next to no perturbed link keeps
  // the slots of the unperturbed state (chain0_, pulley0_), which its kernels would
  // reproduce bit for bit; only the others are computed (2 of 3 joints with 3 colours).
  const auto ranges = [this, threads](const auto& f) {
    if (threads)
      for_joint_ranges(schedule_, m_.links, f);
    else
      f(0, m_.links);
  };
  set_stage_input(m_, w, t, y);
  const StageArgs a{m_, w};
  if (color < 0) return run_stages(kChainForceStages, a, ranges);
  run_stages(stage_set(StageId::link_kinematics), a, ranges);
  // Joint j is next to a perturbed link when link j-1 or link j has the colour.
  const auto touched = [this, color](int j) { return color_[m_.wrap(j - 1)] == color || color_[j] == color; };
  ranges([this, &w, &touched](int b, int e) {
    for (int j = b; j < e;) {
      if (!touched(j)) {
        w.chain_slots[j] = chain0_[j], w.pulley_slots[j] = pulley0_[j];
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
  run_stages(stage_set(StageId::gather), a, ranges);
}

void ChainStiffness::hessian(double t, const double* y) {
  // K(l, l) = link l's own elements + the link-l parts of joints l and l+1 + the friction of
  // its pin ends (at y's velocities); K(l, l-1) and K(l-1, l) are joint l's cross blocks
  // (transposes of each other in the Hessian; the rocker's friction, added per joint, makes
  // them differ). Each block is written by one thread: the same numbers for any thread count.
  const auto ranges = [this](const auto& f) { for_joint_ranges(schedule_, m_.links, f); };
  set_stage_input(m_, ws_, t, y);
  run_stages(stage_set(StageId::link_kinematics), StageArgs{m_, ws_}, ranges);
  for_joints(schedule_, m_.links, [this, y](int j) {
    joint_hessian(m_, y, ws_.status, j, joints_[j]);
    add_rocker_friction_stiffness(m_, ws_, j, joints_[j]);
  });
  for_joints(schedule_, m_.links, [this, y](int l) {
    link_hessian(m_, y, ws_.status, l, diag_[l]);
    add_pulley_friction_stiffness(m_, ws_, l, diag_[l]);
    diag_[l] += joints_[l].own + joints_[m_.wrap(l + 1)].prev;
    sub_[l] = joints_[l].cross;
    super_[l] = joints_[l].up;
  });
}

void ChainStiffness::pack_columns(const LinkBlock& b, PackedColumns& p) {
  p.n = 0;
  for (int c = 0; c < kLinkDim; ++c)
    if (b.col(c).cwiseAbs().maxCoeff() != 0) p.index[p.n] = c, p.cols.col(p.n++) = b.col(c);
}

}  // namespace cvt
