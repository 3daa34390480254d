# The two README commands: `make run` and `make test`. Both install what is missing
# (Debian packages), configure a Release build and build it first.
BUILD   ?= build
JOBS    ?= $(shell nproc)
CONFIG  ?= configs/reference.toml
OUT     ?= results.h5
PYTHON  ?= /usr/bin/python3

PACKAGES = cmake g++ make pkg-config \
  libtbb-dev libtbbbind-2-5 libeigen3-dev libhwloc-dev hwloc \
  libhdf5-dev hdf5-tools libgtest-dev libbenchmark-dev libtomlplusplus-dev libcli11-dev \
  python3-h5py python3-matplotlib python3-numpy

SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

.PHONY: deps configure build run test test-slow bench plots clean

deps:
	@missing=$$(for p in $(PACKAGES); do dpkg-query -W -f='$${Status}\n' $$p 2>/dev/null | grep -q "install ok installed" || echo $$p; done); \
	if [ -n "$$missing" ]; then \
	  echo "installing: $$missing"; \
	  $(SUDO) apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq --no-install-recommends $$missing >/dev/null; \
	fi

$(BUILD)/CMakeCache.txt: CMakeLists.txt | deps
	@cmake -S . -B $(BUILD) -DCMAKE_BUILD_TYPE=Release >/dev/null

configure: $(BUILD)/CMakeCache.txt

build: deps configure
	@cmake --build $(BUILD) -j $(JOBS) 2>&1 | grep -Ev '^\[ *[0-9]+%\]|^-- ' || true
	@test -x $(BUILD)/cvt-engine

THREADS ?= $(shell nproc)

run: build
	$(BUILD)/cvt-engine run $(CONFIG) --out $(OUT) --scheduler flowgraph --threads $(THREADS)

# The whole fast suite (minutes). Long physics runs are named Slow* and run by test-slow.
test: build
	@cd $(BUILD) && ctest -E 'Slow' -j $(JOBS) --output-on-failure --timeout 900

test-slow: build
	@cd $(BUILD) && ctest -R 'Slow' --output-on-failure --timeout 3600

bench: build
	@for b in $(BUILD)/*_bench; do echo "== $$b"; $$b --benchmark_min_time=0.2; done

# Figures of the last run ($(OUT)) into $(PLOTS): time histories, spectrogram of the output
# torque, run-time profile (if the run was profiled), chain animation, and the scaling study
# if $(STUDY) exists. docs/plots.md says what each shows.
PLOTS ?= plots
STUDY ?= study.csv
PLOT   = $(PYTHON) tools/cvt_plot.py
HAS    = $(PYTHON) -c 'import h5py, sys; sys.exit(sys.argv[2] not in h5py.File(sys.argv[1], "r"))'

plots: deps
	@test -f $(OUT) || { echo "make plots: $(OUT) not found: make run first, or OUT=FILE"; exit 2; }
	@mkdir -p $(PLOTS)
	$(PLOT) history $(OUT) --out $(PLOTS)/history.png
	$(PLOT) spectrogram $(OUT) output_torque --out $(PLOTS)/spectrogram-output_torque.png
	@if $(HAS) $(OUT) profile; then echo "$(PLOT) profile $(OUT) --out $(PLOTS)/profile.png"; \
	  $(PLOT) profile $(OUT) --out $(PLOTS)/profile.png; \
	else echo "make plots: $(OUT) has no /profile (run not profiled): no profile.png"; fi
	@if $(HAS) $(OUT) particles/chain/position; then echo "$(PLOT) animate $(OUT) --out $(PLOTS)/chain.gif"; \
	  $(PLOT) animate $(OUT) --out $(PLOTS)/chain.gif; \
	else echo "make plots: $(OUT) has no snapshots (run.snapshot_interval = 0): no chain.gif"; fi
	@if [ -f $(STUDY) ]; then echo "$(PLOT) scaling $(STUDY) --out $(PLOTS)/scaling.png"; \
	  $(PLOT) scaling $(STUDY) --out $(PLOTS)/scaling.png; \
	else echo "make plots: no $(STUDY): no scaling.png"; fi

clean:
	rm -rf $(BUILD)
