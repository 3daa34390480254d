#include "engine/rhs/rhs.hpp"

#include "engine/rhs/stages.hpp"
#include "modules/chain_forces.hpp"
#include "modules/inertia.hpp"
#include "modules/other_forces.hpp"
#include "modules/pulley_contact.hpp"

namespace cvt {

void set_stage_input(const Model& m, Workspace& ws, double t, const double* y) {
  ws.t = t;
  ws.q = y;
  ws.v = y + m.ndof;
  ws.aux = y + 2 * m.ndof;
}

// Sum of one module's two contributions to coordinate i of joint j: its own slot, and,
// for the coordinates of half a_j, the f_next_a of slot j-1. "0.0 +" first, so that the
// result equals a zero-initialized buffer summed in any order (graph/paper_omp.cpp).
static inline double module_sum(const std::vector<JointSlot>& s, int j, int jp, int i) {
  const double own = 0.0 + s[j].f[i];
  return i < half::kSize ? own + s[jp].f_next_a[i] : own;
}
static inline double module_tau(const std::vector<JointSlot>& s, int i, int in) {
  return (0.0 + s[i].tau_own) + s[in].tau_prev;
}

// The gather of joints [begin, end) with the chain and pulley sums taken from `chain` and
// `pulley` (each sum(j, jp, i) and tau(i, in)).
template <class Chain, class Pulley>
static void gather_joints_impl(const Model& m, Workspace& ws, const Chain& chain, const Pulley& pulley, int begin,
                               int end) {
  double* F = ws.force.data();
  for (int j = begin; j < end; ++j) {
    const int jp = m.wrap(j - 1), jn = m.wrap(j + 1);
    double* fj = F + m.joint(j);
    for (int i = 0; i < kJointSize; ++i)
      fj[i] = (chain.sum(j, jp, i) + pulley.sum(j, jp, i)) + module_sum(ws.inertia_slots, j, jp, i);
    // Torque of link i acts through g_i: + on a_{i+1}, - on b_i (docs/model.md 3.2).
    const auto tau = [&](int i, int in) {
      return (chain.tau(i, in) + pulley.tau(i, in)) + module_tau(ws.inertia_slots, i, in);
    };
    const double tp = tau(jp, j), to = tau(j, jn);
    ws.link_tau[j] = to;
    double gxp, gyp, gxo, gyo;
    link_g(ws.kin, jp, gxp, gyp);
    link_g(ws.kin, j, gxo, gyo);
    for (int e = 0; e < 2; ++e) {
      fj[kJointA + e * half::kEnd + half::kX] += tp * gxp;
      fj[kJointA + e * half::kEnd + half::kY] += tp * gyp;
      fj[kJointB + e * half::kEnd + half::kX] -= to * gxo;
      fj[kJointB + e * half::kEnd + half::kY] -= to * gyo;
    }
  }
  a0_inverse_joints(m, F, ws.accel_free.data(), begin, end);
}

namespace {
struct FromSlots {
  const std::vector<JointSlot>& s;
  double sum(int j, int jp, int i) const { return module_sum(s, j, jp, i); }
  double tau(int i, int in) const { return module_tau(s, i, in); }
};
struct FromBuffer {
  const Model& m;
  const double* b;
  double sum(int j, int, int i) const { return b[m.joint(j) + i]; }
  double tau(int i, int) const { return b[kJointSize * m.links + i]; }
};
}  // namespace

void gather_joints(const Model& m, Workspace& ws, int begin, int end) {
  gather_joints_impl(m, ws, FromSlots{ws.chain_slots}, FromSlots{ws.pulley_slots}, begin, end);
}

void gather_joints_from_sums(const Model& m, Workspace& ws, const double* chain_sum, const double* pulley_sum,
                             int begin, int end) {
  gather_joints_impl(m, ws, FromBuffer{m, chain_sum}, FromBuffer{m, pulley_sum}, begin, end);
}

void scatter_slot(const Model& m, const JointSlot& s, int j, double* buf) {
  double* fj = buf + m.joint(j);
  for (int i = 0; i < kJointSize; ++i) fj[i] += s.f[i];
  double* fa = buf + m.half_a(j + 1);
  for (int i = 0; i < half::kSize; ++i) fa[i] += s.f_next_a[i];
  double* tau = buf + kJointSize * m.links;
  tau[m.wrap(j - 1)] += s.tau_prev;
  tau[j] += s.tau_own;
}

void gather_shafts(const Model& m, Workspace& ws) {
  double* F = ws.force.data();
  const int N = m.links;
  double* fs = F + m.shaft(0);
  for (int i = 0; i < 2 * kShaftSize + 1; ++i) fs[i] = 0.0;
  double p = ws.other.p_diss;
  // Only pulley contact acts on the shafts, and inertia dissipates nothing: the other
  // slots hold zeros there (adding them would change no bit, only cost cache misses).
  for (int j = 0; j < N; ++j) p += ws.chain_slots[j].p_diss;
  for (int j = 0; j < N; ++j) {
    const JointSlot& s = ws.pulley_slots[j];
    for (int i = 0; i < 2 * kShaftSize; ++i) fs[i] += s.shaft[i];
    p += s.p_diss;
  }
  for (int i = 0; i < 2 * kShaftSize + 1; ++i) fs[i] += ws.other.f[i];
  ws.p_diss = p;
  a0_inverse_shafts(m, F, ws.accel.data());
}

void finish_joints(const Model& m, Workspace& ws, double* dy, const StageOp* op, int begin, int end) {
  woodbury_joints(m, ws, ws.accel_free.data(), ws.accel.data(), begin, end);
  const int n = m.ndof;
  const int lo = m.joint(begin), hi = m.joint(begin) + kJointSize * (end - begin);
  for (int i = lo; i < hi; ++i) dy[i] = ws.v[i];
  for (int i = lo; i < hi; ++i) dy[n + i] = ws.accel[i];
  if (op) stage_update_joints(m, op, dy, begin, end);
}

void stage_update_joints(const Model& m, const StageOp* op, double* dy, int begin, int end) {
  const int n = m.ndof;
  const int lo = m.joint(begin), hi = m.joint(begin) + kJointSize * (end - begin);
  op->apply(dy, lo, hi);
  op->apply(dy, n + lo, n + hi);
}

void finish_shafts(const Model& m, Workspace& ws, double* dy, const StageOp* op) {
  const int n = m.ndof, lo = m.shaft(0);
  for (int i = lo; i < n; ++i) dy[i] = ws.v[i];
  for (int i = lo; i < n; ++i) dy[n + i] = ws.accel[i];
  double* da = dy + 2 * n;
  da[kWorkIn] = ws.other.p_in;
  da[kWorkOut] = ws.other.p_out;
  da[kWorkDiss] = ws.p_diss;
  da[kWorkClamp] = ws.other.p_clamp;
  da[kCtrlIntegral] = ws.other.ctrl_rate;
  da[kWorkSwitch] = 0.0;  // incremented between steps, not integrated (docs/model.md 4.4)
  if (op) stage_update_shafts(m, op, dy);
}

void stage_update_shafts(const Model& m, const StageOp* op, double* dy) {
  const int n = m.ndof, lo = m.shaft(0);
  op->apply(dy, lo, n);
  op->apply(dy, n + lo, m.nstate);
}

void gather_forces(const Model& m, Workspace& ws) {
  gather_joints(m, ws, 0, m.links);
  gather_shafts(m, ws);
}

void rhs_serial(const Model& m, Workspace& ws, double t, const double* y, double* dy, const StageOp* op,
                Profiler* prof, const FrictionExtras& x) {
  if (prof) prof->call_rhs(op != nullptr);
  set_stage_input(m, ws, t, y);
  const StageArgs a{m, ws, dy, op, x};
  for (const StageDecl& s : kStages) run_stage(s, a, prof, 0);
}

void begin_status_update(const Model& m, Workspace& ws, double t, const double* y) {
  set_stage_input(m, ws, t, y);
  link_kinematics(m, ws, 0, m.links);
}

void update_status_joints(const Model& m, Workspace& ws, int begin, int end) {
  for (int j = begin; j < end; ++j) ws.switch_slot[j] = 0.0;
  update_rocker_status(m, ws, begin, end);
  update_pulley_status(m, ws, begin, end);
}

void finish_status_update(const Model& m, Workspace& ws) {
  double w = 0.0;
  for (int j = 0; j < m.links; ++j) w += ws.switch_slot[j];
  ws.switch_work = w;
}

void update_contact_status(const Model& m, Workspace& ws, double t, const double* y, Profiler* prof) {
  if (prof) prof->call(Section::status);
  ScopedTimer tm(prof, 0, Section::status);
  begin_status_update(m, ws, t, y);
  update_status_joints(m, ws, 0, m.links);
  finish_status_update(m, ws);
}

Energies energies(const Model& m, double t, const double* y, const ContactStatus* status) {
  Energies e;
  e.kinetic = kinetic_energy(m, y, y + m.ndof);
  e.elastic = chain_energy(m, y, status) + pulley_energy(m, y, status) + other_energy(m, t, y);
  return e;
}

}  // namespace cvt
