// The flow-graph schedule (docs/runtime.md): per NUMA arena one oneTBB graph, built once and
// reused for every stage, with one continue_node per stage of the stage table and one edge
// per dependency (engine/rhs/stages.hpp):
//   start -> link_kinematics -> {chain_forces, pulley_contact, inertia_decomposition, other_forces}
//         -> {gather (pins), gather_shafts} -> accelerations + stage update
// A per-pin node's body runs a chunked parallel_for over the arena's pin segment
// (owner-preferred parts of about `grain` pins); data lives in the workspace, not in
// messages. With one NUMA node the whole stage is one graph run. With several, a stage
// that reads another stage's results at neighbouring pins (or reads or writes what one
// call on node 0 does) cannot start before every node is done with that stage: the table
// is cut there into phases, each run on all nodes as a graph of its own.
#include <oneapi/tbb/blocked_range.h>
#include <oneapi/tbb/flow_graph.h>
#include <oneapi/tbb/parallel_for.h>
#include <oneapi/tbb/partitioner.h>
#include <oneapi/tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <sstream>
#include <vector>

#include "graph/schedule.hpp"
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
      for (const StageDecl& s : kStages) spans_.push_back({"node" + std::to_string(n) + "/" + s.name, 0, 0});
    if (nodes > 1) cut_phases();
    for (int n = 0; n < nodes; ++n) arenas_->execute_on(n, [&, n] { build(n); });
    if (nodes > 1) place_slots();
  }

  void rhs(double t, const double* y, double* dy, const StageOp* op, const FrictionExtras& x) override {
    set_stage_input(m_, ws_, t, y);
    args_.dy = dy;
    args_.op = op;
    args_.x = x;
    if (prof_) prof_->call_rhs(op != nullptr);
    if (arenas_->nodes() == 1) {
      const auto run = [&] { parts_[0][0].run(); };
      if (inside_) run();
      else arenas_->execute_on(0, run);
      return;
    }
    for (int p = 0; p < phases_; ++p) arenas_->run_on_all_nodes([&](int n) { parts_[n][p].run(); });
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

  // Every stage a node runs, and every dependency of the table as an edge into it (dashed:
  // across a phase cut, waiting for all nodes).
  std::string graphviz() const override {
    std::ostringstream os;
    os << "digraph stage {\n  rankdir=LR;\n  node [shape=box];\n";
    for (int n = 0; n < arenas_->nodes(); ++n) {
      const std::string p = prefix(n);
      os << "  subgraph cluster_" << n << " {\n    label=\"NUMA node " << n << ": pins [" << bounds_[n] << ", "
         << bounds_[n + 1] << "), " << arenas_->threads(n) << " threads\";\n    " << p << "start;\n";
      for (const StageDecl& s : kStages)
        if (runs_on(n, s)) os << "    " << p << s.name << " [label=\"" << label(s) << "\"];\n";
      for (const StageDecl& s : kStages) {
        if (!runs_on(n, s)) continue;
        if (s.after == 0) os << "    " << p << "start -> " << p << s.name << ";\n";
        for (const StageDecl& d : kStages) {
          if (!contains(s.after, d.id)) continue;
          os << "    " << prefix(runs_on(n, d) ? n : 0) << d.name << " -> " << p << s.name;
          if (phase_[stage_index(d.id)] != phase_[stage_index(s.id)]) os << " [style=dashed, label=\"all nodes\"]";
          os << ";\n";
        }
      }
      os << "  }\n";
    }
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
      pins(n, kStatusPass, [this, n](int b, int e) {
        ScopedTimer tm(prof_, worker(n), Section::status);
        update_status_joints(m_, ws_, b, e);
      }, coarse(n));
    };
    if (arenas_->nodes() == 1) {
      if (inside_) pass(0);
      else arenas_->execute_on(0, [&] { pass(0); });
    } else {
      arenas_->run_on_all_nodes(pass);
    }
    ScopedTimer tm(prof_, 0, Section::status);
    finish_status_update(m_, ws_);
  }
  void within_impl(void (*body)(void*), void* ctx) override {
    if (arenas_->nodes() > 1 || inside_) return body(ctx);
    arenas_->execute_on(0, [&] {
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
  bool enqueue(void (*job)(void*), void* ctx) override {
    if (arenas_->nodes() > 1 || arenas_->total_threads() < 2) return false;
    arenas_->arena(0).enqueue(numa::enqueued(job, ctx));
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
  // One node's graph of one phase (with one NUMA node: of the whole stage).
  struct Part {
    std::unique_ptr<flow::graph> graph;
    std::unique_ptr<flow::broadcast_node<Msg>> start;
    std::vector<std::unique_ptr<flow::continue_node<Msg>>> nodes;
    // What ThreadSanitizer is told of the graph's edges (numa/hand_off.hpp): the run's
    // fork and join, and per stage its end, which the stages after it acquire.
    numa::ForkJoin sync;
    std::array<char, kStageCount> done{};
    void run() {
      if (nodes.empty()) return;
      sync.fork();
      start->try_put(Msg());
      graph->wait_for_all();
      sync.joined();
    }
  };

  // Runs f(b, e) over the node's pin segment in chunks of `grain` pins (the configured
  // grain for the expensive chain kernel; the cheap passes use coarse chunks, two per
  // thread, since a task costs a fraction of a microsecond).
  // Every pass gives a pin to the same thread while all are awake (owner-preferred parts,
  // below), so that its data stays in that core's cache (a cache line moved between cores
  // costs about 80 ns here, and a stage touches ~2000).
  // The passes: the stages of the table, then the status update.
  static constexpr int kStatusPass = kStageCount, kPasses = kStageCount + 1;
  template <class F>
  void pins(int n, int pass, const F& f, int grain) {
    const int T = arenas_->threads(n), b0 = bounds_[n], len = bounds_[n + 1] - b0;
    if (T == 1) return f(b0, b0 + len);
    // Owner-preferred parts (docs/runtime.md): the segment is cut into parts of about
    // `grain` pins, c per thread; thread k runs its own parts [k c, (k+1) c) first, then
    // takes what is left from the end. A pin thus stays on the same thread in every pass
    // while all threads are awake, and its data in that core's cache; a late thread's
    // parts are still taken by the others. The parts are fixed, so the bits are too.
    const int c = std::clamp((len + T * grain - 1) / (T * grain), 1, kMaxPartsPerThread);
    const int P = T * c;
    std::atomic<unsigned char>* claim = claims_[n * kPasses + pass].get();
    for (int p = 0; p < P; ++p) claim[p].store(0, std::memory_order_relaxed);
    const auto part = [&](int) {
      const int me = tbb::this_task_arena::current_thread_index();
      const auto run = [&](int p) {
        if (claim[p].exchange(1, std::memory_order_acq_rel)) return;
        f(b0 + p * len / P, b0 + (p + 1) * len / P);
      };
      if (me >= 0 && me < T)
        for (int p = me * c; p < (me + 1) * c; ++p) run(p);
      for (int p = P - 1; p >= 0; --p) run(p);
    };
    const numa::ScopedForkJoin fj;
    tbb::parallel_for(0, T, fj.task(part), tbb::simple_partitioner());
  }
  // This thread's index among all the schedule's threads (arena n's slots come after
  // those of the nodes before it).
  int worker(int n) const { return offset_[n] + tbb::this_task_arena::current_thread_index(); }
  // Stage s on node n: its pins of the node's segment, then (node 0) its part off the pins.
  void run(int n, const StageDecl& s) {
    if (s.pins)
      pins(n, stage_index(s.id), [this, n, &s](int b, int e) {
        run_stage_pins(s, args_, prof_, prof_ ? worker(n) : 0, b, e);
      }, s.split == Split::fine ? grain_ : coarse(n));
    if (n == 0) run_stage_once(s, args_, prof_, prof_ ? worker(0) : 0);
  }
  // Once stages run on node 0 only.
  static bool runs_on(int n, const StageDecl& s) { return n == 0 || s.split != Split::once; }
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
        pins(n, stage_index(StageId::chain_forces), [&](int pb, int pe) {
          for (int j = pb; j < pe; ++j) ws_.chain_slots[j].clear(), ws_.pulley_slots[j].clear(), ws_.inertia_slots[j].clear();
        }, grain_);
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

  // With several NUMA nodes: the phase of each stage, the first after every stage it reads
  // that it must wait for on all nodes (it reads that stage's results at neighbouring pins,
  // or one of the two is a call on node 0 alone).
  void cut_phases() {
    for (const StageDecl& s : kStages) {
      int p = 0;
      for (const StageDecl& d : kStages) {
        if (!contains(s.after, d.id)) continue;
        const bool cut = contains(s.neighbours, d.id) || d.split == Split::once || s.split == Split::once;
        p = std::max(p, phase_[stage_index(d.id)] + (cut ? 1 : 0));
      }
      phase_[stage_index(s.id)] = p;
      phases_ = std::max(phases_, p + 1);
    }
  }

  // Declares node n's graphs, one per phase: a continue_node per stage of the table that
  // runs on the node, an edge per dependency within the phase, the start into the others.
  void build(int n) {
    parts_[n].resize(phases_);
    for (int ph = 0; ph < phases_; ++ph) {
      Part& p = parts_[n][ph];
      p.graph = std::make_unique<flow::graph>();
      p.start = std::make_unique<flow::broadcast_node<Msg>>(*p.graph);
      std::array<flow::continue_node<Msg>*, kStageCount> made{};
      for (const StageDecl& s : kStages) {
        if (phase_[stage_index(s.id)] != ph || !runs_on(n, s)) continue;
        // (The sanitizer's view of the node's edges: it acquires the ends of the stages
        // it reads and releases its own.)
        auto body = [this, n, &s, &p](const Msg&) {
          if constexpr (numa::kThreadSanitizer)
            for (const StageDecl& d : kStages)
              if (contains(s.after, d.id)) numa::tsan_acquire(&p.done[stage_index(d.id)]);
          if (!empty_ && !tracing_) {
            run(n, s);
          } else if (!empty_) {
            NodeSpan& span = spans_[n * kStageCount + stage_index(s.id)];
            span.begin = now();
            run(n, s);
            span.end = now();
          }
          numa::tsan_release(&p.done[stage_index(s.id)]);
        };
        p.nodes.push_back(std::make_unique<flow::continue_node<Msg>>(*p.graph, p.sync.task(std::move(body))));
        flow::continue_node<Msg>* node = made[stage_index(s.id)] = p.nodes.back().get();
        bool fed = false;
        for (const StageDecl& d : kStages)
          if (contains(s.after, d.id) && made[stage_index(d.id)]) {
            flow::make_edge(*made[stage_index(d.id)], *node);
            fed = true;
          }
        if (!fed) flow::make_edge(*p.start, *node);
      }
    }
  }

  static std::string prefix(int n) {
    // (Built with += : GCC 12 warns falsely, -Wrestrict, on "n" + std::to_string(n).)
    std::string p = "n";
    p += std::to_string(n);
    p += '_';
    return p;
  }
  std::string label(const StageDecl& s) const {
    std::string l = s.name;
    if (s.update_pins) l += " + stage update";
    if (s.split == Split::fine) l += "\\nper-thread parts, grain " + std::to_string(grain_);
    else if (s.split == Split::coarse) l += "\\nper-thread parts";
    if (phases_ > 1) l += "\\nphase " + std::to_string(phase_[stage_index(s.id)]);
    return l;
  }

  const Model& m_;
  Workspace& ws_;
  int grain_;
  numa::Topology topo_;
  std::unique_ptr<numa::NodeArenas> arenas_;
  std::vector<int> bounds_, offset_;
  std::vector<std::vector<Part>> parts_;  // [NUMA node][phase]
  std::array<int, kStageCount> phase_{};  // all 0 with one NUMA node
  int phases_ = 1;
  StageArgs args_{m_, ws_};  // the evaluation in progress
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
