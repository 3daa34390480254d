#include "engine/studies/sweep_mpi.hpp"

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>

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

constexpr int kTagToRoot = 1, kTagToWorker = 2;

void send_text(const std::string& s, int to, int tag) {
  MPI_Send(s.data(), static_cast<int>(s.size()), MPI_CHAR, to, tag, MPI_COMM_WORLD);
}

std::string recv_text(int from, int tag, int* source) {
  MPI_Status st;
  MPI_Probe(from, tag, MPI_COMM_WORLD, &st);
  int n = 0;
  MPI_Get_count(&st, MPI_CHAR, &n);
  std::string s(static_cast<std::size_t>(n), '\0');
  MPI_Recv(s.data(), n, MPI_CHAR, st.MPI_SOURCE, tag, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
  if (source) *source = st.MPI_SOURCE;
  return s;
}

// Rank 0: a message from any worker, sleeping between polls (a blocking receive would
// spin on a core a worker needs).
std::string wait_for_worker(int* source) {
  for (int flag = 0;;) {
    MPI_Iprobe(MPI_ANY_SOURCE, kTagToRoot, MPI_COMM_WORLD, &flag, MPI_STATUS_IGNORE);
    if (flag) return recv_text(MPI_ANY_SOURCE, kTagToRoot, source);
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
}

long coordinate(const SweepOptions& o, const SweepPlan& plan, int workers) {
  const auto log = sweep_log(o);
  SweepLedger ledger(o, plan);
  const long total = static_cast<long>(plan.points.size());
  log_resumed(o, ledger);
  long next = 0;
  for (int active = workers; active > 0;) {
    int from = 0;
    const std::string text = wait_for_worker(&from);
    if (!text.empty()) {
      const SweepRow r = parse_sweep_csv_row(text, plan);
      ledger.add(r);
      log("  " + sweep_point_line(plan, r, total) + "  [rank " + std::to_string(from) + "]");
    }
    while (next < total && ledger.done(next)) ++next;
    const long give = next < total ? next++ : -1;
    MPI_Send(&give, 1, MPI_LONG, from, kTagToWorker, MPI_COMM_WORLD);
    if (give < 0) --active;
  }
  return close_sweep(o, ledger);
}

void work(const SweepOptions& o, const SweepPlan& plan) {
  std::filesystem::create_directories(o.out + ".runs");
  send_text("", 0, kTagToRoot);  // ready
  for (;;) {
    long i = -1;
    MPI_Recv(&i, 1, MPI_LONG, 0, kTagToWorker, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
    if (i < 0) return;
    std::string row = sweep_csv_row(run_sweep_point(o, plan, i));
    row.pop_back();  // the newline
    send_text(row, 0, kTagToRoot);
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
