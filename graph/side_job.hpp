// One piece of work at a time that a schedule's other threads may take while the caller goes
// on: a sample's file writes (engine/run.cpp), which would otherwise keep the second thread
// idle between two steps. Whichever thread claims the job first runs it; the caller, when it
// needs the work done before a worker took it, runs it itself, so waiting never depends on
// a worker turning up. On a schedule that takes no side work (serial, one thread, several
// NUMA arenas) start() runs the job at once.
#pragma once

#include <atomic>
#include <exception>
#include <functional>
#include <thread>
#include <utility>

#include "graph/schedule.hpp"

namespace cvt {

class SideJob {
 public:
  explicit SideJob(Schedule& s) : s_(s), st_(new State) {}
  SideJob(const SideJob&) = delete;
  SideJob& operator=(const SideJob&) = delete;
  // Waits for the job (its error, if any, is dropped: a destructor cannot report it; call
  // wait() first where it matters). A task the schedule still holds keeps the shared state.
  ~SideJob() {
    try {
      wait();
    } catch (...) {
    }
    st_->release();
  }

  // Starts f once the job before it has ended (that job's error is thrown here). f must not
  // be started again before wait().
  void start(std::function<void()> f) {
    wait();
    st_->job = std::move(f);
    st_->phase.store(kReady, std::memory_order_release);
    State* st = st_;
    st->refs.fetch_add(1, std::memory_order_relaxed);
    bool taken = false;
    try {
      taken = s_.enqueue(
          [](void* ctx) {
            State* st = static_cast<State*>(ctx);
            st->claim_and_run(), st->release();
          },
          st);
    } catch (...) {
      st->release();  // nothing was enqueued; the job stays ready for wait()
      throw;
    }
    if (!taken) {
      st->release();
      st->claim_and_run();
    }
  }

  // Returns once no job is pending or running; runs a job no thread has claimed yet, and
  // throws the error of the job that ended.
  void wait() {
    State& st = *st_;
    if (!st.claim_and_run())
      while (st.phase.load(std::memory_order_acquire) == kRunning) std::this_thread::yield();
    if (st.phase.load(std::memory_order_acquire) == kDone) {
      st.phase.store(kIdle, std::memory_order_relaxed);
      if (std::exception_ptr e = std::exchange(st.error, nullptr)) std::rethrow_exception(e);
    }
  }

  // True while a started job has not been waited for.
  bool pending() const { return st_->phase.load(std::memory_order_acquire) != kIdle; }

 private:
  enum : int { kIdle, kReady, kRunning, kDone };
  struct State {
    std::atomic<int> phase{kIdle};
    std::atomic<int> refs{1};  // the SideJob's, and one per task the schedule holds
    std::function<void()> job;
    std::exception_ptr error;
    // Runs the job if it is ready and no one else took it; true if this call ran it.
    bool claim_and_run() {
      int ready = kReady;
      if (!phase.compare_exchange_strong(ready, kRunning, std::memory_order_acq_rel)) return false;
      try {
        job();
      } catch (...) {
        error = std::current_exception();
      }
      job = nullptr;  // what the job holds goes here, not on whichever thread frees the state
      phase.store(kDone, std::memory_order_release);
      return true;
    }
    void release() {
      if (refs.fetch_sub(1, std::memory_order_acq_rel) == 1) delete this;
    }
  };
  Schedule& s_;
  State* st_;
};

}  // namespace cvt
