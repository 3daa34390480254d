#include "engine/model/state.hpp"

namespace cvt {

// Sizes every buffer once from the model: nothing is allocated inside a step.
Workspace::Workspace(const Model& m) {
  const int N = m.links;
  for (auto* v : {&kin.ex, &kin.ey, &kin.inv_len, &kin.psi_dot, &kin.dx, &kin.dy, &kin.ddx, &kin.ddy})
    v->assign(N, 0.0);
  status.rocker.assign(N * m.cfg.rocker.stations, 1);
  status.pulley.assign(N * ContactStatus::kPulleyPerJoint, 1);
  chain_slots.resize(N);
  pulley_slots.resize(N);
  inertia_slots.resize(N);
  for (auto* s : {&chain_slots, &pulley_slots, &inertia_slots})
    for (auto& x : *s) x.clear();
  capacitance_inv.assign(N, 0.0);
  switch_slot.assign(N, 0.0);
  force = Eigen::VectorXd::Zero(m.ndof);
  accel = Eigen::VectorXd::Zero(m.ndof);
  accel_free = Eigen::VectorXd::Zero(m.ndof);
  link_tau.assign(N, 0.0);
}

FrictionJacobian::FrictionJacobian(const Model& m) {
  const std::size_t N = static_cast<std::size_t>(m.links);
  rocker_damping.assign(N * kDim * kDim, 0.0);
  pulley_damping.assign(N * kDim * kDim, 0.0);
  pulley_shaft_damping.assign(N * 2 * kDim * kShaftSize, 0.0);
  pulley_shaft_self.assign(N * 2 * kShaftSize * kShaftSize, 0.0);
  const std::size_t nr = N * m.cfg.rocker.stations, np = N * ContactStatus::kPulleyPerJoint;
  rocker_fresh.resize(nr);
  pulley_fresh.resize(np);
  pulley_shaft_cols.assign(np * 2 * kShaftSize, 0.0);
}

FrozenFriction::FrozenFriction(const Model& m) {
  const std::size_t nr = static_cast<std::size_t>(m.links) * m.cfg.rocker.stations;
  const std::size_t np = static_cast<std::size_t>(m.links) * ContactStatus::kPulleyPerJoint;
  rocker_stick.assign(nr, 0), pulley_stick.assign(np, 0);
  rocker_dir.assign(3 * nr, 0.0), pulley_dir.assign(3 * np, 0.0);
}

}  // namespace cvt
