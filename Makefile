# Top-level build: `make setup`, `make test`, `make demo`, `make bench`.
# Everything a fresh Debian 12 machine needs is installed from here.

SHELL := /bin/bash
PY    := .venv/bin/python
VENV  := .venv
BUILD := build/runtime
JOBS  ?= $(shell nproc)

APT_PACKAGES := build-essential cmake pkg-config python3-venv \
  libeigen3-dev libfcl-dev libopenexr-dev nlohmann-json3-dev libcli11-dev \
  libgtest-dev googletest libssl-dev \
  libegl-mesa0 libgl1-mesa-dri libegl-dev libepoxy-dev

.PHONY: setup apt venv runtime test test-py test-cpp demo bench clean

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
	$(VENV)/bin/pip install -q --upgrade pip
	$(VENV)/bin/pip install -q -e '.[test]'
	touch $@

venv: $(VENV)/.stamp

runtime: apt
	cmake -S runtime -B $(BUILD) -DCMAKE_BUILD_TYPE=Release >/dev/null
	cmake --build $(BUILD) -j $(JOBS)
	@mkdir -p $(VENV)/bin
	ln -sf ../../$(BUILD)/hrt $(VENV)/bin/hrt

test: setup test-cpp test-py

test-cpp:
	cd $(BUILD) && ctest --output-on-failure -j $(JOBS)

test-py:
	$(PY) -m pytest -q

demo: setup
	bash examples/demo.sh

bench: setup
	$(VENV)/bin/hbake bench
	bash examples/bench_runtime.sh

clean:
	rm -rf build out
