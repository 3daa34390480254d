// Tests of numa/: topology discovery (real, synthetic, XML), the pin and thread
// partitions, per-node arenas with pinned threads, first-touch buffers and the report.
// The two-node cases run on any machine through hwloc's synthetic layouts; with
// HWLOC_THISSYSTEM=1 the fake nodes' PUs 0 and 1 are the real ones, so pinning is real.
#include <gtest/gtest.h>
#include <oneapi/tbb/blocked_range.h>
#include <oneapi/tbb/parallel_for.h>
#include <oneapi/tbb/partitioner.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <mutex>
#include <optional>
#include <random>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "numa/arenas.hpp"
#include "numa/describe.hpp"
#include "numa/node_buffer.hpp"
#include "numa/topology.hpp"

namespace cvt::numa {
namespace {

const char* const kTwoNodes = "package:2 numa:1 core:1 pu:1";
const char* const kHwlocVars[] = {"HWLOC_SYNTHETIC", "HWLOC_XMLFILE", "HWLOC_THISSYSTEM"};

// Sets or unsets environment variables and puts back the previous values when it goes,
// so that no other test sees a fake topology.
class ScopedEnv {
 public:
  ScopedEnv() = default;
  ScopedEnv(const ScopedEnv&) = delete;
  ScopedEnv& operator=(const ScopedEnv&) = delete;
  ~ScopedEnv() {
    for (auto it = saved_.rbegin(); it != saved_.rend(); ++it) {
      if (it->second) setenv(it->first.c_str(), it->second->c_str(), 1);
      else unsetenv(it->first.c_str());
    }
  }
  void set(const char* name, const std::string& value) {
    remember(name);
    setenv(name, value.c_str(), 1);
  }
  void unset(const char* name) {
    remember(name);
    unsetenv(name);
  }

