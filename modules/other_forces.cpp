// docs/model.md 4.6.
#include "modules/other_forces.hpp"

#include <cmath>

namespace cvt {

void other_forces(const Model& m, Workspace& ws) {
  const Config& c = m.cfg;
  OtherForces& o = ws.other;
  o.f.fill(0.0);
  o.p_diss = o.p_in = o.p_out = o.p_clamp = 0.0;
  const double* q = ws.q;
  const double* v = ws.v;
  const double d = m.damp;
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
      const double cr = c.bearing.radial_damping * d;
      const double Fx = stiff * dx + cr * ddx, Fy = stiff * dy + cr * ddy;  // force on the bearing
      o.p_diss += cr * (ddx * ddx + ddy * ddy);
      f[kUx] -= Fx;
      f[kUy] -= Fy;
      f[kTx] += Fy * zb;
      f[kTy] -= Fx * zb;
      o.support_force[k][b] = std::sqrt(Fx * Fx + Fy * Fy);
    }
    const double ca = c.bearing.axial_damping * d;
    f[kUz] -= c.bearing.axial_stiffness * s[kUz] + ca * sv[kUz];
    o.p_diss += ca * sv[kUz] * sv[kUz];
    // Moving sheave sliding on its shaft.
    const double cw = c.clamping.sheave_damping * d;
    f[kW] -= cw * sv[kW];
    o.p_diss += cw * sv[kW] * sv[kW];
  }
  // 4.6.2 drive: torsion spring-damper from the prescribed input angle.
  const int p1 = m.shaft(0) + kPhi, p2 = m.shaft(1) + kPhi, pl = m.load_index();
  const double win = c.drive.speed;
  const double ct = c.drive.damping * d;
  const double Min = c.drive.stiffness * (input_angle(m, ws.t) - q[p1]) + ct * (win - v[p1]);
  o.f[kPhi] += Min;
  o.input_torque = Min;
  o.p_in = Min * win;
  o.p_diss += ct * (win - v[p1]) * (win - v[p1]);
  // 4.6.3 load: torsion spring-damper to the load inertia, load torque on it.
  const double cl = c.load.damping * d;
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
  const double r = ramp(ws.t, c.ramp.time);
  double F[2], Fd[2];
  clamping_schedule(m, ws.t, F, Fd);
  double ctrl = 0;
  o.ctrl_rate = 0;
  if (c.controller.enabled) {
    const double ratio = v[p2] != 0 ? v[p1] / v[p2] : 0.0;
    const double err = c.controller.target_ratio - ratio;
    o.ctrl_rate = err;
    // Larger ratio wanted -> smaller driving radius -> less driving clamping force.
    ctrl = -(c.controller.kp * err + c.controller.ki * ws.aux[kCtrlIntegral]) * r;
    ctrl = std::max(ctrl, clamping_floor(m, ws.t) - F[0]);
  }
  for (int k = 0; k < 2; ++k) {
    const int sm = m.pulley[k].moving_side;
    const double w = q[m.shaft(k) + kW], wd = v[m.shaft(k) + kW];
    const double Framp = F[k];
    const double Fc = k == 0 ? ctrl : 0.0;
    o.f[kShaftSize * k + kW] -= sm * (Framp + Fc);
    o.clamp[k] = Framp + Fc;
    o.p_clamp += sm * Fd[k] * w - sm * Fc * wd;
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
