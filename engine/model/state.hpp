// Mutable data of a run (MuJoCo's mjData): sized once from the Model, nothing is
// allocated inside a step. Kernels read the stage input (t, q, v) and the link
// kinematics, and write only the per-pin slots of their own module.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

#include "engine/model/model.hpp"

namespace cvt {

// Generalized forces a kernel produced for joint j (docs/model.md 4.0, ordered gather):
// coordinates of joint j, those of half a_{j+1}, torques on links j-1 and j (to be
// multiplied by g_i), the two shafts, and the dissipated power.
struct alignas(64) JointSlot {
  std::array<double, kJointSize> f;   // a_j, b_j, s_j
  std::array<double, half::kSize> f_next_a;  // a_{j+1}
  double tau_prev, tau_own;           // on link j-1 and link j
  std::array<double, 2 * kShaftSize> shaft;
  double p_diss;                      // dissipated power [W], >= 0
  void clear() {
    f.fill(0.0);
    f_next_a.fill(0.0);
    tau_prev = tau_own = 0.0;
    shaft.fill(0.0);
    p_diss = 0.0;
  }
};

// Per-link kinematics of the current stage (docs/model.md 3.1), structure of arrays.
struct LinkKinematics {
  std::vector<double> ex, ey;     // unit link direction e_i
  std::vector<double> inv_len;    // 1/|Delta_i|
  std::vector<double> psi_dot;    // link angular velocity
  std::vector<double> dx, dy, ddx, ddy;  // Delta_i and its rate
};

// Contact statuses, frozen during a step (docs/model.md 4.4).
struct ContactStatus {
  std::vector<std::uint8_t> rocker;  // [joint][station]
  std::vector<std::uint8_t> pulley;  // [joint][half 2][end 2][pulley 2]
  static constexpr int kPulleyPerJoint = 8;  // pin-sheave contacts per joint: 2 halves x 2 ends x 2 pulleys
  static int pulley_index(int j, int h, int e, int k) { return ((j * 2 + h) * 2 + e) * 2 + k; }
};

// Output of other_forces (shafts, drive, load, clamping): small, one slot.
struct OtherForces {
  std::array<double, 2 * kShaftSize + 1> f;  // shafts 0, 1, then the load angle
  double p_in = 0, p_out = 0, p_diss = 0, p_clamp = 0, ctrl_rate = 0;
  double input_torque = 0, output_torque = 0, load_torque = 0;
  double clamp[2] = {0, 0};
  double support_force[2][2] = {{0, 0}, {0, 0}};  // [shaft][bearing] magnitude [N]
};

// The clock of a run: t = t0 + (steps - steps0) h, so that t carries no rounding
// accumulated over the steps while h stays the same (docs/integrators.md). Simulation owns
// the run's clock; a driver that takes sub-steps forms their times the same way from a
// clock of its own that starts at the step.
struct StepClock {
  double t = 0, t0 = 0;        // the time now, and the origin
  long steps = 0, steps0 = 0;  // steps taken, and the origin

  // A clock at (t, steps) with its origin there (a start, a restart from a saved state).
  static StepClock at(double t, long steps) { return {t, t, steps, steps}; }
  // The time after step n of size h.
  double time_after(long n, double h) const { return t0 + static_cast<double>(n - steps0) * h; }
  // Before a step of size h: a caller that changed h (a run warmed at one step and continued
  // at another) gets the origin moved to now instead of a time jump; unchanged h: no effect.
  void keep_origin(double h) {
    if (std::abs(time_after(steps, h) - t) > 1e-6 * h) t0 = t, steps0 = steps;
  }
  // One step of size h taken.
  void tick(double h) {
    ++steps;
    t = time_after(steps, h);
  }
};

struct Workspace {
  explicit Workspace(const Model& m);

  // Stage input.
  double t = 0;
  const double* q = nullptr;
  const double* v = nullptr;
  const double* aux = nullptr;

