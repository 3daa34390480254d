// Scaling study (the published papers: 1 Fig. 9, 2 Figs. 8-11): whole RK4 steps of a
// model under each scheduler, thread count and NUMA layout, timed in interleaved repeats
// from the same running state; speedups against the serial schedule, per-module speedups,
// the thread-local buffers' zeroing and gathering against compute, and the Amdahl serial
// fraction fitted to each curve.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "engine/model/model.hpp"
#include "graph/schedule.hpp"

namespace cvt {

struct ScaleOptions {
  std::vector<int> threads = {1, 2};
  std::vector<SchedulerKind> schedulers = {SchedulerKind::serial, SchedulerKind::flowgraph, SchedulerKind::paper_omp};
  // "native" (the machine's topology) or an hwloc synthetic description such as
  // "package:2 numa:1 core:1 pu:1" (flowgraph only: the others ignore the layout).
  std::vector<std::string> layouts = {"native"};
  long steps = 200;    // per repeat
  int repeat = 5;      // medians over the repeats
  double warmup = 3e-4;  // model time run serially first, so that the contacts are established [s]
  int grain = 4;
};

struct ScaleRow {
  std::string scheduler, layout;
  int threads = 1;
  long steps = 0;
  int repeat = 0;
  double us_per_step = 0, speedup = 0, efficiency = 0;
  // Per-module time per step: the largest busy time over the threads (the module's share
  // of the critical path when its pins are spread over them).
  double chain_us = 0, chain_speedup = 0, pulley_us = 0, pulley_speedup = 0;
  // Per thread and step: zeroing + gathering of thread-local buffers (paper-omp; 0 for the
  // others, which have none) and the module compute they serve (chain forces + pulley).
  double zero_gather_us = 0, compute_us = 0;
  double amdahl_serial_fraction = 0;  // fitted per (scheduler, layout)
  bool identical = true;  // ended in the same bits as the serial baseline
};

// Runs the study; `progress` (if given) is told each measured combination.
std::vector<ScaleRow> run_scaling_study(const Model& m, const ScaleOptions& o,
                                        const std::function<void(const std::string&)>& progress = {});

// Least-squares fit of S(p) = 1 / (f + (1 - f) / p) in 1/S, which is linear in f.
double fit_amdahl(const std::vector<int>& threads, const std::vector<double>& speedup);

std::string scale_csv(const std::vector<ScaleRow>& rows);
std::string scale_json(const std::vector<ScaleRow>& rows, const std::string& config);
std::string scale_table(const std::vector<ScaleRow>& rows);

}  // namespace cvt
