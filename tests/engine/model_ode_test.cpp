// The CVT model through the generic integrators (engine/model_ode.hpp,
// docs/integrators.md 11): the Jacobian pattern and its values against a dense
// finite-difference Jacobian, RK4 through the adapter against Simulation::step, an implicit
// method against RK4, and the energy balance.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdio>

#include "engine/model_ode.hpp"
#include "engine/rhs.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

// The mini model running under load (0.1 ms, ramp 0.1 ms), contacts established.
struct Running {
  Model m;
  Eigen::VectorXd y;
  ContactStatus status;
  double t = 0;
  Running() : m(test::model("mini", {"ramp.time=1e-4"})) {
    Simulation sim(m);
    for (int k = 0; k < 10000; ++k) sim.step(m.cfg.integrator.step);
    y = sim.state();
    status = sim.workspace().status;
    t = sim.time();
  }
};

const Running& running() {
  static Running r;
  return r;
}

// Dense forward-difference Jacobian (the same increments as the coloured one).
Eigen::MatrixXd dense_fd(const Model& m, Workspace& ws, double t, const Eigen::VectorXd& y) {
  const int ns = m.nstate;
  Eigen::VectorXd f0(ns), f1(ns), yp = y;
  rhs_serial(m, ws, t, y.data(), f0.data());
  Eigen::MatrixXd J(ns, ns);
  const double eps = std::numeric_limits<double>::epsilon();
  for (int c = 0; c < ns; ++c) {
    const double d = std::sqrt(eps * std::max(1e-5, std::abs(y[c])));
    yp[c] = y[c] + d;
    rhs_serial(m, ws, t, yp.data(), f1.data());
    J.col(c) = (f1 - f0) / d;
    yp[c] = y[c];
  }
  return J;
}

TEST(ModelOde, PatternCoversDenseJacobian) {
  const Running& r = running();
  const Model& m = r.m;
  Workspace ws(m);
  ws.status = r.status;
  const Eigen::MatrixXd D = dense_fd(m, ws, r.t, r.y);
  for (bool exact : {true, false}) {
    Workspace ws2(m);
    ws2.status = r.status;
    auto sched = make_schedule(m, ws2, {});
    ModelOde ode(m, ws2, *sched, {2, exact});
    Eigen::SparseMatrix<double> J = ode.system().sparsity;
    ode.jacobian(r.t, r.y.data(), J);
    const Eigen::MatrixXd S = Eigen::MatrixXd(J);
    // Every entry of the dense Jacobian outside the pattern, by kind.
    const int n = m.ndof, tail0 = m.shaft(0);
    double worst_out = 0, worst_pin_tail = 0, worst_diff = 0, scale = D.cwiseAbs().maxCoeff();
    int max_band = 0;
    std::string worst_at;
    Eigen::MatrixXd P = Eigen::MatrixXd(ode.system().sparsity).cwiseAbs();
    for (int c = 0; c < m.nstate; ++c)
      for (int rr = 0; rr < m.nstate; ++rr) {
        const double v = std::abs(D(rr, c));
        if (v == 0) continue;
        const bool pin_col = c < 2 * n && c % n < tail0, pin_row = rr < 2 * n && rr % n < tail0;
        if (pin_col && pin_row && rr >= n) {
          int d = std::abs((rr % n) / kJointSize - (c % n) / kJointSize);
          d = std::min(d, m.links - d);
          max_band = std::max(max_band, d);
        }
        if (P(rr, c) == 0) {
          if (pin_col && !pin_row) worst_pin_tail = std::max(worst_pin_tail, v);
          else worst_out = std::max(worst_out, v);
        } else {
          // Relative to the entry, with a floor at the row's rounding noise (sums of many
          // pins' forces in the shaft rows).
          const double dd = std::abs(S(rr, c) - D(rr, c)) / (v + 1e-7 * D.row(rr).cwiseAbs().maxCoeff());
          if (dd > worst_diff) {
            worst_diff = dd;
            worst_at = describe_state_index(m, rr) + " / " + describe_state_index(m, c);
          }
        }
      }
    std::printf("[model_ode] mini %s: %d colours, nnz %ld, joint band of the dense FD %d; largest dense entry "
                "outside the pattern %.3g (pins -> tail rows %.3g) of max %.3g; max |coloured - dense| relative "
                "%.3g at %s\n",
                exact ? "exact dense rows" : "approximate", ode.colors(), static_cast<long>(J.nonZeros()), max_band,
                worst_out, worst_pin_tail, scale, worst_diff, worst_at.c_str());
    EXPECT_LE(max_band, 2);
    EXPECT_EQ(worst_out, 0.0);
    if (exact) {
      EXPECT_EQ(worst_pin_tail, 0.0);
    }
    EXPECT_LE(worst_diff, 1e-2);  // 4e-3 measured, in the dissipated-power row (rounding of its sum)
  }
}

}  // namespace
}  // namespace cvt
