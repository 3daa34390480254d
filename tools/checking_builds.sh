#!/usr/bin/env bash
# The checking builds that `make test` runs after the fast suite (docs/testing.md):
#   tools/checking_builds.sh BUILD JOBS KIND...
# KIND is one of
#   asan      AddressSanitizer and UndefinedBehaviorSanitizer over the fast suite's C++ tests
#             (the kernels, the integrators, the runs and the command line);
#   tsan      ThreadSanitizer over the tests that run threads: the schedules (graph), the
#             side jobs, the W-method's two tasks, the sweeps, and the Python module's runs
#             in Python threads (the hand-offs to oneTBB and OpenMP, which are not built with
#             the sanitizer, annotated in numa/hand_off.hpp; docs/testing.md);
#   portable  the -march=x86-64-v2 build (what a machine without AVX2 builds): the
#             determinism tests, the same bits for any thread count and schedule.
# Each is its own CMake build in BUILD/check-KIND that builds only what its tests need; a
# finding of a sanitizer fails its test (halt_on_error), and the script stops at the first
# kind that fails.
set -euo pipefail
build=$1
jobs=$2
shift 2
src=$(cd "$(dirname "$0")/.." && pwd)
supp=$src/tests/sanitizers
python=${PYTHON:-/usr/bin/python3}

# gtest's names are Case.Name; the rest of ctest (Python, install, tools) has no dot.
fast_gtests='^[A-Za-z0-9_]+[.][A-Za-z0-9_/]+$'
not_slow='^Slow|[.]Slow'

export ASAN_OPTIONS="halt_on_error=1:abort_on_error=0:detect_leaks=1:detect_stack_use_after_return=0"
export LSAN_OPTIONS="suppressions=$supp/lsan.supp:print_suppressions=0"
export UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1"
export TSAN_OPTIONS="halt_on_error=1:second_deadlock_stack=1:suppressions=$supp/tsan.supp"

configure_and_build() {  # dir, targets (space-separated), cmake arguments...
  local dir=$1 targets=$2
  shift 2
  cmake -S "$src" -B "$dir" -DCMAKE_BUILD_TYPE=Release -DCVT_BUILD_BENCHMARKS=OFF -DCVT_BUILD_VIEWER=OFF \
    "$@" >"$dir.configure.log" 2>&1 || { cat "$dir.configure.log"; return 1; }
  # shellcheck disable=SC2086
  cmake --build "$dir" -j "$jobs" --target $targets >"$dir.build.log" 2>&1 ||
    { grep -E -B2 -A12 'error|Error' "$dir.build.log" | head -80; return 1; }
}

for kind in "$@"; do
  dir=$build/check-$kind
  mkdir -p "$dir"
  start=$SECONDS
  echo "make test: checking build $kind in $dir"
  case $kind in
    asan)
      configure_and_build "$dir" "cvt_tests" -DCVT_SANITIZE=address,undefined -DCVT_BUILD_PYTHON=OFF \
        "-DCVT_TEST_FOLDERS=modules;engine/rhs;engine/ode;engine/wmethod;engine/io;engine/model;engine/cli;graph;numa"
      # Without the two command-line tests that wait out minutes of model time (a full disk
      # at a late checkpoint, a --max-wall job); their paths are the other tests' paths.
      (cd "$dir" && ctest -R "$fast_gtests" -E "$not_slow|AFullDiskEndsWithExit73|AJobStoppedByMaxWall" -j "$jobs" \
         --output-on-failure --timeout 1800) ;;
    tsan)
      configure_and_build "$dir" "cvt_tests cvt_engine_core" -DCVT_SANITIZE=thread \
        "-DCVT_TEST_FOLDERS=numa;graph;engine/wmethod;engine/studies"
      # Without the five sweep tests that run points for long model times (serial, MPI and
      # killed sweeps, a job array of every point, a sweep stopped by --max-wall, a warm
      # start from a steady state, a map by continuation; under the sanitizer the first
      # alone took 758 s): a sweep starts no thread of its own, and its points' threads are
      # the schedules' of the tests above.
      (cd "$dir" && ctest -R '^(HandOffTest|DeterminismTest|FlowGraphTest|StageTableTest|SideJobTest|TwoTasks|Sweep[A-Za-z]*)[.]' \
         -E "$not_slow|MiniSerialMpiAndKilledGiveTheSameCsv|AJobArrayOfPointsGivesTheSweepsCsv|ASweepStoppedByMaxWallContinuesItsPoint|WarmStartFromASteadyState|ContinuedPointsStartFromTheNearestLoadsSteadyState" \
         -j "$jobs" --output-on-failure --timeout 1800)
      # The module in Debian's Python, which is not built with ThreadSanitizer: the runtime
      # comes first (LD_PRELOAD) so that it sees every thread and lock.
      LD_PRELOAD=$(g++ -print-file-name=libtsan.so) PYTHONPATH=$dir/python CVT_ENGINE_EXE=$dir/cvt-engine \
        MPLBACKEND=Agg "$python" -m pytest -q -p no:cacheprovider -k 'thread' "$src/tests/python" ;;
    portable)
      configure_and_build "$dir" "cvt_tests" -DCVT_MARCH=x86-64-v2 -DCVT_BUILD_PYTHON=OFF -DCVT_TEST_FOLDERS=graph
      (cd "$dir" && ctest -R '^(DeterminismTest|StageTableTest)[.]' -E "$not_slow" -j "$jobs" --output-on-failure \
         --timeout 1800) ;;
    *)
      echo "tools/checking_builds.sh: unknown kind $kind (asan, tsan or portable)" >&2
      exit 2 ;;
  esac
  echo "make test: checking build $kind passed in $((SECONDS - start)) s"
done
