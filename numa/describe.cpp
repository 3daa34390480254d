// Plain text with fixed columns: read by people and grepped by the scaling scripts.
#include "numa/describe.hpp"

#include <algorithm>
#include <cstdio>
#include <vector>

namespace cvt::numa {

namespace {

std::string pad_left(const std::string& s, std::size_t width) {
  return s.size() >= width ? s : std::string(width - s.size(), ' ') + s;
}

std::string pad_right(const std::string& s, std::size_t width) {
  return s.size() >= width ? s : s + std::string(width - s.size(), ' ');
}

}  // namespace

std::string describe(const Topology& topo, const NodeArenas* arenas, int pins) {
  std::string out;
  out += "topology: " + topo.source_description();
#ifdef HWLOC_VERSION
  out += " (hwloc " HWLOC_VERSION ")";
#endif
  out += "\nis this system: ";
  out += topo.is_this_system() ? "yes" : "no (binding calls do nothing; HWLOC_THISSYSTEM=1 forces them)";
  out += "\nNUMA nodes with PUs: " + std::to_string(topo.node_count());
  if (topo.numa_nodes_inferred()) out += " (hwloc reports none: the machine stands as one node)";
  out += ", memory-only nodes: " + std::to_string(topo.memory_only_nodes());
  out += ", cores: " + std::to_string(topo.total_cores()) + ", PUs: " + std::to_string(topo.total_pus()) + "\n";

  const int n = topo.node_count();
  std::vector<int> threads(n, 0);
  if (arenas)
    for (int i = 0; i < arenas->nodes() && i < n; ++i) threads[i] = arenas->threads(i);
  std::vector<int> begin;
  if (pins > 0) {
    std::vector<int> weights(n, 0);
    for (int i = 0; i < n; ++i) weights[i] = arenas ? threads[i] : topo.node(i).cores;
    begin = partition_pins(pins, weights);
  }

  std::vector<std::string> pu_text(n);
  std::size_t pu_width = 3;
  for (int i = 0; i < n; ++i) {
    pu_text[i] = index_list(topo.node(i).pus);
    pu_width = std::max(pu_width, pu_text[i].size());
  }
  out += "node    os  cores  " + pad_right("PUs", pu_width) + "  threads";
  if (pins > 0) out += "  pins (of " + std::to_string(pins) + ", split by " + (arenas ? "threads" : "cores") + ")";
  out += "\n";
  for (int i = 0; i < n; ++i) {
    const NumaNode& node = topo.node(i);
    out += pad_left(std::to_string(i), 4) + pad_left(std::to_string(node.os_index), 6) +
           pad_left(std::to_string(node.cores), 7) + "  " + pad_right(pu_text[i], pu_width) + "  " +
           pad_left(arenas ? std::to_string(threads[i]) : "-", 7);
    if (pins > 0) out += "  [" + std::to_string(begin[i]) + ", " + std::to_string(begin[i + 1]) + ")";
    out += "\n";
  }
  if (arenas) {
    out += arenas->binding_message() + "\n";
  } else {
    out += "thread binding: not checked (no arenas built)\nmemory binding: not checked (no arenas built)\n";
  }
  return out;
}

}  // namespace cvt::numa
