// Every schedule gives the same bits: the trajectory of the mini
// model over a few hundred RK4 steps, from a perturbed state with contacts switching, is
// compared byte for byte across schedulers, thread counts, grains and NUMA layouts; and
// every schedule runs the stage table of engine/rhs/stages.hpp: its GraphViz names every
// stage, and the flow graph's edges are the table's dependencies.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <regex>
#include <set>
#include <utility>

#include "engine/rhs/stages.hpp"
#include "engine/simulation.hpp"
#include "graph/schedule.hpp"
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
    ASSERT_EQ(spans.size(), static_cast<std::size_t>(kStageCount));
    const NodeSpan* chain = nullptr;
    for (const NodeSpan& s : spans)
      if (s.name == "node0/chain_forces") chain = &s;
    ASSERT_NE(chain, nullptr);
    bool any = false;
    for (const NodeSpan& s : spans)
      any |= &s != chain && s.begin < chain->end && chain->begin < s.end;
    overlapping += any;
  }
  std::printf("stages where another module node overlapped chain_forces: %d of %d\n", overlapping, stages);
  EXPECT_GT(overlapping, 0);
}

using Edges = std::set<std::pair<std::string, std::string>>;

// The table's dependencies as (from, to) stage names, with "start" into the stages that
// depend on none.
Edges table_edges() {
  Edges e;
  for (const StageDecl& s : kStages) {
    if (s.after == 0) e.insert({"start", s.name});
    for (const StageDecl& d : kStages)
      if (contains(s.after, d.id)) e.insert({d.name, s.name});
  }
  return e;
}

// The edges of a flow-graph dump (nK_from -> nK_to), without the NUMA node's prefix.
Edges dumped_edges(const std::string& dot) {
  Edges e;
  static const std::regex edge(R"(n\d+_(\w+) -> n\d+_(\w+))");
  for (auto it = std::sregex_iterator(dot.begin(), dot.end(), edge); it != std::sregex_iterator(); ++it)
    e.insert({(*it)[1].str(), (*it)[2].str()});
  return e;
}

std::string dump(const Model& m, SchedulerKind kind, int threads) {
  Workspace ws(m);
  ScheduleOptions o;
  o.kind = kind;
  o.threads = threads;
  return make_schedule(m, ws, o)->graphviz();
}

// The table's own checks, run here too: the sanitizer build (CVT_SANITIZE) cannot evaluate the
// kernels' check at compile time.
TEST(StageTableTest, IsOrderedAndEveryStageHasTheKernelsOfItsSplit) {
  EXPECT_TRUE(stage_table_is_ordered());
  EXPECT_TRUE(stage_table_has_its_kernels());
}

TEST(StageTableTest, FlowGraphHasOneEdgePerDependencyOfTheTable) {
  const Model m = test::model("mini");
  for (int threads : {1, 2}) {
    const std::string dot = dump(m, SchedulerKind::flowgraph, threads);
    EXPECT_EQ(dumped_edges(dot), table_edges()) << dot;
  }
}

TEST(StageTableTest, FlowGraphOnTwoNodesHasEveryStageAndEveryDependencyOfTheTable) {
  setenv("HWLOC_SYNTHETIC", "package:2 numa:1 core:1 pu:1", 1);
  setenv("HWLOC_THISSYSTEM", "1", 1);
  const Model m = test::model("mini");
  const std::string dot = dump(m, SchedulerKind::flowgraph, 2);
  unsetenv("HWLOC_SYNTHETIC");
  unsetenv("HWLOC_THISSYSTEM");
  ASSERT_NE(dot.find("cluster_1"), std::string::npos) << dot;
  EXPECT_EQ(dumped_edges(dot), table_edges()) << dot;
  // Per-pin stages on both nodes, once stages on node 0 alone.
  for (const StageDecl& s : kStages) {
    EXPECT_NE(dot.find("n0_" + std::string(s.name) + " [label"), std::string::npos) << s.name;
    EXPECT_EQ(dot.find("n1_" + std::string(s.name) + " [label") != std::string::npos, s.split != Split::once)
        << s.name << "\n" << dot;
  }
  // Where a stage reads another's results at neighbouring pins, the edge waits for all nodes.
  EXPECT_NE(dot.find("n0_link_kinematics -> n0_chain_forces [style=dashed"), std::string::npos) << dot;
  EXPECT_NE(dot.find("n1_gather -> n1_accelerations [style=dashed"), std::string::npos) << dot;
}

