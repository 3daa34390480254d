// docs/model.md 4.6.
#include "modules/other_forces.hpp"

#include <algorithm>
#include <cmath>

#include "modules/damping.hpp"

namespace cvt {

namespace {

// The slip-safe clamping (docs/model.md 4.6.4): the smaller force B carries the torque the
// driven pulley must transmit with the safety factor, the PI on the sheaves' ratio sets
// kappa = F1/F2; ctrl_k is what it adds to the potential part F_k rho.
void slip_safe_control(const Model& m, Workspace& ws, const double F[2], double ctrl[2]) {
  const Config& c = m.cfg;
  const double R1 = sheave_radius(m, 0, ws.q[m.shaft(0) + kW]), R2 = sheave_radius(m, 1, ws.q[m.shaft(1) + kW]);
  const double err = target_ratio(c, ws.t) - R2 / R1;
  const double B = std::max(std::min(F[0], F[1]), slip_safe_gain(m) * transmitted_torque(c, ws.t) / R2);
  // Larger ratio wanted -> smaller driving radius -> a smaller thrust ratio.
  // The gains at the input speed they are given for (gain_speed): the shift rate grows with it.
  const double g = c.controller.gain_speed > 0 ? c.controller.gain_speed / drive_speed(c, ws.t) : 1.0;
  const double u = std::log(c.clamping.driving / c.clamping.driven) -
                   (g * c.controller.shift_kp * err + g * c.controller.shift_ki * ws.aux[kCtrlIntegral]);
  const double lim = std::log(c.controller.thrust_limit);
  const double lk = std::clamp(u, -lim, lim);
  // The integral stops while the thrust ratio sits at its limit and the error pushes on.
  ws.other.ctrl_rate = (u > lim && err < 0) || (u < -lim && err > 0) ? 0.0 : err;
  const double kappa = std::exp(lk);
  const double Ft[2] = {B * std::max(kappa, 1.0), B * std::max(1.0 / kappa, 1.0)};
  for (int k = 0; k < 2; ++k) ctrl[k] = Ft[k] - F[k];
}

}  // namespace

void other_forces(const Model& m, Workspace& ws) {
  const Config& c = m.cfg;
  OtherForces& o = ws.other;
  o.f.fill(0.0);
  o.p_diss = o.p_in = o.p_out = o.p_clamp = 0.0;
  const double* q = ws.q;
  const double* v = ws.v;
  const Damping d = damping(m);
  // 4.6.1 supports: two radial bearings at z = -+l_b, an axial bearing.
  for (int k = 0; k < 2; ++k) {
    const double* s = q + m.shaft(k);
    const double* sv = v + m.shaft(k);
    double* f = o.f.data() + kShaftSize * k;
    for (int b = 0; b < 2; ++b) {
      const double zb = (b == 0 ? -1.0 : 1.0) * c.bearing.half_span;
      const double dx = s[kUx] + s[kTy] * zb, dy = s[kUy] - s[kTx] * zb;
      const double ddx = sv[kUx] + sv[kTy] * zb, ddy = sv[kUy] - sv[kTx] * zb;
      const double stiff = c.bearing.k1 + c.bearing.k3 * (dx * dx + dy * dy);
      const double cr = d.bearing_radial;
      const double Fx = stiff * dx + cr * ddx, Fy = stiff * dy + cr * ddy;  // force on the bearing
      o.p_diss += cr * (ddx * ddx + ddy * ddy);
      f[kUx] -= Fx;
      f[kUy] -= Fy;
      f[kTx] += Fy * zb;
      f[kTy] -= Fx * zb;
      o.support_force[k][b] = std::sqrt(Fx * Fx + Fy * Fy);
    }
    const double ca = d.bearing_axial;
    f[kUz] -= c.bearing.axial_stiffness * s[kUz] + ca * sv[kUz];
    o.p_diss += ca * sv[kUz] * sv[kUz];
    // Moving sheave sliding on its shaft.
    const double cw = d.sheave;
    f[kW] -= cw * sv[kW];
    o.p_diss += cw * sv[kW] * sv[kW];
  }
  // 4.6.2 drive: torsion spring-damper from the prescribed input angle.
  const int p1 = m.shaft(0) + kPhi, p2 = m.shaft(1) + kPhi, pl = m.load_index();
  const double win = drive_speed(c, ws.t);
  const double ct = d.drive;
  const double Min = c.drive.stiffness * (input_angle(m, ws.t) - q[p1]) + ct * (win - v[p1]);
  o.f[kPhi] += Min;
  o.input_torque = Min;
  o.p_in = Min * win;
  o.p_diss += ct * (win - v[p1]) * (win - v[p1]);
  // 4.6.3 load: torsion spring-damper to the load inertia, load torque on it.
  const double cl = d.load;
  const double Ms = c.load.stiffness * (q[p2] - q[pl]) + cl * (v[p2] - v[pl]);
  o.f[kShaftSize + kPhi] -= Ms;
  o.f[2 * kShaftSize] += Ms;
  o.output_torque = Ms;
  o.p_diss += cl * (v[p2] - v[pl]) * (v[p2] - v[pl]);
  const double Mload = ramped_load_torque(c, ws.t) + c.load.speed_coefficient * v[pl];
  o.f[2 * kShaftSize] -= Mload;
  o.load_torque = Mload;
  o.p_out = Mload * v[pl];
  // 4.6.4 clamping: F_k(t) pushes the moving sheave towards the chain; the ramped part is
  // the potential sigma_m F w with explicit time dependence, the controller part external.
  double F[2], Fd[2], ctrl[2] = {0.0, 0.0};
  clamping_schedule(m, ws.t, F, Fd);
  o.ctrl_rate = 0;
  if (c.controller.enabled) {
    if (c.controller.clamping_safety > 0) {
      slip_safe_control(m, ws, F, ctrl);
    } else {
      const double ratio = v[p2] != 0 ? v[p1] / v[p2] : 0.0;
      const double err = target_ratio(c, ws.t) - ratio;
      o.ctrl_rate = err;
      // Larger ratio wanted -> smaller driving radius -> less driving clamping force.
      ctrl[0] = -(c.controller.kp * err + c.controller.ki * ws.aux[kCtrlIntegral]) * ramp(ws.t, c.ramp.time);
      ctrl[0] = std::max(ctrl[0], -F[0]);
    }
  }
  for (int k = 0; k < 2; ++k) {
    const int sm = m.pulley[k].moving_side;
    const double w = q[m.shaft(k) + kW], wd = v[m.shaft(k) + kW];
    o.f[kShaftSize * k + kW] -= sm * (F[k] + ctrl[k]);
    o.clamp[k] = F[k] + ctrl[k];
    o.p_clamp += sm * Fd[k] * w - sm * ctrl[k] * wd;
  }
}

double other_energy(const Model& m, double t, const double* q) {
  const Config& c = m.cfg;
  double E = 0, F[2], Fd[2];
  clamping_schedule(m, t, F, Fd);
  for (int k = 0; k < 2; ++k) {
    const double* s = q + m.shaft(k);
    for (int b = 0; b < 2; ++b) {
      const double zb = (b == 0 ? -1.0 : 1.0) * c.bearing.half_span;
      const double dx = s[kUx] + s[kTy] * zb, dy = s[kUy] - s[kTx] * zb;
      const double d2 = dx * dx + dy * dy;
      E += 0.5 * c.bearing.k1 * d2 + 0.25 * c.bearing.k3 * d2 * d2;
    }
    E += 0.5 * c.bearing.axial_stiffness * s[kUz] * s[kUz];
    E += m.pulley[k].moving_side * F[k] * s[kW];
  }
  const double dphi_in = input_angle(m, t) - q[m.shaft(0) + kPhi];
  E += 0.5 * c.drive.stiffness * dphi_in * dphi_in;
  const double dphi_l = q[m.shaft(1) + kPhi] - q[m.load_index()];
  E += 0.5 * c.load.stiffness * dphi_l * dphi_l;
  return E;
}

}  // namespace cvt
