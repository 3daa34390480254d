// Buffers whose pages lie on one NUMA node: the per-pin arrays a node's threads work on,
// allocated once at set-up (never in a step). Pages are taken fresh from the kernel, bound
// to the node where the kernel lets us, and first touched by the node's own threads inside
// its arena, so that placement holds even where binding is refused (a fake node, no
// mbind) as long as the threads are pinned.
#pragma once

#include <cstddef>
#include <span>
#include <string>
#include <type_traits>
#include <utility>

#include "numa/arenas.hpp"
#include "numa/topology.hpp"

namespace cvt::numa {

// Untyped storage behind NodeBuffer: page-aligned (so 64-byte aligned), zero-filled.
class NodeMemory {
 public:
  NodeMemory() = default;
  // Maps `bytes` of fresh pages, binds them to `node` (hwloc_set_area_membind, BIND) where
  // the topology is this system and hwloc can bind memory, and touches every page from the
  // node's arena with a static parallel loop. Throws std::bad_alloc if mapping fails.
  NodeMemory(NodeArenas& arenas, int node, std::size_t bytes);
  ~NodeMemory();
  NodeMemory(NodeMemory&& other) noexcept;
  NodeMemory& operator=(NodeMemory&& other) noexcept;
  NodeMemory(const NodeMemory&) = delete;
  NodeMemory& operator=(const NodeMemory&) = delete;

  void* data() const { return data_; }
  std::size_t bytes() const { return bytes_; }
  int node() const { return node_; }
  // True when the kernel accepted the binding of these pages to the node.
  bool bound() const { return bound_; }
  // Why the pages are not bound ("" when bound): placement then rests on first touch.
  const std::string& bind_message() const { return bind_message_; }

 private:
  void release() noexcept;

  void* data_ = nullptr;
  std::size_t bytes_ = 0;         // as asked for
  std::size_t mapped_bytes_ = 0;  // rounded up to whole pages
  int node_ = -1;
  bool bound_ = false;
  std::string bind_message_;
};

// n elements of T on one node. The elements are not constructed: T must be trivially
// copyable and destructible, and starts as all-zero bytes (what fresh pages hold).
template <class T>
class NodeBuffer {
  static_assert(std::is_trivially_copyable_v<T> && std::is_trivially_destructible_v<T>,
                "NodeBuffer holds raw storage: T must be trivially copyable and destructible");
  static_assert(alignof(T) <= 4096, "NodeBuffer aligns to pages");

 public:
  NodeBuffer() = default;
  NodeBuffer(NodeArenas& arenas, int node, std::size_t n) : memory_(arenas, node, n * sizeof(T)), size_(n) {}

  T* data() { return static_cast<T*>(memory_.data()); }
  const T* data() const { return static_cast<const T*>(memory_.data()); }
  std::size_t size() const { return size_; }
  T& operator[](std::size_t i) { return data()[i]; }
  const T& operator[](std::size_t i) const { return data()[i]; }
  T* begin() { return data(); }
  T* end() { return data() + size_; }
  const T* begin() const { return data(); }
  const T* end() const { return data() + size_; }
  std::span<T> span() { return {data(), size_}; }
  std::span<const T> span() const { return {data(), size_}; }

  int node() const { return memory_.node(); }
  bool bound() const { return memory_.bound(); }
  const std::string& bind_message() const { return memory_.bind_message(); }
  const NodeMemory& memory() const { return memory_; }

 private:
  NodeMemory memory_;
  std::size_t size_ = 0;
};

// The node (index into topo.nodes()) on which the touched pages of [p, p + bytes) lie,
// from hwloc_get_area_memlocation; -1 where unknown: the topology is not this system,
// the OS cannot tell, no page is touched yet, the pages are spread over several nodes,
// or they lie on a node the Topology does not use (memory-only).
int memory_node_of(const Topology& topo, const void* p, std::size_t bytes);

// Moves the whole pages inside [p, p + bytes) to the node (hwloc_set_area_membind with
// MIGRATE): for arrays already allocated and touched elsewhere, whose per-node segments
// should live next to the node's threads. Pages that straddle the ends stay where they
// are. Returns "" on success, "-" when no whole page lies inside, else the reason.
std::string migrate_to_node(NodeArenas& arenas, void* p, std::size_t bytes, int node);

}  // namespace cvt::numa
