// docs/model.md 4.1-4.5 differentiated twice; docs/integrators.md 12.2 ("the analytic
// stiffness") writes each element's Hessian.
#include "modules/elastic_hessian.hpp"

#include <cmath>

#include "modules/beam.hpp"
#include "modules/contact_laws.hpp"
#include "modules/pulley_contact.hpp"

namespace cvt {
namespace {

// A value with its gradient and Hessian over N intermediate variables (second-order
// forward differentiation): the keeper's energy is a short function of six quantities that
// are linear in the coordinates, so its Hessian over the coordinates is A^T H A with A the
// linear map.
template <int N>
struct D2 {
  using V = Eigen::Matrix<double, N, 1>;
  using M = Eigen::Matrix<double, N, N>;
  double v = 0;
  V g = V::Zero();
  M h = M::Zero();
  static D2 var(int i, double x) {
    D2 d;
    d.v = x;
    d.g[i] = 1;
    return d;
  }
};
template <int N>
D2<N> operator+(const D2<N>& a, const D2<N>& b) {
  return {a.v + b.v, a.g + b.g, a.h + b.h};
}
template <int N>
D2<N> operator-(const D2<N>& a, const D2<N>& b) {
  return {a.v - b.v, a.g - b.g, a.h - b.h};
}
template <int N>
D2<N> operator*(double s, const D2<N>& a) {
  return {s * a.v, s * a.g, s * a.h};
}
template <int N>
D2<N> operator*(const D2<N>& a, const D2<N>& b) {
  return {a.v * b.v, a.v * b.g + b.v * a.g, a.v * b.h + b.v * a.h + a.g * b.g.transpose() + b.g * a.g.transpose()};
}
// f(a) from f, f' and f'' at a.v.
template <int N>
D2<N> chain(const D2<N>& a, double f, double f1, double f2) {
  return {f, f1 * a.g, f1 * a.h + f2 * a.g * a.g.transpose()};
}
template <int N>
D2<N> sqrt(const D2<N>& a) {
  const double r = std::sqrt(a.v);
  return chain(a, r, 0.5 / r, -0.25 / (a.v * r));
}
template <int N>
D2<N> inverse(const D2<N>& a) {
  const double r = 1.0 / a.v;
  return chain(a, r, -r * r, 2 * r * r * r);
}

// A quantity linear in the coordinates: sum of w[i] times coordinate idx[i] (local indices).
struct Lin {
  int n = 0;
  int idx[4];
  double w[4];
  double value = 0;
  void add(int i, double weight, double x) {
    idx[n] = i, w[n++] = weight;
    value += weight * x;
  }
};

// H += A_r^T Hz A_c for the intermediates zr (A_r's rows) and zc (A_c's rows); put(i, k, v)
// adds v at coordinates (i, k).
template <class Mat, class Put>
void add_mapped(const Mat& Hz, const Lin* zr, const Lin* zc, const Put& put) {
  for (int r = 0; r < Hz.rows(); ++r)
    for (int s = 0; s < Hz.cols(); ++s) {
      const double h = Hz(r, s);
      if (h == 0) continue;
      for (int a = 0; a < zr[r].n; ++a)
        for (int b = 0; b < zc[s].n; ++b) put(zr[r].idx[a], zc[s].idx[b], h * zr[r].w[a] * zc[s].w[b]);
    }
}

// The mid-point difference mid(p) - mid(m) of two halves (plane c) at local offsets op, om.
Lin mid_difference(const double* p, int op, const double* mq, int om, int c) {
  Lin z;
  z.add(op + c, 0.5, p[c]);
  z.add(op + half::kEnd + c, 0.5, p[half::kEnd + c]);
  z.add(om + c, -0.5, mq[c]);
  z.add(om + half::kEnd + c, -0.5, mq[half::kEnd + c]);
  return z;
}

// H += k g g^T for a sparse g given as (index, weight) pairs.
template <class Out, int K>
void add_outer(Out& H, const std::pair<int, double> (&g)[K], double k) {
  for (const auto& [i, wi] : g)
    for (const auto& [j, wj] : g) H(i, j) += k * wi * wj;
}

// d^2/dxi^2 of the Hermite weights (beam.hpp's w and dw, once more).
std::array<double, 4> hermite_second(double xi, double L0) {
  return {-6 + 12 * xi, L0 * (-4 + 6 * xi), 6 - 12 * xi, L0 * (-2 + 6 * xi)};
}

// 4.1: a pin half's beam (axial EA/L, bending EI/L^3 per plane) and tilt hold, constant,
// at local offset o.
void add_half(const Model& m, int o, LinkHessian& H) {
  const double L = m.L0, EA = m.cfg.pin.ea, kb = m.cfg.pin.ei / (L * L * L);
  add_outer(H, {{o + half::kZ, -1.0}, {o + half::kEnd + half::kZ, 1.0}}, EA / L);
  const double K4[4][4] = {{12, 6 * L, -12, 6 * L},
                           {6 * L, 4 * L * L, -6 * L, 2 * L * L},
                           {-12, -6 * L, 12, -6 * L},
                           {6 * L, 2 * L * L, -6 * L, 4 * L * L}};
  for (int pl = 0; pl < 2; ++pl) {
    const auto d = plane_dofs(pl);
    for (int i = 0; i < 4; ++i)
      for (int k = 0; k < 4; ++k) H(o + d[i], o + d[k]) += kb * K4[i][k];
  }
  const double kt = m.cfg.pin.tilt_stiffness / (L * L);
  if (kt > 0)
    for (int c = 0; c < 2; ++c) add_outer(H, {{o + half::kX + c, -1.0}, {o + half::kEnd + half::kX + c, 1.0}}, kt);
}

// 4.5: the Hertz energy (2/5) c Delta^(5/2) of the active pin ends of a half (joint j, half
// h: 0 a_j, 1 b_j) at local offset o, the shafts held: over the sphere centre c (linear in
// the end's x, y, z, sx, sy), c_n (3/2 Delta^(1/2) g g^T + Delta^(3/2) d2Delta/dc2), with
// Delta = R + sigma (l_z - Z - w) cos(beta) - |l_xy| sin(beta) and l = L_theta (c - O - u).
void add_pin_ends(const Model& m, const double* q, const ContactStatus& status, int j, int h, int o,
                  LinkHessian& H) {
  const double* hq = q + (h == 0 ? m.half_a(j) : m.half_b(j));
  const double cn = m.cfg.pulley_contact.stiffness, R = m.cfg.pulley_contact.end_radius;
  for (int k = 0; k < 2; ++k) {
    if (!near_pulley(m, hq, k)) continue;
    const double* sh = q + m.shaft(k);
    for (int e = 0; e < 2; ++e) {
      if (!status.pulley[ContactStatus::pulley_index(j, h, e, k)]) continue;
      const EndGeometry g = end_geometry(m, hq, e, k, sh);
      if (!(g.pen > 0)) continue;
      const double sigma = e == 0 ? -1.0 : 1.0;
      const double tx = sh[kTx], ty = sh[kTy];
      const double lx = g.dx - ty * g.dz, ly = g.dy + tx * g.dz, r = std::sqrt(lx * lx + ly * ly);
      const Eigen::Vector3d Lx(1, 0, -ty), Ly(0, 1, tx), gd(g.gdx, g.gdy, g.gdz);
      const double rx = lx / r, ry = ly / r;
      const double pxx = (1 - rx * rx) / r, pxy = -rx * ry / r, pyy = (1 - ry * ry) / r;
      const Eigen::Matrix3d Hd =
          -m.sin_beta * (pxx * Lx * Lx.transpose() + pxy * (Lx * Ly.transpose() + Ly * Lx.transpose()) +
                         pyy * Ly * Ly.transpose());
      const double sp = std::sqrt(g.pen);
      const Eigen::Matrix3d Hc = 1.5 * cn * sp * gd * gd.transpose() + cn * g.pen * sp * Hd;
      // c = (x - sigma R sx, y - sigma R sy, z - sigma R) of end e.
      const int b = o + e * half::kEnd;
      const std::pair<int, double> rows[3][2] = {{{b + half::kX, 1.0}, {b + half::kSx, -sigma * R}},
                                                 {{b + half::kY, 1.0}, {b + half::kSy, -sigma * R}},
                                                 {{b + half::kZ, 1.0}, {b + half::kZ, 0.0}}};
      for (int a = 0; a < 3; ++a)
        for (int c = 0; c < 3; ++c)
          for (const auto& [i, wi] : rows[a])
            for (const auto& [k2, wk] : rows[c]) H(i, k2) += Hc(a, c) * wi * wk;
    }
  }
}

// 4.2: the plates of link l between b_l (offset 0) and a_{l+1} (offset 10) and the pack
// s_l (20). A plate's ends P_b, P_n lie on the halves' centre lines at xi = xi0 + zeta / L0
// with xi0 = 1/2 + (s - z_mid) / L0 (linear in the coordinates). With D = P_n - P_b, d = |D|,
// u = D / d and T = k (d - l0) where stretched, over intermediates z shared by every plate
// of the link (each half's lateral dofs, xi0_b, xi0_n):
// H_z = J^T (k u u^T + T/d (I - u u^T)) J + T sum_c u_c d2D_c/dz2, J = dD/dz; a point's
// d2P_c/dz2 = its weights' slopes dw (lateral dofs of plane c) x xi0 and back, plus P_c'' at
// (xi0, xi0). Row c of J reaches plane c's lateral dofs of both halves and the two xi0: ten
// intermediates per plane (b's 4, n's 4, xi0_b, xi0_n), so H_z is kept as the three 10 x 10
// blocks of the plane pairs (x x, x y, y y), summed over the plates, then mapped onto the
// coordinates (A: one coordinate per lateral dof, s and the half's two z for xi0).
void add_plates(const Model& m, const double* q, int l, LinkHessian& H) {
  using V10 = Eigen::Matrix<double, 10, 1>;
  using M10 = Eigen::Matrix<double, 10, 10>;
  M10 S[3] = {M10::Zero(), M10::Zero(), M10::Zero()};  // (x, x), (x, y), (y, y)
  const double L = m.L0, invL = 1.0 / L, kpl = m.cfg.chain.plate_stiffness;
  const double sq = q[m.pack(l)];
  const double* hq[2] = {q + m.half_b(l), q + m.half_a(l + 1)};
  const double sign[2] = {-1.0, 1.0};
  double xi0[2];
  for (int s = 0; s < 2; ++s) xi0[s] = 0.5 + (sq - 0.5 * (hq[s][half::kZ] + hq[s][half::kEnd + half::kZ])) * invL;
  for (const double zeta : m.plate_zeta) {
    double P[2][2], P1[2][2], P2[2][2];
    HermiteWeights hw[2];
    for (int s = 0; s < 2; ++s) {
      const double xi = xi0[s] + zeta * invL;
      hw[s] = hermite(xi, L);
      const std::array<double, 4> ddw = hermite_second(xi, L);
      for (int c = 0; c < 2; ++c) {
        const auto d = plane_dofs(c);
        P[s][c] = lateral(hq[s], hw[s], c);
        P1[s][c] = lateral_dxi(hq[s], hw[s], c);
        P2[s][c] = ddw[0] * hq[s][d[0]] + ddw[1] * hq[s][d[1]] + ddw[2] * hq[s][d[2]] + ddw[3] * hq[s][d[3]];
      }
    }
    const double Dx = P[1][0] - P[0][0], Dy = P[1][1] - P[0][1];
    const double dist = std::sqrt(Dx * Dx + Dy * Dy), stretch = dist - m.plate_rest;
    if (!(stretch > 0)) continue;
    const double u[2] = {Dx / dist, Dy / dist};
    const double T = kpl * stretch, g = T / dist;
    const double cxx = kpl * u[0] * u[0] + g * (1 - u[0] * u[0]), cxy = (kpl - g) * u[0] * u[1];
    const double cyy = kpl * u[1] * u[1] + g * (1 - u[1] * u[1]);
    V10 J[2];
    for (int c = 0; c < 2; ++c) {
      for (int s = 0; s < 2; ++s) {
        for (int i = 0; i < 4; ++i) J[c][4 * s + i] = sign[s] * hw[s].w[i];
        J[c][8 + s] = sign[s] * P1[s][c];
      }
    }
    S[0].noalias() += cxx * J[0] * J[0].transpose();
    S[1].noalias() += cxy * J[0] * J[1].transpose();
    S[2].noalias() += cyy * J[1] * J[1].transpose();
    for (int c = 0; c < 2; ++c) {
      M10& B = S[2 * c];
      for (int s = 0; s < 2; ++s) {
        const double t = T * u[c] * sign[s];
        for (int i = 0; i < 4; ++i) {
          B(4 * s + i, 8 + s) += t * hw[s].dw[i];
          B(8 + s, 4 * s + i) += t * hw[s].dw[i];
        }
        B(8 + s, 8 + s) += t * P2[s][c];
      }
    }
  }
  // Plane c's ten intermediates -> coordinates.
  Lin z[2][10];
  for (int c = 0; c < 2; ++c) {
    const auto d = plane_dofs(c);
    for (int s = 0; s < 2; ++s) {
      for (int i = 0; i < 4; ++i) z[c][4 * s + i].add(s * half::kSize + d[i], 1.0, 0.0);
      Lin& x = z[c][8 + s];
      x.add(2 * half::kSize, invL, 0.0);
      x.add(s * half::kSize + half::kZ, -0.5 * invL, 0.0);
      x.add(s * half::kSize + half::kEnd + half::kZ, -0.5 * invL, 0.0);
    }
  }
  const auto put = [&H](int i, int k, double v) { H(i, k) += v; };
  add_mapped(S[0], z[0], z[0], put);
  add_mapped(S[1], z[0], z[1], put);
  add_mapped(S[1].transpose(), z[1], z[0], put);
  add_mapped(S[2], z[1], z[1], put);
}

}  // namespace

void joint_hessian(const Model& m, const double* q, const ContactStatus& status, int j, JointHessian& out) {
  // Over intermediates w (20): a_j's lateral dofs (plane c, dof i at 4 c + i), b_j's (8 +
  // 4 c + i), the link vectors D_{j-1} = mid(a_j) - mid(b_{j-1}) (16, 17) and D_j =
  // mid(a_{j+1}) - mid(b_j) (18, 19), which both the rocker and the keeper read; then onto
  // the local coordinates: link j-1's block (b_{j-1} 0..9, a_j 10..19, s 20), then link j's
  // (b_j 21..30, a_{j+1} 31..40, s 41).
  constexpr int kW = 20, kDp = 16, kDc = 18;
  constexpr int kBp = 0, kA = half::kSize, kB = kLinkDim, kN = kLinkDim + half::kSize;
  using Mat6 = Eigen::Matrix<double, 6, 6>;
  using Map6 = Eigen::Matrix<double, 6, kW>;
  Eigen::Matrix<double, kW, kW> Hw = Eigen::Matrix<double, kW, kW>::Zero();
  const Config& c = m.cfg;
  const int jp = m.wrap(j - 1);
  const double* qbp = q + m.half_b(jp);
  const double* qa = q + m.half_a(j);
  const double* qb = q + m.half_b(j);
  const double* qn = q + m.half_a(j + 1);
  const Lin Dp[2] = {mid_difference(qa, kA, qbp, kBp, 0), mid_difference(qa, kA, qbp, kBp, 1)};
  const Lin Dc[2] = {mid_difference(qn, kN, qb, kB, 0), mid_difference(qn, kN, qb, kB, 1)};
  // The link directions e = D / |D| and de/dD = (I - e e^T) / |D|.
  const Eigen::Vector2d Dpv(Dp[0].value, Dp[1].value), Dcv(Dc[0].value, Dc[1].value);
  const double Lp = Dpv.norm(), Lc = Dcv.norm();
  const Eigen::Vector2d ep = Dpv / Lp, ec = Dcv / Lc;
  const Eigen::Matrix2d Ep = (Eigen::Matrix2d::Identity() - ep * ep.transpose()) / Lp;
  const Eigen::Matrix2d Ec = (Eigen::Matrix2d::Identity() - ec * ec.transpose()) / Lc;
  // sum_k m_k d2e_k/dD2 for a unit vector e = D / L.
  const auto curvature = [](const Eigen::Vector2d& mv, const Eigen::Vector2d& e, double L) {
    const double me = mv.dot(e);
    return Eigen::Matrix2d((-(mv * e.transpose() + e * mv.transpose()) - me * Eigen::Matrix2d::Identity() +
                            3 * me * e * e.transpose()) /
                           (L * L));
  };
  // 4.3 the rocker's active stations: Delta = 2 R_r - |X - kappa e_{j-1} - kappa e_j| with
  // X = P_a - P_b (the centre lines at the station), energy phi = (2/5) c Delta^(5/2). Over
  // (X, D_{j-1}, D_j): G = d(X - kappa e_p - kappa e_c) = [I, -kappa E_p, -kappa E_c],
  // grad Delta = -G^T mu (mu the unit normal), d2Delta = -G^T (I - mu mu^T) G / dist +
  // kappa diag(0, Q_p, Q_c), Q = sum_k mu_k d2e_k/dD2; H = phi'' grad grad^T + phi' d2Delta.
  const int nst = c.rocker.stations;
  const double crk = c.rocker.stiffness;
  Eigen::Matrix<double, 2, 6> G;
  G.leftCols<2>().setIdentity();
  G.middleCols<2>(2) = -m.kappa * Ep;
  G.rightCols<2>() = -m.kappa * Ec;
  for (int st = 0; st < nst; ++st) {
    if (!status.rocker[j * nst + st]) continue;
    const HermiteWeights hw = hermite(m.station_xi[st], m.L0);
    const Eigen::Vector2d X(lateral(qa, hw, 0) - lateral(qb, hw, 0), lateral(qa, hw, 1) - lateral(qb, hw, 1));
    const Eigen::Vector2d Dv = X - m.kappa * (ep + ec);
    const double dist = Dv.norm(), pen = 2 * c.rocker.radius - dist;
    if (!(pen > 0)) continue;
    const Eigen::Vector2d mu = Dv / dist;
    const Eigen::Matrix<double, 6, 1> grad = -G.transpose() * mu;
    Mat6 H2 = -G.transpose() * (Eigen::Matrix2d::Identity() - mu * mu.transpose()) * G / dist;
    H2.block<2, 2>(2, 2) += m.kappa * curvature(mu, ep, Lp);
    H2.block<2, 2>(4, 4) += m.kappa * curvature(mu, ec, Lc);
    const double sp = std::sqrt(pen);
    const Mat6 Hz = 1.5 * crk * sp * grad * grad.transpose() + crk * pen * sp * H2;
    // X_c = sum_i w_i (a's dof 4 c + i) - w_i (b's 8 + 4 c + i): its weights x (8) per plane.
    Eigen::Matrix<double, 8, 1> x;
    x << hw.w[0], hw.w[1], hw.w[2], hw.w[3], -hw.w[0], -hw.w[1], -hw.w[2], -hw.w[3];
    const Eigen::Matrix<double, 8, 8> xx = x * x.transpose();
    for (int r = 0; r < 2; ++r) {
      for (int cc = 0; cc < 2; ++cc) {
        const double h = Hz(r, cc);
        for (int a = 0; a < 8; ++a)
          for (int b = 0; b < 8; ++b) Hw(4 * r + a % 4 + 8 * (a / 4), 4 * cc + b % 4 + 8 * (b / 4)) += h * xx(a, b);
      }
      for (int k = 0; k < 4; ++k) {
        const double h = Hz(r, 2 + k);
        for (int a = 0; a < 8; ++a) {
          const int i = 4 * r + a % 4 + 8 * (a / 4);
          Hw(i, kDp + k) += h * x[a];
          Hw(kDp + k, i) += h * x[a];
        }
      }
    }
    Hw.bottomRightCorner<4, 4>() += Hz.bottomRightCorner<4, 4>();
  }
  // 4.3 the keeper: (k/2) s^2, s = nbar . (mid(a_j) - mid(b_j)), nbar normal to the
  // bisector e_{j-1} + e_j; over (mid(a_j) - mid(b_j), D_{j-1}, D_j) by second-order forward
  // differentiation.
  if (c.rocker.keeper_stiffness > 0) {
    using R6 = D2<6>;
    const double dm[2] = {mid(qa, 0) - mid(qb, 0), mid(qa, 1) - mid(qb, 1)};
    const double zv[6] = {dm[0], dm[1], Dpv[0], Dpv[1], Dcv[0], Dcv[1]};
    R6 v[6];
    for (int i = 0; i < 6; ++i) v[i] = R6::var(i, zv[i]);
    const R6 ip = inverse(sqrt(v[2] * v[2] + v[3] * v[3])), ic = inverse(sqrt(v[4] * v[4] + v[5] * v[5]));
    const R6 bx = v[2] * ip + v[4] * ic, by = v[3] * ip + v[5] * ic;
    const R6 shear = (bx * v[1] - by * v[0]) * inverse(sqrt(bx * bx + by * by));
    const R6 E = (0.5 * c.rocker.keeper_stiffness) * (shear * shear);
    Map6 K = Map6::Zero();
    for (int cc = 0; cc < 2; ++cc) {  // mid = (end 0 + end 1) / 2: plane dofs 0 and 2
      K(cc, 4 * cc) = K(cc, 4 * cc + 2) = 0.5;
      K(cc, 8 + 4 * cc) = K(cc, 8 + 4 * cc + 2) = -0.5;
    }
    K(2, kDp) = K(3, kDp + 1) = K(4, kDc) = K(5, kDc + 1) = 1;
    Hw.noalias() += K.transpose() * E.h * K;
  }
  // w -> local coordinates.
  Lin w[kW];
  for (int cc = 0; cc < 2; ++cc) {
    const auto d = plane_dofs(cc);
    for (int i = 0; i < 4; ++i) w[4 * cc + i].add(kA + d[i], 1.0, 0.0), w[8 + 4 * cc + i].add(kB + d[i], 1.0, 0.0);
    w[kDp + cc] = Dp[cc];
    w[kDc + cc] = Dc[cc];
  }
  out.prev.setZero(), out.own.setZero(), out.cross.setZero();
  const auto put = [&out](int i, int k, double v) {
    if (i < kLinkDim && k < kLinkDim)
      out.prev(i, k) += v;
    else if (i >= kLinkDim && k >= kLinkDim)
      out.own(i - kLinkDim, k - kLinkDim) += v;
    else if (i >= kLinkDim)
      out.cross(i - kLinkDim, k) += v;  // the upper-right block is its transpose
  };
  add_mapped(Hw, w, w, put);
  out.up = out.cross.transpose();
}

void link_hessian(const Model& m, const double* q, const ContactStatus& status, int l, LinkHessian& out) {
  out.setZero();
  constexpr int kB = 0, kN = half::kSize, kS = 2 * half::kSize;
  add_half(m, kB, out);
  add_half(m, kN, out);
  // 4.2 the pack: (k_s/2) (s - z_mid)^2 against each of the two halves.
  for (const int o : {kB, kN})
    add_outer(out, {{kS, 1.0}, {o + half::kZ, -0.5}, {o + half::kEnd + half::kZ, -0.5}}, m.cfg.chain.pack_stiffness);
  add_plates(m, q, l, out);
  add_pin_ends(m, q, status, l, 1, kB, out);
  add_pin_ends(m, q, status, m.wrap(l + 1), 0, kN, out);
}

}  // namespace cvt
