// A sweep across MPI ranks (docs/studies.md): rank 0 reads and writes the sweep's files
// and hands the points out one at a time to ranks 1..N-1 as they ask for work, each rank
// running its point with its own threads (the flow graph). Rank 0 computes nothing: it
// waits, asleep between polls, so it can share a node with a worker.
#pragma once

#include "engine/studies/sweep.hpp"

namespace cvt {

// MPI when the process was started by mpirun, mpiexec or srun (and the build has MPI),
// else a world of one. A build without MPI started by a launcher with several ranks
// throws: its ranks would each run the whole sweep.
class MpiWorld {
 public:
  MpiWorld();
  ~MpiWorld();
  MpiWorld(const MpiWorld&) = delete;
  MpiWorld& operator=(const MpiWorld&) = delete;
  int rank() const { return rank_; }
  int size() const { return size_; }

 private:
  int rank_ = 0, size_ = 1;
  bool initialized_ = false;
};

// The sweep over the ranks of world (size > 1); returns, on rank 0, the number of points
// that did not end steady (0 on the others).
long run_sweep_mpi(const SweepOptions& o, const SweepPlan& plan, const MpiWorld& world);

}  // namespace cvt
