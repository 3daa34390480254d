// Counting of heap allocations (the global operator new) for the tests of the house rule
// "nothing is allocated inside a step". The counting operators are defined once, in
// tests/engine/ode/ode_alloc_test.cpp; they count while `counting` is set.
#pragma once

#include <atomic>

namespace cvt::test {
extern std::atomic<bool> counting;
extern std::atomic<long> allocations;
}  // namespace cvt::test
