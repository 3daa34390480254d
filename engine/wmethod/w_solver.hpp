// The W-method's linear solver on the model (docs/integrators.md 12), in the shape of a
// SUNDIALS linear-solver module: its own memory, set up by factor() (CVODE's lsetup) and
// applied by solve() (lsolve), installed into the ODE system's w_factor / w_solve hooks by
// ModelOde; the integrator never sees the matrix.
//
// W = I - gh J~ with J~ = [0, I; -A^-1 K, -A^-1 C] on the chain's coordinates: C the
// friction damping blocks that the step's first evaluation recorded (FrictionJacobian,
// asked for by ask()), K = -dF/dq the chain's stiffness (ChainStiffness), A the chain's
// mass matrix (A0, plus the link inertia). Solved as (A + gh C + gh^2 K) x_v = A b_v -
// gh K b_q, x_q = b_q + gh x_v: block-tridiagonal over the links with cyclic corners
// (CyclicBlockLU, 21 x 21 blocks); with w_shafts the shafts' 14 velocity rows border it
// (a Schur complement), and with w_fresh a low-rank correction keeps the friction current
// between rebuilds (FreshFriction).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "engine/wmethod/chain_lu.hpp"
#include "engine/wmethod/chain_stiffness.hpp"
#include "engine/wmethod/fresh_friction.hpp"
#include "engine/wmethod/options.hpp"

namespace cvt {

class WSolver {
 public:
  // unit and offset: the ODE system's state scaling (y = offset + unit z), which must
  // outlive the solver.
  WSolver(const Model& m, Workspace& ws, Schedule& schedule, const ModelOdeOptions& opt,
          const Eigen::VectorXd& unit, const Eigen::VectorXd& offset);

  // The next step is the run's step `index`: its first evaluation fills the friction part
  // of W (recording()) where the step needs it: the blocks when it rebuilds the matrix
  // (due), each contact's mu for the fresh-friction correction (fresh_on).
  void ask(long index) {
    index_ = index;
    fjac_.blocks = due();
    fjac_.mu = fresh_on();
  }
  // What an evaluation is to record (nullptr: nothing), and the call after it.
  FrictionJacobian* recording() { return fjac_.requested() ? &fjac_ : nullptr; }
  void recorded() {
    fresh_recorded_ = fjac_.mu;
    fjac_.blocks = fjac_.mu = false;
  }
  // lsetup: W for gh at (t, y) (the system's state, scaled or not), right after the step's
  // first evaluation: rebuilt when due or when gh left its band, else kept (and corrected).
  void factor(double t, const double* y, double gh);
  // lsolve: x <- W^-1 x, timed as the profile's w_solve row; untimed for callers that time
  // themselves.
  void solve(double* x) const;
  void solve_untimed(double* x) const;

  // Whether the next step rebuilds the matrix.
  bool due() const {
    return gh_ == 0 || invalid_ || retake_ || fresh_.force_rebuild() || opt_.w_every <= 1 || index_ % opt_.w_every == 0;
  }
  double gh() const { return gh_; }  // gh of the factorized W (0: none yet)
  long index() const { return index_; }  // the index of the next step
  // The contact statuses changed: the next step rebuilds the whole matrix, its stiffness
  // included (a contact that turned on is stiff in J but absent from a stale W).
  void invalidate() { invalid_ = true; }
  // A step taken again after it failed: the next step rebuilds the whole matrix.
  void retake() { retake_ = true; }
  bool fresh_on() const { return opt_.w_fresh > 0 && opt_.w_blocks && opt_.w_secant; }
  const FrictionJacobian& friction_jacobian() const { return fjac_; }
  const ChainStiffness& stiffness() const { return stiffness_; }
  std::int64_t status_rebuilds() const { return status_rebuilds_; }
  std::int64_t fresh_contacts() const { return fresh_.joined(); }
  std::int64_t fresh_rebuilds() const { return fresh_rebuilds_; }