  LinkKinematics kin;
  ContactStatus status;
  std::vector<JointSlot> chain_slots, pulley_slots, inertia_slots;
  OtherForces other;
  std::vector<double> capacitance_inv;  // 1/C_i of the Woodbury solve (3.2)

  // Gather and solve.
  Eigen::VectorXd force;       // generalized forces F (n)
  std::vector<double> link_tau;  // summed torques per link
  Eigen::VectorXd accel;       // q'' (n)
  Eigen::VectorXd accel_free;  // A0^-1 F, between the two passes of the solve (3.2)
  double p_diss = 0;           // total dissipated power of the stage
  // Contact energy added by the status updates since the last read (docs/model.md 4.4):
  // a pair switched on while penetrating brings its Hertz energy in, one switched off
  // takes it out.
  double switch_work = 0;
  std::vector<double> switch_slot;  // per joint, summed in pin order into switch_work


};

// What an evaluation may be asked to fill besides f: the friction part of the W-method's
// matrix (docs/integrators.md 12). The W-method owns it and hands it to the evaluation that
// starts a step (Schedule::rhs's last argument); the kernels chain_forces and pulley_contact
// then fill, for their own joints only, what `blocks` and `mu` ask for. The production RK4
// path never passes one.
struct FrictionJacobian {
  explicit FrictionJacobian(const Model& m);
  // What this evaluation is asked for.
  // blocks: for each active rocker station of joint j (chain_forces) and each active pin end
  // of joint j (pulley_contact),
  //   K_j += G^T D G,   D = mu (P - t t^T) + mu_t t t^T on the contact's tangent plane,
  // where u = G v is the contact's slip velocity as a function of the four halves that it
  // moves: b_{j-1}, a_j, b_j, a_{j+1} in this order (the two halves of joint j directly, and
  // through the link spins psi_{j-1} and psi_j also the other half of each of the two links
  // that hold them; the shafts are left out). In link order that is link j-1 (b_{j-1}, a_j)
  // then link j (b_j, a_{j+1}), so the sum over joints is block-tridiagonal (cyclic) over
  // the links. Row-major 40 x 40 per joint, lower triangle only (the blocks are symmetric);
  // each kernel zeroes and fills only its own joints' blocks.
  // mu: fresh friction (ModelOdeOptions::w_fresh, docs/integrators.md 12.4). With the secant
  // slope a contact's block is mu U U^T, U = G^T [t s] (its slip velocity's columns projected
  // on the tangent plane), so between two rebuilds a contact whose mu moved adds a rank-2
  // term to W. The kernels write each contact's mu (0 when inactive or without friction),
  // and its columns U when it is not yet recorded and |mu - mu_w| > mu_tol; with `blocks`
  // also, mu_w = mu and the columns of every active contact (the state the factorized W
  // holds). Indexed like the statuses; columns [idx][2][40] (G^T t, G^T s over the four
  // halves), for the pulley contacts also the sheave's [idx][2][7] (u's shaft part).
  bool blocks = false, mu = false;
  bool requested() const { return blocks || mu; }

  // Options, set once by the W-method.
  // secant: the secant slope N f(v)/v also along the sliding direction (over-damps sliding
  // contacts in W, but keeps a contact about to stick stiff in W); false: the exact N f'(v).
  bool secant = false;
  double mu_tol = 0;  // [N s/m]: a contact's columns are recorded when its mu moved by more

  // The blocks.
  static constexpr int kDim = 40;  // the four halves' coordinates
  std::vector<double> rocker_damping, pulley_damping;  // [joint][40][40]
  // The pulley contacts' cross damping between those 40 half coordinates and the 7
  // coordinates of each shaft (the slip velocity's sheave part), per joint [j][shaft][40][7]
  // row-major: K_ps with the pins' friction force -K_ps v_shaft.
  std::vector<double> pulley_shaft_damping;
  // The same contacts' damping among each shaft's own 7 coordinates (G_s^T D G_s), per joint
  // [j][shaft][7][7] row-major: the shafts' rows of W (ModelOdeOptions::w_shafts).
  std::vector<double> pulley_shaft_self;

