// StepClock (engine/model/state.hpp): the run's time is formed as t0 + (n - n0) h, never
// accumulated, and its origin moves only when the step changes.
#include <gtest/gtest.h>

#include "engine/model/state.hpp"

namespace cvt {
namespace {

TEST(StepClock, TimeIsFormedNotAccumulated) {
  const double h = 1e-5 / 12;  // not a binary fraction: a sum of steps drifts
  StepClock c = StepClock::at(0.0, 0);
  double summed = 0;
  for (long n = 1; n <= 120000; ++n) {
    c.keep_origin(h);
    c.tick(h);
    summed += h;
  }
  EXPECT_EQ(c.steps, 120000);
  EXPECT_EQ(c.t, static_cast<double>(120000) * h);  // the product, rounded once
  EXPECT_NE(summed, c.t);                           // what accumulation would have given
  EXPECT_EQ(c.t0, 0.0);
  EXPECT_EQ(c.steps0, 0);
}

TEST(StepClock, OriginMovesOnlyWhenTheStepChanges) {
  StepClock c = StepClock::at(1e-3, 100);
  c.keep_origin(1e-5);
  for (int k = 0; k < 10; ++k) c.tick(1e-5);
  EXPECT_EQ(c.t0, 1e-3);
  EXPECT_EQ(c.steps0, 100);
  c.keep_origin(1e-5);  // same step: no change
  EXPECT_EQ(c.steps0, 100);
  c.keep_origin(2e-5);  // a new step: the origin is now, so no time jump
  EXPECT_EQ(c.steps0, 110);
  EXPECT_EQ(c.t0, c.t);
  const double before = c.t;
  c.tick(2e-5);
  EXPECT_EQ(c.t, before + 2e-5);
  EXPECT_EQ(c.time_after(c.steps + 1, 2e-5), before + 2 * 2e-5);
}

}  // namespace
}  // namespace cvt
