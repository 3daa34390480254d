// Chain forces (docs/model.md 4.1-4.3) against the chain's own invariants: the elastic
// forces of every part (beams, rocker stations, keeper, plates, pack) are minus the
// gradient of that part's energy, written here from the documented formulas; the chain's
// internal forces exert no net force and no net moment about z; an open rocker station and
// a contact without slip exert nothing; the dissipated power is >= 0 and is exactly the
// power of the velocity-dependent forces.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "engine/rhs/rhs.hpp"
#include "modules/chain_forces.hpp"
#include "modules/inertia.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

// ---- The documented geometry, written independently of the kernel (docs/model.md 2-4).

// Layout (2.2): joint j at 21 j: half a (10), half b (10), pack s (1).
int jw(const Model& m, int j) { return ((j % m.links) + m.links) % m.links; }
int ia(const Model& m, int j) { return 21 * jw(m, j); }
int ib(const Model& m, int j) { return 21 * jw(m, j) + 10; }
int is(const Model& m, int j) { return 21 * jw(m, j) + 20; }

// Hermite weights (2.1) on (p0, s_p0, p1, s_p1); half offsets: end 0 x,y,z,sx,sy = 0..4,
// end 1 = 5..9, so plane p has the dofs p, 3 + p, 5 + p, 8 + p.
struct Weights {
  double w[4], dw[4];
};
Weights weights(double xi, double L) {
  Weights h;
  h.w[0] = 1 - 3 * xi * xi + 2 * xi * xi * xi;
  h.w[1] = L * (xi - 2 * xi * xi + xi * xi * xi);
  h.w[2] = 3 * xi * xi - 2 * xi * xi * xi;
  h.w[3] = L * (-xi * xi + xi * xi * xi);
  h.dw[0] = -6 * xi + 6 * xi * xi;
  h.dw[1] = L * (1 - 4 * xi + 3 * xi * xi);
  h.dw[2] = 6 * xi - 6 * xi * xi;
  h.dw[3] = L * (-2 * xi + 3 * xi * xi);
  return h;
}
double lat(const double* h, const Weights& w, int p) {
  return w.w[0] * h[p] + w.w[1] * h[3 + p] + w.w[2] * h[5 + p] + w.w[3] * h[8 + p];
}
double midp(const double* h, int p) { return 0.5 * (h[p] + h[5 + p]); }
double zmid(const double* h) { return 0.5 * (h[2] + h[7]); }

// Link i holds b_i and a_{i+1}: Delta_i = mid(a_{i+1}) - mid(b_i) (3.1).
void link_delta(const Model& m, const double* q, int i, double& dx, double& dy) {
  dx = midp(q + ia(m, i + 1), 0) - midp(q + ib(m, i), 0);
  dy = midp(q + ia(m, i + 1), 1) - midp(q + ib(m, i), 1);
}
void link_dir(const Model& m, const double* q, int i, double& ex, double& ey) {
  double dx, dy;
  link_delta(m, q, i, dx, dy);
  const double l = std::hypot(dx, dy);
  ex = dx / l, ey = dy / l;
}

// Rocker penetration delta at station st of joint j (4.3).
double rocker_delta(const Model& m, const double* q, int j, int st) {
  const Config& c = m.cfg;
  const double kap = 0.5 * c.rocker.half_distance - c.rocker.radius;
  const Weights w = weights((st + 0.5) / c.rocker.stations, c.pin.length);
  double epx, epy, ecx, ecy;
  link_dir(m, q, j - 1, epx, epy);
  link_dir(m, q, j, ecx, ecy);
  const double* a = q + ia(m, j);
  const double* b = q + ib(m, j);
  const double Dx = (lat(a, w, 0) - kap * epx) - (lat(b, w, 0) + kap * ecx);
  const double Dy = (lat(a, w, 1) - kap * epy) - (lat(b, w, 1) + kap * ecy);
  return 2 * c.rocker.radius - std::hypot(Dx, Dy);
}

