// The published OpenMP scheme (paper 2, section 3), reproduced as the baseline to beat:
// one parallel region per RHS in which every thread zeroes its thread-local force
// buffers, runs static loops over the pins for chain forces and pulley contact adding
// into its buffers, and then gathers a slice of the buffers into the common vectors;
// everything else (the rest of the stage table: other forces, inertia, the solve) runs
// serially. Each coordinate gets at most two contributions per module, so the buffer sums
// equal the ordered gather to the bit (engine/rhs/rhs.hpp) and the trajectory is that of
// the serial schedule. A build without OpenMP (CVT_WITH_OPENMP off) refuses the scheduler.
#include <stdexcept>
#include <vector>

#include "graph/schedule.hpp"
#include "numa/hand_off.hpp"

#ifndef CVT_WITH_OPENMP

namespace cvt {

std::unique_ptr<Schedule> make_paper_omp_schedule(const Model&, Workspace&, const ScheduleOptions&) {
  throw std::invalid_argument("the scheduler paper-omp needs OpenMP, which this build was made without "
                              "(cmake -DCVT_WITH_OPENMP=ON with the compiler's OpenMP installed)");
}

}  // namespace cvt

#else

#include <omp.h>

namespace cvt {

namespace {

class PaperOmpSchedule final : public Schedule {
 public:
  PaperOmpSchedule(const Model& m, Workspace& ws, int threads)
      : m_(m), ws_(ws), threads_(threads), size_((kJointSize + 1) * m.links),
        cbuf_(threads, std::vector<double>(size_)), pbuf_(threads, std::vector<double>(size_)),
        csum_(size_), psum_(size_), times_(threads) {}

  void rhs(double t, const double* y, double* dy, const StageOp* op, const FrictionExtras& x) override {
    set_stage_input(m_, ws_, t, y);
    if (prof_) prof_->call_rhs(op != nullptr);
    const StageArgs a{m_, ws_, dy, op, x};
    // The table top to bottom on the master, but for the published parallel region (chain
    // and pulley forces into the thread buffers) and the gather from the buffers' sums.
    for (const StageDecl& s : kStages) {
      if (s.id == StageId::chain_forces) {
        parallel_region(a);
      } else if (s.id == StageId::pulley_contact) {
        continue;  // in the region
      } else if (s.id == StageId::gather) {
        ScopedTimer tm(prof_, 0, s.section);
        gather_joints_from_sums(m_, ws_, csum_.data(), psum_.data(), 0, m_.links);
      } else {
        run_stage(s, a, prof_, 0);
      }
    }
  }

  // The published code updated its contact events serially.
  void update_status(double t, const double* y) override { update_contact_status(m_, ws_, t, y, prof_); }

  std::string describe() const override {
    return "paper-omp (" + std::to_string(threads_) + " OpenMP threads, static loops, thread-local buffers)";
  }
  std::string graphviz() const override {
    std::string dot = "digraph stage {\n  rankdir=LR;\n  start";
    for (const StageDecl& s : kStages) {
      if (s.id == StageId::pulley_contact) continue;
      if (s.id == StageId::chain_forces) {
        dot += " -> zero_buffers;\n  subgraph cluster_omp { label=\"omp parallel\"; zero_buffers -> chain_forces -> "
               "pulley_contact -> gather_buffers; }\n  gather_buffers";
        continue;
      }
      (dot += " -> ") += s.name;
    }
    dot += ";\n  gather [label=\"gather\\nfrom the buffers' sums\"];\n  accelerations [label=\"accelerations\\n+ stage "
           "update\"];\n}\n";
    return dot;
  }
  int threads() const override { return threads_; }
  ScheduleCounters counters() const override {
    ScheduleCounters c;
    for (const Times& t : times_) {
      c.zero_s += t.zero;
      c.compute_s += t.compute;
      c.gather_s += t.gather;
    }
    return c;
  }

