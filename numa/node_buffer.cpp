// mmap rather than malloc: pages the allocator has already handed out (and touched) lie
// wherever they were first touched, and neither binding without migration nor our own
// first touch would move them. Fresh anonymous pages also need no topology to free.
#include "numa/node_buffer.hpp"

#include <cstdint>

#include <oneapi/tbb/blocked_range.h>
#include <oneapi/tbb/parallel_for.h>
#include <oneapi/tbb/partitioner.h>
#include <sys/mman.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <new>
#include <stdexcept>

namespace cvt::numa {

NodeMemory::NodeMemory(NodeArenas& arenas, int node, std::size_t bytes) : bytes_(bytes), node_(node) {
  if (node < 0 || node >= arenas.nodes())
    throw std::out_of_range("NodeMemory: no node " + std::to_string(node) + " in use");
  if (bytes == 0) {
    bind_message_ = "empty buffer";
    return;
  }
  const std::size_t page = static_cast<std::size_t>(sysconf(_SC_PAGESIZE));
  mapped_bytes_ = (bytes + page - 1) / page * page;
  void* p = mmap(nullptr, mapped_bytes_, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  if (p == MAP_FAILED) throw std::bad_alloc();
  data_ = p;

  hwloc_topology_t t = arenas.topology();
  const hwloc_topology_support* support = hwloc_topology_get_support(t);
  if (!hwloc_topology_is_thissystem(t)) {
    bind_message_ = "topology is not this system";
  } else if (!support->membind->set_area_membind || !support->membind->bind_membind) {
    bind_message_ = "hwloc cannot bind memory on this system";
  } else if (hwloc_set_area_membind(t, data_, mapped_bytes_, arenas.nodeset(node), HWLOC_MEMBIND_BIND,
                                    HWLOC_MEMBIND_BYNODESET) != 0) {
    bind_message_ = "binding to OS node " + bitmap_list(arenas.nodeset(node)) + " failed: " + std::strerror(errno);
  } else {
    bound_ = true;
  }

  // First touch by the node's threads: with binding refused this is what places the pages.
  char* base = static_cast<char*>(data_);
  const std::size_t pages = mapped_bytes_ / page;
  try {
    arenas.execute_on(node, [&] {
      const auto touch = [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i != r.end(); ++i) *static_cast<volatile char*>(base + i * page) = 0;
      };
      const ScopedForkJoin fj;
      tbb::parallel_for(tbb::blocked_range<std::size_t>(0, pages), fj.task(touch), tbb::static_partitioner());
    });
  } catch (...) {
    release();  // a throwing constructor gets no destructor
    throw;
  }
}

NodeMemory::~NodeMemory() { release(); }

NodeMemory::NodeMemory(NodeMemory&& other) noexcept
    : data_(std::exchange(other.data_, nullptr)),
      bytes_(std::exchange(other.bytes_, 0)),
      mapped_bytes_(std::exchange(other.mapped_bytes_, 0)),
      node_(std::exchange(other.node_, -1)),
      bound_(std::exchange(other.bound_, false)),
      bind_message_(std::move(other.bind_message_)) {}

NodeMemory& NodeMemory::operator=(NodeMemory&& other) noexcept {
  if (this != &other) {
    release();
    data_ = std::exchange(other.data_, nullptr);
    bytes_ = std::exchange(other.bytes_, 0);
    mapped_bytes_ = std::exchange(other.mapped_bytes_, 0);
    node_ = std::exchange(other.node_, -1);
    bound_ = std::exchange(other.bound_, false);
    bind_message_ = std::move(other.bind_message_);
  }
  return *this;
}

void NodeMemory::release() noexcept {
  if (data_) munmap(data_, mapped_bytes_);
  data_ = nullptr;
  bytes_ = mapped_bytes_ = 0;
}

int memory_node_of(const Topology& topo, const void* p, std::size_t bytes) {
  if (!p || bytes == 0 || !topo.is_this_system()) return -1;
  hwloc_topology_t t = topo.handle();
  if (!hwloc_topology_get_support(t)->membind->get_area_memlocation) return -1;
  hwloc_bitmap_t where = hwloc_bitmap_alloc();
  int node = -1;
  if (hwloc_get_area_memlocation(t, p, bytes, where, HWLOC_MEMBIND_BYNODESET) == 0 && hwloc_bitmap_weight(where) == 1) {
    for (int i = 0; i < topo.node_count() && node < 0; ++i)
      if (hwloc_bitmap_isincluded(where, topo.node(i).nodeset)) node = i;
  }
  hwloc_bitmap_free(where);
  return node;
}

std::string migrate_to_node(NodeArenas& arenas, void* p, std::size_t bytes, int node) {
  const std::uintptr_t page = static_cast<std::uintptr_t>(sysconf(_SC_PAGESIZE));
  const std::uintptr_t lo = (reinterpret_cast<std::uintptr_t>(p) + page - 1) / page * page;
  const std::uintptr_t hi = (reinterpret_cast<std::uintptr_t>(p) + bytes) / page * page;
  if (hi <= lo) return "-";
  hwloc_topology_t t = arenas.topology();
  if (!hwloc_topology_is_thissystem(t)) return "topology is not this system";
  const hwloc_topology_support* support = hwloc_topology_get_support(t);
  if (!support->membind->set_area_membind || !support->membind->migrate_membind)
    return "hwloc cannot migrate memory on this system";
  if (hwloc_set_area_membind(t, reinterpret_cast<void*>(lo), hi - lo, arenas.nodeset(node), HWLOC_MEMBIND_BIND,
                             HWLOC_MEMBIND_BYNODESET | HWLOC_MEMBIND_MIGRATE) != 0)
    return "migrating to OS node " + bitmap_list(arenas.nodeset(node)) + " failed: " + std::strerror(errno);
  return "";
}

}  // namespace cvt::numa
