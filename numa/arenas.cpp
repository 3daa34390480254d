// Binding is checked, not assumed: hwloc returns success without doing anything on a
// topology that is not this system, and the kernel may refuse a PU set (cgroups, a fake
// layout larger than the machine), so every binding is read back.
#include "numa/arenas.hpp"

#include <oneapi/tbb/task_scheduler_observer.h>
#include <sys/mman.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>
#include <stdexcept>

namespace cvt::numa {

struct NodeArenas::Counters {
  std::atomic<long> binds{0};
  std::atomic<long> failures{0};
};

namespace {

// The bindings a thread had before it entered our arenas, innermost last: a thread can
// enter a node's arena from inside another's (execute_on in a task), and each exit must
// give back what the matching entry found. Bitmaps are kept for reuse, so entering an
// arena allocates only the first time a thread reaches a given depth.
struct SavedBinding {
  const void* owner = nullptr;
  hwloc_bitmap_t set = nullptr;
  bool valid = false;
};

// `current` caches the binding this thread was last given or read (valid once `known`):
// entering an arena the thread is already bound for, and leaving back to the same set,
// then cost no system call. That matters because the master enters node 0's arena once
// per RK4 stage, and get/set/get/set would cost microseconds per stage. The cache assumes
// nothing else rebinds the thread behind our back.
struct ThreadBindings {
  std::vector<SavedBinding> stack;
  std::size_t depth = 0;
  hwloc_bitmap_t scratch = hwloc_bitmap_alloc();
  hwloc_bitmap_t current = hwloc_bitmap_alloc();
  bool known = false;
  ~ThreadBindings() {
    for (auto& s : stack) hwloc_bitmap_free(s.set);
    hwloc_bitmap_free(scratch);
    hwloc_bitmap_free(current);
  }
  SavedBinding& push(const void* owner) {
    if (depth == stack.size()) stack.push_back({nullptr, hwloc_bitmap_alloc(), false});
    SavedBinding& s = stack[depth++];
    s.owner = owner;
    s.valid = false;
    return s;
  }
};

thread_local ThreadBindings tls_bindings;

std::string errno_text(int e) { return std::strerror(e); }

}  // namespace

// Pins every thread that enters its arena to the node's PUs and, when the thread leaves,
// gives it back the binding it came with: the caller must not stay pinned to a remote
// node after execute_on, and a worker must not carry a node's pinning into an arena
// that is not a node's (TBB's default arena, another NodeArenas).
class BindingObserver final : public tbb::task_scheduler_observer {
 public:
  BindingObserver(tbb::task_arena& arena, hwloc_topology_t topo, hwloc_const_cpuset_t set,
                  std::atomic<long>& binds, std::atomic<long>& failures)
      : tbb::task_scheduler_observer(arena), topo_(topo), set_(set), binds_(binds), failures_(failures) {
    tsan_release(&made_);
    observe(true);
  }
  // Stops notifications before this object is half destroyed (TBB's advice).
  ~BindingObserver() override {
    observe(false);
    tsan_acquire(&used_);
  }

  // (The notifications reach the threads through libtbb: hand_off.hpp's annotations order
  // them after the constructor and before the destructor.)
  void on_scheduler_entry(bool) override {
    tsan_acquire(&made_);
    enter();
    tsan_release(&used_);
  }
  void on_scheduler_exit(bool) override {
    tsan_acquire(&made_);
    leave();
    tsan_release(&used_);
  }

 private:
  void enter() {
    ThreadBindings& tb = tls_bindings;
    SavedBinding& saved = tb.push(this);
    if (!tb.known) tb.known = hwloc_get_cpubind(topo_, tb.current, HWLOC_CPUBIND_THREAD) == 0;
    saved.valid = tb.known;
    if (saved.valid) hwloc_bitmap_copy(saved.set, tb.current);
    binds_.fetch_add(1, std::memory_order_relaxed);
    if (tb.known && hwloc_bitmap_isequal(tb.current, set_)) return;  // bound for this node already
    const bool ok = hwloc_set_cpubind(topo_, set_, HWLOC_CPUBIND_THREAD) == 0 &&
                    hwloc_get_cpubind(topo_, tb.scratch, HWLOC_CPUBIND_THREAD) == 0 &&
                    hwloc_bitmap_isequal(tb.scratch, set_);
    tb.known = hwloc_get_cpubind(topo_, tb.current, HWLOC_CPUBIND_THREAD) == 0;
    if (!ok) failures_.fetch_add(1, std::memory_order_relaxed);
  }