 private:
  void remember(const char* name) {
    for (const auto& s : saved_)
      if (s.first == name) return;
    const char* v = std::getenv(name);
    saved_.emplace_back(name, v ? std::optional<std::string>(v) : std::nullopt);
  }
  std::vector<std::pair<std::string, std::optional<std::string>>> saved_;
};

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

bool is_subset(const std::vector<int>& small, const std::vector<int>& big) {
  return std::all_of(small.begin(), small.end(),
                     [&](int x) { return std::find(big.begin(), big.end(), x) != big.end(); });
}

std::string list(const std::vector<int>& v) { return index_list(v); }

// What one chunk of a loop saw about its thread.
struct Seen {
  int node;
  std::vector<int> binding;
  int pu;
  bool caller;
};

// Runs a parallel loop of many small chunks inside the node's arena (the caller is in
// it already) and records the binding and PU of every chunk.
void record_chunks(const Topology& topo, int node, std::thread::id caller, std::mutex& mutex, std::vector<Seen>& seen) {
  tbb::parallel_for(tbb::blocked_range<int>(0, 64, 1), [&](const tbb::blocked_range<int>&) {
    Seen s{node, current_binding(topo), current_pu(topo), std::this_thread::get_id() == caller};
    volatile double x = 0;  // long enough for several threads to get a chunk
    for (int i = 0; i < 20000; ++i) x = x + 1e-9 * i;
    std::lock_guard<std::mutex> lock(mutex);
    seen.push_back(std::move(s));
  });
}

// ---------------------------------------------------------------- the real machine

class TopologyRealMachine : public ::testing::Test {
 protected:
  void SetUp() override {
    for (const char* name : kHwlocVars) env_.unset(name);
  }
  ScopedEnv env_;
};

TEST_F(TopologyRealMachine, HasNodesWithCoresAndAReport) {
  const Topology topo = discover_topology();
  std::printf("source: %s, this system: %d, nodes: %d, memory-only: %d, cores: %d, PUs: %d\n",
              topo.source_description().c_str(), topo.is_this_system(), topo.node_count(), topo.memory_only_nodes(),
              topo.total_cores(), topo.total_pus());
  EXPECT_EQ(topo.source(), TopologySource::this_system);
  EXPECT_EQ(topo.source_description(), "this system");
  EXPECT_TRUE(topo.is_this_system());
  ASSERT_GE(topo.node_count(), 1);
  std::vector<int> all_pus;
  for (const NumaNode& node : topo.nodes()) {
    std::printf("node L%d os %d: %d cores, PUs %s\n", node.logical_index, node.os_index, node.cores,
                list(node.pus).c_str());
    EXPECT_GT(node.cores, 0);
    EXPECT_FALSE(node.pus.empty());
    EXPECT_TRUE(std::is_sorted(node.pus.begin(), node.pus.end()));
    EXPECT_EQ(bitmap_list(node.cpuset), list(node.pus));
    all_pus.insert(all_pus.end(), node.pus.begin(), node.pus.end());
  }
  std::sort(all_pus.begin(), all_pus.end());
  EXPECT_TRUE(std::adjacent_find(all_pus.begin(), all_pus.end()) == all_pus.end()) << "a PU in two nodes";

  const std::string without_arenas = describe(topo, nullptr, 84);
  std::printf("%s", without_arenas.c_str());
  EXPECT_TRUE(contains(without_arenas, "topology: this system"));
  EXPECT_TRUE(contains(without_arenas, "[0, "));
  EXPECT_TRUE(contains(without_arenas, "not checked"));

  const NodeArenas arenas(topo, topo.total_pus());
  const std::string report = describe(topo, &arenas, 84);
  std::printf("%s", report.c_str());
  EXPECT_TRUE(contains(report, "thread binding: "));
  EXPECT_TRUE(contains(report, "memory binding: "));
  EXPECT_TRUE(contains(report, ", 84)"));
}

TEST_F(TopologyRealMachine, MovesKeepTheTree) {
  Topology a = discover_topology();
  const std::string pus = bitmap_list(a.node(0).cpuset);
  Topology b = std::move(a);
  EXPECT_EQ(a.handle(), nullptr);
  EXPECT_EQ(a.node_count(), 0);
  EXPECT_EQ(bitmap_list(b.node(0).cpuset), pus);
  Topology c = discover_topology();
  c = std::move(b);
  EXPECT_EQ(bitmap_list(c.node(0).cpuset), pus);
  EXPECT_THROW(NodeArenas(a, 1), std::invalid_argument);
  std::printf("node 0 PUs after two moves: %s\n", pus.c_str());
}

TEST_F(TopologyRealMachine, ArenaThreadsStayOnTheirNode) {
  const Topology topo = discover_topology();
  NodeArenas arenas(topo, topo.total_pus());
  std::printf("%s\n", arenas.binding_message().c_str());
  if (!hwloc_topology_get_support(topo.handle())->cpubind->set_thisthread_cpubind) {
    EXPECT_FALSE(arenas.thread_binding_in_effect());
    EXPECT_TRUE(contains(arenas.thread_binding_message(), "not in effect (hwloc cannot bind threads"));
    GTEST_SKIP() << "hwloc cannot bind threads on this system";
  }
  ASSERT_TRUE(arenas.thread_binding_in_effect()) << arenas.binding_message();
  const std::vector<int> before = current_binding(topo);
  std::mutex mutex;
  std::vector<Seen> seen;
  const auto caller = std::this_thread::get_id();
  arenas.run_on_all_nodes([&](int node) { record_chunks(topo, node, caller, mutex, seen); });
  for (const Seen& s : seen) {
    EXPECT_EQ(list(s.binding), list(topo.node(s.node).pus)) << "node " << s.node;
    EXPECT_TRUE(is_subset({s.pu}, topo.node(s.node).pus)) << "node " << s.node << " ran on PU " << s.pu;
  }
  for (int node = 0; node < arenas.nodes(); ++node) {
    EXPECT_EQ(arenas.arena(node).max_concurrency(), arenas.threads(node));
    EXPECT_EQ(arenas.bind_failures(node), 0);
    std::printf("node %d: %d threads, %ld entries bound, %ld failed\n", node, arenas.threads(node),
                arenas.binds(node), arenas.bind_failures(node));
  }
  EXPECT_EQ(list(current_binding(topo)), list(before)) << "the caller keeps a node's pinning";
  std::printf("%zu chunks all on their node's PUs; caller binding %s before and after\n", seen.size(),
              list(before).c_str());
}

TEST_F(TopologyRealMachine, BufferLiesOnNodeZero) {
  const Topology topo = discover_topology();
  NodeArenas arenas(topo, topo.total_pus());
  NodeBuffer<double> buffer(arenas, 0, std::size_t{1} << 20);
  ASSERT_EQ(buffer.size(), std::size_t{1} << 20);
  EXPECT_EQ(reinterpret_cast<std::uintptr_t>(buffer.data()) % 64, 0u);
  EXPECT_TRUE(std::all_of(buffer.begin(), buffer.end(), [](double x) { return x == 0.0; }));
  const int where = memory_node_of(topo, buffer.data(), buffer.size() * sizeof(double));
  std::printf("buffer of 8 MiB: bound %d (%s), lies on node %d; memory binding: %s\n", buffer.bound(),
              buffer.bind_message().c_str(), where, arenas.memory_binding_message().c_str());
  if (hwloc_topology_get_support(topo.handle())->membind->get_area_memlocation) {
    if (topo.node_count() == 1) {
      EXPECT_EQ(where, 0);
    } else {
      EXPECT_TRUE(where == 0 || !arenas.memory_binding_in_effect());
    }
  }
  if (arenas.nodes() == 1) {
    EXPECT_EQ(arenas.memory_binding_in_effect(), buffer.bound() && where == 0);
  }

  NodeBuffer<double> moved = std::move(buffer);
  EXPECT_EQ(buffer.data(), nullptr);
  EXPECT_EQ(moved.size(), std::size_t{1} << 20);
  const NodeBuffer<int> empty(arenas, 0, 0);
  EXPECT_EQ(empty.data(), nullptr);
  EXPECT_THROW(NodeBuffer<int>(arenas, arenas.nodes(), 8), std::out_of_range);
}

TEST_F(TopologyRealMachine, MoreThreadsThanPUsRaiseTbbsLimit) {
  const Topology topo = discover_topology();
  using tbb::global_control;
  const std::size_t limit = global_control::active_value(global_control::max_allowed_parallelism);
  const int threads = static_cast<int>(limit) + 2;
  {
    NodeArenas arenas(topo, threads);
    const std::size_t raised = global_control::active_value(global_control::max_allowed_parallelism);
    std::printf("TBB limit %zu; NodeArenas of %d threads raises it to %zu\n", limit, threads, raised);
    EXPECT_GE(raised, static_cast<std::size_t>(threads));
    int sum = 0;
    for (int node = 0; node < arenas.nodes(); ++node) {
      EXPECT_EQ(arenas.arena(node).max_concurrency(), arenas.threads(node));
      sum += arenas.threads(node);
    }
    EXPECT_EQ(sum, threads);
  }
  EXPECT_EQ(global_control::active_value(global_control::max_allowed_parallelism), limit);
}

TEST(NumaText, IndexListsCompressRuns) {
  EXPECT_EQ(index_list({0, 1, 2, 5, 7, 8}), "0-2,5,7-8");
  EXPECT_EQ(index_list({3}), "3");
  EXPECT_EQ(index_list({}), "");
  hwloc_bitmap_t set = hwloc_bitmap_alloc();
  hwloc_bitmap_set_range(set, 4, 6);
  hwloc_bitmap_set(set, 9);
  EXPECT_EQ(bitmap_list(set), "4-6,9");
  hwloc_bitmap_free(set);
}

// ---------------------------------------------------------------- partitions

// Checks what partition_pins promises and returns the segment sizes.
std::vector<int> check_partition(int pins, const std::vector<int>& weights) {
  const std::vector<int> begin = partition_pins(pins, weights);
  EXPECT_EQ(begin.size(), weights.size() + 1);
  EXPECT_EQ(begin.front(), 0);
  EXPECT_EQ(begin.back(), pins);
  std::vector<int> owner(pins, -1);
  double total = 0;
  for (int w : weights) total += w;
  std::vector<int> sizes;
  for (std::size_t i = 0; i < weights.size(); ++i) {
    EXPECT_LE(begin[i], begin[i + 1]);
    for (int p = begin[i]; p < begin[i + 1]; ++p) {
      EXPECT_EQ(owner[p], -1) << "pin " << p << " twice";
      owner[p] = static_cast<int>(i);
    }
    const int size = begin[i + 1] - begin[i];
    EXPECT_LT(std::abs(size - pins * weights[i] / total), 1.0) << "segment " << i;
    if (weights[i] == 0) {
      EXPECT_EQ(size, 0);
    }
    sizes.push_back(size);
  }
  EXPECT_EQ(std::count(owner.begin(), owner.end(), -1), 0) << "a pin in no segment";
  EXPECT_EQ(partition_pins(pins, weights), begin) << "not deterministic";
  return sizes;
}

TEST(NumaPartition, CoversEveryPinOnceInProportion) {
  EXPECT_EQ(partition_pins(84, {1, 1}), (std::vector<int>{0, 42, 84}));
  EXPECT_EQ(partition_pins(84, {1, 2, 3}), (std::vector<int>{0, 14, 42, 84}));
  EXPECT_EQ(check_partition(84, {5, 3, 1}), (std::vector<int>{47, 28, 9}));
  EXPECT_EQ(check_partition(85, {1, 1}), (std::vector<int>{43, 42}));
  EXPECT_EQ(check_partition(84, {8, 0, 8}), (std::vector<int>{42, 0, 42}));
  EXPECT_EQ(check_partition(1, {1}), (std::vector<int>{1}));
  // More nodes than pins: some segments are empty, none gets more than its share + 1.
  EXPECT_EQ(check_partition(2, {1, 1, 1, 1, 1}), (std::vector<int>{0, 1, 0, 1, 0}));
  EXPECT_EQ(check_partition(3, {1, 1, 1, 1}), (std::vector<int>{1, 1, 0, 1}));
  std::printf("84 over {5,3,1}: 47/28/9; 2 over 5 equal: 0/1/0/1/0; 3 over 4 equal: 1/1/0/1\n");

  std::mt19937 rng(20240611);
  for (int trial = 0; trial < 500; ++trial) {
    const int nodes = 1 + static_cast<int>(rng() % 9);
    std::vector<int> weights(nodes);
    for (int& w : weights) w = static_cast<int>(rng() % 65);
    if (std::all_of(weights.begin(), weights.end(), [](int w) { return w == 0; })) weights[0] = 1;
    check_partition(1 + static_cast<int>(rng() % 5000), weights);
  }
  // No overflow in the exact arithmetic.
  EXPECT_EQ(partition_pins(2000000000, {2000000000, 1, 2000000000}),
            (std::vector<int>{0, 1000000000, 1000000000, 2000000000}));
}

TEST(NumaPartition, RejectsWhatCannotBeSplit) {
  EXPECT_THROW(partition_pins(0, {1}), std::invalid_argument);
  EXPECT_THROW(partition_pins(-3, {1, 1}), std::invalid_argument);
  EXPECT_THROW(partition_pins(84, {}), std::invalid_argument);
  EXPECT_THROW(partition_pins(84, {0, 0}), std::invalid_argument);
  EXPECT_THROW(partition_pins(84, {2, -1}), std::invalid_argument);
  EXPECT_THROW(threads_per_node(std::vector<int>{}, 2), std::invalid_argument);
  EXPECT_THROW(threads_per_node(std::vector<int>{1, 1}, 0), std::invalid_argument);
}

TEST(NumaThreadsPerNode, FollowsCoresWithOneEach) {
  using V = std::vector<int>;
  EXPECT_EQ(threads_per_node(V{1, 1}, 2), (V{1, 1}));
  EXPECT_EQ(threads_per_node(V{1, 1}, 3), (V{2, 1}));
  EXPECT_EQ(threads_per_node(V{16, 16}, 32), (V{16, 16}));
  EXPECT_EQ(threads_per_node(V{12, 4}, 8), (V{6, 2}));
  EXPECT_EQ(threads_per_node(V{30, 1}, 2), (V{1, 1}));      // one each beats proportion
  EXPECT_EQ(threads_per_node(V{30, 1, 1}, 4), (V{2, 1, 1}));
  EXPECT_EQ(threads_per_node(V{8, 8, 8}, 2), (V{1, 1, 0}));  // fewer threads than nodes
  EXPECT_EQ(threads_per_node(V{8, 8}, 1), (V{1, 0}));
  EXPECT_EQ(threads_per_node(V{0, 0}, 4), (V{2, 2}));        // no core count: equal shares
  std::mt19937 rng(7);
  for (int trial = 0; trial < 300; ++trial) {
    V cores(1 + rng() % 6);
    for (int& c : cores) c = 1 + static_cast<int>(rng() % 32);
    const int total = 1 + static_cast<int>(rng() % 100);
    const V threads = threads_per_node(cores, total);
    int sum = 0;
    for (std::size_t i = 0; i < cores.size(); ++i) {
      sum += threads[i];
      if (total >= static_cast<int>(cores.size())) {
        EXPECT_GE(threads[i], 1);
      } else {
        EXPECT_EQ(threads[i], static_cast<int>(i) < total ? 1 : 0);
      }
    }
    EXPECT_EQ(sum, total);
  }
  std::printf("{12,4} cores, 8 threads: 6/2; {30,1}, 2 threads: 1/1; {8,8,8}, 2 threads: 1/1/0\n");
}

// ---------------------------------------------------------------- synthetic, not bound

// Two fake nodes of one core each; binding calls are no-ops (not this system).
class TopologySynthetic : public ::testing::Test {
 protected:
  void SetUp() override {
    for (const char* name : kHwlocVars) env_.unset(name);
    env_.set("HWLOC_SYNTHETIC", kTwoNodes);
  }
  ScopedEnv env_;
};

TEST_F(TopologySynthetic, TwoNodesTwoArenasOfOneThread) {
  const Topology topo = discover_topology();
  EXPECT_EQ(topo.source(), TopologySource::synthetic);
  EXPECT_EQ(topo.source_description(), std::string("synthetic: ") + kTwoNodes);
  EXPECT_FALSE(topo.is_this_system());
  ASSERT_EQ(topo.node_count(), 2);
  for (int i = 0; i < 2; ++i) {
    EXPECT_EQ(topo.node(i).logical_index, i);
    EXPECT_EQ(topo.node(i).os_index, i);
    EXPECT_EQ(topo.node(i).cores, 1);
    EXPECT_EQ(topo.node(i).pus, std::vector<int>{i});
  }
  EXPECT_EQ(threads_per_node(topo, 2), (std::vector<int>{1, 1}));
  EXPECT_EQ(threads_per_node(topo, 1), (std::vector<int>{1, 0}));

  NodeArenas arenas(topo, 2);
  ASSERT_EQ(arenas.nodes(), 2);
  for (int i = 0; i < 2; ++i) {
    EXPECT_EQ(arenas.threads(i), 1);
    EXPECT_EQ(arenas.arena(i).max_concurrency(), 1);
  }
  EXPECT_EQ(arenas.reserved_slots(0), 1);
  EXPECT_EQ(arenas.reserved_slots(1), 0);
  EXPECT_FALSE(arenas.thread_binding_in_effect());
  EXPECT_FALSE(arenas.memory_binding_in_effect());
  EXPECT_TRUE(contains(arenas.thread_binding_message(), "not in effect (topology is not this system"));
  EXPECT_TRUE(contains(arenas.memory_binding_message(), "not in effect (topology is not this system"));
  EXPECT_EQ(current_pu(topo), -1);
  EXPECT_TRUE(current_binding(topo).empty());

  // Unbound arenas still run every node's work, side by side: each node waits to see the
  // other arrive (a serial schedule would time out).
  std::atomic<int> arrived{0};
  std::atomic<int> calls[2] = {0, 0};
  std::atomic<bool> met[2] = {false, false};
  arenas.run_on_all_nodes([&](int node) {
    calls[node].fetch_add(1);
    arrived.fetch_add(1);
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(20);
    while (arrived.load() < 2 && std::chrono::steady_clock::now() < deadline) std::this_thread::yield();
    met[node] = arrived.load() == 2;
  });
  EXPECT_TRUE(met[0].load() && met[1].load()) << "the nodes did not run side by side";
  EXPECT_EQ(calls[0].load(), 1);
  EXPECT_EQ(calls[1].load(), 1);
  EXPECT_EQ(arenas.binds(0) + arenas.binds(1), 0) << "no observer while binding is off";

  NodeArenas one(topo, 1);
  EXPECT_EQ(one.nodes(), 1);

  const std::string report = describe(topo, &arenas, 84);
  std::printf("%s", report.c_str());
  EXPECT_TRUE(contains(report, "[0, 42)"));
  EXPECT_TRUE(contains(report, "[42, 84)"));
  EXPECT_TRUE(contains(report, "is this system: no"));
}

TEST_F(TopologySynthetic, RunOnAllNodesRethrowsAfterAllFinish) {
  const Topology topo = discover_topology();
  NodeArenas arenas(topo, 2);
  std::atomic<int> finished{0};
  try {
    arenas.run_on_all_nodes([&](int node) {
      finished.fetch_add(1);
      if (node == 1) throw std::runtime_error("node 1 failed");
    });
    ADD_FAILURE() << "no exception";
  } catch (const std::runtime_error& e) {
    EXPECT_STREQ(e.what(), "node 1 failed");
  }
  EXPECT_EQ(finished.load(), 2);
  std::printf("node 1's exception reached the caller after %d nodes ran\n", finished.load());
}

TEST_F(TopologySynthetic, BuffersAllocateButNobodyKnowsWhere) {
  const Topology topo = discover_topology();
  NodeArenas arenas(topo, 2);
  for (int node = 0; node < 2; ++node) {
    NodeBuffer<float> buffer(arenas, node, 100000);
    EXPECT_FALSE(buffer.bound());
    EXPECT_EQ(buffer.bind_message(), "topology is not this system");
    EXPECT_EQ(memory_node_of(topo, buffer.data(), buffer.size() * sizeof(float)), -1);
    buffer[99999] = 1.0f;
    EXPECT_EQ(buffer[99999], 1.0f);
  }
  std::printf("buffers on fake nodes: unbound, location unknown (-1)\n");
}

TEST_F(TopologySynthetic, RejectedDescriptionThrows) {
  env_.set("HWLOC_SYNTHETIC", "package:2 gizmo:3");
  try {
    discover_topology();
    ADD_FAILURE() << "hwloc accepted a bad description";
  } catch (const std::runtime_error& e) {
    std::printf("%s\n", e.what());
    EXPECT_TRUE(contains(e.what(), "HWLOC_SYNTHETIC"));
  }
}

TEST_F(TopologySynthetic, XmlFileIsASource) {
  const std::string path = ::testing::TempDir() + "cvt_numa_two_nodes.xml";
  {
    const Topology synthetic = discover_topology();
    ASSERT_EQ(hwloc_topology_export_xml(synthetic.handle(), path.c_str(), 0), 0);
  }
  env_.unset("HWLOC_SYNTHETIC");
  env_.set("HWLOC_XMLFILE", path);
  const Topology topo = discover_topology();
  EXPECT_EQ(topo.source(), TopologySource::xml);
  EXPECT_EQ(topo.source_description(), "xml: " + path);
  EXPECT_FALSE(topo.is_this_system());
  EXPECT_EQ(topo.node_count(), 2);
  std::printf("%s: %d nodes, this system %d\n", topo.source_description().c_str(), topo.node_count(),
              topo.is_this_system());
  std::remove(path.c_str());

  env_.set("HWLOC_XMLFILE", path + ".missing");
  EXPECT_THROW(discover_topology(), std::runtime_error);
}

// ---------------------------------------------------------------- synthetic, bound

// The same two nodes with HWLOC_THISSYSTEM=1: hwloc binds for real, node 0 to PU 0 and
// node 1 to PU 1 of this machine; memory binding to the fake node 1 is refused by the
// kernel where the machine has one node.
class NumaPinnedSynthetic : public ::testing::Test {
 protected:
  void SetUp() override {
    for (const char* name : kHwlocVars) env_.unset(name);
    {
      const Topology real = discover_topology();
      hwloc_bitmap_t both = hwloc_bitmap_alloc();
      hwloc_bitmap_set_range(both, 0, 1);
      const bool have = hwloc_bitmap_isincluded(both, hwloc_topology_get_allowed_cpuset(real.handle()));
      hwloc_bitmap_free(both);
      if (!have) GTEST_SKIP() << "this machine has no PUs 0 and 1 to pin the fake nodes to";
    }
    env_.set("HWLOC_SYNTHETIC", kTwoNodes);
    env_.set("HWLOC_THISSYSTEM", "1");
  }
  ScopedEnv env_;
};

TEST_F(NumaPinnedSynthetic, TasksRunOnTheirNodesPUs) {
  const Topology topo = discover_topology();
  ASSERT_TRUE(topo.is_this_system());
  ASSERT_EQ(topo.node_count(), 2);
  NodeArenas arenas(topo, 2);
  std::printf("%s\n", arenas.binding_message().c_str());
  ASSERT_TRUE(arenas.thread_binding_in_effect()) << arenas.binding_message();
  const std::vector<int> before = current_binding(topo);

  // The caller, inside each node's arena.
  for (int node = 0; node < 2; ++node) {
    const auto [binding, pu] = arenas.execute_on(node, [&] { return std::make_pair(current_binding(topo), current_pu(topo)); });
    std::printf("caller in node %d's arena: bound to %s, last on PU %d\n", node, list(binding).c_str(), pu);
    EXPECT_EQ(binding, std::vector<int>{node});
    EXPECT_EQ(pu, node);
    EXPECT_EQ(list(current_binding(topo)), list(before)) << "caller not given back its binding";
  }

  // A worker: node 1's arena reserves no slot, so an enqueued task runs on a TBB worker
  // while the caller stays out of the arena.
  std::atomic<bool> done{false};
  std::vector<int> worker_binding;
  int worker_pu = -2;
  bool worker_is_caller = true;
  const auto caller = std::this_thread::get_id();
  arenas.arena(1).enqueue([&] {
    worker_binding = current_binding(topo);
    worker_pu = current_pu(topo);
    worker_is_caller = std::this_thread::get_id() == caller;
    done.store(true, std::memory_order_release);
  });
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(20);
  while (!done.load(std::memory_order_acquire) && std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  ASSERT_TRUE(done.load()) << "no worker ran node 1's task";
  std::printf("worker in node 1's arena: bound to %s, last on PU %d\n", list(worker_binding).c_str(), worker_pu);
  EXPECT_FALSE(worker_is_caller);
  EXPECT_EQ(worker_binding, std::vector<int>{1});
  EXPECT_EQ(worker_pu, 1);

  // Both nodes at once, loops inside.
  std::mutex mutex;
  std::vector<Seen> seen;
  arenas.run_on_all_nodes([&](int node) { record_chunks(topo, node, caller, mutex, seen); });
  int by_caller = 0;
  for (const Seen& s : seen) {
    EXPECT_EQ(s.binding, std::vector<int>{s.node});
    EXPECT_EQ(s.pu, s.node);
    by_caller += s.caller;
  }
  EXPECT_EQ(seen.size(), 128u);
  for (int node = 0; node < 2; ++node) {
    std::printf("node %d: %ld entries bound, %ld failed\n", node, arenas.binds(node), arenas.bind_failures(node));
    EXPECT_GE(arenas.binds(node), 1);
    EXPECT_EQ(arenas.bind_failures(node), 0);
  }
  EXPECT_TRUE(arenas.thread_binding_in_effect());
  EXPECT_EQ(list(current_binding(topo)), list(before));
  std::printf("run_on_all_nodes: %zu chunks on their node's PU (%d by the caller); caller bound to %s after\n",
              seen.size(), by_caller, list(current_binding(topo)).c_str());
}

TEST_F(NumaPinnedSynthetic, BuffersLieOnTheirNodeOrSayWhyNot) {
  const Topology topo = discover_topology();
  NodeArenas arenas(topo, 2);
  std::printf("%s\n", arenas.binding_message().c_str());
  const bool can_tell = hwloc_topology_get_support(topo.handle())->membind->get_area_memlocation;
  bool all_on_node = true;
  for (int node = 0; node < 2; ++node) {
    NodeBuffer<double> buffer(arenas, node, std::size_t{1} << 18);
    const int where = memory_node_of(topo, buffer.data(), buffer.size() * sizeof(double));
    std::printf("buffer for node %d: bound %d%s%s, lies on node %d\n", node, buffer.bound(),
                buffer.bound() ? "" : ": ", buffer.bind_message().c_str(), where);
    if (buffer.bound() && can_tell) {
      EXPECT_EQ(where, node) << "bound memory away from its node";
    }
    all_on_node = all_on_node && buffer.bound() && where == node;
  }
  // The probe and the buffers must tell the same story.
  EXPECT_EQ(arenas.memory_binding_in_effect(), all_on_node) << arenas.memory_binding_message();
  if (!arenas.memory_binding_in_effect()) {
    EXPECT_TRUE(contains(arenas.memory_binding_message(), "not in effect ("));
    EXPECT_TRUE(contains(describe(topo, &arenas, 84), "memory binding: not in effect ("));
  }
}

}  // namespace
}  // namespace cvt::numa
