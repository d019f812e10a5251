# herd_ros — `make demo` and `make test` are all a fresh machine needs.
SHELL := /bin/bash
.DEFAULT_GOAL := help

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip --disable-pip-version-check -q
STAMP  := $(VENV)/.herd_ros-installed

# ROS 2 Jazzy from PyPI (real rclpy + Fast DDS), the numerics, and the test/build tools.
ROS_WHEELS := "ros-jazzy-rclpy[fastrtps]" ros-jazzy-sensor-msgs ros-jazzy-nav-msgs \
              ros-jazzy-geometry-msgs ros-jazzy-std-msgs ros-jazzy-std-srvs \
              ros-jazzy-visualization-msgs ros-jazzy-diagnostic-msgs \
              ros-jazzy-rosgraph-msgs ros-jazzy-builtin-interfaces ros-jazzy-ament-index-python
PY_DEPS    := setuptools wheel numpy scipy pandas numba filterpy rosbags PyYAML matplotlib tqdm pillow
DEV_DEPS   := pytest pytest-timeout pytest-xdist pymap3d mcap mcap-ros2-support ruff sphinx myst-parser \
              colcon-core colcon-ros colcon-python-setup-py colcon-bash
BENCH_DEPS := padasip

# DDS never leaves this machine: loopback-only discovery and a per-run domain id.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
export ROS_STATIC_PEERS :=
ifndef ROS_DOMAIN_ID
ROS_DOMAIN_ID := $(shell echo $$(( (RANDOM % 100) + 1 )))
endif
export ROS_DOMAIN_ID
# ament_index finds the package in the venv prefix (pip path).
export AMENT_PREFIX_PATH := $(CURDIR)/$(VENV)$(if $(AMENT_PREFIX_PATH),:$(AMENT_PREFIX_PATH))
export MPLBACKEND := Agg
export PYTHONUNBUFFERED := 1

.PHONY: help setup demo test test-fast lint docs bench clean

help:
	@echo "make demo   set up .venv and run the demo on the shipped real herd (19 baboons; writes demo_out/)"
	@echo "make test   set up .venv and run the test suite"
	@echo "make test-fast  the tests that need no ROS node, package build or long statistics (the inner loop)"
	@echo "make docs   build the documentation (doc/, Sphinx) into doc/_build/html"
	@echo "make bench  set up .venv and run the benchmarks (medians, see doc/results.md)"
	@echo "make setup  only create/update .venv (idempotent)"

setup: $(STAMP)

$(VENV)/bin/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): $(VENV)/bin/python setup.py setup.cfg package.xml Makefile
	$(PIP) install $(ROS_WHEELS) $(PY_DEPS) $(DEV_DEPS)
	$(PIP) install --no-deps --no-build-isolation .
	@touch $@

# The package itself is reinstalled on every run so the console scripts match the tree.
install-self: $(STAMP)
	@$(PIP) install --no-deps --no-build-isolation . >/dev/null

demo: install-self
	$(VENV)/bin/herd-ros demo --out demo_out

# pycodestyle errors and warnings and pyflakes, lines up to 100; the package, the launch files
# and doc/conf.py also the pydocstyle rules for public functions, methods, classes and
# packages (D103, D102, D101, D104)
RUFF := $(PY) -m ruff check --quiet --line-length 100
LINT := $(RUFF) --select E,F,W,D101,D102,D103,D104 herd_ros launch doc setup.py && \
        $(RUFF) --select E,F,W test

lint: install-self
	$(LINT)

# two workers (this machine has two cores; each worker keeps its own band of DDS domains,
# test/conftest.py); --dist loadfile keeps a file's tests, and its module fixtures (the
# colcon build, the demo runs), on one worker; the 15 slowest tests are listed at the end
test: install-self
	$(LINT)
	$(PY) -m pytest -q -ra -n 2 --dist loadfile --durations=15

docs: install-self
	$(PY) -m sphinx -W --keep-going -q -b html doc doc/_build/html
	@echo "open doc/_build/html/index.html"

test-fast: install-self
	$(PY) -m pytest -q -ra -n 2 --dist loadfile -m "not ros and not slow and not build"

bench: install-self
	$(PIP) install $(BENCH_DEPS)
	$(PY) test/bench/run_all.py

clean:
	rm -rf build install log demo_out .pytest_cache doc/_build doc/_generated
