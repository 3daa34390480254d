#include "engine/studies/sweep_mpi.hpp"

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>

#include "engine/run.hpp"

#ifdef CVT_WITH_MPI
#define OMPI_SKIP_MPICXX 1  // the C interface only
#define MPICH_SKIP_MPICXX 1
#include <mpi.h>
#endif

namespace cvt {

namespace {

// The number of ranks a launcher announces in the environment (0: not launched by one).
int launched_ranks() {
  for (const char* v : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_SIZE", "SLURM_NTASKS", "MPI_LOCALNRANKS"})
    if (const char* s = std::getenv(v)) return std::atoi(s);
  return 0;
}

}  // namespace

#ifdef CVT_WITH_MPI

namespace {

// To rank 0: a worker's row (or "" when it is ready), or that its point was stopped (by
// run.max_wall or a signal); to a worker: the next point, or -1.
constexpr int kTagToRoot = 1, kTagToWorker = 2, kTagStopped = 3;

void send_text(const std::string& s, int to, int tag) {
  MPI_Send(s.data(), static_cast<int>(s.size()), MPI_CHAR, to, tag, MPI_COMM_WORLD);
}

std::string recv_text(const MPI_Status& st) {
  int n = 0;
  MPI_Get_count(&st, MPI_CHAR, &n);
  std::string s(static_cast<std::size_t>(n), '\0');
  MPI_Recv(s.data(), n, MPI_CHAR, st.MPI_SOURCE, st.MPI_TAG, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
  return s;
}

// Rank 0: a message from any worker (its rank and tag in *st), sleeping between polls (a
// blocking receive would spin on a core a worker needs).
std::string wait_for_worker(MPI_Status* st) {
  for (int flag = 0;;) {
    MPI_Iprobe(MPI_ANY_SOURCE, MPI_ANY_TAG, MPI_COMM_WORLD, &flag, st);
    if (flag) return recv_text(*st);
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
}

long coordinate(const SweepOptions& o, const SweepPlan& plan, int workers) {
  const auto log = sweep_log(o);
  SweepLedger ledger(o, plan);
  const long total = static_cast<long>(plan.points.size());
  log_resumed(o, ledger);
  // Handed out, and the points' order (with continuation, every point after its parent,
  // and handed out only once its parent's row is in: waiting workers idle until then).
  std::vector<bool> given(static_cast<std::size_t>(total), false);
  std::vector<int> idle;
  constexpr long kWait = -2;
  const auto next_point = [&]() -> long {
    bool pending = false;
    for (long k = 0; k < total; ++k) {
      const long i = plan.at(k);
      if (ledger.done(i) || given[static_cast<std::size_t>(i)]) continue;
      const long p = plan.parent(i);
      if (p < 0 || ledger.done(p)) return i;
      pending = true;
    }
    return pending ? kWait : -1;
  };
  // Once a worker's point was stopped (run.max_wall, a signal), or rank 0 caught a signal,
  // no point is handed out: the workers end the points they hold (on a job's limit or
  // signal they stop them too) and the sweep stops like a serial one, its finished points
  // in OUT.csv and each stopped point's checkpoint kept for the same command to continue.
  std::optional<SweepInterrupted> stopped;
  for (int active = workers; active > 0;) {
    MPI_Status st;
    const std::string text = wait_for_worker(&st);
    const int from = st.MPI_SOURCE;
    const std::string rank = "  [rank " + std::to_string(from) + "]";
    if (st.MPI_TAG == kTagStopped) {
      log("  " + text.substr(1) + rank);
      if (!stopped) stopped.emplace(text.substr(1), text[0] == 'w');
    } else if (!text.empty()) {
      const SweepRow r = parse_sweep_csv_row(text, plan);
      ledger.add(r);
      log("  " + sweep_point_line(plan, r, total) + rank);
    }
    if (!stopped && StopSignals::pending())
      stopped.emplace("rank 0 stopped by signal " + std::to_string(StopSignals::pending()));
    idle.push_back(from);
    while (!idle.empty()) {
      const long give = stopped ? -1 : next_point();
      if (give == kWait) break;  // until a running parent's row comes in
      if (give >= 0) given[static_cast<std::size_t>(give)] = true;
      MPI_Send(&give, 1, MPI_LONG, idle.back(), kTagToWorker, MPI_COMM_WORLD);
      idle.pop_back();
      if (give < 0) --active;
    }
  }
  if (stopped) throw *stopped;
  return close_sweep(o, ledger);
}

void work(const SweepOptions& o, const SweepPlan& plan) {
  std::filesystem::create_directories(o.out + ".runs");
  send_text("", 0, kTagToRoot);  // ready
  for (;;) {
    long i = -1;
    MPI_Recv(&i, 1, MPI_LONG, 0, kTagToWorker, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
    if (i < 0) return;
    try {
      std::string row = sweep_csv_row(run_sweep_point(o, plan, i));
      row.pop_back();  // the newline
      send_text(row, 0, kTagToRoot);
    } catch (const SweepInterrupted& e) {
      std::string stop = e.wall_limit ? "w" : "s";  // (+=: GCC 12 warns falsely, -Wrestrict, on "w" + s)
      stop += e.what();
      send_text(stop, 0, kTagStopped);
    }
  }
}

}  // namespace

MpiWorld::MpiWorld() {
  if (launched_ranks() == 0) return;
  int provided = 0;
  MPI_Init_thread(nullptr, nullptr, MPI_THREAD_FUNNELED, &provided);
  initialized_ = true;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank_);
  MPI_Comm_size(MPI_COMM_WORLD, &size_);
}

MpiWorld::~MpiWorld() {
  if (initialized_) MPI_Finalize();
}

long run_sweep_mpi(const SweepOptions& o, const SweepPlan& plan, const MpiWorld& world) {
  try {
    if (world.rank() == 0) return coordinate(o, plan, world.size() - 1);
    work(o, plan);
    return 0;
  } catch (const SweepInterrupted&) {
    throw;  // rank 0, once every worker has stopped
  } catch (const std::exception& e) {
    std::fprintf(stderr, "cvt-engine: rank %d: %s\n", world.rank(), e.what());
    MPI_Abort(MPI_COMM_WORLD, 1);
    return 0;
  }
}

#else

MpiWorld::MpiWorld() {
  if (launched_ranks() > 1)
    throw std::runtime_error("started with " + std::to_string(launched_ranks()) +
                             " MPI ranks, but this cvt-engine was built without MPI (install libopenmpi-dev and "
                             "build again: make build)");
}

MpiWorld::~MpiWorld() = default;

long run_sweep_mpi(const SweepOptions&, const SweepPlan&, const MpiWorld&) {
  throw std::runtime_error("this cvt-engine was built without MPI");
}

#endif

}  // namespace cvt
