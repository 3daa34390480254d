// hwloc is asked once; what the rest of numa/ needs is copied into plain vectors so that
// the partition arithmetic stays testable without hwloc.
#include "numa/topology.hpp"

#include <cstdlib>
#include <stdexcept>
#include <string>
#include <utility>

namespace cvt::numa {

namespace {

const char* env_value(const char* name) {
  const char* v = std::getenv(name);
  return (v && *v) ? v : nullptr;
}

// Frees an hwloc topology that has not reached its Topology owner yet (a throw between
// init and the constructor would leak it otherwise).
struct TopologyGuard {
  hwloc_topology_t topo = nullptr;
  ~TopologyGuard() {
    if (topo) hwloc_topology_destroy(topo);
  }
  hwloc_topology_t release() { return std::exchange(topo, nullptr); }
};

}  // namespace

Topology::Topology(hwloc_topology_t topo) : topo_(topo) {}

Topology::~Topology() { reset(); }

Topology::Topology(Topology&& other) noexcept
    : topo_(std::exchange(other.topo_, nullptr)),
      nodes_(std::move(other.nodes_)),
      source_(other.source_),
      source_description_(std::move(other.source_description_)),
      is_this_system_(other.is_this_system_),
      memory_only_nodes_(other.memory_only_nodes_),
      inferred_(other.inferred_) {
  other.nodes_.clear();
}

Topology& Topology::operator=(Topology&& other) noexcept {
  if (this != &other) {
    reset();
    topo_ = std::exchange(other.topo_, nullptr);
    nodes_ = std::move(other.nodes_);
    other.nodes_.clear();
    source_ = other.source_;
    source_description_ = std::move(other.source_description_);
    is_this_system_ = other.is_this_system_;
    memory_only_nodes_ = other.memory_only_nodes_;
    inferred_ = other.inferred_;
  }
  return *this;
}

void Topology::reset() noexcept {
  nodes_.clear();  // the cpusets point into the tree destroyed next
  if (topo_) hwloc_topology_destroy(topo_);
  topo_ = nullptr;
}

int Topology::total_cores() const {
  int n = 0;
  for (const auto& node : nodes_) n += node.cores;
  return n;
}

int Topology::total_pus() const {
  int n = 0;
  for (const auto& node : nodes_) n += static_cast<int>(node.pus.size());
  return n;
}

Topology discover_topology() {
  TopologyGuard guard;
  if (hwloc_topology_init(&guard.topo) != 0) throw std::runtime_error("hwloc_topology_init failed");

  // hwloc would read these two itself in hwloc_topology_load (same precedence), but it
  // falls back to the real machine without a word when it cannot use them: a test or a
  // `topology` report would then describe a machine nobody asked for.
  TopologySource source = TopologySource::this_system;
  std::string description = "this system";
  if (const char* synthetic = env_value("HWLOC_SYNTHETIC")) {
    if (hwloc_topology_set_synthetic(guard.topo, synthetic) != 0)
      throw std::runtime_error(std::string("HWLOC_SYNTHETIC=\"") + synthetic +
                               "\": hwloc rejects this synthetic description");
    source = TopologySource::synthetic;
    description = std::string("synthetic: ") + synthetic;
  } else if (const char* xml = env_value("HWLOC_XMLFILE")) {
    if (hwloc_topology_set_xml(guard.topo, xml) != 0)
      throw std::runtime_error(std::string("HWLOC_XMLFILE=\"") + xml + "\": hwloc cannot read this XML topology");
    source = TopologySource::xml;
    description = std::string("xml: ") + xml;
  }
  if (hwloc_topology_load(guard.topo) != 0) throw std::runtime_error("hwloc_topology_load failed (" + description + ")");

  Topology topo(guard.release());
  hwloc_topology_t t = topo.topo_;
  topo.source_ = source;
  topo.source_description_ = std::move(description);
  topo.is_this_system_ = hwloc_topology_is_thissystem(t) != 0;

  auto make_node = [t](hwloc_const_cpuset_t cpuset, hwloc_const_nodeset_t nodeset, int logical, int os) {
    NumaNode node;
    node.logical_index = logical;
    node.os_index = os;
    node.cpuset = cpuset;
    node.nodeset = nodeset;
    for (hwloc_obj_t pu = hwloc_get_next_obj_inside_cpuset_by_type(t, cpuset, HWLOC_OBJ_PU, nullptr); pu;
         pu = hwloc_get_next_obj_inside_cpuset_by_type(t, cpuset, HWLOC_OBJ_PU, pu))
      node.pus.push_back(static_cast<int>(pu->os_index));
    node.cores = hwloc_get_nbobjs_inside_cpuset_by_type(t, cpuset, HWLOC_OBJ_CORE);
    if (node.cores <= 0) node.cores = static_cast<int>(node.pus.size());
    return node;
  };

  // A node whose PUs an earlier node already has (the high-bandwidth memory beside the
  // DRAM of the same package) would otherwise get threads of its own on the same cores.
  hwloc_bitmap_t claimed = hwloc_bitmap_alloc();
  const int numa_count = hwloc_get_nbobjs_by_type(t, HWLOC_OBJ_NUMANODE);
  for (int i = 0; i < numa_count; ++i) {
    hwloc_obj_t obj = hwloc_get_obj_by_type(t, HWLOC_OBJ_NUMANODE, static_cast<unsigned>(i));
    if (!obj->cpuset || hwloc_bitmap_iszero(obj->cpuset) || hwloc_bitmap_intersects(obj->cpuset, claimed)) {
      ++topo.memory_only_nodes_;
      continue;
    }
    hwloc_bitmap_or(claimed, claimed, obj->cpuset);
    topo.nodes_.push_back(make_node(obj->cpuset, obj->nodeset, static_cast<int>(obj->logical_index),
                                    static_cast<int>(obj->os_index)));
  }
  hwloc_bitmap_free(claimed);
  if (topo.nodes_.empty()) {
    hwloc_obj_t root = hwloc_get_root_obj(t);
    topo.nodes_.push_back(make_node(root->cpuset, root->nodeset, 0, 0));
    topo.inferred_ = true;
  }
  return topo;
}

std::vector<int> partition_pins(int pins, const std::vector<int>& weights) {
  if (pins <= 0) throw std::invalid_argument("partition_pins: pins must be positive, got " + std::to_string(pins));
  __int128 sum = 0;
  for (int w : weights) {
    if (w < 0) throw std::invalid_argument("partition_pins: negative weight " + std::to_string(w));
    sum += w;
  }
  if (sum == 0) throw std::invalid_argument("partition_pins: no positive weight");
  std::vector<int> begin(weights.size() + 1, 0);
  __int128 prefix = 0;
  for (std::size_t i = 0; i < weights.size(); ++i) {
    prefix += weights[i];
    // round(pins * prefix / sum), halves up, in exact integer arithmetic.
    begin[i + 1] = static_cast<int>((2 * static_cast<__int128>(pins) * prefix + sum) / (2 * sum));
  }
  return begin;
}

std::vector<int> threads_per_node(const std::vector<int>& cores_per_node, int total_threads) {
  if (cores_per_node.empty()) throw std::invalid_argument("threads_per_node: no node");
  if (total_threads <= 0)
    throw std::invalid_argument("threads_per_node: thread count must be positive, got " + std::to_string(total_threads));
  const int n = static_cast<int>(cores_per_node.size());
  std::vector<int> threads(n, 0);
  if (total_threads < n) {
    for (int i = 0; i < total_threads; ++i) threads[i] = 1;
    return threads;
  }
  std::vector<int> weights = cores_per_node;
  bool any = false;
  for (int& w : weights) {
    w = w < 0 ? 0 : w;
    any = any || w > 0;
  }
  if (!any) weights.assign(n, 1);
  const std::vector<int> begin = partition_pins(total_threads, weights);
  for (int i = 0; i < n; ++i) threads[i] = begin[i + 1] - begin[i];
  // Every node gets a thread: a node without one would leave its pins to remote threads.
  // The thread comes from the first node with the most, which has at least two because
  // total_threads >= n.
  for (int i = 0; i < n; ++i) {
    if (threads[i] > 0) continue;
    int donor = 0;
    for (int j = 1; j < n; ++j)
      if (threads[j] > threads[donor]) donor = j;
    --threads[donor];
    ++threads[i];
  }
  return threads;
}

std::vector<int> threads_per_node(const Topology& topo, int total_threads) {
  std::vector<int> cores;
  for (const auto& node : topo.nodes()) cores.push_back(node.cores);
  return threads_per_node(cores, total_threads);
}

std::string bitmap_list(hwloc_const_bitmap_t set) {
  if (!set) return "";
  char* text = nullptr;
  if (hwloc_bitmap_list_asprintf(&text, set) < 0 || !text) return "?";
  std::string out(text);
  std::free(text);
  return out;
}

std::string index_list(const std::vector<int>& indices) {
  std::string out;
  for (std::size_t i = 0; i < indices.size();) {
    std::size_t j = i;
    while (j + 1 < indices.size() && indices[j + 1] == indices[j] + 1) ++j;
    if (!out.empty()) out += ',';
    out += std::to_string(indices[i]);
    if (j > i) out += '-' + std::to_string(indices[j]);
    i = j + 1;
  }
  return out;
}

}  // namespace cvt::numa
