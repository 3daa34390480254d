// docs/model.md 2, 3, 5: derived parameters, constant inertia, initial state.
#include "engine/model/model.hpp"

#include <algorithm>
#include <cmath>

#include "engine/model/geometry.hpp"

namespace cvt {

double ramp(double t, double t_ramp) {
  if (t_ramp <= 0 || t >= t_ramp) return 1.0;
  if (t <= 0) return 0.0;
  return 0.5 * (1 - std::cos(M_PI * t / t_ramp));
}

double ramp_rate(double t, double t_ramp) {
  if (t_ramp <= 0 || t >= t_ramp || t <= 0) return 0.0;
  return 0.5 * M_PI / t_ramp * std::sin(M_PI * t / t_ramp);
}

double profile_value(const Config::Profile& p, double t) {
  if (t <= p.front()[0]) return p.front()[1];
  for (std::size_t i = 1; i < p.size(); ++i)
    if (t < p[i][0]) return p[i - 1][1] + (p[i][1] - p[i - 1][1]) * (t - p[i - 1][0]) / (p[i][0] - p[i - 1][0]);
  return p.back()[1];
}

double profile_rate(const Config::Profile& p, double t) {
  for (std::size_t i = 1; i < p.size(); ++i)
    if (t >= p[i - 1][0] && t < p[i][0]) return (p[i][1] - p[i - 1][1]) / (p[i][0] - p[i - 1][0]);
  return 0.0;
}

double profile_integral(const Config::Profile& p, double t) {
  double sum = p.front()[1] * std::min(t, p.front()[0]);  // held before the first point
  for (std::size_t i = 1; i < p.size() && t > p[i - 1][0]; ++i) {
    const double dt = p[i][0] - p[i - 1][0];
    if (!(dt > 0)) continue;  // a step: no area
    const double b = std::min(t, p[i][0]);
    const double vb = p[i - 1][1] + (p[i][1] - p[i - 1][1]) * (b - p[i - 1][0]) / dt;  // this segment's line at b
    sum += 0.5 * (p[i - 1][1] + vb) * (b - p[i - 1][0]);
  }
  if (t > p.back()[0]) sum += p.back()[1] * (t - p.back()[0]);
  return sum;
}

double drive_speed(const Config& c, double t) {
  return c.drive.speed_profile.empty() ? c.drive.speed : profile_value(c.drive.speed_profile, t);
}

double drive_angle(const Config& c, double t) {
  return c.drive.speed_profile.empty() ? c.drive.speed * t : profile_integral(c.drive.speed_profile, t);
}

double peak_drive_speed(const Config& c) {
  double v = std::abs(c.drive.speed_profile.empty() ? c.drive.speed : 0.0);
  for (const auto& p : c.drive.speed_profile) v = std::max(v, std::abs(p[1]));
  return v;
}

double final_drive_speed(const Config& c) {
  return c.drive.speed_profile.empty() ? c.drive.speed : c.drive.speed_profile.back()[1];
}

double ramped_load_torque(const Config& c, double t) {
  if (!c.load.torque_profile.empty()) return profile_value(c.load.torque_profile, t);
  const double from = c.ramp.load_from, to = c.load.torque, ts = t - c.ramp.load_start;
  if (ts < 0) return from;
  return from + (to - from) * ramp(ts, c.ramp.load_time);
}

void clamping_schedule(const Model& m, double t, double F[2], double Fdot[2]) {
  const Config& c = m.cfg;
  const double r = ramp(t, c.ramp.time), rd = ramp_rate(t, c.ramp.time);
  const double F0[2] = {c.clamping.driving, c.clamping.driven};
  const Config::Profile* profile[2] = {&c.clamping.driving_profile, &c.clamping.driven_profile};
  for (int k = 0; k < 2; ++k) {
    if (!profile[k]->empty()) F[k] = profile_value(*profile[k], t), Fdot[k] = profile_rate(*profile[k], t);
    else F[k] = F0[k] * r, Fdot[k] = F0[k] * rd;
  }
}

double target_ratio(const Config& c, double t) {
  const auto& p = c.controller.target_profile;
  return p.empty() ? c.controller.target_ratio : profile_value(p, t);
}

double target_rate(const Config& c, double t) { return profile_rate(c.controller.target_profile, t); }

double transmitted_torque(const Config& c, double t) {
  const double r = target_ratio(c, t);
  return std::abs(ramped_load_torque(c, t)) + c.load.inertia * drive_speed(c, t) * std::abs(target_rate(c, t)) / (r * r);
}

double sheave_radius(const Model& m, int k, double w) {
  const Config& c = m.cfg;
  const double r = m.pulley[k].running_radius - m.pulley[k].moving_side * w / (2 * m.tan_beta);
  return std::clamp(r, c.sheave.hub_radius, c.sheave.outer_radius);
}

double slip_safe_gain(const Model& m) {
  const Config& c = m.cfg;
  if (!c.controller.enabled || !(c.controller.clamping_safety > 0)) return 0.0;
  return c.controller.clamping_safety * m.cos_beta / (2 * c.friction.f0);
}

double ramps_end(const Config& c) {
  double end = std::max(c.ramp.time, c.ramp.load_start + c.ramp.load_time);
  for (const Config::Profile* p : {&c.drive.speed_profile, &c.load.torque_profile, &c.clamping.driving_profile,
                                   &c.clamping.driven_profile})
    if (!p->empty()) end = std::max(end, p->back()[0]);  // the inputs' last change
  return end;
}

double settle_end(const Config& c) { return c.integrator.settle_time < 0 ? ramps_end(c) : c.integrator.settle_time; }

double torsion_period(const Model& m) {
  const Config& c = m.cfg;
  const double i = c.geometry.ratio;  // pulley 2 turns at omega_1 / i: all referred to shaft 1
  const double Ja = c.shaft.polar_inertia * (1 + 1 / (i * i)), Jb = c.load.inertia / (i * i);
  const double ka = c.drive.stiffness, kb = c.load.stiffness / (i * i);
  // M x'' + K x = 0 with M = diag(Ja, Jb), K = [[ka + kb, -kb], [-kb, kb]]: the lowest
  // root of det(K - lambda M) = Ja Jb lambda^2 - ((ka + kb) Jb + kb Ja) lambda + ka kb = 0.
  const double A = Ja * Jb, B = (ka + kb) * Jb + kb * Ja, C = ka * kb;
  double lambda = 0;
  if (C > 0) lambda = (B - std::sqrt(std::max(0.0, B * B - 4 * A * C))) / (2 * A);
  else if (kb > 0) lambda = kb * (1 / Ja + 1 / Jb);  // no drive spring: the two inertias against each other
  else if (ka > 0) lambda = ka / (Ja + Jb);
  return lambda > 0 ? 2 * M_PI / std::sqrt(lambda) : 0.0;
}

double steady_window(const Model& m) {
  if (m.cfg.run.steady_window > 0) return m.cfg.run.steady_window;
  const double v_chain = final_drive_speed(m.cfg) * m.pulley[0].running_radius;
  const double t_mesh = v_chain > 0 ? m.cfg.chain.pitch / v_chain : 0.0;
  const double w = 2 * torsion_period(m);
  if (!(t_mesh > 0)) return w;
  // A whole number of meshing periods, at least 4: the polygon ripple averages out.
  return std::max(4.0, std::ceil(w / t_mesh - 1e-9)) * t_mesh;
}

namespace {

// Every ratio the controller is asked for must be one the chain can run at (5).
void check_targets(const Config& cfg, ChainPathParams gp) {
  const auto check = [&](double ratio, const char* key) {
    gp.ratio = ratio;
    try {
      place_chain(gp);
    } catch (const ConfigError& e) {
      throw ConfigError(key, std::to_string(ratio), "the chain cannot run at this ratio: " + e.reason());
    }
  };
  if (cfg.controller.target_profile.empty()) check(cfg.controller.target_ratio, "controller.target_ratio");
  for (const auto& p : cfg.controller.target_profile) check(p[1], "controller.target_profile");
}

}  // namespace

Model build_model(const Config& cfg) {
  Model m;
  m.cfg = cfg;
  m.links = cfg.chain.links;
  m.ndof = kJointSize * m.links + 2 * kShaftSize + 1;
  m.nstate = 2 * m.ndof + kAuxSize;

  m.L0 = cfg.pin.length;
  m.plate_rest = cfg.chain.pitch + cfg.rocker.half_distance;
  m.kappa = 0.5 * cfg.rocker.half_distance - cfg.rocker.radius;
  const double beta = cfg.sheave.cone_angle * M_PI / 180.0;
  m.tan_beta = std::tan(beta);
  m.sin_beta = std::sin(beta);
  m.cos_beta = std::cos(beta);
  m.damp = cfg.damping.scale;
  m.beam_beta = cfg.pin.damping_time * m.damp;

  const int npl = cfg.chain.plates_per_link;
  m.plate_zeta.resize(npl);
  for (int k = 0; k < npl; ++k)
    m.plate_zeta[k] = npl == 1 ? 0.0 : cfg.chain.plate_spread * (double(k) / (npl - 1) - 0.5);
  const int nst = cfg.rocker.stations;
  m.station_xi.resize(nst);
  for (int k = 0; k < nst; ++k) m.station_xi[k] = (k + 0.5) / nst;

  // 3.1: consistent beam masses of a half, plus its share of the plate mass lumped on the
  // lateral translations of its two ends.
  const double mh = cfg.pin.mass, L = m.L0;
  m.bend_mass << 156, 22 * L, 54, -13 * L,
                 22 * L, 4 * L * L, 13 * L, -3 * L * L,
                 54, 13 * L, 156, -22 * L,
                 -13 * L, -3 * L * L, -22 * L, 4 * L * L;
  m.bend_mass *= mh / 420.0;
  const double plate_share = 0.5 * npl * cfg.chain.plate_mass;  // per half
  m.bend_mass(0, 0) += 0.5 * plate_share;
  m.bend_mass(2, 2) += 0.5 * plate_share;
  m.bend_mass_inv = m.bend_mass.inverse();
  m.axial_mass << 2, 1, 1, 2;
  m.axial_mass *= mh / 6.0;
  m.axial_mass_inv = m.axial_mass.inverse();
  m.pack_mass = npl * cfg.chain.plate_mass;
  const double ms = cfg.shaft.mass, mw = cfg.shaft.sheave_mass;
  m.shaft_axial_mass << ms + mw, mw, mw, mw;
  m.shaft_axial_mass_inv = m.shaft_axial_mass.inverse();
  m.bend_inv_w = m.bend_mass_inv * Eigen::Vector4d(1, 0, 1, 0);
  m.bend_inv_s = m.bend_inv_w[0] + m.bend_inv_w[2];

  // 5: geometry.
  const ChainPathParams gp = chain_path_params(cfg);
  ChainPlacement pl = place_chain(gp);
  m.closure_residual = pl.closure_residual;
  m.geometry_iterations = pl.iterations;

  m.pulley[0].centre = {0.0, 0.0};
  m.pulley[1].centre = {cfg.geometry.centre_distance, 0.0};
  m.pulley[0].moving_side = +1;
  m.pulley[1].moving_side = -1;
  m.pulley[0].running_radius = pl.R1;
  m.pulley[1].running_radius = pl.R2;
  if (cfg.controller.enabled) check_targets(cfg, gp);
  // Faces placed so that the crowned ends of wrapped pins just touch them (5.3): the
  // half centre lines of a regular arc sit at radius r_h.
  const double Rend = cfg.pulley_contact.end_radius;
  for (int k = 0; k < 2; ++k) {
    // Every half starts on or (where lifted, 5.2) just outside the path circle rho_k.
    const double r_h = k == 0 ? pl.rho1 : pl.rho2;
    const double zc = 0.5 * L - Rend;  // sphere centre of the + end
    const double zplus = zc + (Rend - r_h * m.sin_beta) / m.cos_beta;
    m.pulley[k].face_z = {-zplus, zplus};
  }

  // Initial state: positions and rigid motion along the path (5.4).
  m.y0 = Eigen::VectorXd::Zero(m.nstate);
  double* q = m.y0.data();
  double* v = q + m.ndof;
  const double w1 = drive_speed(cfg, 0.0);
  const double speed = w1 * pl.R1;
  const double w2 = speed / pl.R2;
  for (int j = 0; j < m.links; ++j) {
    const Eigen::Vector2d* P[2] = {&pl.pa[j], &pl.pb[j]};
    const Eigen::Vector2d* U[2] = {&pl.unit_va[j], &pl.unit_vb[j]};
    const int base[2] = {m.half_a(j), m.half_b(j)};
    for (int h = 0; h < 2; ++h) {
      const Eigen::Vector2d vel = speed * *U[h];
      for (int e = 0; e < 2; ++e) {
        const int o = base[h] + e * half::kEnd;
        q[o + half::kX] = P[h]->x();
        q[o + half::kY] = P[h]->y();
        q[o + half::kZ] = (e == 0 ? -0.5 : 0.5) * L;
        v[o + half::kX] = vel.x();
        v[o + half::kY] = vel.y();
      }
    }
  }
  v[m.shaft(0) + kPhi] = w1;
  v[m.shaft(1) + kPhi] = w2;
  v[m.load_index()] = w2;
  return m;
}

}  // namespace cvt