 private:
  // The published region: chain and pulley forces of the thread's static block of pins,
  // each pin's slot added into the thread's buffers, then the buffers summed.
  static constexpr PinKernel kChain = stage(StageId::chain_forces).pins;
  static constexpr PinKernel kPulley = stage(StageId::pulley_contact).pins;
  static_assert(stage_index(StageId::pulley_contact) == stage_index(StageId::chain_forces) + 1 &&
                    stage(StageId::pulley_contact).after == stage(StageId::chain_forces).after,
                "one region runs chain and pulley forces: neighbours in the table, reading the same stages");
  // The region's threads run region_thread. What the sanitizer is told of libgomp's
  // hand-offs (numa/hand_off.hpp): the region's start and end, and its three barriers. The
  // region itself only reads its arguments, before the acquire (tests/sanitizers/tsan.supp).
  void parallel_region(const StageArgs& a) {
    numa::ForkJoin region;
    region.fork();
#pragma omp parallel num_threads(threads_)
    region_thread(a, region);
    region.joined();
  }
  void region_thread(const StageArgs& a, const numa::ForkJoin& region) {
    const numa::ForkJoin::Member member(region);
    const Model& m = m_;
    Workspace& ws = ws_;
    const int N = m.links;
    Profiler* prof = prof_;
    {
      const int th = omp_get_thread_num();
      const double t0 = omp_get_wtime();
      const std::uint64_t c0 = prof ? Profiler::ticks() : 0;
      double* cb = cbuf_[th].data();
      double* pb = pbuf_[th].data();
      for (int i = 0; i < size_; ++i) cb[i] = 0.0;
      for (int i = 0; i < size_; ++i) pb[i] = 0.0;
      const double t1 = omp_get_wtime();
      const std::uint64_t c1 = prof ? Profiler::ticks() : 0;
      // (nowait + barrier: the loops' implicit barriers, made explicit so that the busy
      // time of each thread is timed without its wait.)
#pragma omp for schedule(static) nowait
      for (int j = 0; j < N; ++j) {
        kChain(a, j, j + 1);
        scatter_slot(m, ws.chain_slots[j], j, cb);
      }
      const std::uint64_t c2 = prof ? Profiler::ticks() : 0;
      numa::barrier_arrive(&barrier_[0]);
#pragma omp barrier
      numa::barrier_leave(&barrier_[0]);
      const std::uint64_t c3 = prof ? Profiler::ticks() : 0;
#pragma omp for schedule(static) nowait
      for (int j = 0; j < N; ++j) {
        kPulley(a, j, j + 1);
        scatter_slot(m, ws.pulley_slots[j], j, pb);
      }
      const std::uint64_t c4 = prof ? Profiler::ticks() : 0;
      numa::barrier_arrive(&barrier_[1]);
#pragma omp barrier
      numa::barrier_leave(&barrier_[1]);
      const double t2 = omp_get_wtime();
      const std::uint64_t c5 = prof ? Profiler::ticks() : 0;
#pragma omp for schedule(static) nowait
      for (int i = 0; i < size_; ++i) {
        double c = 0.0, p = 0.0;
        for (int k = 0; k < threads_; ++k) c += cbuf_[k][i];
        for (int k = 0; k < threads_; ++k) p += pbuf_[k][i];
        csum_[i] = c;
        psum_[i] = p;
      }
      const std::uint64_t c6 = prof ? Profiler::ticks() : 0;
      numa::barrier_arrive(&barrier_[2]);
#pragma omp barrier
      numa::barrier_leave(&barrier_[2]);
      const double t3 = omp_get_wtime();
      Times& tm = times_[th];
      tm.zero += t1 - t0;
      tm.compute += t2 - t1;
      tm.gather += t3 - t2;
      if (prof) {
        // The thread-local buffers' zeroing and reduction count as the gather (accelerations).
        prof->add(th, Section::accel, (c1 - c0) + (c6 - c5));
        prof->add(th, Section::chain, c2 - c1);
        prof->add(th, Section::pulley, c4 - c3);
      }
    }
  }

  struct alignas(64) Times {
    double zero = 0, compute = 0, gather = 0;
  };
  const Model& m_;
  Workspace& ws_;
  int threads_, size_;
  std::vector<std::vector<double>> cbuf_, pbuf_;
  std::vector<double> csum_, psum_;
  std::vector<Times> times_;
  char barrier_[3] = {};
};

}  // namespace

std::unique_ptr<Schedule> make_paper_omp_schedule(const Model& m, Workspace& ws, const ScheduleOptions& opt) {
  return std::make_unique<PaperOmpSchedule>(m, ws, opt.threads);
}

}  // namespace cvt

#endif  // CVT_WITH_OPENMP