// Stretch d - l0 of plate k of link i (4.2).
double plate_stretch(const Model& m, const double* q, int i, int k) {
  const Config& c = m.cfg;
  const int npl = c.chain.plates_per_link;
  const double L = c.pin.length;
  const double zeta = npl == 1 ? 0.0 : c.chain.plate_spread * (double(k) / (npl - 1) - 0.5);
  const double Z = q[is(m, i)] + zeta;
  const double* b = q + ib(m, i);
  const double* a = q + ia(m, i + 1);
  const Weights wb = weights(0.5 + (Z - zmid(b)) / L, L), wa = weights(0.5 + (Z - zmid(a)) / L, L);
  const double d = std::hypot(lat(a, wa, 0) - lat(b, wb, 0), lat(a, wa, 1) - lat(b, wb, 1));
  return d - (c.chain.pitch + c.rocker.half_distance);
}

struct ChainEnergy {
  double beam = 0, tilt = 0, rocker = 0, keeper = 0, plates = 0, pack = 0;
  double beam_abs_terms = 0;  // sum of |terms| of U_beam written in absolute coordinates
  double min_abs_delta = std::numeric_limits<double>::infinity();    // over rocker stations
  double min_abs_stretch = std::numeric_limits<double>::infinity();  // over plates
  double total() const { return beam + tilt + rocker + keeper + plates + pack; }
};

// Section 6's chain terms: sum of U_beam, U_tilt = K / (2 L^2) |c|^2, (2/5) c_r delta_+^(5/2), the keeper's
// (1/2) k s^2, (1/2) k_pl (d - l0)_+^2 and (1/2) k_s (s - zbar)^2.
ChainEnergy documented_energy(const Model& m, const double* q) {
  const Config& c = m.cfg;
  const double L = c.pin.length, EA = c.pin.ea, kb = c.pin.ei / (L * L * L);
  ChainEnergy E;
  for (int j = 0; j < m.links; ++j) {
    for (const double* h : {q + ia(m, j), q + ib(m, j)}) {
      const double eps = h[7] - h[2] - L;
      E.beam += 0.5 * EA / L * eps * eps;
      const double K[4][4] = {{12, 6 * L, -12, 6 * L},
                              {6 * L, 4 * L * L, -6 * L, 2 * L * L},
                              {-12, -6 * L, 12, -6 * L},
                              {6 * L, 2 * L * L, -6 * L, 4 * L * L}};
      for (int p = 0; p < 2; ++p) {
        // K annihilates translation (1, 0, 1, 0): the end positions relative to end 0 give
        // the same energy without the round-off of absolute positions (~2e-2 m).
        const double u[4] = {0.0, h[3 + p], h[5 + p] - h[p], h[8 + p]};
        const double abs_u[4] = {h[p], h[3 + p], h[5 + p], h[8 + p]};
        for (int r = 0; r < 4; ++r)
          for (int s = 0; s < 4; ++s) {
            E.beam += 0.5 * kb * u[r] * K[r][s] * u[s];
            E.beam_abs_terms += std::abs(0.5 * kb * abs_u[r] * K[r][s] * abs_u[s]);
          }
      }
      const double cx = h[5] - h[0], cy = h[6] - h[1];
      E.tilt += 0.5 * c.pin.tilt_stiffness / (L * L) * (cx * cx + cy * cy);
    }
    for (int st = 0; st < c.rocker.stations; ++st) {
      const double d = rocker_delta(m, q, j, st);
      E.min_abs_delta = std::min(E.min_abs_delta, std::abs(d));
      if (d > 0) E.rocker += 0.4 * c.rocker.stiffness * std::pow(d, 2.5);
    }
    double epx, epy, ecx, ecy;
    link_dir(m, q, j - 1, epx, epy);
    link_dir(m, q, j, ecx, ecy);
    const double bl = std::hypot(epx + ecx, epy + ecy);
    const double bx = (epx + ecx) / bl, by = (epy + ecy) / bl;
    const double dx = midp(q + ia(m, j), 0) - midp(q + ib(m, j), 0);
    const double dy = midp(q + ia(m, j), 1) - midp(q + ib(m, j), 1);
    const double shear = -by * dx + bx * dy;
    E.keeper += 0.5 * c.rocker.keeper_stiffness * shear * shear;
    for (int k = 0; k < c.chain.plates_per_link; ++k) {
      const double s = plate_stretch(m, q, j, k);
      E.min_abs_stretch = std::min(E.min_abs_stretch, std::abs(s));
      if (s > 0) E.plates += 0.5 * c.chain.plate_stiffness * s * s;
    }
    for (const double* h : {q + ib(m, j), q + ia(m, j + 1)}) {
      const double rel = q[is(m, j)] - zmid(h);
      E.pack += 0.5 * c.chain.pack_stiffness * rel * rel;
    }
  }
  return E;
}

