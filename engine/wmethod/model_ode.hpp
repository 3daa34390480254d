// The CVT model as a first-order system y' = f(t, y) for the generic integrators of
// engine/ode/ode.hpp (docs/integrators.md 11): the right-hand side is Schedule::rhs with the
// contact statuses frozen, the Jacobian is coloured finite differences over a sparsity
// pattern built from the model's structure (model_ode.cpp), and the W-method's matrix is
// assembled, factorized and solved on the chain's links (w_matrix.cpp) with the fresh
// friction's low-rank correction (fresh_friction.cpp). engine/wmethod/driver.hpp runs any
// OdeMethod on it.
#pragma once

#include <cstdint>
#include <utility>
#include <array>
#include <memory>
#include <vector>

#include "engine/ode/block_cyclic.hpp"
#include "engine/ode/ode.hpp"
#include "graph/schedule.hpp"

namespace cvt {

struct ModelOdeOptions {
  // Joints on each side whose coordinates a joint's acceleration may depend on (pattern
  // half-width; 2 covers the rocker faces turning with the neighbouring links and the
  // Woodbury correction, verified by tests/engine/wmethod/model_ode_test.cpp).
  int band = 2;
  // true: the pins -> shaft accelerations and pins -> dissipated power entries (the dense
  // rows) are in the Jacobian, computed from the per-pin force slots of the same coloured
  // evaluations (no extra RHS); false: they are left out (an approximate Jacobian, which
  // only slows Newton's convergence).
  bool exact_dense_rows = true;
  // Integrate z = (y - c) / s instead of y, with s the unit vector below and c the state at
  // the start of each OdeDriver macro step (s_i = 1, c = 0 when off): the solvers have a
  // scalar atol, and the CVT's state mixes absolute positions (0.05 m, to be known to
  // 1e-8 m), slopes, velocities and energies. With the shift, |z| is the motion within the
  // macro step, so rtol = atol = tol is meaningful (and so is Newton's tolerance, which
  // RADAU5-style is a fraction of rtol: a tiny rtol made Newton chase 1e-10 m).
  bool scaled = false;
  // Freeze each contact's friction branch (stick / slide) within a macro step: the first
  // evaluation of each OdeDriver macro step records it (FrozenFriction). Only
  // for the implicit methods; without it Newton diverges at h ~ 1e-6 on the kink of the
  // nonsmooth law at v0 (docs/integrators.md 11).
  bool freeze_friction = true;
  // The W-method settings default to the configuration's [integrator] defaults (one source:
  // Config::Integrator; w_run_options maps a configuration).
  // W-methods: rebuild the friction blocks and refactorize at every step whose index is a
  // multiple of this (a W-method keeps its order with a stale matrix; only the stiff part
  // must be captured).
  int w_every = Config::Integrator{}.w_every;
  // FrictionJacobian::secant: true (the secant slope N f(v)/v along the sliding direction
  // too, never below the exact one) keeps a sliding contact that is about to stick stiff in
  // W; with the exact slope (0 above v0 for the nonsmooth law) a stale W meets such a
  // contact explicitly, and its friction chatters (docs/integrators.md 12.2).
  bool w_secant = Config::Integrator{}.w_secant;
  // false: no friction blocks; ROS2 then takes the full coloured finite-difference Jacobian
  // and a sparse LU at every step (slow: for checking what the blocks leave out).
  bool w_blocks = true;
  // true: W carries the chain's stiffness K = -dF/dq (finite differences over link colours,
  // 21 evaluations per colour: 63 for 3 colours), taken at every w_k_every-th step's rebuild
  // (the elastic forces change slowly; the friction blocks, every w_every steps).
  bool w_stiffness = true;
  int w_k_every = Config::Integrator{}.w_k_every;
  // true: a change of the contact statuses (after a step) makes the next step rebuild the
  // whole matrix. Off: measured worse (8-10 % against 0.8 % over the 5 ms window at 2.5e-7,
  // and 5x further from RK4 in the mini model's load ramp), as the stiffness differences
  // taken right where a contact switches step across its boundary (docs/integrators.md 15).
  bool w_status_rebuild = false;
  // The block LU of W drops the fill of its cyclic corners below this fraction of the next
  // pivot block (CyclicBlockLU::set_drop_tolerance): W is then factored exactly as W + E,
  // |E| <= 1e-12 |W|, the same for every stage, far below the approximation a W-method
  // works with anyway (a matrix up to w_every steps old). On the reference model at 1e-6
  // the fill rows fall from 58 to 21 of 83 per factorization (docs/integrators.md 12.2).
  double w_fill_drop = 1e-12;
  // Fresh friction between rebuilds (docs/integrators.md 12.4): > 0 keeps W's friction part
  // current at every step, as a low-rank (Woodbury) correction of the factorized W for the
  // contacts whose friction coefficient mu (the secant N f(v)/v) moved since the rebuild by
  // more than w_fresh * m_pin / (gamma h), i.e. whose stiffness gamma h mu / m_pin changed by
  // more than w_fresh. Each such contact costs two solves with the factorized W when it
  // joins, and a rank-2 term in every solve after. More than w_fresh_max of them make the
  // next step rebuild the friction blocks. 0: off (the stale blocks of docs/integrators.md 12.3); off too
  // without w_secant.
  double w_fresh = Config::Integrator{}.w_fresh;
  // true: W holds the shafts' velocity rows too (their mass and the pulley friction's damping
  // between sheaves and pins, both ways), solved by the Schur complement of the 14 shaft
  // unknowns on the factorized chain (docs/integrators.md 12.2); false: the identity there
  // (the shafts' increments are the right side's and drag the pins).
  bool w_shafts = Config::Integrator{}.w_shafts;
  int w_fresh_max = Config::Integrator{}.w_fresh_max;
  // Adaptive steps (OdeSystem::error_norm): > 0 gives the system the norm of the chain's
  // error, per joint (its two pin halves and its plate pack, positions and velocities), per
  // shaft and for the load, each the RMS of its components in units of tol * (length_unit,
  // velocity_unit), maximized over these groups; the work integrals are left out. So
  // error_tol = 1 accepts a step whose estimate is about 1 um and 1 mm/s at the pin that errs
  // most, however smoothly the other 83 run. 0: the library's norm over atol / rtol.
  double error_tol = 0;
  // Adaptive steps: W = I - gh' J~ is kept while the step's gh stays within
  // [gh' / w_h_shrink, gh' w_h_grow] (a W-method keeps its order with J~' = (h'/h) J~; with
  // the exact J ROS34PW2 stays stable for h'/h >= 0.67, |R(-inf)| <= 0.2 for h'/h in
  // 0.67 .. 4, docs/integrators.md 16), and refactorized outside it. 1, 1: any change of gh
  // (beyond rounding) refactorizes, as fixed steps need.
  double w_h_grow = 1, w_h_shrink = 1;
  double length_unit = 1e-6;    // [m] for positions; slopes and angles: length_unit / 0.05 m
  double velocity_unit = 1e-3;  // [m/s] for velocities; angular: velocity_unit / 0.05 m
  double energy_unit = 1e-3;    // [J] for the work integrals
};

// The unit vector s of ModelOdeOptions::scaled.
Eigen::VectorXd model_state_units(const Model& m, const ModelOdeOptions& opt);

// Nonzero pattern of df/dy for model m. With pin_to_tail the dense rows (shaft
// accelerations, dissipated power) carry every pin column; without, only the tail columns.
std::vector<std::pair<int, int>> model_jacobian_pattern(const Model& m, int band, bool pin_to_tail);

// The adapter. Holds references: model, workspace and schedule must outlive it. The
// workspace must be the schedule's (its statuses are the frozen ones, its slots are read
// by the Jacobian).
class ModelOde {
 public:
  ModelOde(const Model& m, Workspace& ws, Schedule& schedule, const ModelOdeOptions& opt = {});
  const OdeSystem& system() const { return sys_; }
  // State units (all ones unless scaled): the system integrates z = y / units().
  const Eigen::VectorXd& units() const { return unit_; }
  // The shift c (scaled mode): y = c + units() * z.
  Eigen::VectorXd& offset() { return offset_; }
  void to_z(const Eigen::VectorXd& y, Eigen::VectorXd& z) const { z = (y - offset_).cwiseQuotient(unit_); }
  void to_y(const Eigen::VectorXd& z, Eigen::VectorXd& y) const { y = offset_ + z.cwiseProduct(unit_); }
  // Every evaluation of f, including the Jacobian's (OdeStats does not see the latter:
  // to the solver the Jacobian is "analytic").
  std::int64_t rhs_evals() const { return rhs_evals_; }
  std::int64_t jacobian_evals() const { return jac_evals_; }
  int colors() const {
    ensure_colors();
    return n_colors_;
  }
  // Wall seconds spent in the W-method's stiffness differences (part of its w_factor time).
  double w_stiffness_seconds() const { return w_k_seconds_; }
  // The coloured finite-difference Jacobian at (t, y) into jac (which has sys.sparsity).
  void jacobian(double t, const double* y, Eigen::SparseMatrix<double>& jac);
  // The W-method's matrix (OdeSystem::w_factor / w_solve, docs/integrators.md 12):
  // W = I - gh J~ with J~ = [0, I; -A^-1 K, -A^-1 C] on the chain's coordinates, C the
  // friction damping blocks that the last evaluation recorded (FrictionJacobian::blocks,
  // asked for by ask_friction_jacobian), K = -dF/dq the chain's stiffness
  // (finite differences), A the chain's mass matrix (A0, plus the link inertia); on the
  // shafts' velocities the identity (their increments drag the pins through the pulley
  // friction). Solved as (A + gh C + gh^2 K) x_v = A b_v - gh K b_q, x_q = b_q + gh x_v:
  // block-tridiagonal over the links with cyclic corners (CyclicBlockLU, 21 x 21 blocks).
  // ModelOdeOptions::w_stiffness = false leaves K out.
  void w_factor(double t, const double* y, double gh);
  void w_solve(double* x) const;
  void w_solve_untimed(double* x) const;
  // The next step is the run's step `index`: its first evaluation also fills the friction
  // part of W (FrictionJacobian) where the step needs it: the blocks when it rebuilds the
  // matrix (w_due), each contact's mu for the fresh-friction correction (w_fresh_on).
  // An evaluation taken ahead for that step (eval_ahead) has answered the request already.
  void ask_friction_jacobian(long index) {
    w_index_ = index;
    if (ahead_ && index == ahead_index_) return;
    fjac_.blocks = w_due();
    fjac_.mu = w_fresh_on();
  }
  // The first evaluation of the next step, taken now (for a sample of the state the step
  // starts from, which then reads the workspace as this evaluation leaves it): f(t, y) into
  // dy, after ask_friction_jacobian for that step. The step's own first evaluation, at the
  // same t, y and statuses with nothing more asked of it, returns this one's f unevaluated;
  // any other evaluation drops it.
  void eval_ahead(double t, const double* y, double* dy);
  // The implicit methods' frozen friction branch (FrozenFriction): from now on the
  // evaluations keep each contact's branch, and the next one records it afresh (OdeDriver,
  // at the start of each macro step).
  void record_friction_branches() { freeze_ = frozen_.record = true; }
  // What the kernels filled at the last request (tests).
  const FrictionJacobian& friction_jacobian() const { return fjac_; }
  // Whether the next step rebuilds the matrix.
  bool w_due() const {
    return w_gh_ == 0 || w_invalid_ || wf_force_ || opt_.w_every <= 1 || w_index_ % opt_.w_every == 0;
  }
  // gamma h of the factorized W (0: none yet).
  double w_gh() const { return w_gh_; }
  // The contact statuses changed (OdeDriver): the next step rebuilds the whole matrix, its
  // stiffness included (a contact that turned on is stiff in J but absent from a stale W).
  void w_invalidate() { w_invalid_ = true; }
  std::int64_t w_status_rebuilds() const { return w_status_rebuilds_; }
  // w_fresh: the contacts that joined a correction, and the rebuilds that w_fresh_max forced.
  std::int64_t w_fresh_contacts() const { return wf_joined_; }
  std::int64_t w_fresh_rebuilds() const { return wf_rebuilds_; }
  // Whether the next step's first evaluation must record each contact's mu (w_fresh).
  // Off without the secant slope (a contact's block is then not mu U U^T).
  bool w_fresh_on() const { return opt_.w_fresh > 0 && opt_.w_blocks && opt_.w_secant; }

