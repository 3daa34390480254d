// docs/model.md 4.1 (beams), 4.2 (plates, pack), 4.3 (rocker joints).
#include "modules/chain_forces.hpp"

#include <algorithm>
#include <cmath>

#include <Eigen/Dense>

#include "modules/beam.hpp"
#include "modules/contact_laws.hpp"
#include "modules/damping.hpp"

namespace cvt {
namespace {

// 4.1: bending stiffness of one plane in (w1, s1, w2, s2), times EI/L^3.
inline void bend_stiffness_times(double L, const double u[4], double out[4]) {
  out[0] = 12 * u[0] + 6 * L * u[1] - 12 * u[2] + 6 * L * u[3];
  out[1] = 6 * L * u[0] + 4 * L * L * u[1] - 6 * L * u[2] + 2 * L * L * u[3];
  out[2] = -12 * u[0] - 6 * L * u[1] + 12 * u[2] - 6 * L * u[3];
  out[3] = 6 * L * u[0] + 2 * L * L * u[1] - 6 * L * u[2] + 4 * L * L * u[3];
}

}  // namespace

// 4.1: beam forces of one half; returns the dissipated power.
double beam(const Model& m, const double* q, const double* v, double* f) {
  const double L = m.L0, EA = m.cfg.pin.ea, k_b = m.cfg.pin.ei / (L * L * L);
  const double beta = m.beam_beta;
  double p = 0;
  const double eps = q[half::kEnd + half::kZ] - q[half::kZ] - L;
  const double eps_dot = v[half::kEnd + half::kZ] - v[half::kZ];
  const double Nax = EA / L * (eps + beta * eps_dot);
  f[half::kZ] += Nax;
  f[half::kEnd + half::kZ] -= Nax;
  p += beta * EA / L * eps_dot * eps_dot;
  for (int pl = 0; pl < 2; ++pl) {
    const auto d = plane_dofs(pl);
    double u[4], ud[4], ku[4], kud[4];
    for (int i = 0; i < 4; ++i) {
      u[i] = q[d[i]];
      ud[i] = v[d[i]];
    }
    bend_stiffness_times(L, u, ku);
    bend_stiffness_times(L, ud, kud);
    for (int i = 0; i < 4; ++i) {
      f[d[i]] -= k_b * (ku[i] + beta * kud[i]);
      p += beta * k_b * ud[i] * kud[i];
    }
  }
  return p;
}

namespace {

double tilt_energy(const Model& m, const double* q) {
  const double K = m.cfg.pin.tilt_stiffness / (m.L0 * m.L0);
  double E = 0;
  for (int c = 0; c < 2; ++c) {
    const double d = q[half::kEnd + half::kX + c] - q[half::kX + c];
    E += 0.5 * K * d * d;
  }
  return E;
}

double beam_energy(const Model& m, const double* q) {
  const double L = m.L0, EA = m.cfg.pin.ea, k_b = m.cfg.pin.ei / (L * L * L);
  const double eps = q[half::kEnd + half::kZ] - q[half::kZ] - L;
  double E = 0.5 * EA / L * eps * eps;
  for (int pl = 0; pl < 2; ++pl) {
    const auto d = plane_dofs(pl);
    double u[4], ku[4];
    for (int i = 0; i < 4; ++i) u[i] = q[d[i]];
    bend_stiffness_times(L, u, ku);
    for (int i = 0; i < 4; ++i) E += 0.5 * k_b * u[i] * ku[i];
  }
  return E;
}

// 4.2: where plate k of link j meets a half: parameter xi = 1/2 + (s + zeta - z_mid)/L0.
struct PlatePoint {
  HermiteWeights h;
  double x, y;    // lateral position
  double vx, vy;  // its rate (including the rate of xi)
  double dx_dxi, dy_dxi;
};

inline PlatePoint plate_point(const Model& m, const double* hq, const double* hv, double Z, double Zdot) {
  const double zm = 0.5 * (hq[half::kZ] + hq[half::kEnd + half::kZ]);
  const double zmd = 0.5 * (hv[half::kZ] + hv[half::kEnd + half::kZ]);
  const double xi = 0.5 + (Z - zm) / m.L0;
  const double xid = (Zdot - zmd) / m.L0;
  PlatePoint p;
  p.h = hermite(xi, m.L0);
  p.x = lateral(hq, p.h, 0);
  p.y = lateral(hq, p.h, 1);
  p.dx_dxi = lateral_dxi(hq, p.h, 0);
  p.dy_dxi = lateral_dxi(hq, p.h, 1);
  p.vx = lateral(hv, p.h, 0) + p.dx_dxi * xid;
  p.vy = lateral(hv, p.h, 1) + p.dy_dxi * xid;
  return p;
}

struct PlateEval {
  PlatePoint b, a;
  double ux, uy, stretch, rate;
};

inline PlateEval plate_eval(const Model& m, const double* qb, const double* vb, const double* qa,
                            const double* va, double s, double sd, double zeta) {
  PlateEval e;
  e.b = plate_point(m, qb, vb, s + zeta, sd);
  e.a = plate_point(m, qa, va, s + zeta, sd);
  const double dx = e.a.x - e.b.x, dy = e.a.y - e.b.y;
  const double d = std::sqrt(dx * dx + dy * dy), inv = 1.0 / d;
  e.ux = dx * inv;
  e.uy = dy * inv;
  e.stretch = d - m.plate_rest;
  e.rate = e.ux * (e.a.vx - e.b.vx) + e.uy * (e.a.vy - e.b.vy);
  return e;
}

// 4.2, fast form: the lateral position of a half at xi, sum_i w_i(xi) q_i, as the cubic
// c0 + c1 xi + c2 xi^2 + c3 xi^3 (the Hermite weights of beam.hpp expanded in xi).
struct Cubic {
  double c0, c1, c2, c3;
};
inline Cubic cubic_of(const double* hq, int plane, double L) {
  const auto d = plane_dofs(plane);
  const double q0 = hq[d[0]], q1 = hq[d[1]], q2 = hq[d[2]], q3 = hq[d[3]];
  return {q0, L * q1, -3 * q0 - 2 * L * q1 + 3 * q2 - L * q3, 2 * q0 + L * q1 - 2 * q2 + L * q3};
}
// Its value and slope at four parameters at once, and the sum of four lanes in a fixed order.
inline Eigen::Array4d at4(const Cubic& c, const Eigen::Array4d& x) { return c.c0 + x * (c.c1 + x * (c.c2 + x * c.c3)); }
inline Eigen::Array4d slope4(const Cubic& c, const Eigen::Array4d& x) {
  return c.c1 + x * (2 * c.c2 + x * (3 * c.c3));
}
inline double lanes(const Eigen::Array4d& a) { return (a[0] + a[1]) + (a[2] + a[3]); }
// Generalized forces on (x1, sx1, x2, sx2) of one plane from the moments M_p = sum f xi^p
// of lateral forces f applied at parameters xi: sum_p (coefficient of xi^p in w_i) M_p.
inline void add_moments(double* hf, int plane, double L, const double M[4]) {
  const auto d = plane_dofs(plane);
  hf[d[0]] += M[0] - 3 * M[2] + 2 * M[3];
  hf[d[1]] += L * (M[1] - 2 * M[2] + M[3]);
  hf[d[2]] += 3 * M[2] - 2 * M[3];
  hf[d[3]] += L * (M[3] - M[2]);
}

// config.cpp limits rocker.stations to 16, chain.plates_per_link to 64 (16 groups of four).
constexpr int kMaxStations = 16;
constexpr int kMaxPlateGroups = 16;

// 4.3: rocker geometry at one station.
struct RockerEval {
  HermiteWeights h;
  double xi;
  double pax, pay, pbx, pby;  // half centre lines at the station
  double mx, my;              // unit normal from b to a
  double pen, pen_rate;       // penetration Delta and its rate
  double lvax, lvay, lvbx, lvby;  // lateral velocities of the centre lines at the station
};

inline RockerEval rocker_eval(const Model& m, const LinkKinematics& k, const double* qa, const double* va,
                              const double* qb, const double* vb, int lp, int lc, double xi,
                              const HermiteWeights& h) {
  RockerEval r;
  r.xi = xi;
  r.h = h;
  r.pax = lateral(qa, r.h, 0);
  r.pay = lateral(qa, r.h, 1);
  r.pbx = lateral(qb, r.h, 0);
  r.pby = lateral(qb, r.h, 1);
  const double kap = m.kappa;
  // C_a = P_a - kappa e_prev, C_b = P_b + kappa e_own.
  const double cax = r.pax - kap * k.ex[lp], cay = r.pay - kap * k.ey[lp];
  const double cbx = r.pbx + kap * k.ex[lc], cby = r.pby + kap * k.ey[lc];
  const double Dx = cax - cbx, Dy = cay - cby;
  const double dist = std::sqrt(Dx * Dx + Dy * Dy), inv = 1.0 / dist;
  r.mx = Dx * inv;
  r.my = Dy * inv;
  r.pen = 2 * m.cfg.rocker.radius - dist;
  r.lvax = lateral(va, r.h, 0);
  r.lvay = lateral(va, r.h, 1);
  r.lvbx = lateral(vb, r.h, 0);
  r.lvby = lateral(vb, r.h, 1);
  // e_dot = psi_dot n, n = (-ey, ex).
  const double cadx = r.lvax + kap * k.psi_dot[lp] * k.ey[lp];
  const double cady = r.lvay - kap * k.psi_dot[lp] * k.ex[lp];
  const double cbdx = r.lvbx - kap * k.psi_dot[lc] * k.ey[lc];
  const double cbdy = r.lvby + kap * k.psi_dot[lc] * k.ex[lc];
  r.pen_rate = -(r.mx * (cadx - cbdx) + r.my * (cady - cbdy));
  return r;
}

// The slip at a rocker station (4.3): the levers from the halves' centre lines at the
// station to the contact point P = C_b + R_r m, and the faces' sliding velocity u (a's less
// b's, each half turning with its link) tangential to m; returns |u|.
struct RockerSlip {
  double rax, ray, rbx, rby;
  double u[3];
};

inline double rocker_slip(const Model& m, const LinkKinematics& kin, const RockerEval& r, const double* va,
                          const double* vb, int lp, int lc, RockerSlip& w) {
  const double px = r.pbx + m.kappa * kin.ex[lc] + m.cfg.rocker.radius * r.mx;
  const double py = r.pby + m.kappa * kin.ey[lc] + m.cfg.rocker.radius * r.my;
  w.rax = px - r.pax, w.ray = py - r.pay, w.rbx = px - r.pbx, w.rby = py - r.pby;
  const double xi = r.xi;
  const double vax = r.lvax - kin.psi_dot[lp] * w.ray;
  const double vay = r.lvay + kin.psi_dot[lp] * w.rax;
  const double vaz = (1 - xi) * va[half::kZ] + xi * va[half::kEnd + half::kZ];
  const double vbx = r.lvbx - kin.psi_dot[lc] * w.rby;
  const double vby = r.lvby + kin.psi_dot[lc] * w.rbx;
  const double vbz = (1 - xi) * vb[half::kZ] + xi * vb[half::kEnd + half::kZ];
  double wx = vax - vbx, wy = vay - vby;
  const double wz = vaz - vbz;
  const double wn = wx * r.mx + wy * r.my;
  wx -= wn * r.mx;
  wy -= wn * r.my;
  w.u[0] = wx, w.u[1] = wy, w.u[2] = wz;
  return std::sqrt(wx * wx + wy * wy + wz * wz);
}

// FrictionJacobian blocks / mu: G (u = G v, zeroed by the caller) of the slip
// velocity u = v_a - v_b at a rocker station as a function of the four halves it moves (b_{j-1}: 0..9, a_j: 10..19, b_j: 20..29, a_{j+1}:
// 30..39): the centre lines' velocities at the station, their axial rates, and the link
// spins psi_dot_{j-1} (a_j turns with link j-1: +n/(2|Delta|) through a_j's mid-point,
// -n/(2|Delta|) through b_{j-1}'s) and psi_dot_j (b_j with link j: -n/(2|Delta|) through
// b_j's mid-point, +n/(2|Delta|) through a_{j+1}'s), each times the sign of its side in u.
void rocker_slip_columns(const LinkKinematics& kin, const RockerEval& r, int lp, int lc, double rax, double ray,
                         double rbx, double rby, double (*G)[3]) {
  for (int side = 0; side < 2; ++side) {
    const int o = side == 0 ? 10 : 20;     // the joint's own half
    const int other = side == 0 ? 0 : 30;  // the other half of the link that holds it
    const double sg = side == 0 ? 1.0 : -1.0;  // u = v_a - v_b
    for (int pl = 0; pl < 2; ++pl) {
      const auto d = plane_dofs(pl);
      for (int i = 0; i < 4; ++i) G[o + d[i]][pl] += sg * r.h.w[i];
    }
    G[o + half::kZ][2] += sg * (1 - r.xi);
    G[o + half::kEnd + half::kZ][2] += sg * r.xi;
    // psi_dot (-r_y, r_x, 0).
    const int l = side == 0 ? lp : lc;
    const double c = (side == 0 ? 0.5 : -0.5) * kin.inv_len[l];
    const double nx = -kin.ey[l], ny = kin.ex[l];
    const double lx = side == 0 ? -ray : -rby, ly = side == 0 ? rax : rbx;
    add_spin_columns(G + o, sg * c, nx, ny, lx, ly);
    add_spin_columns(G + other, -sg * c, nx, ny, lx, ly);
  }
}

// The chain's constants of one call (docs/model.md 4.1-4.3), with what is the same for
// every joint computed once: the stations' Hermite weights and the plates' offsets.
struct ChainConstants {
  using A4 = Eigen::Array4d;
  double kpl, cpl, crk, brk, ks, cs, kkeep;
  double ktilt, beta;  // the tilt hold per unit lateral offset, K / L0^2, and its damping time
  FrictionLaw law;
  double f0, v0;
  int nst, groups;
  HermiteWeights sh[kMaxStations];  // the stations sit at fixed xi
  // The plates' offsets in groups of four; the last group padded with the first plate's
  // offset and valid = 0.
  A4 zeta4[kMaxPlateGroups], valid4[kMaxPlateGroups];
  explicit ChainConstants(const Model& m) {
    const Config& c = m.cfg;
    const Damping d = damping(m);
    kpl = c.chain.plate_stiffness, cpl = d.plate;
    crk = c.rocker.stiffness, brk = d.rocker;
    ks = c.chain.pack_stiffness, cs = d.pack;
    kkeep = c.rocker.keeper_stiffness;
    ktilt = c.pin.tilt_stiffness / (m.L0 * m.L0), beta = m.beam_beta;
    law = c.friction.law;
    f0 = c.friction.f0, v0 = c.friction.v0;
    nst = c.rocker.stations;
    for (int st = 0; st < nst; ++st) sh[st] = hermite(m.station_xi[st], m.L0);
    const int npl = static_cast<int>(m.plate_zeta.size());
    groups = (npl + 3) / 4;
    for (int g = 0; g < groups; ++g)
      for (int l = 0; l < 4; ++l) {
        const bool in = 4 * g + l < npl;
        zeta4[g][l] = m.plate_zeta[in ? 4 * g + l : 0];
        valid4[g][l] = in ? 1.0 : 0.0;
      }
  }
};

// 4.1: the plate holes' hold on the tilt of one half, E = K / (2 L0^2) |c|^2 with c the
// lateral offset of end 1 from end 0, damped like the beam (beta); returns the dissipated power.
double tilt(const ChainConstants& k, const double* q, const double* v, double* f) {
  double p = 0;
  for (int c = 0; c < 2; ++c) {
    const double d = q[half::kEnd + half::kX + c] - q[half::kX + c];
    const double dd = v[half::kEnd + half::kX + c] - v[half::kX + c];
    const double F = k.ktilt * (d + k.beta * dd);
    f[half::kEnd + half::kX + c] -= F;
    f[half::kX + c] += F;
    p += k.beta * k.ktilt * dd * dd;
  }
  return p;
}

// What joint j's parts read and write: the halves a_j and b_j, a_{j+1} (the other end of
// link j's plates), the pack s_j, and the slot's force entries.
struct JointHalves {
  const double *qa, *va, *qb, *vb, *qn, *vn;
  double sq, sv;
  double *fa, *fb, *fs, *fn;
  JointHalves(const Model& m, const Workspace& ws, int j, JointSlot& s)
      : qa(ws.q + m.half_a(j)), va(ws.v + m.half_a(j)), qb(ws.q + m.half_b(j)), vb(ws.v + m.half_b(j)),
        qn(ws.q + m.half_a(j + 1)), vn(ws.v + m.half_a(j + 1)), sq(ws.q[m.pack(j)]), sv(ws.v[m.pack(j)]),
        fa(s.f.data() + kJointA), fb(s.f.data() + kJointB), fs(s.f.data() + kJointS), fn(s.f_next_a.data()) {}
};

// 4.3 the rocker joint j (its active stations; a_j turns with link j-1, b_j with link j):
// Hertz normal force with damping, friction on the sliding of the faces (under its frozen
// branch if x.frozen), and what x.jacobian asks for (the W-method's friction part).
void rocker_stations(const Model& m, const ChainConstants& k, Workspace& ws, const FrictionExtras& x, int j,
                     const JointHalves& h, JointSlot& s) {
  const LinkKinematics& kin = ws.kin;
  const double crk = k.crk, brk = k.brk;
  const FrictionLaw law = k.law;
  const double f0 = k.f0, v0 = k.v0;
  const int nst = k.nst;
  const HermiteWeights* sh = k.sh;
  const double *qa = h.qa, *va = h.va, *qb = h.qb, *vb = h.vb;
  double *fa = h.fa, *fb = h.fb;
  const int lp = m.wrap(j - 1), lc = j;
  FrictionJacobian* jac = x.jacobian;
  constexpr int kD = FrictionJacobian::kDim;
  double* Kd = jac && jac->blocks ? jac->rocker_damping.data() + static_cast<std::size_t>(j) * kD * kD : nullptr;
  if (Kd) std::fill(Kd, Kd + kD * kD, 0.0);
  const bool rec_mu = jac && jac->mu;
  if (rec_mu) jac->rocker_fresh.clear(j * nst, nst, Kd != nullptr);
  for (int st = 0; st < nst; ++st) {
    if (!ws.status.rocker[j * nst + st]) continue;
    const RockerEval r = rocker_eval(m, kin, qa, va, qb, vb, lp, lc, m.station_xi[st], sh[st]);
    const double Nel = hertz_force(crk, r.pen);
    const double N = Nel + (r.pen > 0 ? brk * r.pen_rate : 0.0);
    s.p_diss += (N - Nel) * r.pen_rate;
    // Normal: F_a = N m, F_b = -N m; link torques -N kappa (m . n).
    s.tau_prev += -N * m.kappa * (r.mx * -kin.ey[lp] + r.my * kin.ex[lp]);
    s.tau_own += -N * m.kappa * (r.mx * -kin.ey[lc] + r.my * kin.ex[lc]);
    double Rx = 0, Ry = 0;  // friction on a (lateral part)
    if (Nel > 0 && law != FrictionLaw::none) {
      // Friction on the sliding of the two faces at the contact point P = C_b + R_r m.
      RockerSlip sl;
      const double speed = rocker_slip(m, kin, r, va, vb, lp, lc, sl);
      const double *u = sl.u, rax = sl.rax, ray = sl.ray, rbx = sl.rbx, rby = sl.rby, xi = r.xi;
      const int idx = j * nst + st;
      const double nrm[3] = {r.mx, r.my, 0.0};
      double Rv[3];
      s.p_diss +=
          contact_friction(rocker_branch(x.frozen, idx), law, f0, v0, Nel, u, speed, nrm, Rv);
      Rx = Rv[0], Ry = Rv[1];
      const double Rz = Rv[2];
      if (Kd || rec_mu) {
        const double mu = Nel * friction_over_speed(law, f0, v0, speed);
        const bool cols = rec_mu && jac->rocker_fresh.note(idx, mu, Kd != nullptr, jac->mu_tol);
        if (Kd || cols) {
          double G[kD][3] = {};
          rocker_slip_columns(kin, r, lp, lc, rax, ray, rbx, rby, G);
          if (Kd)
            add_friction_damping(Kd, kD, G, nrm, u, speed, mu,
                                 jac->secant ? mu : Nel * friction_slope(law, f0, v0, speed));
          if (cols) {
            double* U = jac->rocker_fresh.columns(idx);
            friction_columns(kD, G, nrm, u, speed, U, U + kD);
          }
        }
      }
      fa[half::kZ] += (1 - xi) * Rz;
      fa[half::kEnd + half::kZ] += xi * Rz;
      fb[half::kZ] -= (1 - xi) * Rz;
      fb[half::kEnd + half::kZ] -= xi * Rz;
      s.tau_prev += rax * Ry - ray * Rx;
      s.tau_own -= rbx * Ry - rby * Rx;
    }
    // Normal and friction act at the same station: one Hermite distribution each plane.
    const double Fx = N * r.mx + Rx, Fy = N * r.my + Ry;
    add_lateral(fa, r.h, 0, Fx);
    add_lateral(fa, r.h, 1, Fy);
    add_lateral(fb, r.h, 0, -Fx);
    add_lateral(fb, r.h, 1, -Fy);
  }
}

// 4.3 the rolling keeper of joint j: s = nbar . (mid(a_j) - mid(b_j)), nbar normal to the
// bisector of e_{j-1} and e_j; ds/dpsi_{j-1} = ds/dpsi_j = -(1/2) ebar . (mid(a) - mid(b)).
void keeper(const Model& m, const ChainConstants& k, const LinkKinematics& kin, int j, const JointHalves& h,
            JointSlot& s) {
  const double kkeep = k.kkeep;
  const int lp = m.wrap(j - 1), lc = j;
  const double *qa = h.qa, *qb = h.qb;
  double *fa = h.fa, *fb = h.fb;
  if (kkeep > 0) {
    double bx = kin.ex[lp] + kin.ex[lc], by = kin.ey[lp] + kin.ey[lc];
    const double bl = std::sqrt(bx * bx + by * by);
    bx /= bl;
    by /= bl;
    const double dx = mid(qa, 0) - mid(qb, 0), dy = mid(qa, 1) - mid(qb, 1);
    const double shear = -by * dx + bx * dy;
    const double along = bx * dx + by * dy;
    const double F = kkeep * shear;  // -dE/ds = -F
    for (int e = 0; e < 2; ++e) {
      fa[e * half::kEnd + half::kX] -= 0.5 * F * -by;
      fa[e * half::kEnd + half::kY] -= 0.5 * F * bx;
      fb[e * half::kEnd + half::kX] += 0.5 * F * -by;
      fb[e * half::kEnd + half::kY] += 0.5 * F * bx;
    }
    s.tau_prev -= F * (-0.5 * along);
    s.tau_own -= F * (-0.5 * along);
  }
}

// 4.2 the plates of link j between b_j and a_{j+1}. Each half's lateral centre line is a
// cubic in xi (Horner, instead of four Hermite weights per plate), and the plate forces are
// gathered as moments sum f xi^p, mapped back to the half's coordinates once.
void plates(const Model& m, const ChainConstants& k, const JointHalves& h, JointSlot& s) {
  using A4 = Eigen::Array4d;
  const double kpl = k.kpl, cpl = k.cpl;
  const int groups = k.groups;
  const A4* zeta4 = k.zeta4;
  const A4* valid4 = k.valid4;
  const double *qb = h.qb, *vb = h.vb, *qn = h.qn, *vn = h.vn;
  const double sq = h.sq, sv = h.sv;
  double *fb = h.fb, *fn = h.fn, *fs = h.fs;
  {
    const double L = m.L0, invL = 1.0 / L;
    const Cubic bx = cubic_of(qb, 0, L), by = cubic_of(qb, 1, L), bvx = cubic_of(vb, 0, L), bvy = cubic_of(vb, 1, L);
    const Cubic nx = cubic_of(qn, 0, L), ny = cubic_of(qn, 1, L), nvx = cubic_of(vn, 0, L), nvy = cubic_of(vn, 1, L);
    const double zmb = 0.5 * (qb[half::kZ] + qb[half::kEnd + half::kZ]);
    const double zmn = 0.5 * (qn[half::kZ] + qn[half::kEnd + half::kZ]);
    const double xidb = (sv - 0.5 * (vb[half::kZ] + vb[half::kEnd + half::kZ])) * invL;
    const double xidn = (sv - 0.5 * (vn[half::kZ] + vn[half::kEnd + half::kZ])) * invL;
    // Four plates at a time (one AVX2 register per quantity, lanes summed at the end in
    // a fixed order); a plate beyond the pack's count, or not stretched (d <= rest),
    // contributes zeros (selected, so that its values, finite or not, never enter).
    A4 mbx[4], mby[4], mnx[4], mny[4];
    for (int p = 0; p < 4; ++p) mbx[p] = mby[p] = mnx[p] = mny[p] = A4::Zero();
    A4 sb = A4::Zero(), sn = A4::Zero(), pd = A4::Zero();
    for (int g = 0; g < groups; ++g) {
      const A4& zeta = zeta4[g];
      const A4& valid = valid4[g];
      const A4 xb = 0.5 + (sq + zeta - zmb) * invL, xn = 0.5 + (sq + zeta - zmn) * invL;
      const A4 dx = at4(nx, xn) - at4(bx, xb), dy = at4(ny, xn) - at4(by, xb);
      const A4 d = (dx * dx + dy * dy).sqrt();
      const A4 stretch = d - m.plate_rest;
      const A4 inv = 1.0 / d, ux = dx * inv, uy = dy * inv;
      const A4 sbx = slope4(bx, xb), sby = slope4(by, xb), snx = slope4(nx, xn), sny = slope4(ny, xn);
      const A4 rate = ux * ((at4(nvx, xn) + snx * xidn) - (at4(bvx, xb) + sbx * xidb)) +
                      uy * ((at4(nvy, xn) + sny * xidn) - (at4(bvy, xb) + sby * xidb));
      const auto on = stretch > 0.0;
      const A4 T = kpl * stretch + cpl * rate;
      pd += valid * on.select(cpl * rate * rate, 0.0);
      // (T ux, T uy) on the b point, the opposite on the n point.
      const A4 fx = valid * on.select(T * ux, 0.0), fy = valid * on.select(T * uy, 0.0);
      const A4 xb2 = xb * xb, xn2 = xn * xn, xb3 = xb2 * xb, xn3 = xn2 * xn;
      mbx[0] += fx, mbx[1] += fx * xb, mbx[2] += fx * xb2, mbx[3] += fx * xb3;
      mby[0] += fy, mby[1] += fy * xb, mby[2] += fy * xb2, mby[3] += fy * xb3;
      mnx[0] += fx, mnx[1] += fx * xn, mnx[2] += fx * xn2, mnx[3] += fx * xn3;
      mny[0] += fy, mny[1] += fy * xn, mny[2] += fy * xn2, mny[3] += fy * xn3;
      sb += fx * sbx + fy * sby;
      sn += fx * snx + fy * sny;
    }
    double Mbx[4], Mby[4], Mnx[4], Mny[4];
    for (int p = 0; p < 4; ++p)
      Mbx[p] = lanes(mbx[p]), Mby[p] = lanes(mby[p]), Mnx[p] = -lanes(mnx[p]), Mny[p] = -lanes(mny[p]);
    const double Sb = lanes(sb), Sn = -lanes(sn);  // sum of f . dP/dxi at the b and the n points
    s.p_diss += lanes(pd);
    add_moments(fb, 0, L, Mbx);
    add_moments(fb, 1, L, Mby);
    add_moments(fn, 0, L, Mnx);
    add_moments(fn, 1, L, Mny);
    // Through xi the forces also act on s (+1/L0) and on the half's end z (-1/(2 L0) each).
    *fs += (Sb + Sn) * invL;
    fb[half::kZ] -= 0.5 * Sb * invL;
    fb[half::kEnd + half::kZ] -= 0.5 * Sb * invL;
    fn[half::kZ] -= 0.5 * Sn * invL;
    fn[half::kEnd + half::kZ] -= 0.5 * Sn * invL;
  }
}

// 4.2 the pack of link j: s held to the axial mid-position of each of its two halves, so
// that no half slides out through its plates.
void pack(const ChainConstants& k, const JointHalves& h, JointSlot& s) {
  const double ks = k.ks, cs = k.cs;
  const double *qb = h.qb, *vb = h.vb, *qn = h.qn, *vn = h.vn;
  const double sq = h.sq, sv = h.sv;
  double *fb = h.fb, *fn = h.fn, *fs = h.fs;
  for (int h = 0; h < 2; ++h) {
    const double* hq = h == 0 ? qb : qn;
    const double* hv = h == 0 ? vb : vn;
    double* hf = h == 0 ? fb : fn;
    const double rel = sq - 0.5 * (hq[half::kZ] + hq[half::kEnd + half::kZ]);
    const double rate = sv - 0.5 * (hv[half::kZ] + hv[half::kEnd + half::kZ]);
    const double Fp = ks * rel + cs * rate;
    s.p_diss += cs * rate * rate;
    *fs -= Fp;
    hf[half::kZ] += 0.5 * Fp;
    hf[half::kEnd + half::kZ] += 0.5 * Fp;
  }
}

}  // namespace

// Joint j: the beams of its two halves (4.1), its rocker stations and keeper (4.3), then
// the plates and the pack of link j (4.2), in this order into chain_slots[j].
void chain_forces(const Model& m, Workspace& ws, int begin, int end, const FrictionExtras& x) {
  const ChainConstants k(m);
  for (int j = begin; j < end; ++j) {
    JointSlot& s = ws.chain_slots[j];
    s.clear();
    const JointHalves h(m, ws, j, s);
    s.p_diss += beam(m, h.qa, h.va, h.fa);
    s.p_diss += beam(m, h.qb, h.vb, h.fb);
    if (k.ktilt > 0) {
      s.p_diss += tilt(k, h.qa, h.va, h.fa);
      s.p_diss += tilt(k, h.qb, h.vb, h.fb);
    }
    rocker_stations(m, k, ws, x, j, h, s);
    keeper(m, k, ws.kin, j, h, s);
    plates(m, k, h, s);
    pack(k, h, s);
  }
}

double chain_energy(const Model& m, const double* q, const ContactStatus* status) {
  const Config& c = m.cfg;
  // Link directions from positions only (velocity-free kinematics): link j's and the one
  // before it, carried along the chain (nothing allocated: a W-step's energy test calls it).
  const auto direction = [&](int i, double& ex, double& ey) {
    const double* b = q + m.half_b(i);
    const double* a = q + m.half_a(i + 1);
    const double dx = mid(a, 0) - mid(b, 0), dy = mid(a, 1) - mid(b, 1);
    const double l = std::sqrt(dx * dx + dy * dy);
    ex = dx / l;
    ey = dy / l;
  };
  double exl = 0, eyl = 0, exj = 0, eyj = 0;
  direction(m.wrap(-1), exj, eyj);
  double E = 0;
  for (int j = 0; j < m.links; ++j) {
    const double* qa = q + m.half_a(j);
    const double* qb = q + m.half_b(j);
    const double* qn = q + m.half_a(j + 1);
    exl = exj, eyl = eyj;
    direction(j, exj, eyj);
    E += beam_energy(m, qa) + beam_energy(m, qb);
    if (c.pin.tilt_stiffness > 0) E += tilt_energy(m, qa) + tilt_energy(m, qb);
    for (int st = 0; st < c.rocker.stations; ++st) {
      if (status && !status->rocker[j * c.rocker.stations + st]) continue;
      const HermiteWeights h = hermite(m.station_xi[st], m.L0);
      const double cax = lateral(qa, h, 0) - m.kappa * exl, cay = lateral(qa, h, 1) - m.kappa * eyl;
      const double cbx = lateral(qb, h, 0) + m.kappa * exj, cby = lateral(qb, h, 1) + m.kappa * eyj;
      const double pen = 2 * c.rocker.radius - std::hypot(cax - cbx, cay - cby);
      E += hertz_energy(c.rocker.stiffness, pen);
    }
    if (c.rocker.keeper_stiffness > 0) {
      double bx = exl + exj, by = eyl + eyj;
      const double bl = std::sqrt(bx * bx + by * by);
      const double shear = (-by * (mid(qa, 0) - mid(qb, 0)) + bx * (mid(qa, 1) - mid(qb, 1))) / bl;
      E += 0.5 * c.rocker.keeper_stiffness * shear * shear;
    }
    const double sq = q[m.pack(j)];
    for (double zeta : m.plate_zeta) {
      const PlateEval e = plate_eval(m, qb, qb, qn, qn, sq, 0.0, zeta);
      if (e.stretch > 0) E += 0.5 * c.chain.plate_stiffness * e.stretch * e.stretch;
    }
    for (const double* hq : {qb, qn}) {
      const double rel = sq - 0.5 * (hq[half::kZ] + hq[half::kEnd + half::kZ]);
      E += 0.5 * c.chain.pack_stiffness * rel * rel;
    }
  }
  return E;
}

double link_tension(const Model& m, const Workspace& ws, int j) {
  const double* qb = ws.q + m.half_b(j);
  const double* vb = ws.v + m.half_b(j);
  const double* qn = ws.q + m.half_a(j + 1);
  const double* vn = ws.v + m.half_a(j + 1);
  const double cpl = damping(m).plate;
  double T = 0;
  for (double zeta : m.plate_zeta) {
    const PlateEval e = plate_eval(m, qb, vb, qn, vn, ws.q[m.pack(j)], ws.v[m.pack(j)], zeta);
    if (e.stretch > 0)
      T += m.cfg.chain.plate_stiffness * e.stretch + cpl * e.rate;
  }
  return T;
}

Eigen::Vector2d joint_centre(const Model& m, const double* q, int j) {
  const double* a = q + m.half_a(j);
  const double* b = q + m.half_b(j);
  return Eigen::Vector2d(0.5 * (mid(a, 0) + mid(b, 0)), 0.5 * (mid(a, 1) + mid(b, 1)));
}

void strand_tensions(const Model& m, const Workspace& ws, double out[2]) {
  const Eigen::Vector2d c0 = m.pulley[0].centre, d = m.pulley[1].centre - c0;
  const double a2 = d.squaredNorm();
  double sum[2] = {0, 0};
  int count[2] = {0, 0};
  Eigen::Vector2d next = joint_centre(m, ws.q, 0);  // each joint's centre once
  for (int j = 0; j < m.links; ++j) {
    const Eigen::Vector2d here = next;
    next = joint_centre(m, ws.q, m.wrap(j + 1));
    const Eigen::Vector2d p = 0.5 * (here + next) - c0;
    const double along = p.dot(d) / a2;
    if (!(along >= 0.2 && along <= 0.8)) continue;
    const int k = d.x() * p.y() - d.y() * p.x() > 0 ? 0 : 1;
    sum[k] += link_tension(m, ws, j), ++count[k];
  }
  for (int k = 0; k < 2; ++k) out[k] = count[k] > 0 ? sum[k] / count[k] : 0.0;
}

void plate_tensions(const Model& m, const Workspace& ws, int j, double* out) {
  const double* qb = ws.q + m.half_b(j);
  const double* vb = ws.v + m.half_b(j);
  const double* qn = ws.q + m.half_a(j + 1);
  const double* vn = ws.v + m.half_a(j + 1);
  const double cpl = damping(m).plate;
  for (std::size_t k = 0; k < m.plate_zeta.size(); ++k) {
    const PlateEval e = plate_eval(m, qb, vb, qn, vn, ws.q[m.pack(j)], ws.v[m.pack(j)], m.plate_zeta[k]);
    out[k] = e.stretch > 0 ? m.cfg.chain.plate_stiffness * e.stretch + cpl * e.rate : 0.0;
  }
}

double rocker_force(const Model& m, const Workspace& ws, int j) {
  const int nst = m.cfg.rocker.stations;
  const double crk = m.cfg.rocker.stiffness, brk = damping(m).rocker;
  double F = 0;
  for (int st = 0; st < nst; ++st) {
    if (!ws.status.rocker[j * nst + st]) continue;
    const RockerEval r = rocker_eval(m, ws.kin, ws.q + m.half_a(j), ws.v + m.half_a(j), ws.q + m.half_b(j),
                                     ws.v + m.half_b(j), m.wrap(j - 1), j, m.station_xi[st],
                                     hermite(m.station_xi[st], m.L0));
    if (r.pen > 0) F += hertz_force(crk, r.pen) + brk * r.pen_rate;
  }
  return F;
}

double chain_torsion_angle(const Model& m, const Workspace& ws, int j) {
  const auto slope = [&](int pin, int axis) {
    double s = 0;
    for (int o : {m.half_a(pin), m.half_b(pin)})
      s += (ws.q[o + half::kEnd + axis] - ws.q[o + axis]) / (ws.q[o + half::kEnd + half::kZ] - ws.q[o + half::kZ]);
    return 0.5 * s;
  };
  const int n = m.wrap(j + 1);
  const double nx = -ws.kin.ey[j], ny = ws.kin.ex[j];
  return nx * (slope(n, half::kX) - slope(j, half::kX)) + ny * (slope(n, half::kY) - slope(j, half::kY));
}

double max_rocker_penetration(const Model& m, const double* q, int* joint) {
  const Config& c = m.cfg;
  double worst = -1e300;
  *joint = 0;
  const auto dir = [&](int i, double& ex, double& ey) {
    const double* b = q + m.half_b(i);
    const double* a = q + m.half_a(i + 1);
    const double dx = mid(a, 0) - mid(b, 0), dy = mid(a, 1) - mid(b, 1);
    const double l = std::sqrt(dx * dx + dy * dy);
    ex = dx / l, ey = dy / l;
  };
  for (int j = 0; j < m.links; ++j) {
    const double* qa = q + m.half_a(j);
    const double* qb = q + m.half_b(j);
    double pex, pey, cex, cey;
    dir(m.wrap(j - 1), pex, pey);
    dir(j, cex, cey);
    for (int st = 0; st < c.rocker.stations; ++st) {
      const HermiteWeights h = hermite(m.station_xi[st], m.L0);
      const double cax = lateral(qa, h, 0) - m.kappa * pex, cay = lateral(qa, h, 1) - m.kappa * pey;
      const double cbx = lateral(qb, h, 0) + m.kappa * cex, cby = lateral(qb, h, 1) + m.kappa * cey;
      const double pen = 2 * c.rocker.radius - std::hypot(cax - cbx, cay - cby);
      if (pen > worst || std::isnan(pen)) worst = pen, *joint = j;
      if (std::isnan(pen)) return pen;
    }
  }
  return worst;
}

double half_axial_force(const Model& m, const double* q, const double* v, int o) {
  const double eps = q[o + half::kEnd + half::kZ] - q[o + half::kZ] - m.L0;
  const double rate = v[o + half::kEnd + half::kZ] - v[o + half::kZ];
  return m.cfg.pin.ea / m.L0 * (eps + m.beam_beta * rate);
}

void add_rocker_friction_stiffness(const Model& m, const Workspace& ws, int j, JointHessian& J) {
  const ChainConstants k(m);
  if (k.law == FrictionLaw::none) return;
  const LinkKinematics& kin = ws.kin;
  const int lp = m.wrap(j - 1), lc = j, nst = k.nst;
  const double *qa = ws.q + m.half_a(j), *va = ws.v + m.half_a(j);
  const double *qb = ws.q + m.half_b(j), *vb = ws.v + m.half_b(j);
  const double kap = m.kappa, Rr = m.cfg.rocker.radius;
  // Intermediates w (20), as joint_hessian: a_j's lateral dofs (4 c + i), b_j's (8 + 4 c + i),
  // D_{j-1} (16, 17), D_j (18, 19); local coordinates: link j-1's block, then link j's (+21).
  constexpr int kW = 20, kA = half::kSize, kB = kLinkDim, kN = kLinkDim + half::kSize;
  using Row = Eigen::Matrix<double, 1, kW>;
  // The link vectors, their directions' derivatives E = (I - e e^T) / |D|, and dpsi_dot/dD =
  // (D'_y - 2 D_x psi_dot, -D'_x - 2 D_y psi_dot) / |D|^2.
  const auto link = [&](int l, Eigen::Vector2d& e, Eigen::Matrix2d& E, Eigen::Vector2d& dpsi) {
    e = Eigen::Vector2d(kin.ex[l], kin.ey[l]);
    E = (Eigen::Matrix2d::Identity() - e * e.transpose()) * kin.inv_len[l];
    const double il2 = kin.inv_len[l] * kin.inv_len[l];
    dpsi = Eigen::Vector2d((kin.ddy[l] - 2 * kin.dx[l] * kin.psi_dot[l]) * il2,
                           (-kin.ddx[l] - 2 * kin.dy[l] * kin.psi_dot[l]) * il2);
  };
  Eigen::Vector2d ep, ec, dpp, dpc;
  Eigen::Matrix2d Ep, Ec;
  link(lp, ep, Ep, dpp);
  link(lc, ec, Ec, dpc);
  // w -> local coordinates (42).
  struct Map {
    int n = 0, idx[4];
    double wt[4];
  } map[kW];
  for (int c = 0; c < 2; ++c) {
    const auto d = plane_dofs(c);
    for (int i = 0; i < 4; ++i) {
      map[4 * c + i] = {1, {kA + d[i]}, {1.0}};
      map[8 + 4 * c + i] = {1, {kB + d[i]}, {1.0}};
    }
    map[16 + c] = {4, {kA + c, kA + half::kEnd + c, c, half::kEnd + c}, {0.5, 0.5, -0.5, -0.5}};
    map[18 + c] = {4, {kN + c, kN + half::kEnd + c, kB + c, kB + half::kEnd + c}, {0.5, 0.5, -0.5, -0.5}};
  }
  const auto put = [&J](int r, int c, double v) {
    if (r < kLinkDim) (c < kLinkDim ? J.prev(r, c) : J.up(r, c - kLinkDim)) += v;
    else (c < kLinkDim ? J.cross(r - kLinkDim, c) : J.own(r - kLinkDim, c - kLinkDim)) += v;
  };
  // -G^T dR of every station over (half coordinates, w), mapped onto the blocks at the end.
  Eigen::Matrix<double, FrictionJacobian::kDim, kW> Kw = Eigen::Matrix<double, FrictionJacobian::kDim, kW>::Zero();
  for (int st = 0; st < nst; ++st) {
    if (!ws.status.rocker[j * nst + st]) continue;
    const RockerEval r = rocker_eval(m, kin, qa, va, qb, vb, lp, lc, m.station_xi[st], k.sh[st]);
    const double Nel = hertz_force(k.crk, r.pen);
    if (!(Nel > 0)) continue;
    // The slip as rocker_stations forms it.
    RockerSlip sl;
    const double speed = rocker_slip(m, kin, r, va, vb, lp, lc, sl);
    const double *u = sl.u, rax = sl.rax, ray = sl.ray, rbx = sl.rbx, rby = sl.rby;
    const double psp = kin.psi_dot[lp], psc = kin.psi_dot[lc];
    const double nrm[3] = {r.mx, r.my, 0.0};
    double Rv[3];
    contact_friction(FrozenBranch{}, k.law, k.f0, k.v0, Nel, u, speed, nrm, Rv);
    const double mu = Nel * friction_over_speed(k.law, k.f0, k.v0, speed);
    const double mu_t = Nel * friction_slope(k.law, k.f0, k.v0, speed);
    const FrictionAxes ax(nrm, u, speed);
    // d/dw of X = P_a - P_b (row c: the station's weights), of Delta = X - kappa (e_p + e_c),
    // of m = Delta / |Delta|, and of pen = 2 R_r - |Delta|.
    Eigen::Matrix<double, 2, kW> dX = Eigen::Matrix<double, 2, kW>::Zero();
    for (int c = 0; c < 2; ++c)
      for (int i = 0; i < 4; ++i) dX(c, 4 * c + i) = r.h.w[i], dX(c, 8 + 4 * c + i) = -r.h.w[i];
    Eigen::Matrix<double, 2, kW> dDelta = dX;
    dDelta.middleCols<2>(16) -= kap * Ep;
    dDelta.middleCols<2>(18) -= kap * Ec;
    const Eigen::Vector2d mv(r.mx, r.my);
    const double dist = 2 * Rr - r.pen;
    const Eigen::Matrix<double, 2, kW> dm = (Eigen::Matrix2d::Identity() - mv * mv.transpose()) / dist * dDelta;
    const Row dpen = -mv.transpose() * dDelta;
    // The slip's xy part moves by: psi_dot_p's change times ra_perp, psi_dot_c's times -rb_perp,
    // and the levers' turning: psi_p d(ra)_perp - psi_c d(rb)_perp, ra = rb - X, rb = kappa e_c + R_r m.
    Eigen::Matrix<double, 2, kW> drb = Rr * dm;
    drb.middleCols<2>(18) += kap * Ec;
    const Eigen::Matrix<double, 2, kW> dra = drb - dX;
    const auto perp = [](const Eigen::Matrix<double, 2, kW>& a) {
      Eigen::Matrix<double, 2, kW> p;
      p.row(0) = -a.row(1), p.row(1) = a.row(0);
      return p;
    };
    Eigen::Matrix<double, 2, kW> du = psp * perp(dra) - psc * perp(drb);
    du.middleCols<2>(16) += Eigen::Vector2d(-ray, rax) * dpp.transpose();
    du.middleCols<2>(18) -= Eigen::Vector2d(-rby, rbx) * dpc.transpose();
    // dR/dw = rho dN/dw - D du/dw, D = mu_t t t^T + mu s s^T (u's z part does not move).
    const Row dN = 1.5 * k.crk * std::sqrt(r.pen) * dpen;
    const Eigen::Vector3d t(ax.t[0], ax.t[1], ax.t[2]), s(ax.s[0], ax.s[1], ax.s[2]);
    Eigen::Matrix<double, 3, kW> dR = Eigen::Vector3d(Rv[0] / Nel, Rv[1] / Nel, Rv[2] / Nel) * dN;
    dR -= mu_t * t * (t.head<2>().transpose() * du) + mu * s * (s.head<2>().transpose() * du);
    // K = -G^T dR over the joint's 40 half coordinates (b_{j-1}, a_j, b_j, a_{j+1}).
    double G[FrictionJacobian::kDim][3] = {};
    rocker_slip_columns(kin, r, lp, lc, rax, ray, rbx, rby, G);
    Kw.noalias() -= Eigen::Map<const Eigen::Matrix<double, FrictionJacobian::kDim, 3, Eigen::RowMajor>>(&G[0][0]) * dR;
  }
  for (int row = 0; row < FrictionJacobian::kDim; ++row) {
    const int lr = row < 2 * half::kSize ? row : row + 1;  // link j's rows after link j-1's pack
    for (int c = 0; c < kW; ++c) {
      const double v = Kw(row, c);
      if (v == 0) continue;
      for (int a = 0; a < map[c].n; ++a) put(lr, map[c].idx[a], v * map[c].wt[a]);
    }
  }
}

void update_rocker_status(const Model& m, Workspace& ws, int begin, int end) {
  const int nst = m.cfg.rocker.stations;
  const double crk = m.cfg.rocker.stiffness, brk = damping(m).rocker;
  HermiteWeights sh[kMaxStations];
  for (int st = 0; st < nst; ++st) sh[st] = hermite(m.station_xi[st], m.L0);
  for (int j = begin; j < end; ++j) {
    const double* qa = ws.q + m.half_a(j);
    const double* va = ws.v + m.half_a(j);
    const double* qb = ws.q + m.half_b(j);
    const double* vb = ws.v + m.half_b(j);
    for (int st = 0; st < nst; ++st) {
      const RockerEval r = rocker_eval(m, ws.kin, qa, va, qb, vb, m.wrap(j - 1), j, m.station_xi[st], sh[st]);
      std::uint8_t& status = ws.status.rocker[j * nst + st];
      const std::uint8_t now = r.pen > 0 && hertz_force(crk, r.pen) + brk * r.pen_rate > 0;
      if (now != status) ws.switch_slot[j] += (now ? 1.0 : -1.0) * hertz_energy(crk, r.pen);
      status = now;
    }
  }
}

}  // namespace cvt
