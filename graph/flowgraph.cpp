// The flow-graph schedule (docs/runtime.md): per NUMA arena one oneTBB graph, built once and
// reused for every stage:
//   start -> {chain_forces, pulley_contact, other_forces, inertia_decomposition}
//         -> {gather (pins), gather_shafts} -> accelerations + stage update
// Module nodes are continue_nodes whose bodies run a chunked parallel_for over the arena's
// pin segment (owner-preferred parts of about `grain` pins); data lives in the workspace,
// not in messages. With one NUMA node the whole stage is one graph run. With several,
// the gather of a segment reads the slots of its neighbour's boundary pin and the solve
// reads the neighbours' A0^-1 F, so the graphs stop after the modules and the gather and
// the solve run as two more all-node phases.
#include <oneapi/tbb/blocked_range.h>
#include <oneapi/tbb/flow_graph.h>
#include <oneapi/tbb/parallel_for.h>
#include <oneapi/tbb/partitioner.h>
#include <oneapi/tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <sstream>
#include <vector>

#include "graph/schedule.hpp"
#include "modules/chain_forces.hpp"
#include "modules/inertia.hpp"
#include "modules/other_forces.hpp"
#include "modules/pulley_contact.hpp"
#include "numa/arenas.hpp"
#include "numa/node_buffer.hpp"
#include "numa/topology.hpp"

namespace cvt {

namespace {

namespace flow = tbb::flow;
using Msg = flow::continue_msg;

class FlowGraphSchedule final : public Schedule {
 public:
  FlowGraphSchedule(const Model& m, Workspace& ws, const ScheduleOptions& opt)
      : m_(m), ws_(ws), grain_(opt.grain), topo_(numa::discover_topology()),
        arenas_(std::make_unique<numa::NodeArenas>(topo_, opt.threads)) {
    const int nodes = arenas_->nodes();
    std::vector<int> weights(nodes);
    for (int n = 0; n < nodes; ++n) weights[n] = arenas_->threads(n);
    bounds_ = numa::partition_pins(m.links, weights);
    offset_.assign(nodes + 1, 0);
    for (int n = 0; n < nodes; ++n) offset_[n + 1] = offset_[n] + arenas_->threads(n);
    parts_.resize(nodes);
    empty_ = opt.empty_kernels;
    for (int n = 0; n < nodes; ++n)
      for (int i = 0; i < kPasses; ++i)
        claims_.push_back(std::make_unique<std::atomic<unsigned char>[]>(
            static_cast<std::size_t>(kMaxPartsPerThread * arenas_->threads(n))));
    for (int n = 0; n < nodes; ++n)
      for (const char* name : {"chain_forces", "pulley_contact", "inertia_decomposition", "other_forces"})
        spans_.push_back({"node" + std::to_string(n) + "/" + name, 0, 0});
    for (int n = 0; n < nodes; ++n) arenas_->execute_on(n, [&, n] { build(n, nodes == 1); });
    if (nodes > 1) place_slots();
  }

  void rhs(double t, const double* y, double* dy, const StageOp* op, const FrictionExtras& x) override {
    set_stage_input(m_, ws_, t, y);
    // With one node the graph computes the link kinematics itself, in parallel: done here by
    // the master it would pull the whole state across to one core every stage. With
    // several, every node's modules read links of the neighbouring segment, so it is
    // done before the graphs start.
    if (!empty_ && arenas_->nodes() > 1) {
      ScopedTimer tm(prof_, 0, Section::inertia);
      link_kinematics(m_, ws_, 0, m_.links);
    }
    dy_ = dy;
    op_ = op;
    extras_ = x;
    if (prof_) prof_->call_rhs(op != nullptr);
    const int nodes = arenas_->nodes();
    if (nodes == 1) {
      const auto run = [&] {
        parts_[0].start->try_put(Msg());
        parts_[0].graph->wait_for_all();
      };
      if (inside_) run();
      else arenas_->arena(0).execute(run);
      return;
    }
    arenas_->run_on_all_nodes([&](int n) {
      parts_[n].start->try_put(Msg());
      parts_[n].graph->wait_for_all();
    });
    arenas_->run_on_all_nodes([&](int n) {
      pins(n, kGather, Section::accel, [&](int b, int e) { gather_joints(m_, ws_, b, e); }, coarse(n));
      if (n == 0) {
        ScopedTimer tm(prof_, worker(0), Section::accel);
        gather_shafts(m_, ws_);
      }
    });
    arenas_->run_on_all_nodes([&](int n) {
      pins(n, kFinish, Section::count, [&](int b, int e) { finish(n, b, e); }, coarse(n));
      if (n == 0) finish(0, -1, -1);
    });
  }

