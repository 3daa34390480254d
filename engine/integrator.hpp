// Fixed-step RK4 over a generic first-order system y' = f(t, y) (docs/model.md 7).
#pragma once

#include <Eigen/Dense>

namespace cvt {

class Rk4 {
 public:
  explicit Rk4(int size)
      : k1_(Eigen::VectorXd::Zero(size)), k2_(Eigen::VectorXd::Zero(size)), k3_(Eigen::VectorXd::Zero(size)),
        k4_(Eigen::VectorXd::Zero(size)), tmp_(Eigen::VectorXd::Zero(size)) {}
  // Advances y from t to t + h. f(t, y_ptr, dy_ptr).
  template <class F>
  void step(F&& f, double t, double h, Eigen::VectorXd& y) {
    const Eigen::Index n = y.size();
    f(t, y.data(), k1_.data());
    for (Eigen::Index i = 0; i < n; ++i) tmp_[i] = y[i] + 0.5 * h * k1_[i];
    f(t + 0.5 * h, tmp_.data(), k2_.data());
    for (Eigen::Index i = 0; i < n; ++i) tmp_[i] = y[i] + 0.5 * h * k2_[i];
    f(t + 0.5 * h, tmp_.data(), k3_.data());
    for (Eigen::Index i = 0; i < n; ++i) tmp_[i] = y[i] + h * k3_[i];
    f(t + h, tmp_.data(), k4_.data());
    const double h6 = h / 6.0;
    for (Eigen::Index i = 0; i < n; ++i) y[i] += h6 * (k1_[i] + 2.0 * k2_[i] + 2.0 * k3_[i] + k4_[i]);
  }

 private:
  Eigen::VectorXd k1_, k2_, k3_, k4_, tmp_;
};

}  // namespace cvt
