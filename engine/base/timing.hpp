// Wall-clock helpers shared by every layer: elapsed seconds and the median of repeated
// timings (the machine is shared: timings are compared as medians).
#pragma once

#include <algorithm>
#include <chrono>
#include <vector>

namespace cvt {

using WallClock = std::chrono::steady_clock;

// Seconds from t0 to now.
inline double seconds_since(WallClock::time_point t0) {
  return std::chrono::duration<double>(WallClock::now() - t0).count();
}

// The median of v (0 for none).
inline double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

}  // namespace cvt