  std::string describe() const override {
    std::ostringstream os;
    os << "flowgraph (" << arenas_->total_threads() << " threads, " << arenas_->nodes() << " NUMA arena"
       << (arenas_->nodes() > 1 ? "s" : "") << ", grain " << grain_ << " pins; pins per node:";
    for (int n = 0; n < arenas_->nodes(); ++n) os << ' ' << bounds_[n + 1] - bounds_[n];
    if (!placement_.empty()) os << "; " << placement_;
    os << ')';
    return os.str();
  }

  std::string graphviz() const override {
    std::ostringstream os;
    os << "digraph stage {\n  rankdir=LR;\n  node [shape=box];\n";
    for (int n = 0; n < arenas_->nodes(); ++n) {
      // (Built with += : GCC 12 warns falsely, -Wrestrict, on "n" + std::to_string(n).)
      std::string p = "n";
      p += std::to_string(n);
      p += '_';
      os << "  subgraph cluster_" << n << " {\n    label=\"NUMA node " << n << ": pins [" << bounds_[n] << ", "
         << bounds_[n + 1] << "), " << arenas_->threads(n) << " threads\";\n";
      if (arenas_->nodes() == 1)
        os << "    " << p << "start;\n    " << p << "kinematics [label=\"link kinematics\\nper-thread parts\"];\n    " << p
           << "start -> " << p << "kinematics;\n";
      else
        os << "    " << p << "start [label=\"start\\n(link kinematics, all links)\"];\n";
      const std::string src = arenas_->nodes() == 1 ? p + "kinematics" : p + "start";
      for (const char* mod : {"chain_forces", "pulley_contact", "inertia_decomposition"})
        os << "    " << p << mod << " [label=\"" << mod << "\\nper-thread parts, grain " << grain_ << "\"];\n"
           << "    " << src << " -> " << p << mod << ";\n";
      if (n == 0) os << "    " << p << "other_forces;\n    " << src << " -> " << p << "other_forces;\n";
      if (arenas_->nodes() == 1) {
        os << "    " << p << "gather [label=\"gather\\nper-thread parts\"];\n    " << p
           << "gather_shafts;\n    " << p << "accelerations [label=\"accelerations + stage update\\nper-thread parts\"];\n";
        for (const char* mod : {"chain_forces", "pulley_contact", "other_forces", "inertia_decomposition"})
          os << "    " << p << mod << " -> {" << p << "gather " << p << "gather_shafts};\n";
        os << "    {" << p << "gather " << p << "gather_shafts} -> " << p << "accelerations;\n";
      }
      os << "  }\n";
    }
    if (arenas_->nodes() > 1)
      os << "  all_nodes_modules -> gather_phase -> accelerations_phase [style=dashed, label=\"cross-node\"];\n";
    os << "}\n";
    return os.str();
  }

  int threads() const override { return arenas_->total_threads(); }
  int numa_nodes() const override { return arenas_->nodes(); }

