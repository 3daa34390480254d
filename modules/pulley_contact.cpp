// docs/model.md 4.5.
#include "modules/pulley_contact.hpp"

#include <algorithm>
#include <cmath>

#include "modules/beam.hpp"
#include "modules/contact_laws.hpp"
#include "modules/damping.hpp"

namespace cvt {
namespace {

// dDelta/dt from the pin end's and the shaft's velocities (4.5.3).
inline double penetration_rate(const Model& m, const EndGeometry& g, const double* hv, int e, const double* shv) {
  const double sigma = e == 0 ? -1.0 : 1.0;
  const double R = m.cfg.pulley_contact.end_radius;
  const double* pv = hv + e * half::kEnd;
  return g.gdx * (pv[half::kX] - sigma * R * pv[half::kSx] - shv[kUx]) +
         g.gdy * (pv[half::kY] - sigma * R * pv[half::kSy] - shv[kUy]) + g.gdz * (pv[half::kZ] - shv[kUz]) +
         g.gtx * shv[kTx] + g.gty * shv[kTy] + g.gw * shv[kW];
}

// A pin end's contact point P = c + R_end n (4.5.4): the unit normal n, o = P - c, and
// rs = P - O - u, the sheave's lever.
struct EndPoint {
  double n[3], o[3], rs[3];
};

inline EndPoint end_point(const EndGeometry& g, double R) {
  EndPoint p;
  const double gnorm = std::sqrt(g.gdx * g.gdx + g.gdy * g.gdy + g.gdz * g.gdz);
  p.n[0] = g.gdx / gnorm, p.n[1] = g.gdy / gnorm, p.n[2] = g.gdz / gnorm;
  for (int i = 0; i < 3; ++i) p.o[i] = R * p.n[i];
  p.rs[0] = g.dx + p.o[0], p.rs[1] = g.dy + p.o[1], p.rs[2] = g.dz + p.o[2];
  return p;
}

// The slip u at P (4.5.4), tangential to n: the cap's point (c_dot, the cap turning with the
// end slopes, omega = (-sy', sx', 0), and with the link's spin psid) less the sheave's point
// (its translation, tilt and spin w, and its axial rate where it moves the contact); returns |u|.
inline double end_slip(const EndGeometry& g, const EndPoint& p, const double* pv, const double* shv, double sigma,
                       double R, double psid, double u[3]) {
  const double *o = p.o, *rs = p.rs, *n = p.n;
  const double cvx = pv[half::kX] - sigma * R * pv[half::kSx];
  const double cvy = pv[half::kY] - sigma * R * pv[half::kSy];
  const double cvz = pv[half::kZ];
  const double sxd = pv[half::kSx], syd = pv[half::kSy];
  const double vpx = cvx - psid * o[1] + sxd * o[2];
  const double vpy = cvy + psid * o[0] + syd * o[2];
  const double vpz = cvz - sxd * o[0] - syd * o[1];
  const double wx = shv[kTx], wy = shv[kTy], wz = shv[kPhi];
  const double vsx = shv[kUx] + wy * rs[2] - wz * rs[1];
  const double vsy = shv[kUy] + wz * rs[0] - wx * rs[2];
  const double vsz = shv[kUz] + wx * rs[1] - wy * rs[0] + (g.gw != 0 ? shv[kW] : 0.0);
  u[0] = vpx - vsx, u[1] = vpy - vsy, u[2] = vpz - vsz;
  const double un = u[0] * n[0] + u[1] * n[1] + u[2] * n[2];
  for (int i = 0; i < 3; ++i) u[i] -= un * n[i];
  return std::sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
}

// The rows of G (u = G v) of a pin end's own coordinates at row b: c_dot and the cap's tilt;
// and the link's spin through the end's half (cp = +-1/(2|Delta|)) and through the link's
// other half (-cp), with the lever o's perpendicular.
inline void add_end_columns(double (*G)[3], int b, double (*own)[3], double (*other)[3], double sigma, double R,
                            const double* o, double cp, double lnx, double lny) {
  G[b + half::kX][0] += 1;
  G[b + half::kY][1] += 1;
  G[b + half::kZ][2] += 1;
  G[b + half::kSx][0] += -sigma * R + o[2], G[b + half::kSx][2] += -o[0];
  G[b + half::kSy][1] += -sigma * R + o[2], G[b + half::kSy][2] += -o[1];
  add_spin_columns(own, cp, lnx, lny, -o[1], o[0]);
  add_spin_columns(other, -cp, lnx, lny, -o[1], o[0]);
}


// What FrictionJacobian asks of one pin end with friction (docs/integrators.md 12): u as a
// function of the two halves of the link that this half turns with (the sheave's velocity
// left out): c_dot, the cap's tilt, and the link spin through this half's mid-point (a_j:
// +n/(2|Delta|), b_j: -n/(2|Delta|)) and through the link's other half (the opposite sign).
// Columns: b_{j-1} 0..9, a_j 10..19 (link j-1); b_j 20..29, a_{j+1} 30..39 (link j). Then
// the sheave's columns (its point's velocity enters u with the sign -). Kd, Xd, Sd: the
// joint's blocks (pins, pins x sheave, sheave x sheave; nullptr unless asked); cols: record
// the contact's columns.
struct PinEndSlip {
  int h, e, k, idx, link;
  double sigma, R;
  double o[3], rs[3];  // P - c, and P - O - u (the sheave's lever)
  bool axial;          // the sheave's axial coordinate moves the contact (g.gw != 0)
  const double* u;
  const double* n;
  double speed;
};

void pin_end_friction_jacobian(const LinkKinematics& kin, FrictionJacobian& jac, double* Kd, double* Xd, double* Sd,
                               bool cols, const PinEndSlip& p, double mu, double mu_t) {
  constexpr int kD = FrictionJacobian::kDim;
  const int h = p.h, e = p.e, k = p.k, idx = p.idx, link = p.link;
  const double sigma = p.sigma, R = p.R;
  const double rsx = p.rs[0], rsy = p.rs[1], rsz = p.rs[2];
  const double* u = p.u;
  const double* nrm = p.n;
  const double speed = p.speed;
  double G[kD][3] = {};
  double(*Gh)[3] = G + (h == 0 ? 10 : 20);
  const double cp = (h == 0 ? 0.5 : -0.5) * kin.inv_len[link];
  add_end_columns(Gh, e * half::kEnd, Gh, G + (h == 0 ? 0 : 30), sigma, R, p.o, cp, -kin.ey[link], kin.ex[link]);
  if (Kd) add_friction_damping(Kd, kD, G, nrm, u, speed, mu, mu_t);
  double Gs[kShaftSize][3] = {};
  Gs[kUx][0] = -1, Gs[kUy][1] = -1, Gs[kUz][2] = -1;
  Gs[kTx][1] = rsz, Gs[kTx][2] = -rsy;
  Gs[kTy][0] = -rsz, Gs[kTy][2] = rsx;
  Gs[kPhi][0] = rsy, Gs[kPhi][1] = -rsx;
  if (p.axial) Gs[kW][2] = -1;
  if (Kd) {
    add_friction_cross(Xd + k * kD * kShaftSize, kD, G, kShaftSize, Gs, nrm, u, speed, mu, mu_t);
    add_friction_cross(Sd + k * kShaftSize * kShaftSize, kShaftSize, Gs, kShaftSize, Gs, nrm, u, speed, mu, mu_t);
  }
  if (cols) {
    double* U = jac.pulley_fresh.columns(idx);
    double* V = jac.pulley_shaft_cols.data() + static_cast<std::size_t>(idx) * 2 * kShaftSize;
    friction_columns(kD, G, nrm, u, speed, U, U + kD);
    friction_columns(kShaftSize, Gs, nrm, u, speed, V, V + kShaftSize);
  }
}

}  // namespace

void pulley_contact_joint(const Model& m, Workspace& ws, int j, JointSlot& s, PinContactReport* report,
                          const FrictionExtras& x) {
  FrictionJacobian* jac = x.jacobian;
  const Config& c = m.cfg;
  const double cn = c.pulley_contact.stiffness, bn = damping(m).pulley_contact;
  const double R = c.pulley_contact.end_radius;
  const FrictionLaw law = c.friction.law;
  const double f0 = c.friction.f0, v0 = c.friction.v0;
  s.clear();
  constexpr int kD = FrictionJacobian::kDim;
  const bool blocks = jac && jac->blocks;
  double* Kd = blocks ? jac->pulley_damping.data() + static_cast<std::size_t>(j) * kD * kD : nullptr;
  constexpr int kX = 2 * kD * kShaftSize;
  double* Xd = blocks ? jac->pulley_shaft_damping.data() + static_cast<std::size_t>(j) * kX : nullptr;
  constexpr int kS = 2 * kShaftSize * kShaftSize;
  double* Sd = blocks ? jac->pulley_shaft_self.data() + static_cast<std::size_t>(j) * kS : nullptr;
  if (Kd) std::fill(Kd, Kd + kD * kD, 0.0), std::fill(Xd, Xd + kX, 0.0), std::fill(Sd, Sd + kS, 0.0);
  const bool rec_mu = jac && jac->mu;
  if (rec_mu) jac->pulley_fresh.clear(ContactStatus::pulley_index(j, 0, 0, 0), ContactStatus::kPulleyPerJoint, Kd != nullptr);
  for (int h = 0; h < 2; ++h) {
    const int o = h == 0 ? m.half_a(j) : m.half_b(j);
    const double* hq = ws.q + o;
    const double* hv = ws.v + o;
    double* hf = s.f.data() + (h == 0 ? kJointA : kJointB);
    const int link = h == 0 ? m.wrap(j - 1) : j;  // a_j turns with link j-1, b_j with link j
    double& tau = h == 0 ? s.tau_prev : s.tau_own;
    for (int k = 0; k < 2; ++k) {
      if (!near_pulley(m, hq, k)) continue;
      const double* sh = ws.q + m.shaft(k);
      const double* shv = ws.v + m.shaft(k);
      double* sf = s.shaft.data() + kShaftSize * k;
      for (int e = 0; e < 2; ++e) {
        if (!ws.status.pulley[ContactStatus::pulley_index(j, h, e, k)]) continue;
        const EndGeometry g = end_geometry(m, hq, e, k, sh);
        const double sigma = e == 0 ? -1.0 : 1.0;
        const double* pv = hv + e * half::kEnd;
        const double rate = penetration_rate(m, g, hv, e, shv);
        const double Nel = hertz_force(cn, g.pen);
        const double N = Nel + (g.pen > 0 ? bn * rate : 0.0);
        s.p_diss += (N - Nel) * rate;
        // Normal: Q = -N grad(Delta).
        double* pf = hf + e * half::kEnd;
        double Fx = -N * g.gdx, Fy = -N * g.gdy, Fz = -N * g.gdz;
        // Friction (4.5.4) at the contact point P = c + R_end n.
        double Rx = 0, Ry = 0, Rz = 0, Rmag = 0;
        const EndPoint P = end_point(g, R);
        const double ox = P.o[0], oy = P.o[1], oz = P.o[2];
        const double rsx = P.rs[0], rsy = P.rs[1], rsz = P.rs[2];
        if (Nel > 0 && law != FrictionLaw::none) {
          double u[3];
          const double speed = end_slip(g, P, pv, shv, sigma, R, ws.kin.psi_dot[link], u);
          const int idx = ContactStatus::pulley_index(j, h, e, k);
          const double* nrm = P.n;
          double Rv[3];
          s.p_diss += contact_friction(pulley_branch(x.frozen, idx), law, f0, v0, Nel, u, speed, nrm, Rv, &Rmag);
          Rx = Rv[0], Ry = Rv[1], Rz = Rv[2];
          tau += ox * Ry - oy * Rx;
          const double mu = (Kd || rec_mu) ? Nel * friction_over_speed(law, f0, v0, speed) : 0.0;
          const bool cols = rec_mu && jac->pulley_fresh.note(idx, mu, Kd != nullptr, jac->mu_tol);
          if (Kd || cols) {
            const PinEndSlip p{h, e, k, idx, link, sigma, R, {ox, oy, oz}, {rsx, rsy, rsz}, g.gw != 0, u, nrm, speed};
            const double mu_t = jac->secant ? mu : Nel * friction_slope(law, f0, v0, speed);
            pin_end_friction_jacobian(ws.kin, *jac, Kd, Xd, Sd, cols, p, mu, mu_t);
          }
        }
        // Pin: translation of c, and the slopes through c = tip - sigma R (sx, sy, 1).
        pf[half::kX] += Fx + Rx;
        pf[half::kY] += Fy + Ry;
        pf[half::kZ] += Fz + Rz;
        pf[half::kSx] += -sigma * R * (Fx + Rx) + Rx * oz - Rz * ox;
        pf[half::kSy] += -sigma * R * (Fy + Ry) + Ry * oz - Rz * oy;
        // Shaft: the normal force through the gradient, friction through the sheave point.
        sf[kUx] += -Fx - Rx;
        sf[kUy] += -Fy - Ry;
        sf[kUz] += -Fz - Rz;
        sf[kTx] += -N * g.gtx - (rsy * Rz - rsz * Ry);
        sf[kTy] += -N * g.gty - (rsz * Rx - rsx * Rz);
        sf[kPhi] += -(rsx * Ry - rsy * Rx);
        sf[kW] += -N * g.gw - (g.gw != 0 ? Rz : 0.0);
        if (report) {
          EndContact& ec = report->end[h][e];
          ec.normal = N;
          ec.friction = Rmag;
          ec.penetration = g.pen;
          ec.pulley = k;
        }
      }
    }
  }
}

void add_pulley_friction_stiffness(const Model& m, const Workspace& ws, int l,
                                   Eigen::Matrix<double, 2 * half::kSize + 1, 2 * half::kSize + 1>& K) {
  const Config& c = m.cfg;
  const FrictionLaw law = c.friction.law;
  if (law == FrictionLaw::none) return;
  const double cn = c.pulley_contact.stiffness, R = c.pulley_contact.end_radius;
  const double f0 = c.friction.f0, v0 = c.friction.v0;
  const LinkKinematics& kin = ws.kin;
  for (int side = 0; side < 2; ++side) {
    // b_l is joint l's half b (h = 1), a_{l+1} joint l+1's half a (h = 0); at block offsets
    // 0 and 10, each with the link's other half at the other offset.
    const int h = side == 0 ? 1 : 0, j = side == 0 ? l : m.wrap(l + 1);
    const int off = side * half::kSize, other = (1 - side) * half::kSize;
    const int o = h == 0 ? m.half_a(j) : m.half_b(j);
    const double* hq = ws.q + o;
    const double* hv = ws.v + o;
    for (int k = 0; k < 2; ++k) {
      if (!near_pulley(m, hq, k)) continue;
      const double* sh = ws.q + m.shaft(k);
      const double* shv = ws.v + m.shaft(k);
      for (int e = 0; e < 2; ++e) {
        if (!ws.status.pulley[ContactStatus::pulley_index(j, h, e, k)]) continue;
        const EndGeometry g = end_geometry(m, hq, e, k, sh);
        const double Nel = hertz_force(cn, g.pen);
        if (!(Nel > 0)) continue;
        // The slip u at the contact point, as pulley_contact_joint forms it.
        const double sigma = e == 0 ? -1.0 : 1.0;
        const EndPoint P = end_point(g, R);
        const double *n = P.n, ox = P.o[0], oy = P.o[1];
        const double psid = kin.psi_dot[l];
        const double w[3] = {shv[kTx], shv[kTy], shv[kPhi]};
        double u[3];
        const double speed = end_slip(g, P, hv + e * half::kEnd, shv, sigma, R, psid, u);
        double Rv[3];
        contact_friction(FrozenBranch{}, law, f0, v0, Nel, u, speed, n, Rv);
        // D = -dR/du at fixed N (the exact slope along the sliding direction).
        const double mu = Nel * friction_over_speed(law, f0, v0, speed), mu_t = Nel * friction_slope(law, f0, v0, speed);
        const FrictionAxes ax(n, u, speed);
        // The generalized forces are G^T R over the block's coordinates (u = G v): the end's
        // point and cap, and the link's spin through both its halves (pin_end_friction_jacobian).
        double G[2 * half::kSize][3] = {};
        const int b = off + e * half::kEnd;
        const double cp = (h == 0 ? 0.5 : -0.5) * kin.inv_len[l];
        add_end_columns(G, b, G + off, G + other, sigma, R, P.o, cp, -kin.ey[l], kin.ex[l]);
        // Columns: the end's x, y, z, sx, sy move the sphere centre c by A_k.
        const int cols[5] = {half::kX, half::kY, half::kZ, half::kSx, half::kSy};
        const double A[5][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {-sigma * R, 0, 0}, {0, -sigma * R, 0}};
        const double dN = 1.5 * cn * std::sqrt(g.pen);
        for (int q = 0; q < 5; ++q) {
          const double* a = A[q];
          // dR/dq = R / N dN/dq + D (omega x A_q).
          const double gN = dN * (g.gdx * a[0] + g.gdy * a[1] + g.gdz * a[2]);
          const double wa[3] = {w[1] * a[2] - w[2] * a[1], w[2] * a[0] - w[0] * a[2], w[0] * a[1] - w[1] * a[0]};
          const double tw = ax.t[0] * wa[0] + ax.t[1] * wa[1] + ax.t[2] * wa[2];
          const double sw = ax.s[0] * wa[0] + ax.s[1] * wa[1] + ax.s[2] * wa[2];
          double dR[3];
          for (int i = 0; i < 3; ++i) dR[i] = Rv[i] / Nel * gN + mu_t * tw * ax.t[i] + mu * sw * ax.s[i];
          for (int r = 0; r < 2 * half::kSize; ++r)
            K(r, b + cols[q]) -= G[r][0] * dR[0] + G[r][1] * dR[1] + G[r][2] * dR[2];
        }
        // The cap turns with the link, psi_dot (-o_y, o_x, 0), and psi_dot = (D x D')_z / |D|^2
        // with D = mid(a_{l+1}) - mid(b_l) moves with the four ends' x and y:
        // dpsi_dot/dD = (D'_y - 2 D_x psi_dot, -D'_x - 2 D_y psi_dot) / |D|^2; dR/dq = -D_f du/dq.
        const double il2 = kin.inv_len[l] * kin.inv_len[l];
        const double dpsi[2] = {(kin.ddy[l] - 2 * kin.dx[l] * psid) * il2, (-kin.ddx[l] - 2 * kin.dy[l] * psid) * il2};
        const double lever[3] = {-oy, ox, 0};
        const double tl = ax.t[0] * lever[0] + ax.t[1] * lever[1], sl = ax.s[0] * lever[0] + ax.s[1] * lever[1];
        for (int c2 = 0; c2 < 2; ++c2)
          for (int hs = 0; hs < 2; ++hs)
            for (int end = 0; end < 2; ++end) {
              const double d = (hs == 0 ? -0.5 : 0.5) * dpsi[c2];  // b_l at 0 (-), a_{l+1} at 10 (+)
              double dR[3];
              for (int i = 0; i < 3; ++i) dR[i] = -d * (mu_t * tl * ax.t[i] + mu * sl * ax.s[i]);
              const int col = hs * half::kSize + end * half::kEnd + half::kX + c2;
              for (int r = 0; r < 2 * half::kSize; ++r) K(r, col) -= G[r][0] * dR[0] + G[r][1] * dR[1] + G[r][2] * dR[2];
            }
      }
    }
  }
}

void pulley_contact(const Model& m, Workspace& ws, int begin, int end, const FrictionExtras& x) {
  for (int j = begin; j < end; ++j) pulley_contact_joint(m, ws, j, ws.pulley_slots[j], nullptr, x);
}

namespace {

// Calls f(j, h, e, k, penetration) for every pin end whose half is near pulley k, in pin
// order; stops early when f returns false.
template <class F>
void for_each_near_end(const Model& m, const double* q, const F& f) {
  for (int j = 0; j < m.links; ++j)
    for (int h = 0; h < 2; ++h) {
      const double* hq = q + (h == 0 ? m.half_a(j) : m.half_b(j));
      for (int k = 0; k < 2; ++k) {
        if (!near_pulley(m, hq, k)) continue;
        for (int e = 0; e < 2; ++e)
          if (!f(j, h, e, k, end_geometry(m, hq, e, k, q + m.shaft(k)).pen)) return;
      }
    }
}

}  // namespace

double pulley_energy(const Model& m, const double* q, const ContactStatus* status) {
  double E = 0;
  for_each_near_end(m, q, [&](int j, int h, int e, int k, double pen) {
    if (!status || status->pulley[ContactStatus::pulley_index(j, h, e, k)])
      E += hertz_energy(m.cfg.pulley_contact.stiffness, pen);
    return true;
  });
  return E;
}

double max_pulley_penetration(const Model& m, const double* q, int* joint) {
  double worst = -1e300;
  *joint = -1;
  for_each_near_end(m, q, [&](int j, int, int, int, double pen) {
    if (pen > worst || std::isnan(pen)) worst = pen, *joint = j;
    return !std::isnan(pen);
  });
  if (std::isnan(worst)) return worst;
  return *joint < 0 ? 0.0 : worst;
}

void update_pulley_status(const Model& m, Workspace& ws, int begin, int end) {
  const double cn = m.cfg.pulley_contact.stiffness, bn = damping(m).pulley_contact;
  for (int j = begin; j < end; ++j)
    for (int h = 0; h < 2; ++h) {
      const int o = h == 0 ? m.half_a(j) : m.half_b(j);
      for (int k = 0; k < 2; ++k)
        for (int e = 0; e < 2; ++e) {
          std::uint8_t& st = ws.status.pulley[ContactStatus::pulley_index(j, h, e, k)];
          const std::uint8_t was = st;
          st = 0;
          if (!near_pulley(m, ws.q + o, k)) continue;
          const double* shv = ws.v + m.shaft(k);
          const EndGeometry g = end_geometry(m, ws.q + o, e, k, ws.q + m.shaft(k));
          if (g.pen <= 0) continue;  // no energy in or out: Hertz energy is 0 here
          const double rate = penetration_rate(m, g, ws.v + o, e, shv);
          st = hertz_force(cn, g.pen) + bn * rate > 0;
          if (st != was) ws.switch_slot[j] += (st ? 1.0 : -1.0) * hertz_energy(cn, g.pen);
        }
    }
}

double wrapped_radius(const Model& m, const Workspace& ws, int k) {
  double sum = 0;
  int count = 0;
  const double* sh = ws.q + m.shaft(k);
  for (int j = 0; j < m.links; ++j) {
    bool touching = false;
    for (int h = 0; h < 2; ++h)
      for (int e = 0; e < 2; ++e) touching |= ws.status.pulley[ContactStatus::pulley_index(j, h, e, k)] != 0;
    if (!touching) continue;
    const double* a = ws.q + m.half_a(j);
    const double* b = ws.q + m.half_b(j);
    const double x = 0.5 * (mid(a, 0) + mid(b, 0)) - m.pulley[k].centre.x() - sh[kUx];
    const double y = 0.5 * (mid(a, 1) + mid(b, 1)) - m.pulley[k].centre.y() - sh[kUy];
    sum += std::sqrt(x * x + y * y);
    ++count;
  }
  return count ? sum / count : 0.0;
}

}  // namespace cvt
