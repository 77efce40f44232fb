# nao_skin developer entry points. README commands: `make demo`, `make test`.
# All targets use the repo-local venv (.venv) made by docker/setup_venv.sh,
# which is idempotent (a stamp makes re-runs return immediately).

ROOT := $(patsubst %/,%,$(dir $(abspath $(lastword $(MAKEFILE_LIST)))))
VENV := $(ROOT)/.venv

# Keep DDS discovery on this machine unless told otherwise
# (e.g. `make demo ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET`).
ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export ROS_AUTOMATIC_DISCOVERY_RANGE

.PHONY: setup setup-test demo test test-core

## setup: create/refresh .venv (ROS 2 wheels, tf2_msgs, deps, nao_skin editable)
setup:
	bash $(ROOT)/docker/setup_venv.sh

## setup-test: setup + YARP Python bindings (needed by the test suite)
setup-test:
	bash $(ROOT)/docker/setup_venv.sh --with-yarp

## demo: run the end-to-end demo
demo: setup
	cd $(ROOT) && $(VENV)/bin/nao-skin demo

# The suite runs on two pytest-xdist workers: each test owns its ROS domain (claimed in /tmp by
# test/ros_harness.py for as long as it runs), its ports (free_port) and its temporary files (tmp_path);
# tests that must not run beside one another would share an @pytest.mark.xdist_group (--dist loadgroup).
PYTEST_PARALLEL ?= -n 2 --dist loadgroup

## test: run the test suite (in parallel: PYTEST_PARALLEL= runs it serially)
test: setup-test
	cd $(ROOT) && $(VENV)/bin/python -m pytest -q $(PYTEST_PARALLEL) test

## test-core: the fast core tests only (no ROS 2 nodes/DDS, libqi, yarpserver; no slow runs)
test-core: setup
	cd $(ROOT) && $(VENV)/bin/python -m pytest -q $(PYTEST_PARALLEL) -m "not middleware and not slow" test
