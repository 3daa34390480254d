// docs/model.md 3.
#include "modules/inertia.hpp"

#include <cmath>

#include "modules/beam.hpp"

namespace cvt {

void link_kinematics(const Model& m, Workspace& ws, int begin, int end) {
  LinkKinematics& k = ws.kin;
  for (int i = begin; i < end; ++i) {
    const double* b = ws.q + m.half_b(i);
    const double* a = ws.q + m.half_a(i + 1);
    const double* vb = ws.v + m.half_b(i);
    const double* va = ws.v + m.half_a(i + 1);
    const double dx = mid(a, 0) - mid(b, 0), dy = mid(a, 1) - mid(b, 1);
    const double ddx = mid(va, 0) - mid(vb, 0), ddy = mid(va, 1) - mid(vb, 1);
    const double inv = 1.0 / std::sqrt(dx * dx + dy * dy);
    k.dx[i] = dx;
    k.dy[i] = dy;
    k.ddx[i] = ddx;
    k.ddy[i] = ddy;
    k.inv_len[i] = inv;
    k.ex[i] = dx * inv;
    k.ey[i] = dy * inv;
    // psi_dot = n . Delta_dot / |Delta|, n = (-ey, ex).
    k.psi_dot[i] = (-k.ey[i] * ddx + k.ex[i] * ddy) * inv;
  }
}

void inertia_decomposition(const Model& m, Workspace& ws, int begin, int end) {
  const double J = m.cfg.chain.link_inertia;
  const LinkKinematics& k = ws.kin;
  for (int i = begin; i < end; ++i) {
    // 3.2: C_i = 1/J + g_i^T A0^-1 g_i = 1/J + s / (2 |Delta|^2).
    const double inv2 = k.inv_len[i] * k.inv_len[i];
    ws.capacitance_inv[i] = 1.0 / (1.0 / J + 0.5 * m.bend_inv_s * inv2);
    // 3.3: -J g (qdot^T H qdot) with qdot^T H qdot = -2 psi_dot (Delta . Delta_dot)/|Delta|^2.
    JointSlot& s = ws.inertia_slots[i];
    s.clear();
    const double dd = k.dx[i] * k.ddx[i] + k.dy[i] * k.ddy[i];
    s.tau_own = 2.0 * J * k.psi_dot[i] * dd * inv2;
  }
}


void add_link_torques(const Model& m, const LinkKinematics& kin, const double* tau, double* F) {
  for (int i = 0; i < m.links; ++i) {
    double gx, gy;
    link_g(kin, i, gx, gy);
    double* a = F + m.half_a(i + 1);
    double* b = F + m.half_b(i);
    const double fx = tau[i] * gx, fy = tau[i] * gy;
    for (int e = 0; e < 2; ++e) {
      a[e * half::kEnd + half::kX] += fx;
      a[e * half::kEnd + half::kY] += fy;
      b[e * half::kEnd + half::kX] -= fx;
      b[e * half::kEnd + half::kY] -= fy;
    }
  }
}

// y = A0^-1 F, block by block (3.1).
void a0_inverse_joints(const Model& m, const double* F, double* y, int begin, int end) {
  for (int j = begin; j < end; ++j) {
    for (int h = 0; h < 2; ++h) {
      const int o = m.joint(j) + (h == 0 ? kJointA : kJointB);
      for (int p = 0; p < 2; ++p) {
        const auto d = plane_dofs(p);
        const Eigen::Vector4d f(F[o + d[0]], F[o + d[1]], F[o + d[2]], F[o + d[3]]);
        const Eigen::Vector4d r = m.bend_mass_inv * f;
        for (int i = 0; i < 4; ++i) y[o + d[i]] = r[i];
      }
      const Eigen::Vector2d fz(F[o + half::kZ], F[o + half::kEnd + half::kZ]);
      const Eigen::Vector2d rz = m.axial_mass_inv * fz;
      y[o + half::kZ] = rz[0];
      y[o + half::kEnd + half::kZ] = rz[1];
    }
    y[m.pack(j)] = F[m.pack(j)] / m.pack_mass;
  }
}

void a0_inverse_shafts(const Model& m, const double* F, double* y) {
  const Config& c = m.cfg;
  for (int k = 0; k < 2; ++k) {
    const int o = m.shaft(k);
    y[o + kUx] = F[o + kUx] / c.shaft.mass;
    y[o + kUy] = F[o + kUy] / c.shaft.mass;
    y[o + kTx] = F[o + kTx] / c.shaft.tilt_inertia;
    y[o + kTy] = F[o + kTy] / c.shaft.tilt_inertia;
    y[o + kPhi] = F[o + kPhi] / c.shaft.polar_inertia;
    const Eigen::Vector2d r = m.shaft_axial_mass_inv * Eigen::Vector2d(F[o + kUz], F[o + kW]);
    y[o + kUz] = r[0];
    y[o + kW] = r[1];
  }
  y[m.load_index()] = F[m.load_index()] / c.load.inertia;
}

// t_i = C_i^-1 g_i^T y for link i (3.2).
static inline double woodbury_t(const Model& m, const Workspace& ws, const double* y, int i, double& gx, double& gy) {
  link_g(ws.kin, i, gx, gy);
  const double* a = y + m.half_a(i + 1);
  const double* b = y + m.half_b(i);
  const double gty = gx * (a[half::kX] + a[half::kEnd + half::kX] - b[half::kX] - b[half::kEnd + half::kX]) +
                     gy * (a[half::kY] + a[half::kEnd + half::kY] - b[half::kY] - b[half::kEnd + half::kY]);
  return gty * ws.capacitance_inv[i];
}

void woodbury_joints(const Model& m, const Workspace& ws, const double* y, double* qdd, int begin, int end) {
  const Eigen::Vector4d& w = m.bend_inv_w;
  for (int j = begin; j < end; ++j) {
    const int o = m.joint(j);
    for (int i = 0; i < kJointSize; ++i) qdd[o + i] = y[o + i];
    // Links share no half: a_j belongs to link j-1 only, b_j to link j only.
    for (int h = 0; h < 2; ++h) {
      double gx, gy;
      const double t = woodbury_t(m, ws, y, h == 0 ? m.wrap(j - 1) : j, gx, gy);
      const double sign = h == 0 ? -1.0 : 1.0;
      double* r = qdd + o + (h == 0 ? kJointA : kJointB);
      for (int p = 0; p < 2; ++p) {
        const double g = p == 0 ? gx : gy;
        const auto d = plane_dofs(p);
        for (int k = 0; k < 4; ++k) r[d[k]] += sign * (t * g * w[k]);
      }
    }
  }
}

void accelerations(const Model& m, Workspace& ws) {
  // ws.accel_free holds y = A0^-1 F between the two passes.
  a0_inverse_joints(m, ws.force.data(), ws.accel_free.data(), 0, m.links);
  a0_inverse_shafts(m, ws.force.data(), ws.accel.data());  // the Woodbury part reads joints only
  woodbury_joints(m, ws, ws.accel_free.data(), ws.accel.data(), 0, m.links);
}

double kinetic_energy(const Model& m, const double* q, const double* v) {
  double T = 0;
  for (int j = 0; j < m.links; ++j) {
    for (int h = 0; h < 2; ++h) {
      const int o = m.joint(j) + (h == 0 ? kJointA : kJointB);
      for (int p = 0; p < 2; ++p) {
        const auto d = plane_dofs(p);
        const Eigen::Vector4d u(v[o + d[0]], v[o + d[1]], v[o + d[2]], v[o + d[3]]);
        T += 0.5 * u.dot(m.bend_mass * u);
      }
      const Eigen::Vector2d uz(v[o + half::kZ], v[o + half::kEnd + half::kZ]);
      T += 0.5 * uz.dot(m.axial_mass * uz);
    }
    T += 0.5 * m.pack_mass * v[m.pack(j)] * v[m.pack(j)];
    // Link rotation: 1/2 J psi_dot^2.
    const double* b = q + m.half_b(j);
    const double* a = q + m.half_a(j + 1);
    const double* vb = v + m.half_b(j);
    const double* va = v + m.half_a(j + 1);
    const double dx = mid(a, 0) - mid(b, 0), dy = mid(a, 1) - mid(b, 1);
    const double ddx = mid(va, 0) - mid(vb, 0), ddy = mid(va, 1) - mid(vb, 1);
    const double pd = (dx * ddy - dy * ddx) / (dx * dx + dy * dy);
    T += 0.5 * m.cfg.chain.link_inertia * pd * pd;
  }
  const Config& c = m.cfg;
  for (int k = 0; k < 2; ++k) {
    const int o = m.shaft(k);
    T += 0.5 * c.shaft.mass * (v[o + kUx] * v[o + kUx] + v[o + kUy] * v[o + kUy]);
    T += 0.5 * c.shaft.tilt_inertia * (v[o + kTx] * v[o + kTx] + v[o + kTy] * v[o + kTy]);
    T += 0.5 * c.shaft.polar_inertia * v[o + kPhi] * v[o + kPhi];
    const Eigen::Vector2d u(v[o + kUz], v[o + kW]);
    T += 0.5 * u.dot(m.shaft_axial_mass * u);
  }
  T += 0.5 * c.load.inertia * v[m.load_index()] * v[m.load_index()];
  return T;
}

Eigen::MatrixXd dense_inertia(const Model& m, const double* q) {
  const int n = m.ndof;
  Eigen::MatrixXd A = Eigen::MatrixXd::Zero(n, n);
  // A0 (3.1), block by block.
  for (int j = 0; j < m.links; ++j) {
    for (int h = 0; h < 2; ++h) set_half_mass(m, A, m.joint(j) + (h == 0 ? kJointA : kJointB));
    A(m.pack(j), m.pack(j)) = m.pack_mass;
  }
  const Config& c = m.cfg;
  for (int k = 0; k < 2; ++k) {
    const int o = m.shaft(k);
    A(o + kUx, o + kUx) = A(o + kUy, o + kUy) = c.shaft.mass;
    A(o + kTx, o + kTx) = A(o + kTy, o + kTy) = c.shaft.tilt_inertia;
    A(o + kPhi, o + kPhi) = c.shaft.polar_inertia;
    const int z[2] = {o + kUz, o + kW};
    for (int r = 0; r < 2; ++r)
      for (int cc = 0; cc < 2; ++cc) A(z[r], z[cc]) = m.shaft_axial_mass(r, cc);
  }
  A(m.load_index(), m.load_index()) = c.load.inertia;
  // + J g g^T.
  for (int i = 0; i < m.links; ++i) {
    Eigen::VectorXd g = Eigen::VectorXd::Zero(n);
    const double* b = q + m.half_b(i);
    const double* a = q + m.half_a(i + 1);
    const double dx = mid(a, 0) - mid(b, 0), dy = mid(a, 1) - mid(b, 1);
    const double l2 = dx * dx + dy * dy;
    const double gx = -0.5 * dy / l2, gy = 0.5 * dx / l2;
    for (int e2 = 0; e2 < 2; ++e2) {
      g(m.half_a(i + 1) + e2 * half::kEnd + half::kX) += gx;
      g(m.half_a(i + 1) + e2 * half::kEnd + half::kY) += gy;
      g(m.half_b(i) + e2 * half::kEnd + half::kX) -= gx;
      g(m.half_b(i) + e2 * half::kEnd + half::kY) -= gy;
    }
    A += c.chain.link_inertia * g * g.transpose();
  }
  return A;
}

}  // namespace cvt
