# Top-level build: `make setup`, `make test`, `make demo`, `make bench`.
# Everything a fresh Debian 12 machine needs is installed from here.

SHELL := /bin/bash
PY    := .venv/bin/python
VENV  := .venv
BUILD := build/runtime
JOBS  ?= $(shell nproc)

APT_PACKAGES := build-essential cmake pkg-config python3-venv \
  libeigen3-dev libfcl-dev libopenexr-dev nlohmann-json3-dev libcli11-dev libtomlplusplus-dev \
  libgtest-dev googletest libssl-dev libhwy-dev python3-dev ccache \
  libegl-mesa0 libgl1-mesa-dri libegl-dev libepoxy-dev \
  clang libclang-rt-14-dev \
  chromium chromium-driver

.PHONY: setup apt venv runtime test test-py test-slow test-cpp lint format demo bench clean

setup: apt venv runtime

# Install the Debian packages only when one is missing (apt-get update first).
apt:
	@missing=""; for p in $(APT_PACKAGES); do \
	  dpkg-query -W -f='$${Status}' $$p 2>/dev/null | grep -q "ok installed" || missing="$$missing $$p"; \
	done; \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages:$$missing"; \
	  SUDO=""; [ "$$(id -u)" = 0 ] || SUDO=sudo; \
	  $$SUDO apt-get update && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y --no-install-recommends $$missing; \
	fi

$(VENV)/.stamp: pyproject.toml
	python3 -m venv $(VENV)
	$(VENV)/bin/pip install -q --upgrade pip "setuptools>=77" wheel
	$(VENV)/bin/pip install -q -C wheel.cmake=false -e '.[test]'
	touch $@

venv: $(VENV)/.stamp

# The runtime and the example plugin only: the C++ test suite (about 40 % of
# what the project compiles) is built by `make test` (test-cpp).
# The Python module hrt._hrt (nanobind, from the venv) is built beside them, and
# a .pth file puts $(BUILD)/python on the venv's path: `import hrt` (docs/python.md).
runtime: apt venv
	cmake -S runtime -B $(BUILD) -DCMAKE_BUILD_TYPE=Release -DHRT_PYTHON=ON -DPython_EXECUTABLE=$(CURDIR)/$(PY) >/dev/null
	cmake --build $(BUILD) -j $(JOBS) --target hrt hrt_example_device hrt_python hrt_python_stub
	@mkdir -p $(VENV)/bin
	ln -sf ../../$(BUILD)/hrt $(VENV)/bin/hrt
	echo "$(CURDIR)/$(BUILD)/python" > "$$($(PY) -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/hrt-runtime.pth"

test: setup lint test-cpp test-py test-fuzz

# Linters, pinned in pyproject.toml's test extra: ruff over the Python ([tool.ruff]: pyflakes,
# pycodestyle's errors, no np.empty), clang-format over the C and C++ (.clang-format), and
# no runtime function over 150 lines (tools/check_function_length.py, with lizard).
# `make format` applies clang-format; ruff's fixes are `.venv/bin/ruff check --fix`.
CXX_SOURCES = git ls-files '*.cpp' '*.h' '*.c'
lint:
	$(VENV)/bin/ruff check hbake tests tools examples
	$(PY) tools/check_file_length.py
	$(CXX_SOURCES) | xargs $(VENV)/bin/clang-format --dry-run -Werror
	$(PY) tools/check_function_length.py

format:
	$(CXX_SOURCES) | xargs $(VENV)/bin/clang-format -i

test-cpp:
	cmake --build $(BUILD) -j $(JOBS)
	cd $(BUILD) && ctest --output-on-failure -j $(JOBS)

# The pytest suite drives the test plugins (runtime/tests/plugins) through `hrt run`.
test-py:
	cmake --build $(BUILD) -j $(JOBS) --target hrt_test_plugins
	$(PY) -m pytest -q -m "not slow" --durations=15

# The sweeps behind the slow marker (bakes of the largest models, the
# 20-orientation thin-feature sweep): minutes each, not in `make test`.
test-slow: setup
	cmake --build $(BUILD) -j $(JOBS) --target hrt_test_plugins
	$(PY) -m pytest -q -m slow

demo: setup
	bash examples/demo.sh

bench: setup
	$(VENV)/bin/hbake bench
	bash examples/bench_runtime.sh

clean:
	rm -rf build out