  // Per pin like the forces: one parallel pass per node (phases when there are several).
  void update_status(double t, const double* y) override {
    if (prof_) prof_->call(Section::status);
    {
      ScopedTimer tm(prof_, 0, Section::status);
      begin_status_update(m_, ws_, t, y);
    }
    const auto pass = [&](int n) {
      pins(n, kStatus, Section::status, [this](int b, int e) { update_status_joints(m_, ws_, b, e); }, coarse(n));
    };
    if (arenas_->nodes() == 1) {
      if (inside_) pass(0);
      else arenas_->arena(0).execute([&] { pass(0); });
    } else {
      arenas_->run_on_all_nodes(pass);
    }
    ScopedTimer tm(prof_, 0, Section::status);
    finish_status_update(m_, ws_);
  }
  void within_impl(void (*body)(void*), void* ctx) override {
    if (arenas_->nodes() > 1 || inside_) return body(ctx);
    arenas_->arena(0).execute([&] {
      inside_ = true;
      try {
        body(ctx);
      } catch (...) {
        inside_ = false;
        throw;
      }
      inside_ = false;
    });
  }
  bool enqueue(std::function<void()>&& f) override {
    if (arenas_->nodes() > 1 || arenas_->total_threads() < 2) return false;
    arenas_->arena(0).enqueue(std::move(f));
    return true;
  }
  void set_tracing(bool on) override { tracing_ = on; }
  std::vector<NodeSpan> last_spans() const override {
    std::vector<NodeSpan> out;
    for (const NodeSpan& s : spans_)
      if (s.end > 0) out.push_back(s);
    return out;
  }

 private:
  struct Part {
    std::unique_ptr<flow::graph> graph;
    std::unique_ptr<flow::broadcast_node<Msg>> start;
    std::vector<std::unique_ptr<flow::continue_node<Msg>>> nodes;
  };

  // Runs f(b, e) over the node's pin segment in chunks of `grain` pins (default: the
  // configured grain, for the expensive chain kernel; the cheap passes use coarse chunks,
  // two per thread, since a task costs a fraction of a microsecond).
  // Every pass gives a pin to the same thread while all are awake (owner-preferred parts,
  // below), so that its data stays in that core's cache (a cache line moved between cores
  // costs about 80 ns here, and a stage touches ~2000).
  enum Pass { kKinematics, kChain, kPulley, kInertia, kGather, kFinish, kStatus, kPasses };
  // Each chunk is timed as `sec` on the worker that runs it when profiling
  // (Section::count: f times itself).
  template <class F>
  void pins(int n, Pass pass, Section sec, const F& f, int grain = 0) {
    if (grain == 0) grain = grain_;
    const auto chunk = [&](int b, int e) {
      if (!prof_ || sec == Section::count) return f(b, e);
      ScopedTimer tm(prof_, worker(n), sec);
      f(b, e);
    };
    const int T = arenas_->threads(n), b0 = bounds_[n], len = bounds_[n + 1] - b0;
    if (T == 1) return chunk(b0, b0 + len);
    // Owner-preferred parts (docs/runtime.md): the segment is cut into parts of about
    // `grain` pins, c per thread; thread k runs its own parts [k c, (k+1) c) first, then
    // takes what is left from the end. A pin thus stays on the same thread in every pass
    // while all threads are awake, and its data in that core's cache; a late thread's
    // parts are still taken by the others. The parts are fixed, so the bits are too.
    const int c = std::clamp((len + T * grain - 1) / (T * grain), 1, kMaxPartsPerThread);
    const int P = T * c;
    std::atomic<unsigned char>* claim = claims_[n * kPasses + pass].get();
    for (int p = 0; p < P; ++p) claim[p].store(0, std::memory_order_relaxed);
    tbb::parallel_for(
        0, T,
        [&](int) {
          const int me = tbb::this_task_arena::current_thread_index();
          const auto run = [&](int p) {
            if (claim[p].exchange(1, std::memory_order_acq_rel)) return;
            chunk(b0 + p * len / P, b0 + (p + 1) * len / P);
          };
          if (me >= 0 && me < T)
            for (int p = me * c; p < (me + 1) * c; ++p) run(p);
          for (int p = P - 1; p >= 0; --p) run(p);
        },
        tbb::simple_partitioner());
  }
  // This thread's index among all the schedule's threads (arena n's slots come after
  // those of the nodes before it).
  int worker(int n) const { return offset_[n] + tbb::this_task_arena::current_thread_index(); }
  // Accelerations and dy of joints [b, e) (b < 0: the shafts), then the stage update,
  // timed apart.
  void finish(int n, int b, int e) {
    const std::uint64_t t0 = prof_ ? Profiler::ticks() : 0;
    if (b < 0) finish_shafts(m_, ws_, dy_, nullptr);
    else finish_joints(m_, ws_, dy_, nullptr, b, e);
    const std::uint64_t t1 = prof_ ? Profiler::ticks() : 0;
    if (op_) {
      if (b < 0) stage_update_shafts(m_, op_, dy_);
      else stage_update_joints(m_, op_, dy_, b, e);
    }
    if (prof_) {
      const int w = worker(n);
      prof_->add(w, Section::accel, t1 - t0);
      prof_->add(w, Section::update, Profiler::ticks() - t1);
    }
  }
  int coarse(int n) const {
    const int len = bounds_[n + 1] - bounds_[n], chunks = 2 * arenas_->threads(n);
    return std::max(1, (len + chunks - 1) / chunks);
  }


