# Everything a fresh machine needs: `make demo` and `make test` set themselves up.
SHELL := /bin/bash
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.setup-stamp

# Discovery traffic must never leave loopback; keep test runs off other domains.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
export ROS_DOMAIN_ID ?= 42
export MUJOCO_GL ?= egl
export ROS_LOG_DIR ?= $(CURDIR)/build/ros_log

.PHONY: setup demo test test-all bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml tools/build_interfaces.py $(shell find runtime/ros/interfaces -type f 2>/dev/null)
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[ros-build,test]'
	$(PY) tools/build_interfaces.py
	@touch $(STAMP)

demo: setup
	$(VENV)/bin/objective run objectives/stack_cubes.xml

test: setup
	$(PY) -m pytest -q

test-all: setup
	$(PY) -m pytest -q -m ''

bench: setup
	@ls benchmarks/*.py >/dev/null 2>&1 || { echo "no benchmarks yet"; exit 0; }; \
	for b in benchmarks/*.py; do echo "== $$b"; $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) build
