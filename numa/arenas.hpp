// One tbb::task_arena per NUMA node in use, with the threads that enter it pinned to the
// node's PUs, so that a node's pins are computed next to the node's memory. Binding is
// done by hand with hwloc (a task_scheduler_observer per arena), not with
// task_arena::constraints: a numa_id that tbb::info::numa_nodes() does not know aborts
// the process, and TBB's own hwloc (tbbbind) need not see the layout this Topology sees.
// Where binding cannot work the arenas still run, unbound, and say so.
#pragma once

#include <oneapi/tbb/global_control.h>
#include <oneapi/tbb/task_arena.h>
#include <oneapi/tbb/task_group.h>

#include <exception>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "numa/hand_off.hpp"
#include "numa/topology.hpp"

namespace cvt::numa {

class BindingObserver;

// Arenas for the first nodes() nodes of a Topology (threads_per_node decides how many are
// used and how many threads each gets).
//
// Slots. Node 0 is the caller's node: its arena has max_concurrency = threads(0) with one
// slot reserved for the external thread that calls execute() (typically main), which
// works in it; TBB adds threads(0) - 1 workers. Every other node's arena has
// max_concurrency = threads(node) and no reserved slot: it is fed by enqueue and its
// threads(node) threads are all TBB workers (a reserved slot nobody fills would leave the
// node a thread short). Together the arenas ask TBB for total_threads() - 1 workers;
// where that exceeds TBB's current limit, the NodeArenas raises it with a
// tbb::global_control held for its lifetime.
//
// The Topology's hwloc tree must outlive the NodeArenas (moving the Topology object is
// fine). Not copyable or movable: the observers hold references to the arenas.
class NodeArenas {
 public:
  NodeArenas(const Topology& topo, int total_threads);
  ~NodeArenas();
  NodeArenas(const NodeArenas&) = delete;
  NodeArenas& operator=(const NodeArenas&) = delete;

  int nodes() const { return static_cast<int>(threads_.size()); }
  int threads(int node) const { return threads_.at(static_cast<std::size_t>(node)); }
  int total_threads() const { return total_threads_; }
  int reserved_slots(int node) const { return node == 0 ? 1 : 0; }
  tbb::task_arena& arena(int node) { return *arenas_.at(static_cast<std::size_t>(node)); }
  hwloc_topology_t topology() const { return topo_; }
  hwloc_const_cpuset_t cpuset(int node) const { return cpusets_.at(static_cast<std::size_t>(node)); }
  hwloc_const_nodeset_t nodeset(int node) const { return nodesets_.at(static_cast<std::size_t>(node)); }

  // True when every node's PUs were bound and read back as bound (probe at construction)
  // and no thread entering an arena since has failed to bind.
  bool thread_binding_in_effect() const;
  // True when memory bound to each node was read back (hwloc_get_area_memlocation) as
  // lying on that node (probe at construction).
  bool memory_binding_in_effect() const { return memory_binding_; }
  // Both facts in words, with the reason where one is not in effect.
  std::string binding_message() const;
  std::string thread_binding_message() const;
  const std::string& memory_binding_message() const { return memory_message_; }
  // Entries of threads into the node's arena, and those whose binding failed or did not
  // read back as the node's PUs (zero while binding is not attempted).
  long binds(int node) const;
  long bind_failures(int node) const;

  // Runs f() in the node's arena on the calling thread (which is pinned to the node for
  // the call and gets its previous binding back afterwards) and returns its result.
  template <class F>
  decltype(auto) execute_on(int node, F&& f) {
    const ScopedForkJoin fj;
    return arena(node).execute(fj.task(f));
  }

  // Runs f(node) for every node at once and waits: node 0 on the calling thread in its
  // arena, the others enqueued as a task_group task in their own arena (run by that
  // node's workers; while waiting, the caller may join a node's arena and help). The
  // first exception by node order, node 0 first, is rethrown after all have finished.
  // For an external thread (one that is not a TBB worker), one call at a time: the
  // task_groups are the NodeArenas' own, so the flow graph's per-stage phases use it too.
  template <class F>
  void run_on_all_nodes(F&& f);

 private:
  hwloc_topology_t topo_ = nullptr;
  std::vector<int> threads_;
  int total_threads_ = 0;
  std::vector<hwloc_const_cpuset_t> cpusets_;
  std::vector<hwloc_const_nodeset_t> nodesets_;
  std::optional<tbb::global_control> worker_limit_;
  std::vector<std::unique_ptr<tbb::task_arena>> arenas_;
  std::unique_ptr<tbb::task_group[]> groups_;  // run_on_all_nodes: one per node
  struct Counters;
  std::unique_ptr<Counters[]> counters_;
  std::vector<std::unique_ptr<BindingObserver>> observers_;  // after arenas_: destroyed first
  bool thread_binding_probe_ = false;
  std::string thread_message_;
  bool memory_binding_ = false;
  std::string memory_message_;
};

template <class F>
void NodeArenas::run_on_all_nodes(F&& f) {
  const int n = nodes();
  tbb::task_group* groups = groups_.get();
  const ScopedForkJoin fj;
  const auto g = fj.task(f);
  for (int node = 1; node < n; ++node) arena(node).enqueue(groups[node].defer([&g, node] { g(node); }));
  std::exception_ptr first;
  try {
    arena(0).execute([&g] { g(0); });
  } catch (...) {
    first = std::current_exception();
  }
  for (int node = 1; node < n; ++node) {
    try {
      arena(node).execute([groups, node] { groups[node].wait(); });
    } catch (...) {
      if (!first) first = std::current_exception();
    }
  }
  if (first) std::rethrow_exception(first);
}

// The PU (OS index) the calling thread last ran on, -1 where the OS cannot tell or the
// topology is not this system.
int current_pu(const Topology& topo);
// The PUs (OS indices) the calling thread is bound to; empty where unknown.
std::vector<int> current_binding(const Topology& topo);

}  // namespace cvt::numa