// The serial and the published schedules run the table top to bottom: their dumps name
// every stage, each after every stage it reads.
TEST(StageTableTest, SerialAndPaperOmpRunEveryStageAfterTheStagesItReads) {
  const Model m = test::model("mini");
  for (SchedulerKind kind : {SchedulerKind::serial, SchedulerKind::paper_omp}) {
    const std::string dot = dump(m, kind, 2);
    const auto at = [&](const StageDecl& s) { return dot.find(std::string(" ") + s.name + " "); };
    for (const StageDecl& s : kStages) {
      ASSERT_NE(at(s), std::string::npos) << scheduler_name(kind) << " lacks " << s.name << "\n" << dot;
      for (const StageDecl& d : kStages) {
        if (!contains(s.after, d.id)) continue;
        EXPECT_LT(at(d), at(s)) << d.name << " -> " << s.name << "\n" << dot;
      }
    }
  }
}

// One evaluation with an RK4 stage update, through every schedule and through the table
// run over a split of the pins, gives the bits of rhs_serial.
TEST(StageTableTest, EveryScheduleEvaluatesTheTableToTheBitsOfRhsSerial) {
  const Model m = test::model("mini");
  const Eigen::VectorXd y = test::perturbed_state(m, 3, 2e-6, 1e-4, 0.05);
  const auto evaluate = [&](const auto& rhs) {
    Eigen::VectorXd dy = Eigen::VectorXd::Zero(m.nstate), next = Eigen::VectorXd::Zero(m.nstate),
                    acc = Eigen::VectorXd::Zero(m.nstate);
    StageOp op;
    op.base = y.data(), op.next = next.data(), op.acc = acc.data(), op.a = 0.5, op.first = true;
    rhs(dy.data(), &op);
    return std::make_pair(dy, next);
  };
  Workspace ws(m);
  const auto reference = evaluate([&](double* dy, const StageOp* op) { rhs_serial(m, ws, 1e-4, y.data(), dy, op); });
  EXPECT_GT(reference.first.cwiseAbs().maxCoeff(), 0.0);
  const auto same = [&](const std::pair<Eigen::VectorXd, Eigen::VectorXd>& r, const std::string& what) {
    EXPECT_TRUE(same_bits(reference.first, r.first) && same_bits(reference.second, r.second)) << what;
  };
  for (SchedulerKind kind : {SchedulerKind::serial, SchedulerKind::flowgraph, SchedulerKind::paper_omp})
    for (int threads : {1, 2}) {
      if (kind == SchedulerKind::serial && threads > 1) continue;
      Workspace w(m);
      ScheduleOptions o;
      o.kind = kind;
      o.threads = threads;
      const auto s = make_schedule(m, w, o);
      same(evaluate([&](double* dy, const StageOp* op) { s->rhs(1e-4, y.data(), dy, op); }),
           std::string(scheduler_name(kind)) + " on " + std::to_string(threads) + " threads");
    }
  Workspace w(m);
  same(evaluate([&](double* dy, const StageOp* op) {
         set_stage_input(m, w, 1e-4, y.data());
         const StageArgs a{m, w, dy, op, {}};
         run_stages(kAllStages, a, [&](const auto& f) {
           for (int b = 0; b < m.links; b += 5) f(b, std::min(b + 5, m.links));
         });
       }),
       "run_stages over ranges of 5 pins");
}

}  // namespace
}  // namespace cvt
