// The stage DAG of one evaluation of f, declared once: its stages, the kernel each runs,
// how it is split and the stages it reads. Every schedule (graph/) derives its order or
// its graph from this table: the serial schedule runs it top to bottom, the flow graph
// builds one continue_node per stage and one edge per dependency, the published OpenMP
// scheme runs it top to bottom with its own parallel region for chain and pulley forces.
//
//   link_kinematics -> {chain_forces, pulley_contact, inertia_decomposition, other_forces}
//                   -> {gather, gather_shafts} -> accelerations (+ the stage update)
#pragma once

#include <cstdint>

#include "engine/rhs/rhs.hpp"
#include "modules/chain_forces.hpp"
#include "modules/inertia.hpp"
#include "modules/other_forces.hpp"
#include "modules/pulley_contact.hpp"

namespace cvt {

enum class StageId : std::uint8_t {
  link_kinematics,
  chain_forces,
  pulley_contact,
  inertia_decomposition,
  other_forces,
  gather,
  gather_shafts,
  accelerations,
  count
};
inline constexpr int kStageCount = static_cast<int>(StageId::count);
constexpr int stage_index(StageId s) { return static_cast<int>(s); }

// A set of stages, bit index(s) for stage s.
using StageSet = std::uint32_t;
template <class... S>
constexpr StageSet stage_set(S... s) {
  return (StageSet{0} | ... | (StageSet{1} << stage_index(s)));
}
constexpr bool contains(StageSet set, StageId s) { return (set >> stage_index(s)) & 1u; }

// How a stage is split over threads.
enum class Split : std::uint8_t {
  fine,    // per pin, in parts of the configured grain (the expensive chain kernel)
  coarse,  // per pin, in a few parts per thread (a task costs a fraction of a microsecond)
  once,    // one call: the shafts, the load, sums over all pins in pin order
};

// What the kernels of one evaluation are given.
struct StageArgs {
  const Model& m;
  Workspace& ws;
  double* dy = nullptr;            // accelerations: f(t, y)
  const StageOp* op = nullptr;     // accelerations: the stage update, if any
  FrictionExtras x{};              // chain and pulley forces: what the friction is asked for
};

using PinKernel = void (*)(const StageArgs&, int begin, int end);
using OnceKernel = void (*)(const StageArgs&);

struct StageDecl {
  StageId id;
  const char* name;
  Split split;
  Section section;      // the profile row it is timed in
  StageSet after;       // the stages whose results it reads
  StageSet neighbours;  // of those, the ones whose results it reads at other pins than its own
  PinKernel pins;       // joints (links) [begin, end); null for a once stage
  OnceKernel once;      // the one call; for a per-pin stage its part off the pins (after them)
  // The stage update fused into the stage when the evaluation has one (elementwise, so
  // per range right after the range's own kernel), timed as Section::update.
  PinKernel update_pins = nullptr;
  OnceKernel update_once = nullptr;
};

namespace stage_table {
using enum StageId;
inline constexpr StageDecl kStages[] = {
    {.id = link_kinematics, .name = "link_kinematics", .split = Split::coarse, .section = Section::inertia,
     .after = 0, .neighbours = 0,
     .pins = [](const StageArgs& a, int b, int e) { cvt::link_kinematics(a.m, a.ws, b, e); }, .once = nullptr},
    // Joint j reads links j-1 and j.
    {.id = chain_forces, .name = "chain_forces", .split = Split::fine, .section = Section::chain,
     .after = stage_set(link_kinematics), .neighbours = stage_set(link_kinematics),
     .pins = [](const StageArgs& a, int b, int e) { cvt::chain_forces(a.m, a.ws, b, e, a.x); }, .once = nullptr},
    {.id = pulley_contact, .name = "pulley_contact", .split = Split::coarse, .section = Section::pulley,
     .after = stage_set(link_kinematics), .neighbours = stage_set(link_kinematics),
     .pins = [](const StageArgs& a, int b, int e) { cvt::pulley_contact(a.m, a.ws, b, e, a.x); }, .once = nullptr},
    {.id = inertia_decomposition, .name = "inertia_decomposition", .split = Split::coarse,
     .section = Section::inertia, .after = stage_set(link_kinematics), .neighbours = stage_set(link_kinematics),
     .pins = [](const StageArgs& a, int b, int e) { cvt::inertia_decomposition(a.m, a.ws, b, e); },
     .once = nullptr},
    {.id = other_forces, .name = "other_forces", .split = Split::once, .section = Section::other,
     .after = stage_set(link_kinematics), .neighbours = 0, .pins = nullptr,
     .once = [](const StageArgs& a) { cvt::other_forces(a.m, a.ws); }},
    // Joint j's forces come from the slots of joints j-1 and j (docs/runtime.md).
    {.id = gather, .name = "gather", .split = Split::coarse, .section = Section::accel,
     .after = stage_set(chain_forces, pulley_contact, inertia_decomposition, other_forces),
     .neighbours = stage_set(chain_forces, pulley_contact, inertia_decomposition),
     .pins = [](const StageArgs& a, int b, int e) { gather_joints(a.m, a.ws, b, e); }, .once = nullptr},
    {.id = gather_shafts, .name = "gather_shafts", .split = Split::once, .section = Section::accel,
     .after = stage_set(chain_forces, pulley_contact, inertia_decomposition, other_forces), .neighbours = 0,
     .pins = nullptr, .once = [](const StageArgs& a) { cvt::gather_shafts(a.m, a.ws); }},
    // The Woodbury correction of joint j reads A0^-1 F of its neighbours (docs/model.md 3.2).
    {.id = accelerations, .name = "accelerations", .split = Split::coarse, .section = Section::accel,
     .after = stage_set(gather, gather_shafts), .neighbours = stage_set(gather),
     .pins = [](const StageArgs& a, int b, int e) { finish_joints(a.m, a.ws, a.dy, nullptr, b, e); },
     .once = [](const StageArgs& a) { finish_shafts(a.m, a.ws, a.dy, nullptr); },
     .update_pins = [](const StageArgs& a, int b, int e) { stage_update_joints(a.m, a.op, a.dy, b, e); },
     .update_once = [](const StageArgs& a) { stage_update_shafts(a.m, a.op, a.dy); }},
};
}  // namespace stage_table
using stage_table::kStages;

constexpr const StageDecl& stage(StageId s) { return kStages[stage_index(s)]; }

// The table is complete, in StageId order, and in an order the edges allow (every stage
// after the ones it reads), so that running it top to bottom is a valid schedule.
constexpr bool stage_table_is_ordered() {
  if (sizeof(kStages) / sizeof(kStages[0]) != static_cast<std::size_t>(kStageCount)) return false;
  for (int i = 0; i < kStageCount; ++i) {
    const StageDecl& s = kStages[i];
    if (stage_index(s.id) != i || (s.after >> i) != 0 || (s.neighbours & ~s.after) != 0) return false;
  }
  return true;
}
static_assert(stage_table_is_ordered());

// Every stage has the kernels its split needs: per pin range, or once.
constexpr bool stage_table_has_its_kernels() {
  for (const StageDecl& s : kStages)
    if ((s.pins == nullptr) != (s.split == Split::once) || (s.split == Split::once && !s.once)) return false;
  return true;
}
// GCC cannot fold a function's address compared with null under -fsanitize=null (the
// sanitizer build, CVT_SANITIZE): there StageTableTest checks this when the tests run.
#ifndef CVT_SANITIZE_NULL
static_assert(stage_table_has_its_kernels());
#endif

inline constexpr StageSet kAllStages = (StageSet{1} << kStageCount) - 1;

// The stages that the joints' generalized forces of the chain and the pulleys need
// (ws.force and ws.accel_free of every joint): the W-method's stiffness differences.
// gather also reads inertia_decomposition, which this set leaves as the last evaluation
// wrote it (its velocity terms are a constant that the differences cancel).
inline constexpr StageSet kChainForceStages =
    stage_set(StageId::link_kinematics, StageId::chain_forces, StageId::pulley_contact, StageId::gather);

// One stage over joints [begin, end) (its per-pin kernel and, with the evaluation's stage
// update, that update), timed into prof as `worker`.
inline void run_stage_pins(const StageDecl& s, const StageArgs& a, Profiler* prof, int worker, int begin, int end) {
  {
    ScopedTimer tm(prof, worker, s.section);
    s.pins(a, begin, end);
  }
  if (s.update_pins && a.op) {
    ScopedTimer tm(prof, worker, Section::update);
    s.update_pins(a, begin, end);
  }
}
// Its part off the pins (the whole of a once stage).
inline void run_stage_once(const StageDecl& s, const StageArgs& a, Profiler* prof, int worker) {
  if (!s.once) return;
  {
    ScopedTimer tm(prof, worker, s.section);
    s.once(a);
  }
  if (s.update_once && a.op) {
    ScopedTimer tm(prof, worker, Section::update);
    s.update_once(a);
  }
}
// The whole stage on the calling thread: all pins, then the part off the pins.
inline void run_stage(const StageDecl& s, const StageArgs& a, Profiler* prof, int worker) {
  if (s.pins) run_stage_pins(s, a, prof, worker, 0, a.m.links);
  run_stage_once(s, a, prof, worker);
}

// The stages of `set`, untimed, level by level: a level is the stages of the set whose
// dependencies within the set have run. The per-pin kernels of a level run together through
// one ranges(f) (ranges calls f(begin, end) over a split of [0, m.links), on any threads,
// and returns when all are done): no stage reads another of its level. Then the level's
// parts off the pins run on the calling thread. What a stage reads from a stage outside
// the set is what the last evaluation left there.
template <class Ranges>
void run_stages(StageSet set, const StageArgs& a, const Ranges& ranges) {
  StageSet left = set & kAllStages;
  while (left) {
    StageSet level = 0;
    bool pins = false;
    for (const StageDecl& s : kStages)
      if (contains(left, s.id) && (s.after & left) == 0) level |= stage_set(s.id), pins |= s.pins != nullptr;
    if (pins)
      ranges([&](int b, int e) {
        for (const StageDecl& s : kStages)
          if (contains(level, s.id) && s.pins) run_stage_pins(s, a, nullptr, 0, b, e);
      });
    for (const StageDecl& s : kStages)
      if (contains(level, s.id)) run_stage_once(s, a, nullptr, 0);
    left &= ~level;
  }
}

}  // namespace cvt
