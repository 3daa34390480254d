// Modal analysis (docs/model.md 9): the model linearized at a state with its contact
// statuses frozen, the natural frequencies of K x = w^2 A x with the part of the CVT that
// dominates each mode, and the spectrum of the first-order Jacobian with the largest
// stable RK4 step it implies.
#pragma once

#include <Eigen/Dense>
#include <complex>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "engine/model/model.hpp"
#include "engine/model/state.hpp"

namespace cvt {

// ---- RK4 stability (docs/model.md 9.4) ----

// RK4's amplification factor R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24 for y' = lambda y, z = h lambda.
std::complex<double> rk4_amplification(std::complex<double> z);
// Where the ray z = r e^{i theta} leaves RK4's stability region: the smallest r > 0 with
// |R(r e^{i theta})| > 1 just beyond it. 2.7853 on the negative real axis (theta = pi),
// 2 sqrt 2 on the imaginary axis (theta = pi/2); 0 for directions into Re z > 0.
double rk4_ray_bound(double theta);
// The largest h with |R(h lambda)| <= 1 on [0, h]: rk4_ray_bound(arg lambda) / |lambda|;
// +infinity for lambda = 0.
double rk4_stable_step(std::complex<double> lambda);

// What a spectrum says about RK4 (eigenvalues of the first-order Jacobian).
struct Rk4Stability {
  double rho = 0;                      // spectral radius max |lambda| [1/s]
  std::complex<double> lambda_rho;     // an eigenvalue with |lambda| = rho
  double h_rho = 0;                    // ray bound along lambda_rho: rk4_stable_step(lambda_rho) [s]
  double h_stable = std::numeric_limits<double>::infinity();  // min over the eigenvalues [s]
  std::complex<double> lambda_limit;   // the eigenvalue that sets h_stable
  int zero = 0;                        // |lambda| <= zero_tol: rigid-body and free coordinates
  int growing = 0;                     // Re lambda > zero_tol: modes that grow in the exact solution too
  double max_growth = 0;               // their largest Re lambda [1/s]
};
// Eigenvalues with Re lambda > zero_tol grow in the exact solution as well, so no step is
// "stable" for them; they are counted and bounded by the imaginary-axis bound of their
// imaginary part (RK4 must at least resolve their oscillation), not by their growth.
Rk4Stability rk4_stability(const Eigen::VectorXcd& eigenvalues, double zero_tol);

// ---- Generic linear algebra ----

// Dense Jacobian df/dx by central differences, column j with step steps[j].
using VectorFunction = std::function<void(const Eigen::VectorXd& x, Eigen::VectorXd& f)>;
Eigen::MatrixXd jacobian_by_differences(const VectorFunction& f, const Eigen::VectorXd& x,
                                        const Eigen::VectorXd& steps);

// K x = w^2 A x for symmetric K and symmetric positive definite A: w^2 ascending, the
// columns of `vectors` A-orthonormal. Throws std::runtime_error if A is not positive definite.
struct GeneralizedModes {
  Eigen::VectorXd omega2;
  Eigen::MatrixXd vectors;
};
GeneralizedModes generalized_modes(const Eigen::MatrixXd& K, const Eigen::MatrixXd& A);

// ---- The CVT model linearized (docs/model.md 9.1) ----

// At the state y (positions q, velocities v) with the statuses frozen: K = -dF/dq,
// C = -dF/dv (generalized forces of 4.0, by central differences), A = A(q) (3.2), and the
// Jacobian J = df/dy of the first-order right-hand side on the coordinates listed in
// `jac_index` (q, v, and the controller integral when the controller is on).
struct Linearization {
  Eigen::MatrixXd K, C, A, J;
  std::vector<int> jac_index;
  int force_evaluations = 0;
  // Entries where the two one-sided differences disagree: the force jumps or kinks at the
  // state (a pair at zero penetration with its damping switching on, a plate at its rest
  // length, friction at |v_t| = v0); there the entry is the one-sided slope of smaller
  // magnitude, 0 if they have opposite signs (9.1).
  long nonsmooth_entries = 0, nonsmooth_jacobian_entries = 0;
  double seconds = 0;  // wall time of the differences
};
Linearization linearize(const Model& m, const ContactStatus& status, double t, const Eigen::VectorXd& y,
                        bool with_jacobian = true);

// d f / d x at x from f(x - h_minus), f(x), f(x + h_plus): the central difference where
// the one-sided ones agree within 10 %, else the smaller one-sided slope (0 for opposite
// signs), with *kinked set.
double smooth_difference(double f_minus, double f0, double f_plus, double h_minus, double h_plus, bool* kinked);

// Finite-difference step for coordinate value `value`: small against the contact
// penetrations (~1e-5 m) and the friction regularization speed (~1e-3 m/s), large against
// the rounding of the forces.
double difference_step(double value);

// ---- Which part of the CVT a mode moves (docs/model.md 9.3) ----

// Kinetic-energy parts of a mode shape x at positions q: x^T A(q) x split over the
// blocks of A0 (3.1) and the link rotations J (g_i^T x)^2. Each part is >= 0 and they sum
// to x^T A(q) x.
enum class PartKind : int {
  kAxialA = 0, kLateralA, kBendingA,  // half a_j: axial (z0, z1), rigid lateral motion, bending
  kAxialB, kLateralB, kBendingB,      // half b_j
  kPack,                              // plate pack s_j
  kLinkRotation,                      // link j
  kChainKinds,                        // (count of the per-joint kinds)
};
struct EnergyParts {
  // [kind][joint]
  std::vector<std::vector<double>> chain;
  // [shaft][0 lateral (ux, uy), 1 axial (uz, w), 2 tilt, 3 rotation phi]
  double shaft[2][4] = {{0, 0, 0, 0}, {0, 0, 0, 0}};
  double load = 0;
  double total() const;
};
EnergyParts energy_parts(const Model& m, const double* q, const Eigen::VectorXd& x);

struct PartShare {
  std::string name;  // e.g. "pins 12-14 half b bending", "driving shaft rotation"
  double share = 0;  // of the modal kinetic energy, 0..1
};
// The two parts with the largest shares: a per-joint kind over the shortest run of
// joints that holds 80 % of that kind's energy (or "all pins"), or a shaft or load part.
std::vector<PartShare> dominant_parts(const Model& m, const EnergyParts& e, int how_many = 2);

// ---- The analysis as the CLI runs it ----

struct ModeRow {
  int index = 0;        // in the ascending list of w^2
  double omega2 = 0;    // [1/s^2]
  double freq_hz = 0;   // sign(w^2) sqrt|w^2| / 2 pi
  std::vector<PartShare> parts;
};

struct ModesOptions {
  int count = 10;            // lowest and highest modes to list
  double rigid_hz = 1.0;     // |f| below this: rigid-body or mechanism mode
  bool jacobian = true;      // also the first-order Jacobian's spectrum
};

struct ModalReport {
  double t = 0;
  int ndof = 0, jac_size = 0;
  int rocker_active = 0, rocker_pairs = 0, pulley_active = 0, pulley_pairs = 0;
  double asymmetry = 0;      // |K - K^T|_F / |K + K^T|_F
  double damping_asymmetry = 0;  // the same for C
  int rigid = 0, negative = 0;   // |f| < rigid_hz; w^2 < 0 beyond it
  // Rigid ones; those with w^2 < 0 beyond the threshold, most negative first; the lowest
  // and highest with w^2 > 0 beyond it.
  std::vector<ModeRow> rigid_modes, negative_modes, lowest, highest;
  int force_evaluations = 0;
  long nonsmooth_entries = 0, nonsmooth_jacobian_entries = 0;
  double t_differences = 0, t_modes = 0, t_eigen_jacobian = 0;  // wall seconds
  bool has_jacobian = false;
  Rk4Stability stability;
  Eigen::VectorXcd jacobian_eigenvalues;
};

ModalReport modal_analysis(const Model& m, const ContactStatus& status, double t, const Eigen::VectorXd& y,
                           const ModesOptions& opt);

// The report as a table (the CLI's output) and as JSON.
std::string format_modal_report(const ModalReport& r, double config_step);
std::string modal_report_json(const ModalReport& r, double config_step);

}  // namespace cvt