 private:
  void eval(double t, const double* y, double* dy) {
    if (ahead_ && take_ahead(t, y, dy)) return;
    Profiler* prof = schedule_.profiler();
    const std::uint64_t t0 = prof ? Profiler::ticks() : 0;
    // The friction part of W comes from the first evaluation of a step that asks for it
    // (ask_friction_jacobian); the step's later evaluations compute f alone.
    schedule_.rhs(t, y, dy, nullptr, {fjac_.requested() ? &fjac_ : nullptr, freeze_ ? &frozen_ : nullptr});
    if (prof) prof->add_rhs_wall(Profiler::ticks() - t0);
    ++rhs_evals_;
    wf_recorded_ = fjac_.mu;
    fjac_.blocks = fjac_.mu = false;
    frozen_.record = false;  // the evaluation that recorded the branches was this one
  }
  void eval_scaled(double t, const double* z, double* dz);
  // The evaluation taken ahead, if (t, y) and the statuses are its own and nothing more is
  // asked (the friction blocks, the frozen branches): its f into dy, true. Drops it either way.
  bool take_ahead(double t, const double* y, double* dy);
  bool ahead_ = false;
  double ahead_t_ = 0;
  long ahead_index_ = -1;
  std::vector<double> ahead_y_, ahead_dy_;
  ContactStatus ahead_status_;
  double chain_error_norm(const double* err) const;  // ModelOdeOptions::error_tol's norm
  std::vector<double> norm_weight_;  // per state component: 1 / (error_tol * its unit), 0: left out
  std::vector<int> norm_group_;      // group boundaries in state order (joints, shafts, load)
  template <class F>
  void for_joints(const F& f) const;  // f(j) for every joint, over the schedule's threads
  void w_assemble_link(int l, double gh);
  // The per-pin parts of the dense rows after an evaluation: shaft forces [N][14] and
  // dissipated power [N] of the chain and pulley slots.
  void read_slots(std::vector<double>& shaft, std::vector<double>& pdiss) const;
  bool is_pin(int col) const { return col < 2 * m_.ndof && col % m_.ndof < kJointSize * m_.links; }
  int joint_of(int col) const { return (col % m_.ndof) / kJointSize; }

