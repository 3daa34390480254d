// The text of `cvt-engine topology`: what a run would use and whether pinning is real,
// so that a scaling figure can be traced back to the placement it was measured with.
#pragma once

#include <string>

#include "numa/arenas.hpp"
#include "numa/topology.hpp"

namespace cvt::numa {

// Source of the topology, then per node: OS index, cores, PUs, threads and the pin
// segment [begin, end) of `pins` pins (split by threads with arenas, by cores without;
// left out for pins <= 0), then whether thread and memory binding are in effect and why
// not. `arenas` may be null (nothing built yet: binding is then reported as not checked).
std::string describe(const Topology& topo, const NodeArenas* arenas, int pins);

}  // namespace cvt::numa