// ---- Running the kernel and reading its slots (4.0).

struct ChainRun {
  std::vector<JointSlot> slots;
  double p_diss = 0;
};

ChainRun run_chain(const Model& m, const Eigen::VectorXd& y, const std::vector<std::uint8_t>* rocker_status = nullptr) {
  Workspace ws(m);
  if (rocker_status) ws.status.rocker = *rocker_status;
  set_stage_input(m, ws, 0.0, y.data());
  link_kinematics(m, ws, 0, m.links);
  chain_forces(m, ws, 0, m.links);
  ChainRun r{ws.chain_slots, 0.0};
  for (const JointSlot& s : r.slots) r.p_diss += s.p_diss;
  return r;
}

// The generalized forces of slot j (or of all slots, j = -1) as a vector over q: f on
// joint j, f_next_a on a_{j+1}, and the link torques through g_i = d psi_i / dq (3.1:
// +n/(2|Delta|) on both ends' x, y of a_{i+1}, the opposite on b_i).
Eigen::VectorXd generalized(const Model& m, const double* q, const std::vector<JointSlot>& slots, int only = -1) {
  Eigen::VectorXd Q = Eigen::VectorXd::Zero(m.ndof);
  const auto torque = [&](int i, double tau) {
    double dx, dy;
    link_delta(m, q, i, dx, dy);
    const double l2 = dx * dx + dy * dy, gx = -0.5 * dy / l2, gy = 0.5 * dx / l2;
    for (int e = 0; e < 2; ++e) {
      Q[ia(m, i + 1) + 5 * e] += tau * gx, Q[ia(m, i + 1) + 5 * e + 1] += tau * gy;
      Q[ib(m, i) + 5 * e] -= tau * gx, Q[ib(m, i) + 5 * e + 1] -= tau * gy;
    }
  };
  for (int j = 0; j < m.links; ++j) {
    if (only >= 0 && j != only) continue;
    const JointSlot& s = slots[j];
    for (int i = 0; i < 21; ++i) Q[21 * j + i] += s.f[i];
    for (int i = 0; i < 10; ++i) Q[ia(m, j + 1) + i] += s.f_next_a[i];
    torque(j - 1, s.tau_prev);
    torque(j, s.tau_own);
    for (int i = 0; i < 14; ++i) Q[21 * m.links + i] += s.shaft[i];
  }
  return Q;
}

// Virtual displacements of the whole chain as a rigid body (translation along x, y, z,
// rotation about z through the origin); shafts and load stay.
enum Rigid { kTransX, kTransY, kTransZ, kRotZ };
Eigen::VectorXd rigid(const Model& m, const double* q, Rigid r) {
  Eigen::VectorXd V = Eigen::VectorXd::Zero(m.ndof);
  for (int j = 0; j < m.links; ++j) {
    for (int o : {ia(m, j), ib(m, j)})
      for (int e = 0; e < 2; ++e) {
        const int b = o + 5 * e;
        switch (r) {
          case kTransX: V[b] = 1; break;
          case kTransY: V[b + 1] = 1; break;
          case kTransZ: V[b + 2] = 1; break;
          case kRotZ:  // x -> -y, y -> x, and the slopes turn with the half
            V[b] = -q[b + 1], V[b + 1] = q[b], V[b + 3] = -q[b + 4], V[b + 4] = q[b + 3];
            break;
        }
      }
    if (r == kTransZ) V[is(m, j)] = 1;
  }
  return V;
}

// Finite-difference step per coordinate: lengths 1e-9 m, slopes 1e-7.
double fd_step(const Model& m, int i) {
  if (i < 21 * m.links) {
    const int r = i % 21;
    if (r < 20 && (r % 5 == 3 || r % 5 == 4)) return 1e-7;
  }
  return 1e-9;
}

