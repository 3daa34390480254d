// The published OpenMP scheme (paper 2, section 3), reproduced as the baseline to beat:
// one parallel region per RHS in which every thread zeroes its thread-local force
// buffers, runs static loops over the pins for chain forces and pulley contact adding
// into its buffers, and then gathers a slice of the buffers into the common vectors;
// everything else (other forces, inertia, the solve) runs serially. Each coordinate gets
// at most two contributions per module, so the buffer sums equal the ordered gather to
// the bit (engine/rhs/rhs.hpp) and the trajectory is that of the serial schedule.
#include <omp.h>

#include <vector>

#include "graph/schedule.hpp"
#include "modules/chain_forces.hpp"
#include "modules/inertia.hpp"
#include "modules/other_forces.hpp"
#include "modules/pulley_contact.hpp"

namespace cvt {

namespace {

class PaperOmpSchedule final : public Schedule {
 public:
  PaperOmpSchedule(const Model& m, Workspace& ws, int threads)
      : m_(m), ws_(ws), threads_(threads), size_((kJointSize + 1) * m.links),
        cbuf_(threads, std::vector<double>(size_)), pbuf_(threads, std::vector<double>(size_)),
        csum_(size_), psum_(size_), times_(threads) {}

  void rhs(double t, const double* y, double* dy, const StageOp* op, const FrictionExtras& x) override {
    const Model& m = m_;
    Workspace& ws = ws_;
    set_stage_input(m, ws, t, y);
    const int N = m.links;
    Profiler* prof = prof_;
    if (prof) prof->call_rhs(op != nullptr);
    {
      ScopedTimer tm(prof, 0, Section::inertia);
      link_kinematics(m, ws, 0, N);
    }
#pragma omp parallel num_threads(threads_)
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
        chain_forces(m, ws, j, j + 1, x);
        scatter_slot(m, ws.chain_slots[j], j, cb);
      }
      const std::uint64_t c2 = prof ? Profiler::ticks() : 0;
#pragma omp barrier
      const std::uint64_t c3 = prof ? Profiler::ticks() : 0;
#pragma omp for schedule(static) nowait
      for (int j = 0; j < N; ++j) {
        pulley_contact(m, ws, j, j + 1, x);
        scatter_slot(m, ws.pulley_slots[j], j, pb);
      }
      const std::uint64_t c4 = prof ? Profiler::ticks() : 0;
#pragma omp barrier
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
#pragma omp barrier
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
    {
      ScopedTimer tm(prof, 0, Section::other);
      other_forces(m, ws);
    }
    {
      ScopedTimer tm(prof, 0, Section::inertia);
      inertia_decomposition(m, ws, 0, N);
    }
    {
      ScopedTimer tm(prof, 0, Section::accel);
      gather_joints_from_sums(m, ws, csum_.data(), psum_.data(), 0, N);
      gather_shafts(m, ws);
    }
    finish_stage(m, ws, dy, op, prof);
  }

  // The published code updated its contact events serially.
  void update_status(double t, const double* y) override { update_contact_status(m_, ws_, t, y, prof_); }

  std::string describe() const override {
    return "paper-omp (" + std::to_string(threads_) + " OpenMP threads, static loops, thread-local buffers)";
  }
  std::string graphviz() const override {
    return "digraph stage {\n  rankdir=LR;\n  start -> link_kinematics -> omp_parallel;\n"
           "  subgraph cluster_omp { label=\"omp parallel\"; zero_buffers -> chain_forces -> pulley_contact -> "
           "gather_buffers; }\n  omp_parallel -> zero_buffers; gather_buffers -> other_forces -> "
           "inertia_decomposition -> gather -> accelerations -> stage_update;\n}\n";
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
  struct alignas(64) Times {
    double zero = 0, compute = 0, gather = 0;
  };
  const Model& m_;
  Workspace& ws_;
  int threads_, size_;
  std::vector<std::vector<double>> cbuf_, pbuf_;
  std::vector<double> csum_, psum_;
  std::vector<Times> times_;
};

}  // namespace

std::unique_ptr<Schedule> make_paper_omp_schedule(const Model& m, Workspace& ws, const ScheduleOptions& opt) {
  return std::make_unique<PaperOmpSchedule>(m, ws, opt.threads);
}

}  // namespace cvt
