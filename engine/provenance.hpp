// Where a result came from (docs/output.md, "/parameters/provenance"): the engine's version
// and commit, whether its tree was clean, the compiler, its flags and the instruction set it
// built for (a run's bits depend on it), the host and its topology, and who ran it. Every
// HDF5 file the engine writes records it.
#pragma once

#include <string>

#include "engine/io/h5_writer.hpp"

namespace cvt {

struct Provenance {
  std::string version;          // CVT_VERSION
  std::string commit;           // 12 hex digits, "-dirty" when tracked files differed; "unknown"
  bool tree_clean = false;      // no "-dirty"
  std::string compiler;         // "GNU 12.2.0"
  std::string flags;            // the C++ flags of the build
  std::string instruction_set;  // -march: x86-64-v3 or x86-64-v2
  std::string host;             // gethostname()
  std::string topology;         // "1 package, 1 NUMA node, 2 cores, 2 PUs"
  std::string user;             // the login name ("unknown" without one)
};

// This process's provenance (the host's topology discovered once).
const Provenance& provenance();

// The provenance as attributes of `group` (created if missing), and the /h5md group of
// H5MD 1.1 (version, author, creator; the units module): what every output file carries.
void write_provenance(H5File& f, const std::string& group = "/parameters/provenance");

}  // namespace cvt