// Fourth-order central differences of E over the chain coordinates (the chain's energy
// does not depend on the shafts).
Eigen::VectorXd fd_gradient(const Model& m, const Eigen::VectorXd& y,
                            const std::function<double(const double*)>& E) {
  Eigen::VectorXd g = Eigen::VectorXd::Zero(m.ndof);
  Eigen::VectorXd z = y;
  for (int i = 0; i < 21 * m.links; ++i) {
    const double h = fd_step(m, i);
    const auto at = [&](double d) {
      z[i] = y[i] + d;
      const double e = E(z.data());
      z[i] = y[i];
      return e;
    };
    g[i] = (-at(2 * h) + 8 * at(h) - 8 * at(-h) + at(-2 * h)) / (12 * h);
  }
  return g;
}

enum class Part { beam, tilt, rocker, keeper, plates, pack, all };
const char* name(Part p) {
  switch (p) {
    case Part::beam: return "beam";
    case Part::tilt: return "tilt";
    case Part::rocker: return "rocker";
    case Part::keeper: return "keeper";
    case Part::plates: return "plates";
    case Part::pack: return "pack";
    case Part::all: return "all";
  }
  return "?";
}

// The mini model with only `p` elastic (the other stiffnesses zeroed in the model's copy
// of the configuration, which the kernels read), no damping, no friction.
Model elastic_model(Part p) {
  Model m = test::model("mini", {"damping.scale=0", "friction.law=none"});
  Config& c = m.cfg;
  if (p != Part::beam && p != Part::all) c.pin.ea = 0, c.pin.ei = 0;
  if (p != Part::tilt && p != Part::all) c.pin.tilt_stiffness = 0;
  if (p != Part::rocker && p != Part::all) c.rocker.stiffness = 0;
  if (p != Part::keeper && p != Part::all) c.rocker.keeper_stiffness = 0;
  if (p != Part::plates && p != Part::all) c.chain.plate_stiffness = 0;
  if (p != Part::pack && p != Part::all) c.chain.pack_stiffness = 0;
  return m;
}

double part_energy(const ChainEnergy& E, Part p) {
  switch (p) {
    case Part::beam: return E.beam;
    case Part::tilt: return E.tilt;
    case Part::rocker: return E.rocker;
    case Part::keeper: return E.keeper;
    case Part::plates: return E.plates;
    case Part::pack: return E.pack;
    case Part::all: return E.total();
  }
  return 0;
}

// Positions perturbed by 4 um / 2e-4 rad about the initial state, at rest.
Eigen::VectorXd strained_state(const Model& m, unsigned seed) {
  Eigen::VectorXd y = test::perturbed_state(m, seed, 4e-6, 2e-4, 0.0);
  y.segment(m.ndof, m.ndof).setZero();
  return y;
}

// ---- Tests.

TEST(ChainForcesTest, ChainEnergyIsTheDocumentedSumOfItsParts) {
  const Model m = test::model("mini");
  for (unsigned seed : {1u, 2u}) {
    const Eigen::VectorXd y = strained_state(m, seed);
    const ChainEnergy E = documented_energy(m, y.data());
    EXPECT_GT(E.rocker, 0.0);
    EXPECT_GT(E.plates, 0.0);
    EXPECT_GT(E.keeper, 0.0);
    EXPECT_GT(E.tilt, 0.0);
    // The kernel sums U_beam in absolute lateral coordinates (~2e-2 m, terms of ~1e2 J that
    // cancel): round-off ~1e-16 of those terms, besides 1e-16 per term of the rest.
    EXPECT_NEAR(chain_energy(m, y.data()), E.total(), 1e-15 * E.beam_abs_terms + 1e-13 * E.total())
        << "seed " << seed;
  }
}

class ChainPartGradientTest : public ::testing::TestWithParam<Part> {};

