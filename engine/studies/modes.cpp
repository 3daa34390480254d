// Modal analysis (docs/model.md 9).
#include "engine/base/timing.hpp"
#include "engine/studies/modes.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <stdexcept>

#include "engine/io/json.hpp"
#include "engine/rhs/rhs.hpp"
#include "modules/beam.hpp"
#include "modules/inertia.hpp"

namespace cvt {

// ---- RK4 stability (9.4) ----

std::complex<double> rk4_amplification(std::complex<double> z) {
  // Horner form of 1 + z + z^2/2 + z^3/6 + z^4/24.
  return 1.0 + z * (1.0 + z * (0.5 + z * (1.0 / 6.0 + z / 24.0)));
}

double rk4_ray_bound(double theta) {
  const std::complex<double> dir = std::polar(1.0, theta);
  // cos(pi/2) rounds to +6e-17: directions that close to the imaginary axis are the axis.
  if (dir.real() > 1e-12) return 0.0;
  // |R| stays below 1 + tol from r = 0 on (on the imaginary axis |R|^2 = 1 - y^6/72 +
  // y^8/576 is 1 to rounding for small y); march out to the first r where it is above,
  // then bisect. The whole region lies within |z| < 3.
  const double tol = 1e-12, dr = 1e-3;
  auto outside = [&](double r) { return std::abs(rk4_amplification(r * dir)) > 1.0 + tol; };
  double lo = 0.0, hi = 0.0;
  for (double r = dr; r <= 4.0; r += dr) {
    if (outside(r)) {
      hi = r;
      break;
    }
    lo = r;
  }
  if (hi == 0.0) return lo;
  for (int it = 0; it < 60; ++it) {
    const double mid = 0.5 * (lo + hi);
    (outside(mid) ? hi : lo) = mid;
  }
  return lo;
}

double rk4_stable_step(std::complex<double> lambda) {
  const double a = std::abs(lambda);
  if (a == 0.0) return std::numeric_limits<double>::infinity();
  return rk4_ray_bound(std::arg(lambda)) / a;
}

Rk4Stability rk4_stability(const Eigen::VectorXcd& eig, double zero_tol) {
  Rk4Stability s;
  const double axis = rk4_ray_bound(std::numbers::pi / 2);
  for (int i = 0; i < eig.size(); ++i) {
    const std::complex<double> l = eig[i];
    const double a = std::abs(l);
    if (a > s.rho) s.rho = a, s.lambda_rho = l;
    if (a <= zero_tol) {
      ++s.zero;
      continue;
    }
    double h;
    if (l.real() > 0) {
      // Growing in the exact solution (or on the axis up to the differences' noise): RK4
      // can follow it at most as far as it resolves its oscillation.
      if (l.real() > zero_tol) ++s.growing, s.max_growth = std::max(s.max_growth, l.real());
      h = l.imag() != 0 ? axis / std::abs(l.imag()) : std::numeric_limits<double>::infinity();
    } else {
      h = rk4_stable_step(l);
    }
    if (h < s.h_stable) s.h_stable = h, s.lambda_limit = l;
  }
  s.h_rho = s.lambda_rho.real() > 0 ? (s.lambda_rho.imag() != 0 ? axis / std::abs(s.lambda_rho.imag()) : 0.0)
                                    : rk4_stable_step(s.lambda_rho);
  return s;
}

// ---- Generic linear algebra ----

Eigen::MatrixXd jacobian_by_differences(const VectorFunction& f, const Eigen::VectorXd& x,
                                        const Eigen::VectorXd& steps) {
  Eigen::VectorXd xp = x, fp, fm;
  Eigen::MatrixXd J;
  for (int j = 0; j < x.size(); ++j) {
    xp[j] = x[j] + steps[j];
    f(xp, fp);
    xp[j] = x[j] - steps[j];
    f(xp, fm);
    // The step actually taken, after rounding of x +- h.
    const double hh = (x[j] + steps[j]) - (x[j] - steps[j]);
    xp[j] = x[j];
    if (j == 0) J.resize(fp.size(), x.size());
    J.col(j) = (fp - fm) / hh;
  }
  return J;
}

GeneralizedModes generalized_modes(const Eigen::MatrixXd& K, const Eigen::MatrixXd& A) {
  Eigen::GeneralizedSelfAdjointEigenSolver<Eigen::MatrixXd> es(K, A, Eigen::ComputeEigenvectors | Eigen::Ax_lBx);
  if (es.info() != Eigen::Success)
    throw std::runtime_error("generalized eigenproblem failed (is the mass matrix positive definite?)");
  return {es.eigenvalues(), es.eigenvectors()};
}

// ---- Linearization (9.1) ----

double difference_step(double value) { return 1e-8 * (1.0 + std::abs(value)); }

double smooth_difference(double f_minus, double f0, double f_plus, double h_minus, double h_plus, bool* kinked) {
  const double dp = (f_plus - f0) / h_plus, dm = (f0 - f_minus) / h_minus;
  // Smooth: the one-sided slopes differ by O(h f''), a few 1e-3 of the slope for a Hertz
  // pair 1e-5 m deep. Far apart: the force jumps or kinks at the state (9.1).
  const double scale = std::abs(dp) + std::abs(dm);
  if (std::abs(dp - dm) <= 0.1 * scale || scale == 0.0) {
    *kinked = false;
    return (f_plus - f_minus) / (h_plus + h_minus);
  }
  *kinked = true;
  if ((dp > 0) != (dm > 0)) return 0.0;
  return std::abs(dp) < std::abs(dm) ? dp : dm;
}

Linearization linearize(const Model& m, const ContactStatus& status, double t, const Eigen::VectorXd& y,
                        bool with_jacobian) {
  const auto t0 = std::chrono::steady_clock::now();
  const int n = m.ndof;
  Linearization L;
  for (int i = 0; i < 2 * n; ++i) L.jac_index.push_back(i);
  // The controller integral feeds back into the clamping force; the other integrals
  // (works) feed nothing back and only add zero eigenvalues.
  if (m.cfg.controller.enabled) L.jac_index.push_back(2 * n + kCtrlIntegral);
  const int nj = static_cast<int>(L.jac_index.size());
  L.K.resize(n, n);
  L.C.resize(n, n);
  if (with_jacobian) L.J.resize(nj, nj);

  Workspace ws(m);
  ws.status = status;
  Eigen::VectorXd yp = y, dy0(m.nstate), dyp(m.nstate), dym(m.nstate), F0(n), Fp(n), Fm(n);
  rhs_serial(m, ws, t, y.data(), dy0.data());
  F0 = ws.force;
  L.force_evaluations = 1;
  const int columns = with_jacobian ? nj : 2 * n;
  bool kinked = false;
  for (int c = 0; c < columns; ++c) {
    const int i = L.jac_index[c];
    const double h = difference_step(y[i]);
    yp[i] = y[i] + h;
    rhs_serial(m, ws, t, yp.data(), dyp.data());
    Fp = ws.force;
    yp[i] = y[i] - h;
    rhs_serial(m, ws, t, yp.data(), dym.data());
    Fm = ws.force;
    // The steps actually taken, after rounding of y +- h.
    const double hp = (y[i] + h) - y[i], hm = y[i] - (y[i] - h);
    yp[i] = y[i];
    L.force_evaluations += 2;
    if (i < 2 * n) {
      Eigen::MatrixXd& M = i < n ? L.K : L.C;
      const int col = i < n ? i : i - n;
      for (int r = 0; r < n; ++r) {
        M(r, col) = -smooth_difference(Fm[r], F0[r], Fp[r], hm, hp, &kinked);
        L.nonsmooth_entries += kinked;
      }
    }
    if (with_jacobian)
      for (int r = 0; r < nj; ++r) {
        const int k = L.jac_index[r];
        L.J(r, c) = smooth_difference(dym[k], dy0[k], dyp[k], hm, hp, &kinked);
        L.nonsmooth_jacobian_entries += kinked;
      }
  }
  L.A = dense_inertia(m, y.data());
  L.seconds = seconds_since(t0);
  return L;
}

// ---- Energy parts (9.3) ----

double EnergyParts::total() const {
  double s = load;
  for (const auto& kind : chain)
    for (double e : kind) s += e;
  for (const auto& sh : shaft)
    for (double e : sh) s += e;
  return s;
}

EnergyParts energy_parts(const Model& m, const double* q, const Eigen::VectorXd& x) {
  const int N = m.links, n = m.ndof;
  EnergyParts e;
  e.chain.assign(static_cast<int>(PartKind::kChainKinds), std::vector<double>(N, 0.0));
  // Link directions at q (velocities play no part in g).
  Eigen::VectorXd y = Eigen::VectorXd::Zero(m.nstate);
  y.head(n) = Eigen::Map<const Eigen::VectorXd>(q, n);
  Workspace ws(m);
  set_stage_input(m, ws, 0.0, y.data());
  link_kinematics(m, ws, 0, N);

  // Rigid lateral motion of a half, p = c0 + c1 z with z = -+L0/2 at the ends: its
  // A0-orthogonal projection splits u^T M_b u into rigid motion and bending exactly.
  const double L = m.L0;
  Eigen::Matrix<double, 4, 2> R;
  R << 1, -L / 2, 0, 1, 1, L / 2, 0, 1;
  const Eigen::Matrix2d Mr = R.transpose() * m.bend_mass * R;
  const Eigen::Matrix2d Mr_inv = Mr.inverse();
  for (int j = 0; j < N; ++j) {
    for (int h = 0; h < 2; ++h) {
      const int off = h == 0 ? m.half_a(j) : m.half_b(j);
      const int base = h == 0 ? static_cast<int>(PartKind::kAxialA) : static_cast<int>(PartKind::kAxialB);
      const Eigen::Vector2d za(x[off + half::kZ], x[off + half::kEnd + half::kZ]);
      e.chain[base][j] = za.dot(m.axial_mass * za);
      double lateral = 0, bending = 0;
      for (int pl = 0; pl < 2; ++pl) {
        const auto d = plane_dofs(pl);
        Eigen::Vector4d u;
        for (int k = 0; k < 4; ++k) u[k] = x[off + d[k]];
        const Eigen::Vector4d Mu = m.bend_mass * u;
        const Eigen::Vector2d c = Mr_inv * (R.transpose() * Mu);
        const double all = u.dot(Mu), rigid = c.dot(Mr * c);
        lateral += rigid;
        bending += std::max(0.0, all - rigid);
      }
      e.chain[base + 1][j] = lateral;
      e.chain[base + 2][j] = bending;
    }
    e.chain[static_cast<int>(PartKind::kPack)][j] = m.pack_mass * x[m.pack(j)] * x[m.pack(j)];
    // Link j holds b_j and a_{j+1}: J (g_j^T x)^2 (3.1).
    double gx, gy;
    link_g(ws.kin, j, gx, gy);
    const int a = m.half_a(j + 1), b = m.half_b(j);
    double gtx = 0;
    for (int end = 0; end < 2; ++end) {
      const int o = end * half::kEnd;
      gtx += gx * (x[a + o + half::kX] - x[b + o + half::kX]) + gy * (x[a + o + half::kY] - x[b + o + half::kY]);
    }
    e.chain[static_cast<int>(PartKind::kLinkRotation)][j] = m.cfg.chain.link_inertia * gtx * gtx;
  }
  for (int k = 0; k < 2; ++k) {
    const int s = m.shaft(k);
    const auto& sh = m.cfg.shaft;
    e.shaft[k][0] = sh.mass * (x[s + kUx] * x[s + kUx] + x[s + kUy] * x[s + kUy]);
    const Eigen::Vector2d zw(x[s + kUz], x[s + kW]);
    e.shaft[k][1] = zw.dot(m.shaft_axial_mass * zw);
    e.shaft[k][2] = sh.tilt_inertia * (x[s + kTx] * x[s + kTx] + x[s + kTy] * x[s + kTy]);
    e.shaft[k][3] = sh.polar_inertia * x[s + kPhi] * x[s + kPhi];
  }
  e.load = m.cfg.load.inertia * x[m.load_index()] * x[m.load_index()];
  return e;
}

std::vector<PartShare> dominant_parts(const Model& m, const EnergyParts& e, int how_many) {
  const double total = e.total();
  std::vector<std::pair<double, PartShare>> cand;  // (rank key, what is named)
  if (!(total > 0)) return {};
  const int N = m.links;
  static const char* kind_name[] = {"half a axial",  "half a lateral", "half a bending", "half b axial",
                                    "half b lateral", "half b bending", "plate pack axial", "rotation"};
  for (int k = 0; k < static_cast<int>(PartKind::kChainKinds); ++k) {
    const auto& v = e.chain[k];
    double sum = 0;
    for (double x : v) sum += x;
    if (!(sum > 0)) continue;
    // Shortest run of joints around the largest one that holds 80 % of this kind.
    const int jmax = static_cast<int>(std::max_element(v.begin(), v.end()) - v.begin());
    int lo = jmax, hi = jmax, len = 1;
    double in = v[jmax];
    while (in < 0.8 * sum && len < N) {
      const double left = v[m.wrap(lo - 1)], right = v[m.wrap(hi + 1)];
      if (right >= left) hi = hi + 1, in += right;
      else lo = lo - 1, in += left;
      ++len;
    }
    const bool link_kind = k >= static_cast<int>(PartKind::kPack);
    std::string where;
    double share;
    if (len > N / 2) {
      where = link_kind ? "all links " : "all pins ";
      share = sum / total;
    } else {
      where = link_kind ? (len > 1 ? "links " : "link ") : (len > 1 ? "pins " : "pin ");
      where += std::to_string(m.wrap(lo));
      if (len > 1) where += "-" + std::to_string(m.wrap(hi));
      where += " ";
      share = in / total;
    }
    cand.push_back({sum / total, {where + kind_name[k], share}});
  }
  static const char* shaft_part[] = {"lateral", "axial (with moving sheave)", "tilt", "rotation"};
  for (int s = 0; s < 2; ++s)
    for (int p = 0; p < 4; ++p)
      if (e.shaft[s][p] > 0)
        cand.push_back({e.shaft[s][p] / total,
                        {std::string(s == 0 ? "driving" : "driven") + " shaft " + shaft_part[p], e.shaft[s][p] / total}});
  if (e.load > 0) cand.push_back({e.load / total, {"load rotation", e.load / total}});
  std::stable_sort(cand.begin(), cand.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
  std::vector<PartShare> out;
  for (int i = 0; i < how_many && i < static_cast<int>(cand.size()); ++i) out.push_back(cand[i].second);
  return out;
}

// ---- The analysis ----

ModalReport modal_analysis(const Model& m, const ContactStatus& status, double t, const Eigen::VectorXd& y,
                           const ModesOptions& opt) {
  ModalReport r;
  r.t = t;
  r.ndof = m.ndof;
  for (auto s : status.rocker) r.rocker_active += s != 0;
  for (auto s : status.pulley) r.pulley_active += s != 0;
  r.rocker_pairs = static_cast<int>(status.rocker.size());
  r.pulley_pairs = static_cast<int>(status.pulley.size());

  const Linearization L = linearize(m, status, t, y, opt.jacobian);
  r.force_evaluations = L.force_evaluations;
  r.nonsmooth_entries = L.nonsmooth_entries;
  r.nonsmooth_jacobian_entries = L.nonsmooth_jacobian_entries;
  r.t_differences = L.seconds;
  r.jac_size = static_cast<int>(L.jac_index.size());
  // Friction, follower forces and the velocity terms make K unsymmetric; the conservative
  // problem takes its symmetric part (9.2).
  const Eigen::MatrixXd Ks = 0.5 * (L.K + L.K.transpose());
  const double ksum = (L.K + L.K.transpose()).norm(), csum = (L.C + L.C.transpose()).norm();
  r.asymmetry = ksum > 0 ? (L.K - L.K.transpose()).norm() / ksum : 0.0;
  r.damping_asymmetry = csum > 0 ? (L.C - L.C.transpose()).norm() / csum : 0.0;

  auto t0 = std::chrono::steady_clock::now();
  const GeneralizedModes gm = generalized_modes(Ks, L.A);
  r.t_modes = seconds_since(t0);
  const double two_pi = 2 * std::numbers::pi;
  const double tol2 = (two_pi * opt.rigid_hz) * (two_pi * opt.rigid_hz);
  const int n = m.ndof;
  auto row = [&](int i) {
    ModeRow mr;
    mr.index = i;
    mr.omega2 = gm.omega2[i];
    mr.freq_hz = std::copysign(std::sqrt(std::abs(mr.omega2)), mr.omega2) / two_pi;
    mr.parts = dominant_parts(m, energy_parts(m, y.data(), gm.vectors.col(i)), 2);
    return mr;
  };
  std::vector<int> flexible;
  for (int i = 0; i < n; ++i) {
    const double w2 = gm.omega2[i];
    if (std::abs(w2) < tol2) {
      if (static_cast<int>(r.rigid_modes.size()) < opt.count) r.rigid_modes.push_back(row(i));
      ++r.rigid;
    } else if (w2 < 0) {
      if (r.negative < opt.count) r.negative_modes.push_back(row(i));
      ++r.negative;
    } else {
      flexible.push_back(i);
    }
  }
  const int nf = static_cast<int>(flexible.size());
  for (int k = 0; k < std::min(opt.count, nf); ++k) r.lowest.push_back(row(flexible[k]));
  for (int k = 0; k < std::min(opt.count, nf); ++k) r.highest.push_back(row(flexible[nf - 1 - k]));

  if (opt.jacobian) {
    t0 = std::chrono::steady_clock::now();
    Eigen::EigenSolver<Eigen::MatrixXd> es(L.J, false);
    if (es.info() != Eigen::Success) throw std::runtime_error("eigenvalues of the Jacobian did not converge");
    r.jacobian_eigenvalues = es.eigenvalues();
    r.t_eigen_jacobian = seconds_since(t0);
    double rho = r.jacobian_eigenvalues.cwiseAbs().maxCoeff();
    r.stability = rk4_stability(r.jacobian_eigenvalues, 1e-7 * rho);
    r.has_jacobian = true;
  }
  return r;
}

// ---- Output ----

namespace {

std::string fmt(const char* f, auto... args) {
  char buf[512];
  std::snprintf(buf, sizeof buf, f, args...);
  return buf;
}

std::string complex_str(std::complex<double> z) {
  return fmt("%.4g %c %.4g i", z.real(), z.imag() < 0 ? '-' : '+', std::abs(z.imag()));
}

std::string mode_table(const std::vector<ModeRow>& rows) {
  std::string s = "    #      f [Hz]         w [rad/s]     dominant part (share of modal kinetic energy); next\n";
  for (const auto& r : rows) {
    std::string part = r.parts.empty() ? "-" : fmt("%s %.0f %%", r.parts[0].name.c_str(), 100 * r.parts[0].share);
    if (r.parts.size() > 1) part += fmt("; %s %.0f %%", r.parts[1].name.c_str(), 100 * r.parts[1].share);
    s += fmt("    %-5d  %-13.6g  %-13.6g %s\n", r.index, r.freq_hz,
             std::copysign(std::sqrt(std::abs(r.omega2)), r.omega2), part.c_str());
  }
  return s;
}


Json json_rows(const std::vector<ModeRow>& rows) {
  Json a = Json::array();
  for (const auto& r : rows) {
    Json parts = Json::array();
    for (const auto& p : r.parts) parts.push_back({{"name", p.name}, {"share", json_number(p.share, 6)}});
    a.push_back({{"index", r.index},
                 {"omega2", json_number(r.omega2)},
                 {"frequency_hz", json_number(r.freq_hz)},
                 {"parts", std::move(parts)}});
  }
  return a;
}


}  // namespace

std::string format_modal_report(const ModalReport& r, double config_step) {
  std::string s;
  s += fmt("linearized at t = %.9g s, contact statuses frozen: rocker pairs active %d/%d, pin-end pairs active %d/%d\n",
           r.t, r.rocker_active, r.rocker_pairs, r.pulley_active, r.pulley_pairs);
  s += fmt("  K = -dF/dq, C = -dF/dv by central differences: %d force evaluations, %.2f s\n", r.force_evaluations,
           r.t_differences);
  s += fmt("  nonsmooth at this state (one-sided differences disagree; smaller side taken): %ld entries of K and C, "
           "%ld of J\n",
           r.nonsmooth_entries, r.nonsmooth_jacobian_entries);
  if (r.t == 0)
    s += "  note: in the initial state every contact pair sits at zero penetration (its damping switching on) and\n"
         "        every plate at its rest length: the chain's entries are mostly nonsmooth and describe the unloaded\n"
         "        chain only roughly; linearize after the ramp with --at T (docs/model.md 9.1)\n";
  s += fmt("  asymmetry |K - K^T|/|K + K^T| = %.3g (friction, follower forces; the symmetric part is used), "
           "of C: %.3g\n",
           r.asymmetry, r.damping_asymmetry);
  s += fmt("\nnatural frequencies, K x = w^2 A(q) x (%d x %d, %.2f s):\n", r.ndof, r.ndof, r.t_modes);
  s += fmt("  %d rigid-body or mechanism modes (|f| < threshold), %d with negative stiffness (w^2 < 0, shown as "
           "f < 0)\n",
           r.rigid, r.negative);
  if (!r.rigid_modes.empty()) s += "  rigid-body and mechanism modes:\n" + mode_table(r.rigid_modes);
  if (!r.negative_modes.empty())
    s += "  negative stiffness, most negative first (symmetric part of K, docs/model.md 9.2):\n" +
         mode_table(r.negative_modes);
  s += "  lowest:\n" + mode_table(r.lowest);
  s += "  highest:\n" + mode_table(r.highest);
  if (r.has_jacobian) {
    const auto& st = r.stability;
    s += fmt("\nfirst-order Jacobian J = df/dy (friction and damping included; %d x %d, eigenvalues %.2f s):\n",
             r.jac_size, r.jac_size, r.t_eigen_jacobian);
    s += fmt("  spectral radius rho = %.4g 1/s at lambda = %s; RK4 ray bound along it: h = %.4g s (|z| = %.4f)\n",
             st.rho, complex_str(st.lambda_rho).c_str(), st.h_rho, st.h_rho * st.rho);
    s += fmt("  largest stable RK4 step over all eigenvalues: h* = %.4g s, set by lambda = %s (|lambda| = %.4g, "
             "|z| = %.4f)\n",
             st.h_stable, complex_str(st.lambda_limit).c_str(), std::abs(st.lambda_limit),
             st.h_stable * std::abs(st.lambda_limit));
    s += fmt("  %d eigenvalues ~ 0 (|lambda| <= 1e-7 rho); %d growing (Re lambda > 1e-7 rho), largest Re lambda = "
             "%.4g 1/s\n",
             st.zero, st.growing, st.max_growth);
    if (config_step > 0)
      s += fmt("  integrator.step = %.4g s is %s h* (ratio %.3f)\n", config_step,
               config_step <= st.h_stable ? "below" : "ABOVE", config_step / st.h_stable);
  }
  return s;
}

std::string modal_report_json(const ModalReport& r, double config_step) {
  Json j = {{"t", json_number(r.t)},
            {"ndof", r.ndof},
            {"rocker_active", r.rocker_active},
            {"rocker_pairs", r.rocker_pairs},
            {"pulley_active", r.pulley_active},
            {"pulley_pairs", r.pulley_pairs},
            {"stiffness_asymmetry", json_number(r.asymmetry, 6)},
            {"damping_asymmetry", json_number(r.damping_asymmetry, 6)},
            {"nonsmooth_entries", r.nonsmooth_entries},
            {"nonsmooth_jacobian_entries", r.nonsmooth_jacobian_entries},
            {"rigid_modes", r.rigid},
            {"negative_modes", r.negative},
            {"seconds",
             {{"differences", json_number(r.t_differences, 4)},
              {"modes", json_number(r.t_modes, 4)},
              {"jacobian_eigenvalues", json_number(r.t_eigen_jacobian, 4)}}},
            {"rigid", json_rows(r.rigid_modes)},
            {"negative", json_rows(r.negative_modes)},
            {"lowest", json_rows(r.lowest)},
            {"highest", json_rows(r.highest)}};
  if (r.has_jacobian) {
    const auto& st = r.stability;
    j["jacobian"] = {{"size", r.jac_size},
                     {"rho", json_number(st.rho)},
                     {"lambda_rho", {json_number(st.lambda_rho.real()), json_number(st.lambda_rho.imag())}},
                     {"h_rho", json_number(st.h_rho)},
                     {"h_stable", json_number(st.h_stable)},
                     {"lambda_limit", {json_number(st.lambda_limit.real()), json_number(st.lambda_limit.imag())}},
                     {"zero", st.zero},
                     {"growing", st.growing},
                     {"max_growth", json_number(st.max_growth)},
                     {"config_step", json_number(config_step)}};
  }
  return json_text(j);
}

}  // namespace cvt
