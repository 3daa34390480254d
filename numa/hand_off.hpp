// What ThreadSanitizer cannot see by itself (docs/testing.md): how work reaches oneTBB's
// workers and OpenMP's threads, and how the caller learns that it is done. Neither library
// is built with the sanitizer here, so the hand-off inside it is invisible, and every read
// of what the spawning thread wrote would be reported as a race. The places that hand work
// over say so with these annotations; outside a ThreadSanitizer build they are empty and
// the code is the same.
//
// A fork-join: the caller releases before it forks, each task acquires when it starts and
// releases when it ends, and the caller acquires once it has joined. Tasks of one fork are
// not ordered with each other, so a race between two of them is still reported.
#pragma once

#include <type_traits>
#include <utility>

#if defined(__SANITIZE_THREAD__)
extern "C" {
void __tsan_acquire(void* addr);
void __tsan_release(void* addr);
}
#endif

namespace cvt::numa {

#if defined(__SANITIZE_THREAD__)
inline constexpr bool kThreadSanitizer = true;
inline void tsan_release(const void* sync) { __tsan_release(const_cast<void*>(sync)); }
inline void tsan_acquire(const void* sync) { __tsan_acquire(const_cast<void*>(sync)); }
#else
inline constexpr bool kThreadSanitizer = false;
inline void tsan_release(const void*) {}
inline void tsan_acquire(const void*) {}
#endif

// The two addresses of a fork-join. A task reaches its thread through the library's own
// copy of it, which the sanitizer cannot order either: the wrappers here read their
// captures (two pointers) before they acquire, and tests/sanitizers/tsan.supp leaves out
// races whose innermost frame is in this file, which are those reads alone. What a wrapped
// body reads is then ordered.
class ForkJoin {
 public:
  void fork() const { tsan_release(&fork_); }
  void joined() const { tsan_acquire(&join_); }

  // One task's part, from its start to its end (for a body that cannot be wrapped).
  class Member {
   public:
    explicit Member(const ForkJoin& fj) : fj_(fj) { tsan_acquire(&fj_.fork_); }
    ~Member() { tsan_release(&fj_.join_); }
    Member(const Member&) = delete;
    Member& operator=(const Member&) = delete;

   private:
    const ForkJoin& fj_;
  };

  // f as a task of this fork: the same call, between the task's acquire and release. A
  // named f is held by reference (built before the fork, it is ordered by it); a temporary
  // is held by value (a flow graph's node, built once).
  template <class F>
  auto task(F&& f) const {
    if constexpr (std::is_lvalue_reference_v<F>) {
      return [this, p = &f](auto&&... a) -> decltype(auto) {
        const Member m(*this);
        return (*p)(std::forward<decltype(a)>(a)...);
      };
    } else {
      return [this, f = std::move(f)](auto&&... a) -> decltype(auto) {
        const Member m(*this);
        return f(std::forward<decltype(a)>(a)...);
      };
    }
  }

 private:
  char fork_ = 0, join_ = 0;
};

// A fork-join over one scope: forks where it is made, joins where it ends.
class ScopedForkJoin : public ForkJoin {
 public:
  ScopedForkJoin() { fork(); }
  ~ScopedForkJoin() { joined(); }
  ScopedForkJoin(const ScopedForkJoin&) = delete;
  ScopedForkJoin& operator=(const ScopedForkJoin&) = delete;
};

// A task that nobody joins (an arena's enqueue): job(ctx), ordered after what the caller
// did before.
inline auto enqueued(void (*job)(void*), void* ctx) {
  tsan_release(ctx);
  return [job, ctx] {
    tsan_acquire(ctx);
    job(ctx);
  };
}

// An OpenMP barrier, which libgomp keeps by futex (not seen by the sanitizer): an address
// that every thread of the region releases when it arrives and acquires when it leaves.
inline void barrier_arrive(const void* sync) { tsan_release(sync); }
inline void barrier_leave(const void* sync) { tsan_acquire(sync); }

}  // namespace cvt::numa
