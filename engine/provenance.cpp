#include "engine/provenance.hpp"

#include <hwloc.h>
#include <pwd.h>
#include <unistd.h>

#include <algorithm>
#include <string>

#include "engine/base/commit.h"  // generated into the build folder at every build (tools/commit_header.cmake)

#ifndef CVT_BUILD_FLAGS
#define CVT_BUILD_FLAGS "unknown"
#endif
#ifndef CVT_BUILD_MARCH
#define CVT_BUILD_MARCH "unknown"
#endif
#ifndef CVT_BUILD_COMPILER
#define CVT_BUILD_COMPILER "unknown"
#endif

namespace cvt {

namespace {

std::string plural(int n, const char* what) {
  return std::to_string(n) + " " + what + (n == 1 ? "" : "s");
}

// The machine as hwloc sees it (the whole machine, not this process's binding).
std::string topology_line() {
  hwloc_topology_t t = nullptr;
  if (hwloc_topology_init(&t) != 0) return "unknown";
  std::string line = "unknown";
  if (hwloc_topology_load(t) == 0) {
    const auto count = [&](hwloc_obj_type_t type) { return std::max(1, hwloc_get_nbobjs_by_type(t, type)); };
    line = plural(count(HWLOC_OBJ_PACKAGE), "package") + ", " + plural(count(HWLOC_OBJ_NUMANODE), "NUMA node") +
           ", " + plural(count(HWLOC_OBJ_CORE), "core") + ", " + plural(count(HWLOC_OBJ_PU), "PU");
  }
  hwloc_topology_destroy(t);
  return line;
}

}  // namespace

const Provenance& provenance() {
  static const Provenance p = [] {
    Provenance q;
    q.version = CVT_VERSION;
    q.commit = CVT_COMMIT;
    q.tree_clean = q.commit != "unknown" && q.commit.find("-dirty") == std::string::npos;
    q.compiler = CVT_BUILD_COMPILER;
    q.flags = CVT_BUILD_FLAGS;
    q.instruction_set = CVT_BUILD_MARCH;
    char host[256] = {};
    q.host = gethostname(host, sizeof host - 1) == 0 ? host : "unknown";
    q.topology = topology_line();
    const passwd* pw = getpwuid(getuid());
    q.user = pw && pw->pw_name ? pw->pw_name : "unknown";
    return q;
  }();
  return p;
}

void write_provenance(H5File& f, const std::string& group) {
  const Provenance& p = provenance();
  f.set_string_attribute(group, "version", p.version);
  f.set_string_attribute(group, "commit", p.commit);
  f.set_int_attribute(group, "tree_clean", p.tree_clean ? 1 : 0);
  f.set_string_attribute(group, "compiler", p.compiler);
  f.set_string_attribute(group, "flags", p.flags);
  f.set_string_attribute(group, "instruction_set", p.instruction_set);
  f.set_string_attribute(group, "host", p.host);
  f.set_string_attribute(group, "topology", p.topology);
  // H5MD 1.1: the format's version, the author (who ran it) and the creator (the program).
  f.set_ints_attribute("/h5md", "version", {1, 1});
  f.set_string_attribute("/h5md/author", "name", p.user);
  f.set_string_attribute("/h5md/creator", "name", "cvt-engine");
  f.set_string_attribute("/h5md/creator", "version", p.version + " (commit " + p.commit + ")");
  // The units module: every `unit` attribute is an SI unit string.
  f.set_ints_attribute("/h5md/modules/units", "version", {1, 0});
  f.set_string_attribute("/h5md/modules/units", "system", "SI");
}

}  // namespace cvt
