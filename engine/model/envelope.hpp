// The envelope (docs/envelope.md): the ranges of the operating point over which the
// engine's results are checked, and the warnings for a configuration outside them. A
// configuration outside the envelope is warned about, never refused.
#pragma once

#include <string>
#include <vector>

#include "engine/model/config.hpp"

namespace cvt {

struct Envelope {
  // Geometric ratios R2/R1 at which the pulleys let the chain be placed (docs/model.md 5.1);
  // NaN where it cannot be placed at all (that configuration is refused when built).
  double ratio_min = 0, ratio_max = 0;
  double speed_min = 50, speed_max = 600;  // drive.speed [rad/s]
  double f0_min = 0.05, f0_max = 0.12;     // friction.f0 [1]
  double light_share = 0.1;                // the lightest load checked, as a share of the slip limit [1]
  // The slip limit estimate at the configured ratio: the Coulomb capacity 2 f0 F R2 / cos(beta)
  // of the smaller clamping force F on the driven running radius R2 (docs/studies.md, "study
  // slip"). With the slip-safe controller F is what it sets for the load, at least the
  // smaller configured force.
  double R2 = 0;           // [m]; 0 where the chain cannot be placed
  double clamping = 0;     // F [N]
  double load = 0;         // |load.torque| + load.speed_coefficient x the output speed [N m]
  double slip_limit = 0;   // [N m]
};

// The envelope of a configuration and where its operating point lies in it.
Envelope envelope(const Config& c);

// One line per key outside the envelope: the key, its value, the range and what is not
// checked there. Empty inside the envelope.
std::vector<std::string> envelope_warnings(const Config& c);

}  // namespace cvt
