// Every schedule gives the same bits: the trajectory of the mini
// model over a few hundred RK4 steps, from a perturbed state with contacts switching, is
// compared byte for byte across schedulers, thread counts, grains and NUMA layouts.
#include <gtest/gtest.h>

#include <chrono>
#include <cstdlib>
#include <cstring>

#include "engine/simulation.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

constexpr int kSteps = 300;

Eigen::VectorXd trajectory(const Model& m, const ScheduleOptions& o) {
  Simulation sim(m, o);
  sim.mutable_state() = test::perturbed_state(m, 7, 2e-6, 1e-4, 0.05);
  for (int i = 0; i < kSteps; ++i) sim.step(m.cfg.integrator.step);
  return sim.state();
}

bool same_bits(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), sizeof(double) * a.size()) == 0;
}

double max_rel_diff(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  return (a - b).cwiseAbs().maxCoeff() / std::max(1e-300, a.cwiseAbs().maxCoeff());
}

class DeterminismTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    model_ = new Model(test::model("mini", {"integrator.step=2e-8"}));
    reference_ = new Eigen::VectorXd(trajectory(*model_, {}));
  }
  static void TearDownTestSuite() {
    delete reference_;
    delete model_;
  }
  static void expect_same(const ScheduleOptions& o, const char* what) {
    const Eigen::VectorXd y = trajectory(*model_, o);
    std::printf("%-40s threads %d grain %d: max rel diff to serial %.3g\n", what, o.threads, o.grain,
                max_rel_diff(*reference_, y));
    EXPECT_TRUE(same_bits(*reference_, y)) << what << " with " << o.threads << " threads";
  }
  static Model* model_;
  static Eigen::VectorXd* reference_;
};
Model* DeterminismTest::model_ = nullptr;
Eigen::VectorXd* DeterminismTest::reference_ = nullptr;

TEST_F(DeterminismTest, TrajectoryMovesAwayFromTheStart) {
  // A test of identity is only worth something if the trajectory does something.
  const Eigen::VectorXd y0 = test::perturbed_state(*model_, 7, 2e-6, 1e-4, 0.05);
  EXPECT_GT(max_rel_diff(y0, *reference_), 1e-6);
}

TEST_F(DeterminismTest, FlowGraphEqualsSerialForAnyThreadCountAndGrain) {
  for (int threads : {1, 2, 3, 4})
    for (int grain : {1, 4, 7}) {
      ScheduleOptions o;
      o.kind = SchedulerKind::flowgraph;
      o.threads = threads;
      o.grain = grain;
      expect_same(o, "flowgraph");
    }
}

TEST_F(DeterminismTest, PaperOmpEqualsSerialForAnyThreadCount) {
  for (int threads : {1, 2, 3, 5}) {
    ScheduleOptions o;
    o.kind = SchedulerKind::paper_omp;
    o.threads = threads;
    expect_same(o, "paper-omp");
  }
}

TEST_F(DeterminismTest, FlowGraphOnASyntheticTwoNodeLayoutEqualsSerial) {
  setenv("HWLOC_SYNTHETIC", "package:2 numa:1 core:1 pu:1", 1);
  setenv("HWLOC_THISSYSTEM", "1", 1);
  for (int threads : {2, 3}) {
    ScheduleOptions o;
    o.kind = SchedulerKind::flowgraph;
    o.threads = threads;
    o.grain = 2;
    Simulation probe(*model_, o);
    const std::string d = probe.schedule().describe();
    std::printf("%s\n", d.c_str());
    EXPECT_NE(d.find("2 NUMA arenas"), std::string::npos) << d;
    EXPECT_NE(d.find("per-node array segments moved to their node"), std::string::npos) << d;
    expect_same(o, "flowgraph, synthetic 2 nodes");
  }
  unsetenv("HWLOC_SYNTHETIC");
  unsetenv("HWLOC_THISSYSTEM");
}

// On two nodes each node's segment of the per-pin arrays is moved to it. Node 0 of the
// synthetic layout is the real node, so its pages must move; node 1 is fake, and the
// kernel's refusal must be reported. The reference model's 42-pin segments (16 KB of
// slots each) always hold whole pages.
TEST(FlowGraphTest, TwoNodeLayoutMovesEachSegmentToItsNode) {
  setenv("HWLOC_SYNTHETIC", "package:2 numa:1 core:1 pu:1", 1);
  setenv("HWLOC_THISSYSTEM", "1", 1);
  const Model m = test::model("reference");
  Workspace ws(m);
  ScheduleOptions o;
  o.kind = SchedulerKind::flowgraph;
  o.threads = 2;
  // A simulation's schedule also places the integrator's state vectors.
  Simulation sim(m, o);
  const std::string d = sim.schedule().describe();
  unsetenv("HWLOC_SYNTHETIC");
  unsetenv("HWLOC_THISSYSTEM");
  std::printf("%s\n", d.c_str());
  int sm = 0, st = 0;
  const auto sat = d.find(" per-node state segments");
  ASSERT_NE(sat, std::string::npos) << d;
  ASSERT_EQ(std::sscanf(d.c_str() + d.rfind("; ", sat) + 2, "%d of %d", &sm, &st), 2) << d;
  EXPECT_GE(sm, 5) << "node 0's state segments did not move: " << d;
  int moved = 0, tried = 0;
  const auto at = d.find(" per-node array segments");
  ASSERT_NE(at, std::string::npos) << d;
  const auto start = d.rfind("; ", at);
  ASSERT_EQ(std::sscanf(d.c_str() + start + 2, "%d of %d", &moved, &tried), 2) << d;
  EXPECT_GE(moved, 3) << "node 0's slot segments did not move: " << d;
  if (moved < tried) {
    EXPECT_NE(d.find("failed"), std::string::npos) << d;
  }
}

// The four module nodes of a stage can run at the same time: with two threads, some
// stage shows another module node running while chain_forces runs.
TEST(FlowGraphTest, ModuleNodesOverlap) {
  const Model m = test::model("reference");
  ScheduleOptions o;
  o.kind = SchedulerKind::flowgraph;
  o.threads = 2;
  Workspace ws(m);
  auto schedule = make_schedule(m, ws, o);
  schedule->set_tracing(true);
  Eigen::VectorXd dy(m.nstate);
  // At least 200 stages; under a loaded machine (ctest -j) keep going for up to 3 s, so
  // that the two threads get a core at the same time.
  int overlapping = 0, stages = 0;
  const auto start = std::chrono::steady_clock::now();
  while (stages < 200 || (overlapping == 0 && std::chrono::steady_clock::now() - start < std::chrono::seconds(3))) {
    ++stages;
    schedule->rhs(0.0, m.y0.data(), dy.data(), nullptr);
    const auto spans = schedule->last_spans();
    ASSERT_EQ(spans.size(), 4u);
    bool any = false;
    for (std::size_t a = 1; a < spans.size(); ++a)
      any |= spans[a].begin < spans[0].end && spans[0].begin < spans[a].end;
    overlapping += any;
  }
  std::printf("stages where another module node overlapped chain_forces: %d of %d\n", overlapping, stages);
  EXPECT_GT(overlapping, 0);
}

}  // namespace
}  // namespace cvt
