// Counting of heap allocations (the global operator new) for the tests of the house rule
// "nothing is allocated inside a step". The counting operators are defined once, in
// tests/engine/ode/ode_alloc_test.cpp; they count while `counting` is set.
#pragma once

#include <atomic>

// Under AddressSanitizer or ThreadSanitizer (make test's checking builds, docs/testing.md) the
// sanitizer's allocator owns malloc: the counting replacements are left out there and the
// allocation tests skip, saying why.
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define CVT_TEST_COUNTS_ALLOCATIONS 0
#else
#define CVT_TEST_COUNTS_ALLOCATIONS 1
#endif
#define CVT_SKIP_UNLESS_ALLOCATIONS_COUNTED()                                                   \
  if (!CVT_TEST_COUNTS_ALLOCATIONS)                                                             \
  GTEST_SKIP() << "a sanitizer's allocator replaces malloc here: allocations are not counted"

namespace cvt::test {
extern std::atomic<bool> counting;
extern std::atomic<long> allocations;
}  // namespace cvt::test
