#include "engine/wmethod/w_step.hpp"

#include <sstream>
#include <stdexcept>

namespace cvt {

namespace {
ModelOdeOptions without_sparsity(ModelOdeOptions opt) {
  opt.sparsity = false;  // the stages need f and W alone
  if (opt.error_tol == 0) opt.error_tol = 1;  // the step's estimate in units of (1 um, 1 mm/s)
  return opt;
}
}  // namespace

WStep::WStep(const Model& m, Workspace& ws, Schedule& schedule, OdeMethod method, const ModelOdeOptions& opt)
    : ode_(m, ws, schedule, without_sparsity(opt)),
      method_(method),
      w4_(method == OdeMethod::Ros2 ? nullptr : &w4_tableau(method)),
      gamma_(w_method_gamma(method)) {
  if (!opt.w_blocks) throw std::invalid_argument("WStep: the production step needs the chain's W (w_blocks)");
  f0_.resize(m.nstate);
  v_.resize(m.nstate);
}

void WStep::evaluate(double t, const Eigen::VectorXd& y, long index) {
  ode_.ask_friction_jacobian(index);
  ode_.system().rhs(t, y.data(), f0_.data());
}

void WStep::finish(double t, double h, Eigen::VectorXd& y) {
  WSolver& w = ode_.w_solver();
  w.factor(t, y.data(), gamma_ * h);
  const OdeSystem& sys = ode_.system();
  const auto f = [&sys](double tt, const Eigen::VectorXd& yy, Eigen::VectorXd& dy) { sys.rhs(tt, yy.data(), dy.data()); };
  const auto solve = [&w](Eigen::VectorXd& x) { w.solve(x.data()); };
  if (!w4_)
    ros2_stages(t, h, y, f0_, nullptr, v_, true, f, solve);
  else
    w4_stages(*w4_, t, h, y, f0_, nullptr, v_, true, f, solve);
  err_ = sys.error_norm(v_.err.data(), y.data(), v_.y_new.data());
  y = v_.y_new;
}

std::string w_step_graphviz(const Config& c, int threads) {
  const Config::Integrator& in = c.integrator;
  const int stages = in.method == IntegratorMethod::ros2 ? 2 : 4;
  const std::string sweeps = threads > 1 ? "top sweep (thread 0) | bottom sweep (thread 1)" : "top sweep, then bottom sweep";
  std::ostringstream tol;
  tol << in.tolerance;
  std::ostringstream os;
  os << "digraph w_step {\n  rankdir=TB;\n  node [shape=box];\n  label=\"one " << to_string(in.method) << " step "
     << (in.tolerance > 0 ? "(adaptive, tolerance " + tol.str() + ")" : "(fixed)") << "\";\n";
  os << "  f1 [label=\"evaluation 1: the stage graph\\n(cvt-engine graph, digraph stage)\\n+ friction blocks and mu\"];\n";
  os << "  subgraph cluster_rebuild {\n    label=\"every " << in.w_every << " steps (stiffness every " << in.w_k_every
     << ")\";\n    stiffness [label=\"stiffness K: 63 force evaluations\\n(per colour and coordinate; "
     << (threads > 1 ? "two halves on two workspaces" : "one after the other") << ")\"];\n"
     << "    assembly [label=\"link blocks A + gh C + gh^2 K\\nper joint, over the threads\"];\n"
     << "    factor [label=\"block LU\\n" << sweeps << "\\nthen the middle and last block\"];\n"
     << "    stiffness -> assembly -> factor;\n  }\n";
  os << "  fresh [label=\"fresh friction: Woodbury terms\\nfor the contacts whose mu moved\\n(per contact: two columns, "
     << (in.w_shafts ? "sweeps, shafts' steps, z - Y x_s; " : "sweeps; ") << "one fork)\"];\n"
     << "  f1 -> stiffness;\n  factor -> fresh;\n";
  std::string prev = "fresh";
  for (int i = 1; i <= stages; ++i) {
    // (Built with += : GCC 12 warns falsely, -Wrestrict, on "f" + std::to_string(i).)
    std::string f = "f", w = "solve";
    f += std::to_string(i), w += std::to_string(i);
    if (i > 1)
      os << "  " << f << " [label=\"evaluation " << i << ": the stage graph\\n(cvt-engine graph, digraph stage)\"];\n"
         << "  " << prev << " -> " << f << ";\n";
    os << "  " << w << " [label=\"right side per link, then\\n" << sweeps
       << (in.w_shafts ? "\\nmiddle block, shafts' Schur step, z - Y x_s per link" : "\\nmiddle block")
       << "\\n(one fork: claimed phases)"
       << "\\n+ Woodbury correction\"];\n";
    os << "  " << (i > 1 ? f : prev) << " -> " << w << ";\n";
    prev = w;
  }
  os << "  sums [label=\"stage sums and the new state\\n(master)\"];\n  " << prev << " -> sums;\n";
  os << "  status [label=\"contact statuses\\nper pin, over the threads\"];\n";
  if (in.tolerance > 0)
    os << "  test [label=\"error norm per pin, shaft, load\\naccept, or retake with a shorter step\"];\n"
       << "  sums -> test -> status;\n";
  else
    os << "  sums -> status;\n";
  os << "}\n";
  return os.str();
}

}  // namespace cvt