TEST_P(ChainPartGradientTest, ElasticForcesAreMinusTheEnergyGradient) {
  const Part part = GetParam();
  const Model m = elastic_model(part);
  for (unsigned seed : {1u, 2u}) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    const Eigen::VectorXd y = strained_state(m, seed);
    const ChainEnergy E0 = documented_energy(m, y.data());
    // delta^(3/2) and (d - l0)_+ are not smooth at 0: a difference stencil (+-2 h, under
    // 4e-9 m of delta or stretch) must not straddle a contact or slack switch.
    if (part == Part::rocker || part == Part::all) {
      ASSERT_GT(E0.min_abs_delta, 1e-8);
    }
    if (part == Part::plates || part == Part::all) {
      ASSERT_GT(E0.min_abs_stretch, 1e-8);
    }
    const Eigen::VectorXd Q = generalized(m, y.data(), run_chain(m, y).slots);
    const Eigen::VectorXd g =
        fd_gradient(m, y, [&](const double* q) { return part_energy(documented_energy(m, q), part); });
    const double scale = Q.cwiseAbs().maxCoeff();
    int worst = 0;
    const double err = (Q + g).cwiseAbs().maxCoeff(&worst);
    std::printf("[%s, seed %u] max |F| = %.4g, max |F + grad E| / max |F| = %.3g\n", name(part), seed, scale,
                err / scale);
    EXPECT_GT(scale, 1e-2) << "the state must load this part";
    // 4th-order differences: truncation ~h^4, round-off ~1e-16 E/h, both < 1e-9 of max|F|;
    // 1e-7 leaves room for the Hertz law's large higher derivatives near small delta.
    EXPECT_LE(err, 1e-7 * scale) << "coordinate " << worst << ": F = " << Q[worst] << ", -grad E = " << -g[worst];
    // Shafts and load take nothing from the chain.
    EXPECT_EQ(Q.tail(m.ndof - 21 * m.links).cwiseAbs().maxCoeff(), 0.0);
  }
}

INSTANTIATE_TEST_SUITE_P(Parts, ChainPartGradientTest,
                         ::testing::Values(Part::beam, Part::tilt, Part::rocker, Part::keeper, Part::plates, Part::pack,
                                           Part::all),
                         [](const ::testing::TestParamInfo<Part>& i) { return std::string(name(i.param)); });

// Action and reaction within one joint: its rocker contact (both faces, the faces' turning
// with links j-1 and j) is an internal force of the chain, invariant under rigid motion.
TEST(ChainForcesTest, OneJointsRockerContactExertsNoNetForceOrMoment) {
  const Model m = elastic_model(Part::rocker);
  const Eigen::VectorXd y = strained_state(m, 3);
  const int nst = m.cfg.rocker.stations;
  int loaded = 0;
  for (int j = 0; j < m.links; ++j) {
    std::vector<std::uint8_t> status(m.links * nst, 0);
    for (int st = 0; st < nst; ++st) status[j * nst + st] = 1;
    const Eigen::VectorXd Q = generalized(m, y.data(), run_chain(m, y, &status).slots);
    double scale = 0;
    for (int i = 0; i < m.ndof; ++i) scale = std::max(scale, std::abs(Q[i]) * (std::abs(y[i]) + 1.0));
    if (scale == 0) continue;  // no station of this joint penetrates
    ++loaded;
    for (Rigid r : {kTransX, kTransY, kTransZ, kRotZ}) {
      const Eigen::VectorXd V = rigid(m, y.data(), r);
      const double work = Q.dot(V), size = Q.cwiseProduct(V).cwiseAbs().sum();
      // Round-off of a sum of ~100 products.
      EXPECT_LE(std::abs(work), 1e-12 * size + 1e-300) << "joint " << j << " rigid mode " << r;
    }
    // Nothing outside the halves and links of joint j: halves a_j, b_j and, through the
    // link torques, b_{j-1} and a_{j+1}.
    for (int i = 0; i < m.ndof; ++i) {
      const bool own = (i >= 21 * j && i < 21 * j + 20) || (i >= ib(m, j - 1) && i < ib(m, j - 1) + 10) ||
                       (i >= ia(m, j + 1) && i < ia(m, j + 1) + 10);
      if (!own) {
        EXPECT_EQ(Q[i], 0.0) << "joint " << j << " coordinate " << i;
      }
    }
  }
  EXPECT_GE(loaded, 5) << "too few penetrating joints for the test to mean something";
}