 private:
  friend class FreshFriction;  // solves its columns with the factors, the shafts' step included
  using ShaftMatrix = Eigen::Matrix<double, 2 * kShaftSize, 2 * kShaftSize>;
  using ShaftVector = FreshFriction::ShaftVector;
  using ShaftVectors = FreshFriction::ShaftVectors;
  using ShaftBlock = Eigen::Matrix<double, kLinkDim, 2 * kShaftSize>;
  void assemble_link(int l, double gh);
  std::string singular_matrix(double t, long index, double gh) const;
  void link_gradient(int l, LinkVector& g) const;
  void shaft_factor(double gh);
  // The bordered solve's shaft step on x's shafts (right side M_s b_s), their x_s into x.
  ShaftVector shaft_solve(double* x) const;
  // Its x_s for the right side r_s, from the products K_ps,l^T z_l in bz (bz_ by default).
  ShaftVector shaft_unknowns(const ShaftVector& rs) const { return shaft_unknowns(rs, bz_); }
  ShaftVector shaft_unknowns(const ShaftVector& rs, const ShaftVectors& bz) const;
  // K_ps,l^T z_l of link l's solved chain part z_l (rhs_[l]) into bz_[l]: on the solve's
  // tasks, so that shaft_unknowns only sums them. The second form: z and the product of
  // another solve (a fresh-friction contact's second column).
  void shaft_product(int l) const { shaft_product(l, rhs_, bz_); }
  void shaft_product(int l, const LinkVectors& z, ShaftVectors& bz) const;
  void shaft_back(int l, const ShaftVector& xs, LinkVector& z) const;  // z -= Y_l x_s
  ShaftVector shaft_velocities(const double* x) const;  // x's 14 shaft velocities, physical units
  int threads() const { return schedule_.threads(); }

  const Model& m_;
  Workspace& ws_;
  Schedule& schedule_;
  ModelOdeOptions opt_;
  const Eigen::VectorXd& unit_;
  const Eigen::VectorXd& offset_;
  FrictionJacobian fjac_;  // filled by the evaluations that ask
  ChainStiffness stiffness_;
  FreshFriction fresh_;
  Eigen::VectorXd y_;  // the physical state of a scaled system's factor()
  LinkBlock a0_link_;  // A0 of a link's coordinates (constant)
  ChainLU lu_;
  std::vector<int> coord_;           // [l * kLinkDim + i]: link_coordinate(m, l, i)
  std::vector<double> unit_q_, unit_v_;  // the units of those positions and velocities (scaled)
  std::vector<double> unit_ratio_;       // [i < ndof]: unit of velocity i / unit of position i
  std::vector<int> other_coord_;         // the coordinates outside the chain's links (shafts, load)
  mutable LinkVectors rhs_;  // the solve's per-link right sides and solutions
  LinkVectors g_;            // per link: d psi / d(link coordinates) at the last rebuild
  // Per link: the pulley friction's K_ps on its rows (21 x 14, both shafts) at the last
  // rebuild, and whether it is nonzero (the link touches a sheave).
  std::vector<ShaftBlock, Eigen::aligned_allocator<ShaftBlock>> cps_;
  std::vector<std::uint8_t> cps_on_;
  // w_shafts: the shafts' mass matrix M_s (constant), Y = (chain's W)^-1 gh K_ps per link,
  // and the LU of the Schur complement M_s + gh C_ss - gh K_ps^T Y (14 x 14).
  ShaftMatrix ms_;
  std::vector<ShaftBlock, Eigen::aligned_allocator<ShaftBlock>> y_shaft_;
  Eigen::PartialPivLU<ShaftMatrix> schur_;
  mutable ShaftVectors bz_;
  double gh_ = 0;    // gh of the factorization (0: none yet)
  long index_ = 0;   // index of the next step
  bool invalid_ = false, retake_ = false, fresh_recorded_ = false;
  std::int64_t status_rebuilds_ = 0, fresh_rebuilds_ = 0;
};

// A0^-1 restricted to the shafts and the load (a constant 15 x 14 block).
Eigen::MatrixXd a0_shaft_inverse(const Model& m);

}  // namespace cvt