  void leave() {
    ThreadBindings& tb = tls_bindings;
    // An exit without our entry on top (observer switched on while the thread was
    // inside) has nothing to give back.
    if (tb.depth == 0 || tb.stack[tb.depth - 1].owner != this) return;
    SavedBinding& saved = tb.stack[--tb.depth];
    if (!saved.valid || (tb.known && hwloc_bitmap_isequal(tb.current, saved.set))) return;
    tb.known = hwloc_set_cpubind(topo_, saved.set, HWLOC_CPUBIND_THREAD) == 0;
    if (tb.known) hwloc_bitmap_copy(tb.current, saved.set);
  }

  hwloc_topology_t topo_;
  hwloc_const_cpuset_t set_;
  std::atomic<long>& binds_;
  std::atomic<long>& failures_;
  char made_ = 0, used_ = 0;
};

namespace {

const char* kNotThisSystem =
    "topology is not this system: hwloc binding calls do nothing; HWLOC_THISSYSTEM=1 makes them act on this layout";

// Binds the calling thread to each node's PUs in turn, reads it back, and restores the
// caller. Returns "" on success, else the reason.
std::string probe_thread_binding(const Topology& topo, const std::vector<hwloc_const_cpuset_t>& sets) {
  hwloc_topology_t t = topo.handle();
  if (!topo.is_this_system()) return kNotThisSystem;
  const hwloc_topology_support* support = hwloc_topology_get_support(t);
  if (!support->cpubind->set_thisthread_cpubind || !support->cpubind->get_thisthread_cpubind)
    return "hwloc cannot bind threads on this system";
  hwloc_bitmap_t saved = hwloc_bitmap_alloc();
  hwloc_bitmap_t seen = hwloc_bitmap_alloc();
  const bool have_saved = hwloc_get_cpubind(t, saved, HWLOC_CPUBIND_THREAD) == 0;
  std::string reason;
  for (std::size_t i = 0; i < sets.size() && reason.empty(); ++i) {
    const std::string node = "node " + std::to_string(i) + " (PUs " + bitmap_list(sets[i]) + ")";
    if (hwloc_set_cpubind(t, sets[i], HWLOC_CPUBIND_THREAD) != 0)
      reason = "binding a thread to " + node + " failed: " + errno_text(errno);
    else if (hwloc_get_cpubind(t, seen, HWLOC_CPUBIND_THREAD) != 0)
      reason = "reading back the binding to " + node + " failed: " + errno_text(errno);
    else if (!hwloc_bitmap_isequal(seen, sets[i]))
      reason = "a thread bound to " + node + " reads back as bound to PUs " + bitmap_list(seen);
  }
  if (have_saved) hwloc_set_cpubind(t, saved, HWLOC_CPUBIND_THREAD);
  hwloc_bitmap_free(seen);
  hwloc_bitmap_free(saved);
  return reason;
}

// Binds one fresh page to each node, touches it and asks the kernel where it lies.
// Returns "" when every page lies on its node, else the reason.
std::string probe_memory_binding(const Topology& topo, const std::vector<hwloc_const_nodeset_t>& sets) {
  hwloc_topology_t t = topo.handle();
  if (!topo.is_this_system()) return kNotThisSystem;
  const hwloc_topology_support* support = hwloc_topology_get_support(t);
  if (!support->membind->set_area_membind || !support->membind->bind_membind)
    return "hwloc cannot bind memory on this system";
  if (!support->membind->get_area_memlocation) return "hwloc cannot tell where memory lies on this system";
  const std::size_t page = static_cast<std::size_t>(sysconf(_SC_PAGESIZE));
  hwloc_bitmap_t where = hwloc_bitmap_alloc();
  std::string reason;
  for (std::size_t i = 0; i < sets.size() && reason.empty(); ++i) {
    const std::string node = "node " + std::to_string(i) + " (OS node " + bitmap_list(sets[i]) + ")";
    void* p = mmap(nullptr, page, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (p == MAP_FAILED) {
      reason = "mmap of one page failed: " + errno_text(errno);
      break;
    }
    if (hwloc_set_area_membind(t, p, page, sets[i], HWLOC_MEMBIND_BIND, HWLOC_MEMBIND_BYNODESET) != 0) {
      reason = "binding memory to " + node + " failed: " + errno_text(errno);
    } else {
      *static_cast<volatile char*>(p) = 0;
      hwloc_bitmap_zero(where);
      if (hwloc_get_area_memlocation(t, p, page, where, HWLOC_MEMBIND_BYNODESET) != 0)
        reason = "asking where memory of " + node + " lies failed: " + errno_text(errno);
      else if (!hwloc_bitmap_isequal(where, sets[i]))
        reason = "memory bound to " + node + " lies on OS node " + bitmap_list(where);
    }
    munmap(p, page);
  }
  hwloc_bitmap_free(where);
  return reason;
}

}  // namespace

NodeArenas::NodeArenas(const Topology& topo, int total_threads) : topo_(topo.handle()) {
  if (!topo_) throw std::invalid_argument("NodeArenas: the topology is empty (moved from)");
  const std::vector<int> per_node = threads_per_node(topo, total_threads);  // validates total_threads
  for (int i = 0; i < static_cast<int>(per_node.size()) && per_node[i] > 0; ++i) {
    threads_.push_back(per_node[i]);
    cpusets_.push_back(topo.node(i).cpuset);
    nodesets_.push_back(topo.node(i).nodeset);
  }
  total_threads_ = total_threads;

  const auto limit = tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism);
  if (static_cast<std::size_t>(total_threads) > limit)
    worker_limit_.emplace(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(total_threads));