// The same for all the chain's forces together, with damping and friction on, in motion.
TEST(ChainForcesTest, ChainInternalForcesSumToZeroForceAndMoment) {
  Model m = test::model("mini");
  // The beams' stiffness-proportional damping -beta K v acts on absolute lateral
  // coordinates (docs/model.md 4.1): a bent half whose bending turns about z meets a
  // damping moment about z (~1e-10 of the forces here), so it is left out; translation
  // and the elastic beam forces are invariant.
  m.beam_beta = 0;
  for (unsigned seed : {4u, 5u}) {
    const Eigen::VectorXd y = test::perturbed_state(m, seed, 4e-6, 2e-4, 0.05);
    const ChainRun r = run_chain(m, y);
    const Eigen::VectorXd Q = generalized(m, y.data(), r.slots);
    EXPECT_GT(r.p_diss, 0.0);
    for (Rigid mode : {kTransX, kTransY, kTransZ, kRotZ}) {
      const Eigen::VectorXd V = rigid(m, y.data(), mode);
      const double work = Q.dot(V), size = Q.cwiseProduct(V).cwiseAbs().sum();
      std::printf("[seed %u] rigid mode %d: |Q . V| = %.3g of sum |Q_i V_i| = %.3g\n", seed, mode, std::abs(work),
                  size);
      // Round-off of a sum of ~1e3 products of mixed sign.
      EXPECT_LE(std::abs(work), 1e-11 * size) << "seed " << seed << " rigid mode " << mode;
    }
  }
}

// A station whose faces are apart (delta < 0) exerts nothing, even while they approach
// (the damping part is off too) and slide: the slots equal those with the station switched off.
TEST(ChainForcesTest, OpenRockerStationGivesNoForce) {
  const Model m = test::model("mini");
  const int nst = m.cfg.rocker.stations, j = 7;
  Eigen::VectorXd y = m.y0;
  // Move a_j away from b_j by 1 um along the joint's contact normal, approaching at 0.1 m/s
  // and sliding axially at 0.2 m/s.
  double mx = midp(y.data() + ia(m, j), 0) - midp(y.data() + ib(m, j), 0);
  double my = midp(y.data() + ia(m, j), 1) - midp(y.data() + ib(m, j), 1);
  const double ml = std::hypot(mx, my);
  mx /= ml, my /= ml;
  const auto place = [&](double gap, double vn) {
    Eigen::VectorXd z = y;
    for (int e = 0; e < 2; ++e) {
      const int b = ia(m, j) + 5 * e;
      z[b] += gap * mx, z[b + 1] += gap * my;
      z[m.ndof + b] += vn * mx, z[m.ndof + b + 1] += vn * my, z[m.ndof + b + 2] += 0.2;
    }
    return z;
  };
  const Eigen::VectorXd open = place(1e-6, -0.1);
  for (int st = 0; st < nst; ++st) ASSERT_LT(rocker_delta(m, open.data(), j, st), -5e-7);
  std::vector<std::uint8_t> off(m.links * nst, 1);
  for (int st = 0; st < nst; ++st) off[j * nst + st] = 0;
  const ChainRun with = run_chain(m, open), without = run_chain(m, open, &off);
  for (int k = 0; k < m.links; ++k) {
    const JointSlot &a = with.slots[k], &b = without.slots[k];
    for (int i = 0; i < 21; ++i) EXPECT_EQ(a.f[i], b.f[i]) << "joint " << k << " coordinate " << i;
    for (int i = 0; i < 10; ++i) EXPECT_EQ(a.f_next_a[i], b.f_next_a[i]) << "joint " << k;
    EXPECT_EQ(a.tau_prev, b.tau_prev) << "joint " << k;
    EXPECT_EQ(a.tau_own, b.tau_own) << "joint " << k;
    EXPECT_EQ(a.p_diss, b.p_diss) << "joint " << k;
  }
  // The same joint closed by 1 um does push: the comparison above is not vacuous.
  const Eigen::VectorXd closed = place(-1e-6, -0.1);
  const ChainRun c_with = run_chain(m, closed), c_without = run_chain(m, closed, &off);
  EXPECT_GT(std::abs(c_with.slots[j].f[0] - c_without.slots[j].f[0]), 1.0);
}

