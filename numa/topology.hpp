// The machine as the numa layer sees it: the NUMA nodes that have processing units,
// read once from hwloc, and the arithmetic that shares pins and threads among them.
// Everything else in numa/ (arenas, buffers, the report) is built on a Topology so
// that a synthetic or XML layout (HWLOC_SYNTHETIC, HWLOC_XMLFILE) exercises the same
// code paths as the real machine. numa/ knows nothing about the physics.
#pragma once

#include <hwloc.h>

#include <string>
#include <vector>

namespace cvt::numa {

// Where hwloc took the layout from. Only `this_system` (or another source together with
// HWLOC_THISSYSTEM=1) lets binding calls act on the real machine.
enum class TopologySource { this_system, synthetic, xml };

// One NUMA node that has processing units. Node i of the numa layer is nodes()[i]:
// compute nodes in hwloc logical order, memory-only nodes left out.
struct NumaNode {
  int logical_index = 0;  // hwloc's logical index of the NUMA node
  int os_index = 0;       // the OS's number, as numactl and /sys/devices/system/node show it
  int cores = 0;          // cores in the node (its PU count where hwloc knows no cores)
  std::vector<int> pus;   // OS indices of the node's processing units, ascending
  // Borrowed from the hwloc tree of the owning Topology: valid while it lives (moving the
  // Topology keeps them valid, the tree does not move).
  hwloc_const_cpuset_t cpuset = nullptr;
  hwloc_const_nodeset_t nodeset = nullptr;
};

// Owns one loaded hwloc topology (RAII, movable, not copyable).
class Topology {
 public:
  ~Topology();
  Topology(Topology&& other) noexcept;
  Topology& operator=(Topology&& other) noexcept;
  Topology(const Topology&) = delete;
  Topology& operator=(const Topology&) = delete;

  hwloc_topology_t handle() const { return topo_; }
  const std::vector<NumaNode>& nodes() const { return nodes_; }
  int node_count() const { return static_cast<int>(nodes_.size()); }
  const NumaNode& node(int i) const { return nodes_.at(static_cast<std::size_t>(i)); }

  TopologySource source() const { return source_; }
  // "this system", "synthetic: <description>" or "xml: <file>".
  const std::string& source_description() const { return source_description_; }
  // hwloc_topology_is_thissystem(): false means binding calls are silent no-ops.
  bool is_this_system() const { return is_this_system_; }
  // NUMA nodes without processing units (high-bandwidth or CXL memory, or nodes whose
  // PUs another node already claims): counted, not used.
  int memory_only_nodes() const { return memory_only_nodes_; }
  // True where hwloc reported no NUMA node and the whole machine stands as node 0.
  bool numa_nodes_inferred() const { return inferred_; }
  int total_cores() const;
  int total_pus() const;

 private:
  friend Topology discover_topology();
  explicit Topology(hwloc_topology_t topo);
  void reset() noexcept;

  hwloc_topology_t topo_ = nullptr;
  std::vector<NumaNode> nodes_;
  TopologySource source_ = TopologySource::this_system;
  std::string source_description_;
  bool is_this_system_ = false;
  int memory_only_nodes_ = 0;
  bool inferred_ = false;
};

// Loads the topology. HWLOC_SYNTHETIC (first) or HWLOC_XMLFILE select a fake layout as
// hwloc itself would, but a value hwloc rejects throws std::runtime_error naming the
// variable instead of silently giving the real machine; HWLOC_THISSYSTEM is left to hwloc.
Topology discover_topology();

// Begin offsets (size weights.size() + 1, first 0, last pins) of contiguous pin segments
// whose sizes are proportional to the weights: each boundary is the exact cumulative
// share rounded half up, so sizes differ from their exact share by less than one pin and
// the result depends on nothing but the arguments. A zero weight gets an empty segment;
// with more nodes than pins some segments are empty. Throws std::invalid_argument for
// pins <= 0, a negative weight, or no positive weight.
std::vector<int> partition_pins(int pins, const std::vector<int>& weights);

// Threads per node in proportion to the node's cores: at least one per node while
// total_threads >= nodes; with fewer threads than nodes the first total_threads nodes get
// one each and the rest none. Throws std::invalid_argument for total_threads <= 0 or no node.
std::vector<int> threads_per_node(const std::vector<int>& cores_per_node, int total_threads);
std::vector<int> threads_per_node(const Topology& topo, int total_threads);

// "0-3,8" for an hwloc bitmap or a list of indices (the form numactl and taskset accept).
std::string bitmap_list(hwloc_const_bitmap_t set);
std::string index_list(const std::vector<int>& indices);

}  // namespace cvt::numa