# --- libFuzzer targets runtime/fuzz (runtime/fuzz/README.md) --------------
# Its own build directory, clang with ASan + UBSan + libFuzzer instrumentation
# (the gcc build in $(BUILD) is untouched). test-fuzz: a deterministic run
# (fixed seed and count) of each target (bundles, UDP packets, scene files and
# trajectories) over a copy of its seed corpus; any crash, sanitizer report,
# timeout or OOM fails it. fuzz-long / fuzz-long-scene: hours of the bundle /
# scene target (HOURS=, FUZZ_JOBS=), with a persistent corpus outside the
# repository (FUZZ_DIR=).
FUZZ_BUILD := build/fuzz
FUZZ_BIN   := $(FUZZ_BUILD)/fuzz/hrt_fuzz_bundle
FUZZ_RUNS  ?= 40000
FUZZ_UDP_BIN  := $(FUZZ_BUILD)/fuzz/hrt_fuzz_udp
FUZZ_UDP_RUNS ?= 1000000
FUZZ_UDP_OPTS := -max_len=65536 -timeout=10 -rss_limit_mb=1024 -dict=$(CURDIR)/runtime/fuzz/udp.dict -print_final_stats=1
FUZZ_SCENE_BIN  := $(FUZZ_BUILD)/fuzz/hrt_fuzz_scene
FUZZ_SCENE_RUNS ?= 300000
FUZZ_SCENE_OPTS := -max_len=32768 -timeout=10 -rss_limit_mb=1024 -dict=$(CURDIR)/runtime/fuzz/scene.dict -print_final_stats=1
FUZZ_OPTS  := -max_len=131072 -timeout=10 -rss_limit_mb=2048 -dict=$(CURDIR)/runtime/fuzz/bundle.dict -print_final_stats=1
HOURS      ?= 1
FUZZ_JOBS  ?= $(JOBS)
FUZZ_DIR   ?= $(HOME)/.cache/hrt-fuzz

.PHONY: fuzz-build test-fuzz fuzz-long fuzz-long-scene

fuzz-build: apt
	cmake -S runtime -B $(FUZZ_BUILD) -DCMAKE_CXX_COMPILER=clang++ -DHRT_FUZZ=ON -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
	cmake --build $(FUZZ_BUILD) -j $(JOBS) --target hrt_fuzz_bundle hrt_fuzz_udp hrt_fuzz_scene

test-fuzz: fuzz-build
	rm -rf $(FUZZ_BUILD)/ci && mkdir -p $(FUZZ_BUILD)/ci/artifacts
	cp -r $(FUZZ_BUILD)/fuzz/seed_corpus $(FUZZ_BUILD)/ci/corpus
	find runtime/fuzz/regressions -name '*.bin' ! -name 'udp-*' ! -name 'scene-*' -exec cp {} $(FUZZ_BUILD)/ci/corpus/ \;
	$(FUZZ_BIN) -seed=1 -runs=$(FUZZ_RUNS) $(FUZZ_OPTS) -artifact_prefix=$(CURDIR)/$(FUZZ_BUILD)/ci/artifacts/ $(FUZZ_BUILD)/ci/corpus
	cp -r $(FUZZ_BUILD)/fuzz/udp_seed_corpus $(FUZZ_BUILD)/ci/udp_corpus
	find runtime/fuzz/regressions -name 'udp-*.bin' -exec cp {} $(FUZZ_BUILD)/ci/udp_corpus/ \;
	$(FUZZ_UDP_BIN) -seed=1 -runs=$(FUZZ_UDP_RUNS) $(FUZZ_UDP_OPTS) -artifact_prefix=$(CURDIR)/$(FUZZ_BUILD)/ci/artifacts/udp- $(FUZZ_BUILD)/ci/udp_corpus
	cp -r $(FUZZ_BUILD)/fuzz/scene_seed_corpus $(FUZZ_BUILD)/ci/scene_corpus
	find runtime/fuzz/regressions -name 'scene-*.bin' -exec cp {} $(FUZZ_BUILD)/ci/scene_corpus/ \;
	$(FUZZ_SCENE_BIN) -seed=1 -runs=$(FUZZ_SCENE_RUNS) $(FUZZ_SCENE_OPTS) -artifact_prefix=$(CURDIR)/$(FUZZ_BUILD)/ci/artifacts/scene- $(FUZZ_BUILD)/ci/scene_corpus

# FUZZ_JOBS workers for HOURS each (a worker stops at its first finding; its
# log is $(FUZZ_DIR)/fuzz-N.log, findings in $(FUZZ_DIR)/artifacts).
fuzz-long: fuzz-build
	mkdir -p $(FUZZ_DIR)/corpus $(FUZZ_DIR)/artifacts
	cd $(FUZZ_DIR) && $(CURDIR)/$(FUZZ_BIN) -max_total_time=$$(awk 'BEGIN{print int($(HOURS)*3600)}') \
	  -jobs=$(FUZZ_JOBS) -workers=$(FUZZ_JOBS) $(FUZZ_OPTS) -artifact_prefix=$(FUZZ_DIR)/artifacts/ \
	  $(FUZZ_DIR)/corpus $(CURDIR)/$(FUZZ_BUILD)/fuzz/seed_corpus

# The same for hrt_fuzz_scene (scene files and trajectories): corpus and logs
# in $(FUZZ_DIR)/scene.
fuzz-long-scene: fuzz-build
	mkdir -p $(FUZZ_DIR)/scene/corpus $(FUZZ_DIR)/scene/artifacts
	cd $(FUZZ_DIR)/scene && $(CURDIR)/$(FUZZ_SCENE_BIN) -max_total_time=$$(awk 'BEGIN{print int($(HOURS)*3600)}') \
	  -jobs=$(FUZZ_JOBS) -workers=$(FUZZ_JOBS) $(FUZZ_SCENE_OPTS) -artifact_prefix=$(FUZZ_DIR)/scene/artifacts/ \
	  $(FUZZ_DIR)/scene/corpus $(CURDIR)/$(FUZZ_BUILD)/fuzz/scene_seed_corpus