  const Model& m_;
  Workspace& ws_;
  Schedule& schedule_;
  ModelOdeOptions opt_;
  FrictionJacobian fjac_;  // the W-method's friction part, filled by the evaluations that ask
  FrozenFriction frozen_;  // the implicit methods' friction branches
  bool freeze_ = false;    // the evaluations take frozen_ (record_friction_branches)
  OdeSystem sys_;
  std::int64_t rhs_evals_ = 0, jac_evals_ = 0;
  // Column colours (the pins by the pattern without pin -> tail entries).
  void ensure_colors() const;  // the colouring below, made at the first Jacobian
  mutable bool colored_ = false;
  mutable std::vector<std::vector<int>> columns_of_color_;
  mutable std::vector<int> owner_;  // [colour * N + joint]: index in columns_of_color_ of the column near the joint, or -1
  mutable int n_colors_ = 0;
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic> a0_shaft_inv_;  // (2 shafts + load) x 14
  Eigen::VectorXd f0_, f1_, yp_, delta_, unit_, ys_, offset_;
  std::vector<double> shaft0_, pdiss0_, shaft1_, pdiss1_;
  mutable Eigen::MatrixXd acc_shaft_;  // [14][columns in the colour] (sized by ensure_colors)
  mutable Eigen::VectorXd acc_p_;
  // W-method: the matrix over the chain's velocities in link order (link l: b_l, a_{l+1},
  // then the pack s_l), block-tridiagonal with cyclic corners.
  static constexpr int kLinkDim = 2 * half::kSize + 1;
  using LinkBlock = CyclicBlockLU<kLinkDim>::Mat;
  using LinkVector = CyclicBlockLU<kLinkDim>::Vec;
  using LinkBlocks = std::vector<LinkBlock, Eigen::aligned_allocator<LinkBlock>>;
  using LinkVectors = std::vector<LinkVector, Eigen::aligned_allocator<LinkVector>>;
  int link_coord(int l, int i) const {  // coordinate index of entry i of link l
    return i < half::kSize ? m_.half_b(l) + i : i < 2 * half::kSize ? m_.half_a(l + 1) + i - half::kSize : m_.pack(l);
  }
  void w_stiffness(double t, const double* y);
  // The differences of items [k0, k1) (item k: colour k / kLinkDim, link coordinate
  // k % kLinkDim) on workspace w, from the unperturbed state ys_ copied in yp (left as it
  // was), with delta as the per-link scratch; serial on the calling thread.
  void w_stiffness_items(Workspace& w, Eigen::VectorXd& yp, std::vector<double>& delta, double t, int k0, int k1);
  // ws.force of the chain at (t, y); with a colour, the differences' evaluation that
  // perturbs that colour's links (only the joints next to them are computed).
  void chain_forces_at(double t, const double* y, int color = -1);
  // The same on workspace w, serially on the calling thread or (threads) over the
  // schedule's threads; not counted as an evaluation.
  void chain_forces_on(Workspace& w, double t, const double* y, int color, bool threads);
  // The second workspace of the differences on two threads (a copy of ws_ at the stiffness's
  // unperturbed evaluation), its perturbed state and per-link steps.
  std::unique_ptr<Workspace> w_ws2_;
  Eigen::VectorXd w_yp2_;
  std::vector<double> w_delta2_;
  std::vector<JointSlot> w_chain0_, w_pulley0_;  // the slots at the unperturbed state
  template <class F>
  void for_ranges(const F& f) const;  // f(begin, end) over the joints, on the schedule's threads
  void link_gradient(int l, LinkVector& g) const;
  LinkBlock a0_link_;  // A0 of a link's coordinates (constant)
  // Per link: the pulley friction's K_ps on its rows (21 x 14, both shafts) at the last
  // rebuild, and whether it is nonzero (the link touches a sheave).
  std::vector<Eigen::Matrix<double, kLinkDim, 2 * kShaftSize>,
              Eigen::aligned_allocator<Eigen::Matrix<double, kLinkDim, 2 * kShaftSize>>>
      w_cps_;
  std::vector<std::uint8_t> w_cps_on_;
  // w_shafts: the shafts' mass matrix M_s (constant), Y = (chain's W)^-1 gh K_ps per link,
  // and the LU of the Schur complement M_s + gh C_ss - gh K_ps^T Y (14 x 14).
  using ShaftMatrix = Eigen::Matrix<double, 2 * kShaftSize, 2 * kShaftSize>;
  using ShaftVector = Eigen::Matrix<double, 2 * kShaftSize, 1>;
  ShaftMatrix w_ms_;
  std::vector<Eigen::Matrix<double, kLinkDim, 2 * kShaftSize>,
              Eigen::aligned_allocator<Eigen::Matrix<double, kLinkDim, 2 * kShaftSize>>>
      w_y_;
  Eigen::PartialPivLU<ShaftMatrix> w_schur_;
  void w_shaft_factor(double gh);
  ShaftVector w_shaft_solve(double* x) const;  // the bordered solve's shaft step (w_solve_untimed)
  using ShaftVectors = std::vector<ShaftVector, Eigen::aligned_allocator<ShaftVector>>;
  // Its x_s for the right side r_s, from the products K_ps,l^T z_l in bz (w_bz_ by default).
  ShaftVector w_shaft_unknowns(const ShaftVector& rs) const { return w_shaft_unknowns(rs, w_bz_); }
  ShaftVector w_shaft_unknowns(const ShaftVector& rs, const ShaftVectors& bz) const;
  // K_ps,l^T z_l of link l's solved chain part z_l (w_rhs_[l]) into w_bz_[l]: on the solve's
  // tasks, so that w_shaft_unknowns only sums them. The second form: z and the product of
  // another solve (a fresh-friction contact's second column, wf_join).
  void w_shaft_product(int l) const { w_shaft_product(l, w_rhs_, w_bz_); }
  void w_shaft_product(int l, const LinkVectors& z, ShaftVectors& bz) const;
  mutable ShaftVectors w_bz_, wf_bz2_;
  ShaftVector shaft_velocities(const double* x) const;  // x's 14 shaft velocities, physical units
  void w_shaft_back(int l, const ShaftVector& xs, LinkVector& z) const;  // z -= Y_l x_s (link l's chain part)
  CyclicBlockLU<kLinkDim> w_lu_;
  std::vector<int> w_coord_;                  // [l * kLinkDim + i]: link_coord(l, i)
  int coord(int l, int i) const { return w_coord_[l * kLinkDim + i]; }
  std::vector<double> w_unit_q_, w_unit_v_;   // the units of those positions and velocities (scaled)
  std::vector<double> w_unit_ratio_;          // [i < ndof]: unit of velocity i / unit of position i
  mutable LinkVectors w_rhs_, wf_rhs2_;  // wf_rhs2_: a fresh-friction contact's second column (wf_join)
  // A fresh-friction contact's two columns [U; V], solved together (wf_join).
  using LinkPair = Eigen::Matrix<double, kLinkDim, 2>;
  std::vector<LinkPair, Eigen::aligned_allocator<LinkPair>> wf_rhs_;
  std::vector<int> w_other_coord_;            // the coordinates outside the chain's links (shafts, load)
  LinkVectors w_g_;  // per link: d psi / d(link coordinates) at the last rebuild
  // K = -dF/dq at the last stiffness rebuild: per link l, M(l, l), M(l, l-1), M(l-1, l).
  LinkBlocks w_k_diag_, w_k_sub_, w_k_super_;
  // The coupling blocks by their nonzero columns (a coupling between links reaches about 12
  // of a link's 21 coordinates: the halves at the joint and the link spins), for the solve's
  // K b_q: per link, [0] sub, [1] super.
  struct PackedColumns {
    int n = 0;
    std::array<int, kLinkDim> index{};
    LinkBlock cols;
  };
  std::vector<std::array<PackedColumns, 2>> w_k_packed_;
  static void pack_columns(const LinkBlock& b, PackedColumns& p);
  std::vector<double> w_force0_, w_delta_;
  std::vector<int> w_color_;
  int w_colors_ = 0;
  double w_k_seconds_ = 0;
  bool w_invalid_ = false;
  std::int64_t w_status_rebuilds_ = 0;
  double w_gh_ = 0;                       // gh of the factorization (0: none yet)
  long w_index_ = 0;                      // index of the next step
  // w_fresh: the correction W' = W + U D U^T, U the columns of the contacts in it (two
  // each), D = gh (mu - mu_w) on both; Z = W^-1 U (chain velocities in link order, physical
  // units), G = U^T Z, the capacitance I + D G factorized once per step.
  struct FreshContact {
    FrictionJacobian::FreshMu* kind;  // fjac_.rocker_fresh or fjac_.pulley_fresh
    int idx, joint, shaft;     // shaft: the sheave of a pin end, -1 for a rocker station
    const double* columns() const;  // its U, 2 x 40 (a pin end's sheave part: ws_.pulley_shaft_cols)
    const double* sheave_columns(const FrictionJacobian& f) const;  // its V, 2 x 7 (nullptr: a rocker station)
  };
  struct FreshCandidate {
    double dmu;
    int rank, kind, idx;  // rank: the order of ties (rocker stations, then pin ends)
  };
  std::vector<FreshCandidate> wf_cand_;
  void wf_clear();
  void wf_update(double gh);
  void wf_join(const FreshContact& c);
  // [U; V](:, col)^T [z; zs] (zs: the shafts' part, 14 entries; nullptr: the chain's alone)
  double wf_dot(const FreshContact& c, int col, const double* z, const double* zs = nullptr) const;
  void wf_correct(double* x) const;
  std::vector<FreshContact> wf_set_;
  Eigen::MatrixXd wf_z_, wf_g_;
  Eigen::MatrixXd wf_zs_;  // w_shafts: Z's shaft rows (14 x columns), physical units
  Eigen::VectorXd wf_d_;
  // The capacitance matrix I + D G and its LU, one of each size 2, 4, .., 2 w_fresh_max.
  std::vector<Eigen::MatrixXd> wf_cap_m_;
  std::vector<Eigen::PartialPivLU<Eigen::MatrixXd>> wf_cap_;
  mutable Eigen::VectorXd wf_s_, wf_t_, wf_p_, wf_b_, wf_corr_;  // wf_correct's scratch
  bool wf_recorded_ = false, wf_force_ = false;
  std::int64_t wf_joined_ = 0, wf_rebuilds_ = 0;
};

}  // namespace cvt
