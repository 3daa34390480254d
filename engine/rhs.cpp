#include "engine/rhs.hpp"

#include "modules/chain_forces.hpp"
#include "modules/inertia.hpp"
#include "modules/other_forces.hpp"
#include "modules/pulley_contact.hpp"

namespace cvt {

Workspace::Workspace(const Model& m) {
  const int N = m.links;
  for (auto* v : {&kin.ex, &kin.ey, &kin.inv_len, &kin.psi_dot, &kin.dx, &kin.dy, &kin.ddx, &kin.ddy})
    v->assign(N, 0.0);
  status.rocker.assign(N * m.cfg.rocker.stations, 1);
  status.pulley.assign(N * 8, 1);
  chain_slots.resize(N);
  pulley_slots.resize(N);
  inertia_slots.resize(N);
  for (auto* s : {&chain_slots, &pulley_slots, &inertia_slots})
    for (auto& x : *s) x.clear();
  capacitance_inv.assign(N, 0.0);
  force = Eigen::VectorXd::Zero(m.ndof);
  accel = Eigen::VectorXd::Zero(m.ndof);
  link_tau.assign(N, 0.0);
}

void set_stage_input(const Model& m, Workspace& ws, double t, const double* y) {
  ws.t = t;
  ws.q = y;
  ws.v = y + m.ndof;
  ws.aux = y + 2 * m.ndof;
}

void gather_forces(const Model& m, Workspace& ws) {
  double* F = ws.force.data();
  ws.force.setZero();
  std::fill(ws.link_tau.begin(), ws.link_tau.end(), 0.0);
  double p = ws.other.p_diss;
  const int N = m.links;
  for (const auto* slots : {&ws.chain_slots, &ws.pulley_slots, &ws.inertia_slots}) {
    for (int j = 0; j < N; ++j) {
      const JointSlot& s = (*slots)[j];
      double* fj = F + m.joint(j);
      for (int i = 0; i < kJointSize; ++i) fj[i] += s.f[i];
      double* fa = F + m.half_a(j + 1);
      for (int i = 0; i < half::kSize; ++i) fa[i] += s.f_next_a[i];
      ws.link_tau[m.wrap(j - 1)] += s.tau_prev;
      ws.link_tau[j] += s.tau_own;
      double* fs = F + m.shaft(0);
      for (int i = 0; i < 2 * kShaftSize; ++i) fs[i] += s.shaft[i];
      p += s.p_diss;
    }
  }
  double* fo = F + m.shaft(0);
  for (int i = 0; i < 2 * kShaftSize + 1; ++i) fo[i] += ws.other.f[i];
  add_link_torques(m, ws.kin, ws.link_tau.data(), F);
  ws.p_diss = p;
}

void write_derivative(const Model& m, const Workspace& ws, double* dy) {
  const int n = m.ndof;
  for (int i = 0; i < n; ++i) dy[i] = ws.v[i];
  for (int i = 0; i < n; ++i) dy[n + i] = ws.accel[i];
  double* da = dy + 2 * n;
  da[kWorkIn] = ws.other.p_in;
  da[kWorkOut] = ws.other.p_out;
  da[kWorkDiss] = ws.p_diss;
  da[kWorkClamp] = ws.other.p_clamp;
  da[kCtrlIntegral] = ws.other.ctrl_rate;
  da[kWorkSwitch] = 0.0;  // incremented between steps, not integrated (docs/model.md 4.4)
}

void rhs_serial(const Model& m, Workspace& ws, double t, const double* y, double* dy) {
  set_stage_input(m, ws, t, y);
  const int N = m.links;
  link_kinematics(m, ws, 0, N);
  chain_forces(m, ws, 0, N);
  pulley_contact(m, ws, 0, N);
  other_forces(m, ws);
  inertia_decomposition(m, ws, 0, N);
  gather_forces(m, ws);
  accelerations(m, ws);
  write_derivative(m, ws, dy);
}

void update_contact_status(const Model& m, Workspace& ws, double t, const double* y) {
  set_stage_input(m, ws, t, y);
  ws.switch_work = 0;
  link_kinematics(m, ws, 0, m.links);
  update_rocker_status(m, ws);
  update_pulley_status(m, ws);
}

Energies energies(const Model& m, double t, const double* y, const ContactStatus* status) {
  Energies e;
  e.kinetic = kinetic_energy(m, y, y + m.ndof);
  e.elastic = chain_energy(m, y, status) + pulley_energy(m, y, status) + other_energy(m, t, y);
  return e;
}

}  // namespace cvt
