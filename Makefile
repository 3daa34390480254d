MAKEFLAGS += --no-print-directory

# The two README commands: `make run` and `make test`. Both install what is missing
# (Debian packages), configure a Release build and build it first.
BUILD   ?= build
JOBS    ?= $(shell nproc)
CONFIG  ?= configs/reference-steady.toml
OUT     ?= results.h5
PYTHON  ?= /usr/bin/python3

PACKAGES = cmake g++ make pkg-config graphviz \
  libtbb-dev libtbbbind-2-5 libeigen3-dev libhwloc-dev hwloc \
  libhdf5-dev hdf5-tools libgtest-dev libbenchmark-dev libtomlplusplus-dev libcli11-dev nlohmann-json3-dev \
  universal-ctags \
  libopenmpi-dev openmpi-bin libsundials-dev \
  python3-h5py python3-matplotlib python3-numpy python3-dev pybind11-dev python3-pytest python3-scipy \
  python3-venv python3-pandas python3-xarray \
  chromium

.PHONY: deps configure build run test test-checks test-slow bench plots view video clean

# Installs the missing Debian packages with apt-get: as root, or through sudo. A user who can
# do neither is told which packages to ask for and make stops before apt-get
# (docs/install.md: the plain CMake build once they are installed).
INSTALL = tools/install_packages.sh

deps:
	@$(INSTALL) $(PACKAGES)
	@# Node.js and npm (Debian's, unless the machine has them), then the 3D viewer's libraries
	@# (three.js, h5wasm; playwright-core, pngjs for its browser test) from its lockfile.
	@command -v node >/dev/null && command -v npm >/dev/null || $(INSTALL) nodejs npm
	@cd tools/viewer && { [ node_modules/.package-lock.json -nt package-lock.json ] || npm ci --no-audit --no-fund --loglevel=error; }

$(BUILD)/CMakeCache.txt: CMakeLists.txt | deps
	@cmake -S . -B $(BUILD) -DCMAKE_BUILD_TYPE=Release -DCVT_REQUIRE_ALL=ON >/dev/null

configure: $(BUILD)/CMakeCache.txt

build: deps configure
	@cmake --build $(BUILD) -j $(JOBS) 2>&1 | grep -Ev '^\[ *[0-9]+%\]|^-- ' || true
	@test -x $(BUILD)/cvt-engine

THREADS ?= $(shell nproc)

# The reference model to a steady operating point (about 1 minute on 2 cores after the build).
run: build
	@$(BUILD)/cvt-engine run $(CONFIG) --out $(OUT) --scheduler flowgraph --threads $(THREADS)

# The whole fast suite (minutes). Long physics runs are named Slow* (the test or its case:
# SlowPythonTest, UntilSteadyTest.SlowReference...) and run by test-slow; a name with "Slow"
# elsewhere (StiffComponentOnItsSlowManifold) is a fast test.
# Then the checking builds (docs/testing.md), each in $(BUILD)/check-KIND: AddressSanitizer
# and UndefinedBehaviorSanitizer over the kernels and runs, ThreadSanitizer over the threaded
# tests, and the determinism tests of the portable x86-64-v2 build. CHECKS= leaves them out;
# CHECKS=tsan runs one.
CHECKS ?= asan tsan portable
test: build
	@cd $(BUILD) && ctest -E '^Slow|[.]Slow' -j $(JOBS) --output-on-failure --timeout 900
	@tools/checking_builds.sh $(BUILD) $(JOBS) $(CHECKS)

test-checks: deps
	@tools/checking_builds.sh $(BUILD) $(JOBS) $(CHECKS)

test-slow: build
	@cd $(BUILD) && ctest -R '^Slow|[.]Slow' --output-on-failure --timeout 3600

bench: build
	@for b in $(BUILD)/*_bench; do echo "== $$b"; $$b --benchmark_min_time=0.2; done

# The 3D viewer of a run's file in the browser (docs/viewer.md): `make view OUT=results.h5`
# serves it on http://127.0.0.1:8765/; `make video OUT=results.h5 VIDEO=run.webm` records
# the 3D view with headless Chromium. The run needs snapshots (run.snapshot_interval > 0).
VIDEO ?= $(basename $(OUT)).webm
view: deps
	@$(PYTHON) tools/cvt_view.py $(OUT)

video: deps
	@$(PYTHON) tools/cvt_view.py $(OUT) --port 0 --video $(VIDEO)

# Figures of the last run ($(OUT)) into $(PLOTS): history.png (speed and geometric ratio, slip,
# torques, clamping forces, sheave positions, efficiency, strand tensions, then the tracked
# link and pin, supports and speeds), spectrogram-output_torque.png, and chain.gif if the run
# has snapshots. Then, separately and only where their input exists, the performance figures
# into $(PLOTS)/perf: profile.png (the run's /profile), scaling.png ($(STUDY)) and
# integrators.png (INTEGRATORS=FILE.csv of `cvt-engine study integrators`).
# docs/plots.md says what each shows.
PLOTS ?= plots
STUDY ?= study.csv
PLOT   = $(PYTHON) tools/cvt_plot.py
HAS    = $(PYTHON) -c 'import h5py, sys; sys.exit(sys.argv[2] not in h5py.File(sys.argv[1], "r"))'

plots: deps
	@test -f $(OUT) || { echo "make plots: $(OUT) not found: make run first, or OUT=FILE"; exit 2; }
	@mkdir -p $(PLOTS)
	@echo "make plots: run figures of $(OUT) into $(PLOTS)/"
	$(PLOT) history $(OUT) -o $(PLOTS)/history.png
	$(PLOT) spectrogram $(OUT) output_torque --fmax 6000 --nperseg 1024 -o $(PLOTS)/spectrogram-output_torque.png
	@if $(HAS) $(OUT) particles/chain/position; then echo "$(PLOT) animate $(OUT) -o $(PLOTS)/chain.gif"; \
	  $(PLOT) animate $(OUT) -o $(PLOTS)/chain.gif; \
	else echo "make plots: $(OUT) has no snapshots (run.snapshot_interval = 0): no chain.gif"; fi
	@echo "make plots: performance figures into $(PLOTS)/perf/ (where their input exists)"
	@mkdir -p $(PLOTS)/perf
	@if $(HAS) $(OUT) profile; then echo "$(PLOT) profile $(OUT) -o $(PLOTS)/perf/profile.png"; \
	  $(PLOT) profile $(OUT) -o $(PLOTS)/perf/profile.png; \
	else echo "make plots: $(OUT) has no /profile (run not profiled): no profile.png"; fi
	@if [ -f $(STUDY) ]; then echo "$(PLOT) scaling $(STUDY) -o $(PLOTS)/perf/scaling.png"; \
	  $(PLOT) scaling $(STUDY) -o $(PLOTS)/perf/scaling.png; \
	else echo "make plots: no $(STUDY) (STUDY=FILE): no scaling.png"; fi
	@if [ -n "$(INTEGRATORS)" ] && [ -f "$(INTEGRATORS)" ]; then \
	  echo "$(PLOT) integrators $(INTEGRATORS) -o $(PLOTS)/perf/integrators.png"; \
	  $(PLOT) integrators $(INTEGRATORS) -o $(PLOTS)/perf/integrators.png; \
	else echo "make plots: no integrator study (INTEGRATORS=FILE.csv): no integrators.png"; fi
	@rmdir $(PLOTS)/perf 2>/dev/null || true

clean:
	rm -rf $(BUILD)