// Rigid motion of the whole chain (translation and rotation about z, the halves turning
// with their links): no slip at any rocker station, so no friction force and no dissipation.
TEST(ChainForcesTest, ContactWithoutSlipGivesNoFrictionForce) {
  // The beams' damping is left out: it acts on absolute lateral coordinates (docs/model.md
  // 4.1), so a bent half spinning about z is damped even in rigid motion.
  Model m = test::model("mini"), nofric = test::model("mini", {"friction.law=none"});
  m.beam_beta = nofric.beam_beta = 0;
  Eigen::VectorXd y = strained_state(m, 6);
  const Eigen::VectorXd V = rigid(m, y.data(), kRotZ) * 200.0 + rigid(m, y.data(), kTransX) * 1.0 +
                            rigid(m, y.data(), kTransY) * -2.0 + rigid(m, y.data(), kTransZ) * 0.5;
  y.segment(m.ndof, m.ndof) = V;
  const ChainRun r = run_chain(m, y), r0 = run_chain(nofric, y);
  const Eigen::VectorXd Q = generalized(m, y.data(), r.slots), Q0 = generalized(m, y.data(), r0.slots);
  const double scale = Q0.cwiseAbs().maxCoeff();
  std::printf("rigid motion: max |F_fric| = %.3g of max |F| = %.4g, p_diss = %.3g W\n",
              (Q - Q0).cwiseAbs().maxCoeff(), scale, r.p_diss);
  EXPECT_GT(scale, 1.0);
  // The slip is zero up to round-off of velocities ~10 m/s (~1e-15 m/s); friction's stick
  // slope f0 N / v0 turns that into ~1e-10 N at most.
  EXPECT_LE((Q - Q0).cwiseAbs().maxCoeff(), 1e-9 * scale);
  EXPECT_LE(std::abs(r.p_diss), 1e-9);
  // A small relative velocity (1 mm/s on one half) does make friction: not vacuous.
  Eigen::VectorXd slip = y;
  for (int e = 0; e < 2; ++e) slip[m.ndof + ia(m, 0) + 5 * e + 2] += 1e-3;
  const Eigen::VectorXd Qs = generalized(m, slip.data(), run_chain(m, slip).slots);
  const Eigen::VectorXd Qs0 = generalized(m, slip.data(), run_chain(nofric, slip).slots);
  EXPECT_GT((Qs - Qs0).cwiseAbs().maxCoeff(), 1e-3);
}

// p_diss >= 0 per joint, and it is exactly the power lost by the velocity-dependent forces:
// p_diss_j = -(Q_j(q, v) - Q_j(q, 0)) . v, Q_j slot j's generalized forces (damping and
// friction act through the same Jacobians as the velocities they use).
TEST(ChainForcesTest, DissipatedPowerIsNonNegativeAndThePowerOfTheDampingAndFrictionForces) {
  const Model m = test::model("mini");
  struct Case {
    unsigned seed;
    double dv;  // velocity perturbation: 1e-4 m/s leaves many stations sticking (v0 = 1e-3)
  };
  for (const Case c : {Case{7, 0.05}, Case{8, 1e-4}, Case{9, 0.5}}) {
    const Eigen::VectorXd y = test::perturbed_state(m, c.seed, 4e-6, 2e-4, c.dv);
    Eigen::VectorXd y_rest = y;
    y_rest.segment(m.ndof, m.ndof).setZero();
    const ChainRun r = run_chain(m, y), r0 = run_chain(m, y_rest);
    const double* v = y.data() + m.ndof;
    double worst = 0;
    for (int j = 0; j < m.links; ++j) {
      EXPECT_GE(r.slots[j].p_diss, 0.0) << "joint " << j;
      const Eigen::VectorXd Qnc =
          generalized(m, y.data(), r.slots, j) - generalized(m, y.data(), r0.slots, j);
      double power = 0, size = 0;
      for (int i = 0; i < m.ndof; ++i) power += Qnc[i] * v[i], size += std::abs(Qnc[i] * v[i]);
      // Round-off of ~50 products of mixed sign.
      EXPECT_NEAR(r.slots[j].p_diss, -power, 1e-10 * size + 1e-13) << "seed " << c.seed << " joint " << j;
      worst = std::max(worst, std::abs(r.slots[j].p_diss + power) / std::max(size, 1e-300));
    }
    std::printf("[seed %u, dv %.0e] p_diss = %.4g W, worst |p_j + Q_nc,j . v| / sum|Q v| = %.3g\n", c.seed, c.dv,
                r.p_diss, worst);
    EXPECT_GT(r.p_diss, 0.0);
  }
}

}  // namespace
}  // namespace cvt