  // With several nodes, the pages of each node's segment of the per-pin arrays (module
  // slots, forces, accelerations) move to that node, and its threads touch them first.
  // Tally of the migrations of one kind of array: "M of T <what> moved to their node (why
  // the first refusal)"; segments without a whole page ("-") do not count.
  struct Moves {
    int moved = 0, tried = 0;
    std::string why;
    void note(const std::string& r) {
      if (r == "-") return;
      ++tried;
      moved += r.empty();
      if (!r.empty() && why.empty()) why = r;
    }
    std::string text(const std::string& what) const {
      return std::to_string(moved) + " of " + std::to_string(tried) + " " + what + " moved to their node" +
             (why.empty() ? "" : " (" + why + ")");
    }
  };

  void place_slots() {
    Moves mv;
    for (int n = 0; n < arenas_->nodes(); ++n) {
      const int b = bounds_[n], e = bounds_[n + 1];
      for (auto* slots : {&ws_.chain_slots, &ws_.pulley_slots, &ws_.inertia_slots})
        mv.note(numa::migrate_to_node(*arenas_, slots->data() + b, sizeof(JointSlot) * (e - b), n));
      for (Eigen::VectorXd* v : {&ws_.force, &ws_.accel, &ws_.accel_free})
        mv.note(numa::migrate_to_node(*arenas_, v->data() + m_.joint(b), sizeof(double) * kJointSize * (e - b), n));
      arenas_->execute_on(n, [&] {
        pins(n, kChain, Section::count, [&](int pb, int pe) {
          for (int j = pb; j < pe; ++j) ws_.chain_slots[j].clear(), ws_.pulley_slots[j].clear(), ws_.inertia_slots[j].clear();
        });
      });
    }
    placement_ = mv.text("per-node array segments");
  }

  void place_state(const std::vector<double*>& vectors) override {
    if (arenas_->nodes() < 2) return;
    Moves mv;
    for (int n = 0; n < arenas_->nodes(); ++n) {
      const int lo = m_.joint(bounds_[n]), len = kJointSize * (bounds_[n + 1] - bounds_[n]);
      for (double* v : vectors)
        for (int off : {lo, m_.ndof + lo}) mv.note(numa::migrate_to_node(*arenas_, v + off, sizeof(double) * len, n));
    }
    placement_ += "; " + mv.text("per-node state segments (q, v of the integrator's vectors)");
  }

