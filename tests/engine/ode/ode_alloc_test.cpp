// No heap allocation inside the generic integrators' steps (the house rule: nothing is
// allocated inside a step). Counts the calls of malloc, calloc, realloc and aligned
// allocation (glibc's, which the C++ operator new and Eigen's aligned allocator both end
// in) while a solver whose workspace is already built integrates. The replacements below
// serve the whole test binary (tests/alloc_count.hpp); they only count while `counting`
// is set.
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <new>

#include <gtest/gtest.h>

#include "engine/ode/ode.hpp"
#include "tests/alloc_count.hpp"
#include "tests/engine/ode/ode_problems.hpp"

namespace cvt::test {
std::atomic<bool> counting{false};
std::atomic<long> allocations{0};
}  // namespace cvt::test

using cvt::test::allocations;
using cvt::test::counting;

#if CVT_TEST_COUNTS_ALLOCATIONS
extern "C" {
void* __libc_malloc(std::size_t);
void* __libc_calloc(std::size_t, std::size_t);
void* __libc_realloc(void*, std::size_t);
void* __libc_memalign(std::size_t, std::size_t);

namespace {
void count() {
  if (counting.load(std::memory_order_relaxed)) allocations.fetch_add(1, std::memory_order_relaxed);
}
}  // namespace

void* malloc(std::size_t n) {
  count();
  return __libc_malloc(n);
}
void* calloc(std::size_t k, std::size_t n) {
  count();
  return __libc_calloc(k, n);
}
void* realloc(void* p, std::size_t n) {
  count();
  return __libc_realloc(p, n);
}
void* aligned_alloc(std::size_t a, std::size_t n) {
  count();
  return __libc_memalign(a, n);
}
void* memalign(std::size_t a, std::size_t n) {
  count();
  return __libc_memalign(a, n);
}
int posix_memalign(void** p, std::size_t a, std::size_t n) {
  count();
  *p = __libc_memalign(a, n);
  return *p ? 0 : 12;  // ENOMEM
}
}
#endif

namespace cvt {
namespace {

using namespace ode_test;

TEST(OdeAlloc, NoAllocationWhileIntegrating) {
  CVT_SKIP_UNLESS_ALLOCATIONS_COUNTED();
  const Heat heat(50);
  const OdeSystem sys = heat.system();  // no pattern: dense Jacobian and LU
  struct Case {
    OdeMethod m;
    bool fixed;
  };
  for (const Case c : {Case{OdeMethod::Rk4, true}, Case{OdeMethod::Rk4, false}, Case{OdeMethod::Dopri5, false},
                       Case{OdeMethod::Rkc, false}, Case{OdeMethod::Trapezoid, false}, Case{OdeMethod::TrBdf2, false},
                       Case{OdeMethod::Esdirk3, false}, Case{OdeMethod::Ros2, false}, Case{OdeMethod::Ros34pw2, false}}) {
    const OdeMethod m = c.m;
    OdeOptions opt;
    opt.rtol = opt.atol = 1e-6;
    if (c.fixed) opt.fixed_step = true, opt.h0 = 1e-5;
    OdeSolver solver(sys, m, opt);
    Eigen::VectorXd y = heat.exact(0);
    for (int i = 0; i < heat.n; ++i) y[i] += 1e-3 * std::sin(40.0 * i);  // wake the fast modes
    long steps = 0;
    const OdeObserver observer = [&](double, const Eigen::VectorXd&) { ++steps; };
    allocations = 0;
    counting = true;
    solver.integrate(0, 0.01, y, observer);
    counting = false;
    std::printf("[ode] %-10s %s %ld observed steps, %ld heap allocations while integrating\n", to_string(m),
                c.fixed ? "fixed   " : "adaptive", steps, allocations.load());
    EXPECT_EQ(allocations.load(), 0) << to_string(m);
    EXPECT_GT(steps, 1);
  }
}

}  // namespace
}  // namespace cvt
