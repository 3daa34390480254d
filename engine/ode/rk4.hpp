// Fixed-step RK4 over a generic first-order system y' = f(t, y) (docs/model.md 7).
#pragma once

#include <type_traits>
#include <vector>

#include <Eigen/Dense>

namespace cvt {

// The integrator's update of one stage, handed to the right-hand side so that a parallel
// schedule can run it over the same pin ranges as the forces (docs/model.md 7). With
// d = dy[i]:  acc[i] = d (first stage) or acc[i] + w d;  then next[i] = base[i] + a d, or
// in the last stage next[i] = base[i] + a acc[i]. Element by element, so the result does
// not depend on how the range is split. base, next and acc are all required.
struct StageOp {
  const double* base = nullptr;
  double* next = nullptr;
  double a = 0;
  double* acc = nullptr;
  double w = 1;
  bool first = false, last = false;
  void apply(const double* dy, int begin, int end) const {
    // One loop per case, so that each vectorizes; the arithmetic is the formula above.
    if (first) {
      for (int i = begin; i < end; ++i) acc[i] = dy[i], next[i] = base[i] + a * dy[i];
    } else if (last) {
      for (int i = begin; i < end; ++i) {
        const double s = acc[i] + w * dy[i];
        acc[i] = s;
        next[i] = base[i] + a * s;
      }
    } else {
      for (int i = begin; i < end; ++i) acc[i] = acc[i] + w * dy[i], next[i] = base[i] + a * dy[i];
    }
  }
};

// Classical RK4. f is either f(t, y, dy) or f(t, y, dy, const StageOp*), the latter applying
// the stage update itself (after dy is complete for the coordinates it updates). The two
// give the same bits: y + h/6 (((k1 + 2 k2) + 2 k3) + k4) and y + (h/2) k in both.
class Rk4 {
 public:
  explicit Rk4(int size)
      : k_(Eigen::VectorXd::Zero(size)), acc_(Eigen::VectorXd::Zero(size)), s1_(Eigen::VectorXd::Zero(size)),
        s2_(Eigen::VectorXd::Zero(size)) {}

  // The integrator's own state-sized vectors (for NUMA placement).
  std::vector<double*> buffers() { return {k_.data(), acc_.data(), s1_.data(), s2_.data()}; }

  template <class F>
  void step(F&& f, double t, double h, Eigen::VectorXd& y) {
    StageOp op;
    op.base = y.data();
    op.acc = acc_.data();
    const double hh = 0.5 * h;
    // Stage inputs alternate between two buffers: no stage writes the vector it reads.
    op.next = s1_.data(), op.a = hh, op.first = true, op.w = 1.0;
    stage(f, t, y.data(), op);
    op.next = s2_.data(), op.a = hh, op.first = false, op.w = 2.0;
    stage(f, t + hh, s1_.data(), op);
    op.next = s1_.data(), op.a = h;
    stage(f, t + hh, s2_.data(), op);
    op.next = y.data(), op.a = h / 6.0, op.w = 1.0, op.last = true;
    stage(f, t + h, s1_.data(), op);
  }

 private:
  template <class F>
  void stage(F& f, double t, const double* in, const StageOp& op) {
    if constexpr (std::is_invocable_v<F&, double, const double*, double*, const StageOp*>) {
      f(t, in, k_.data(), &op);
    } else {
      f(t, in, k_.data());
      op.apply(k_.data(), 0, static_cast<int>(k_.size()));
    }
  }
  Eigen::VectorXd k_, acc_, s1_, s2_;
};

}  // namespace cvt