  // Declares node n's graph; it reads like the DAG of a stage.
  void build(int n, bool whole_stage) {
    Part& p = parts_[n];
    p.graph = std::make_unique<flow::graph>();
    flow::graph& g = *p.graph;
    p.start = std::make_unique<flow::broadcast_node<Msg>>(g);
    const auto node = [&](auto body) {
      p.nodes.push_back(std::make_unique<flow::continue_node<Msg>>(g, [this, body](const Msg&) {
        if (!empty_) body();
      }));
      return p.nodes.back().get();
    };
    // Module nodes, traced when asked (spans_[slot] of node n's stage).
    const auto module = [&](int slot, auto body) {
      return node([this, n, slot, body] {
        if (!tracing_) return body();
        NodeSpan& s = spans_[4 * n + slot];
        s.begin = now();
        body();
        s.end = now();
      });
    };
    // One node: start -> kinematics -> modules. Several: start -> modules.
    flow::sender<Msg>* source = p.start.get();
    if (whole_stage) {
      auto* kin = node([this, n] {
        pins(n, kKinematics, Section::inertia, [this](int b, int e) { link_kinematics(m_, ws_, b, e); }, coarse(n));
      });
      flow::make_edge(*p.start, *kin);
      source = kin;
    }
    auto* chain = module(0, [this, n] {
      pins(n, kChain, Section::chain, [this](int b, int e) { chain_forces(m_, ws_, b, e, extras_); });
    });
    auto* pulley = module(1, [this, n] {
      pins(n, kPulley, Section::pulley, [this](int b, int e) { pulley_contact(m_, ws_, b, e, extras_); }, coarse(n));
    });
    auto* inertia = module(2, [this, n] {
      pins(n, kInertia, Section::inertia, [this](int b, int e) { inertia_decomposition(m_, ws_, b, e); }, coarse(n));
    });
    std::vector<flow::continue_node<Msg>*> modules = {chain, pulley, inertia};
    if (n == 0) modules.push_back(module(3, [this] {
      ScopedTimer tm(prof_, worker(0), Section::other);
      other_forces(m_, ws_);
    }));
    for (auto* mod : modules) flow::make_edge(*source, *mod);
    if (!whole_stage) return;
    auto* gather = node([this, n] {
      pins(n, kGather, Section::accel, [this](int b, int e) { gather_joints(m_, ws_, b, e); }, coarse(n));
    });
    auto* shafts = node([this] {
      ScopedTimer tm(prof_, worker(0), Section::accel);
      gather_shafts(m_, ws_);
    });
    auto* accel = node([this, n] {
      pins(n, kFinish, Section::count, [this, n](int b, int e) { finish(n, b, e); }, coarse(n));
      finish(n, -1, -1);
    });
    for (auto* mod : modules) {
      flow::make_edge(*mod, *gather);
      flow::make_edge(*mod, *shafts);
    }
    flow::make_edge(*gather, *accel);
    flow::make_edge(*shafts, *accel);
  }

  const Model& m_;
  Workspace& ws_;
  int grain_;
  numa::Topology topo_;
  std::unique_ptr<numa::NodeArenas> arenas_;
  std::vector<int> bounds_, offset_;
  std::vector<Part> parts_;
  double* dy_ = nullptr;
  const StageOp* op_ = nullptr;
  FrictionExtras extras_;  // what the evaluation in progress is asked for besides f
  bool empty_ = false, tracing_ = false;
  bool inside_ = false;  // the master is in arena 0 (within())
  std::vector<NodeSpan> spans_;
  std::string placement_;
  static constexpr int kMaxPartsPerThread = 64;
  std::vector<std::unique_ptr<std::atomic<unsigned char>[]>> claims_;  // per node and pass
  static double now() {
    return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
  }
};

}  // namespace

std::unique_ptr<Schedule> make_flowgraph_schedule(const Model& m, Workspace& ws, const ScheduleOptions& opt) {
  return std::make_unique<FlowGraphSchedule>(m, ws, opt);
}

}  // namespace cvt