  // The fresh friction record of one kind of contact.
  struct FreshMu {
    std::vector<double> mu, mu_w, cols;
    std::vector<std::uint8_t> cols_set;
    std::vector<std::uint8_t> in_correction;  // the W-method's: the contact is in its correction
    void resize(std::size_t contacts) {
      mu.assign(contacts, 0.0), mu_w.assign(contacts, 0.0), cols.assign(contacts * 2 * kDim, 0.0);
      cols_set.assign(contacts, 0), in_correction.assign(contacts, 0);
    }
    // A joint's contacts [first, first + count) before its kernel: no mu until found active;
    // at a rebuild none holds the factorized matrix's mu or columns.
    void clear(int first, int count, bool rebuild) {
      std::fill_n(mu.begin() + first, count, 0.0);
      if (rebuild) std::fill_n(mu_w.begin() + first, count, 0.0), std::fill_n(cols_set.begin() + first, count, 0);
    }
    // An active contact's mu (and at a rebuild mu_w); true when its columns are to be written.
    bool note(int idx, double m, bool rebuild, double tol) {
      mu[idx] = m;
      if (rebuild) mu_w[idx] = m;
      return rebuild || (!cols_set[idx] && std::abs(m - mu_w[idx]) > tol);
    }
    // Where contact idx's two columns go (and they are then recorded).
    double* columns(int idx) {
      cols_set[idx] = 1;
      return cols.data() + static_cast<std::size_t>(idx) * 2 * kDim;
    }
  };
  FreshMu rocker_fresh, pulley_fresh;
  std::vector<double> pulley_shaft_cols;  // [idx][2][7]
};

// The implicit methods' frozen friction branch (docs/integrators.md 11): with the nonsmooth
// law, the evaluation that records it notes each contact's branch, stick (|u| < v0:
// R = -f0 N u / v0, linear) or slide (R = -f0 N d with the direction d = u / |u| of that
// evaluation, projected on the current tangent plane), and the evaluations after it keep
// it. f is then smooth within a macro step and Newton does not meet the kink at v0 nor the
// turning of the sliding direction. The adapter of the implicit methods owns it (ModelOde)
// and hands it to its evaluations; indexed like the statuses (directions: 3 per contact).
struct FrozenFriction {
  explicit FrozenFriction(const Model& m);
  bool record = false;  // this evaluation records the branches (else it keeps them)
  std::vector<std::uint8_t> rocker_stick, pulley_stick;
  std::vector<double> rocker_dir, pulley_dir;
};

// One contact's entry in a FrozenFriction (none: the plain law).
struct FrozenBranch {
  bool record = false;
  std::uint8_t* stick = nullptr;
  double* dir = nullptr;
  bool on() const { return stick != nullptr; }
};
inline FrozenBranch rocker_branch(FrozenFriction* f, int idx) {
  return f ? FrozenBranch{f->record, &f->rocker_stick[idx], &f->rocker_dir[3 * idx]} : FrozenBranch{};
}
inline FrozenBranch pulley_branch(FrozenFriction* f, int idx) {
  return f ? FrozenBranch{f->record, &f->pulley_stick[idx], &f->pulley_dir[3 * idx]} : FrozenBranch{};
}

// What an evaluation of f is asked for besides f (Schedule::rhs's last argument, and the
// kernels' that have friction): nothing by default, as the production RK4 path takes it.
struct FrictionExtras {
  FrictionJacobian* jacobian = nullptr;  // W-methods: fill the friction part of W
  FrozenFriction* frozen = nullptr;      // implicit methods: record or keep the branches
};

}  // namespace cvt