  const int n = nodes();
  counters_ = std::make_unique<Counters[]>(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) {
    arenas_.push_back(std::make_unique<tbb::task_arena>(threads_[i], static_cast<unsigned>(reserved_slots(i))));
    arenas_.back()->initialize();
  }
  groups_ = std::make_unique<tbb::task_group[]>(static_cast<std::size_t>(n));

  thread_message_ = probe_thread_binding(topo, cpusets_);
  thread_binding_probe_ = thread_message_.empty();
  if (thread_binding_probe_) {
    for (int i = 0; i < n; ++i)
      observers_.push_back(std::make_unique<BindingObserver>(*arenas_[i], topo_, cpusets_[i], counters_[i].binds,
                                                             counters_[i].failures));
    thread_message_ = "threads bound to their node's PUs (read back with hwloc_get_cpubind)";
  } else {
    thread_message_ = "not in effect (" + thread_message_ + "); arenas run unbound";
  }

  memory_message_ = probe_memory_binding(topo, nodesets_);
  memory_binding_ = memory_message_.empty();
  memory_message_ = memory_binding_
                        ? "memory bound to its node (read back with hwloc_get_area_memlocation)"
                        : "not in effect (" + memory_message_ + "); buffers are placed by first touch only";
}

NodeArenas::~NodeArenas() {
  observers_.clear();  // stop pinning before the arenas go
}

long NodeArenas::binds(int node) const {
  if (node < 0 || node >= nodes()) throw std::out_of_range("NodeArenas::binds: no node " + std::to_string(node));
  return counters_[node].binds.load(std::memory_order_relaxed);
}

long NodeArenas::bind_failures(int node) const {
  if (node < 0 || node >= nodes())
    throw std::out_of_range("NodeArenas::bind_failures: no node " + std::to_string(node));
  return counters_[node].failures.load(std::memory_order_relaxed);
}

bool NodeArenas::thread_binding_in_effect() const {
  if (!thread_binding_probe_) return false;
  for (int i = 0; i < nodes(); ++i)
    if (bind_failures(i) > 0) return false;
  return true;
}

std::string NodeArenas::thread_binding_message() const {
  if (!thread_binding_probe_) return thread_message_;
  long failures = 0, binds_total = 0;
  for (int i = 0; i < nodes(); ++i) {
    failures += bind_failures(i);
    binds_total += binds(i);
  }
  if (failures == 0) return thread_message_;
  return "not in effect (" + std::to_string(failures) + " of " + std::to_string(binds_total) +
         " threads entering an arena could not be bound to the node's PUs)";
}

std::string NodeArenas::binding_message() const {
  return "thread binding: " + thread_binding_message() + "\nmemory binding: " + memory_message_;
}

int current_pu(const Topology& topo) {
  if (!topo.is_this_system()) return -1;
  hwloc_bitmap_t set = hwloc_bitmap_alloc();
  int pu = -1;
  if (hwloc_get_last_cpu_location(topo.handle(), set, HWLOC_CPUBIND_THREAD) == 0) pu = hwloc_bitmap_first(set);
  hwloc_bitmap_free(set);
  return pu;
}

std::vector<int> current_binding(const Topology& topo) {
  std::vector<int> pus;
  if (!topo.is_this_system()) return pus;
  hwloc_bitmap_t set = hwloc_bitmap_alloc();
  if (hwloc_get_cpubind(topo.handle(), set, HWLOC_CPUBIND_THREAD) == 0) {
    for (int i = hwloc_bitmap_first(set); i >= 0; i = hwloc_bitmap_next(set, i)) pus.push_back(i);
  }
  hwloc_bitmap_free(set);
  return pus;
}

}  // namespace cvt::numa
