# Everything a fresh machine needs: `make demo` and `make test` set themselves up.
SHELL := /bin/bash
# Python 3.12 (ROS 2 Jazzy's Python, and LeRobot 0.6's): the first `python3.12` on PATH that runs
# (a pyenv shim may not), else pyenv's 3.12.1.
PYTHON ?= $(firstword $(shell for p in python3.12 $(HOME)/.pyenv/versions/3.12.1/bin/python3.12; do \
	$$p -c 'import sys' 2>/dev/null && command -v $$p; done))
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.setup-stamp

# Discovery traffic must never leave loopback; keep test runs off other domains.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
export ROS_DOMAIN_ID ?= 42
export MUJOCO_GL ?= egl
export ROS_LOG_DIR ?= $(CURDIR)/build/ros_log

.PHONY: setup demo lint typecheck test test-all bench clean lerobot lerobot-policy lerobot-diffusion chromium ray

# Every run then reads the project's bytecode instead of compiling ~150 modules from source: the
# import system reads .pyc files even under PYTHONDONTWRITEBYTECODE=1 (which only stops it writing
# them), and compileall writes them regardless. Only changed modules are compiled again (~0.1 s).
setup: $(STAMP)
	@$(PY) -m compileall -q runtime behaviors policy sim evaluation recording
	@$(PY) -c 'import sys; sys.version_info[:2] == (3, 12) or print(f"make: note: $(VENV) runs Python {sys.version.split()[0]}, not 3.12: `make clean setup` builds it on 3.12")'

# Set-up installs with uv (pinned; put into the venv with pip): 20 s for what pip takes a minute
# over, and a second venv on the machine links its files from uv's cache (~/.cache/uv) in seconds.
# uv reads no pip configuration (UV_INDEX_URL and friends name another index). The interface
# packages build once per machine and Python (about a minute on two cores) and install from
# ~/.cache/objective-runtime after that (runtime/app/build_interfaces.py). PIP_QUIET drops the one
# warning per package that a pip configuration naming an index directory that is not there causes.
UV_VERSION := 0.13.9
PIP_QUIET := 2>&1 | { grep -v "is ignored: it is neither a file nor a directory" || true; }

$(STAMP): pyproject.toml runtime/app/build_interfaces.py $(shell find runtime/io/ros/interfaces -type f 2>/dev/null)
	@test -x $(PY) || test -n "$(PYTHON)" || { echo "make: no Python 3.12 found (python3.12, ~/.pyenv/versions/3.12.1); name one with PYTHON=..."; exit 2; }
	@test -x $(PY) || { echo "setup: creating $(VENV) with $(PYTHON)"; $(PYTHON) -m venv $(VENV); }
	@echo "setup: installing the project and its pinned dependencies into $(VENV) (uv $(UV_VERSION))"
	@set -o pipefail; $(PY) -m pip install --quiet uv==$(UV_VERSION) $(PIP_QUIET)
	@$(VENV)/bin/uv pip install --quiet --python $(PY) --compile-bytecode -e '.[sim,record,ros,ros-build,test,dev,monitor]'
	@echo "setup: the ROS 2 interface packages (built once per machine and Python, then from its cache)"
	@$(PY) -m runtime.app.build_interfaces --build-dir build/interfaces
	@touch $(STAMP)

# Optional LeRobot extra (LeRobot 0.6.1, torch 2.11.0 from the registry) in the project's venv:
# `pip install -e '.[lerobot]'` (docs/lerobot.md, What it costs: what it downloads and how long it takes).
# `make test` runs the LeRobot tests when it is installed.
LEROBOT_STAMP := $(VENV)/.lerobot-stamp

lerobot: $(LEROBOT_STAMP)

$(LEROBOT_STAMP): $(STAMP) pyproject.toml
	@echo "make lerobot: installing LeRobot 0.6.1 and torch 2.11.0 into $(VENV) (about 4 GB the first time)"
	set -o pipefail; $(PY) -m pip install --quiet -e '.[lerobot]' $(PIP_QUIET)
	HF_HUB_OFFLINE=1 $(PY) -c "import torch, lerobot; import lerobot.policies.smolvla.modeling_smolvla, lerobot.async_inference.robot_client; print('lerobot', lerobot.__version__, 'torch', torch.__version__)"
	@touch $@

# The tiny SmolVLA (docs/lerobot.md): records 360 oracle demonstrations in two workers
# (build/demos/stack_cubes_360, reused when present; layout seeds 1000-1359, wrist and overview
# cameras at 128 px, the gripper at 0.5 rad/s, 0.04 rad of motion noise, frames until 2 s after the
# plan), plays the oracle's plan for 2,000 more layouts straight into the cell (seeds 30000-31999, a
# frame every 5th step; build/plan_frames, made once), then trains on the overview's workspace crop
# and the wrist at 64 px with one torch thread for 30 minutes: half of every batch from the played
# layouts, 6 of 16 samples from the episodes' first second, 4 of 16 from the 2 s after the grasp,
# the cube layout as an auxiliary target of the overview's vision tokens. Saves
# build/policies/tiny_smolvla and evaluates it on held-out seeds 100-149.
LEROBOT_POLICY_DEMOS := --dataset build/demos/stack_cubes_360 --episodes 360 --demo-seed 1000 --workers 2 \
	--record-steps 220 --cameras wrist,overview --gripper-velocity 0.5 --motion-noise 0.04 --hold-after-plan 2
LEROBOT_POLICY_MODEL := --crop overview=0.21875,0.25,0.71875,0.75 --train-size 64 --patch-size 8 \
	--layout-target 1 --early-frames 10 --early-share 0.375 --lift-steps 20 --lift-share 0.25 \
	--plan-layouts 2000 --plan-seed 30000 --plan-every 5 --plan-share 0.5
lerobot-policy: lerobot
	HF_HUB_OFFLINE=1 MUJOCO_GL=egl ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST $(PY) tools/train_tiny_smolvla.py \
		$(LEROBOT_POLICY_DEMOS) $(LEROBOT_POLICY_MODEL) --seed 0 --steps 9000 --minutes 30 \
		--threads 1 --eval-episodes 50 --eval-seed-start 100

# LeRobot's DiffusionPolicy (docs/lerobot.md): records 120 oracle demonstrations with the settings
# of lerobot-policy (build/demos/stack_cubes_120, layout seeds 1000-1119, reused when present),
# trains a random-weight ResNet-18 + SpatialSoftmax encoder on the wrist and the overview's
# workspace crop at 64 px with a narrow UNet that predicts the clean chunk (32 steps, DDIM 10),
# one torch thread for 30 minutes, saves build/policies/diffusion and evaluates it on held-out
# seeds 100-149.
LEROBOT_DIFFUSION_DEMOS := --dataset build/demos/stack_cubes_120 --episodes 120 --demo-seed 1000 --workers 2 \
	--record-steps 220 --cameras wrist,overview --gripper-velocity 0.5 --motion-noise 0.04 --hold-after-plan 2
LEROBOT_DIFFUSION_MODEL := --crop overview=0.21875,0.25,0.71875,0.75 --train-size 64 --prediction sample
lerobot-diffusion: lerobot
	HF_HUB_OFFLINE=1 MUJOCO_GL=egl ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST $(PY) tools/train_diffusion.py \
		$(LEROBOT_DIFFUSION_DEMOS) $(LEROBOT_DIFFUSION_MODEL) --out build/policies/diffusion --seed 0 --steps 4000 \
		--minutes 30 --threads 1 --eval-episodes 50 --eval-seed-start 100

# The learned policy that stacks (docs/lerobot.md): plays the oracle's plan for 600 layouts straight
# into the cell from the Home waypoint (layout seeds 40000-40599, a frame every policy step, the grasp
# 7 mm higher than the oracle's own, no camera rendered; kept in build/plan_frames/), trains LeRobot's
# Multi-Task DiT with flow matching on the joints, the cubes' poses (with the perception's error) and
# the stack's keypoints with one torch thread for 30 minutes, saves build/policies/learned with its
# perception stage's configuration, and evaluates it with objectives/stack_cubes_learned.xml on
# held-out seeds 100-149.
.PHONY: learned-policy
learned-policy: lerobot
	HF_HUB_OFFLINE=1 MUJOCO_GL=egl ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST $(PY) tools/train_learned.py \
		--out build/policies/learned --layouts 600 --layout-seed 40000 --workers 2 --seed 0 --steps 20000 \
		--minutes 30 --threads 1 --eval-episodes 50 --eval-seed-start 100 --eval-workers 2

# Headless Chromium (Debian's package) for the report's browser test; skipped when absent.
chromium:
	@command -v chromium >/dev/null || { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; }
	@chromium --version 2>/dev/null

# Optional Ray extra for `objective eval --executor ray` (ray==2.60.0, pure pip wheels). The
# installed numpy, torch and torchvision are pinned while it installs: Ray must never move them.
RAY_STAMP := $(VENV)/.ray-stamp

ray: $(RAY_STAMP)

$(RAY_STAMP): $(STAMP) pyproject.toml
	@mkdir -p build
	$(PY) -m pip freeze | grep -E '^(numpy|torch|torchvision)==' > build/ray-constraints.txt || true
	$(PY) -m pip install --quiet -c build/ray-constraints.txt -e '.[ray]'
	$(PY) -c "import ray, numpy; print('ray', ray.__version__, 'numpy', numpy.__version__)"
	@touch $@

demo: setup
	$(VENV)/bin/objective run objectives/stack_cubes.xml

# ruff's pyflakes rules and syntax errors (pyproject.toml, [tool.ruff]) over the whole tree: seconds.
lint: setup
	$(VENV)/bin/ruff check --quiet .

# mypy over the first-party tree (pyproject.toml, [tool.mypy]; docs/testing.md): the default level
# everywhere, --strict's flags on runtime, behaviors, policy, recording and evaluation.
# 25 s to a minute on 2 cores with an empty cache (build/mypy_cache), about a second after.
typecheck: setup
	$(VENV)/bin/mypy

test: lint typecheck
	$(PY) -m pytest -q -rs

# The fast tier (docs/testing.md): pure functions and the loader, no world, no ROS 2, no subprocess.
FAST_TESTS := tests/test_compliance_maths.py tests/test_execute_policy_math.py tests/test_execute_policy_core.py \
	tests/test_trajectory_maths.py tests/test_trajectory_points.py tests/test_step_spline.py tests/test_seam_blend.py \
	tests/test_svg_chart.py tests/test_script.py tests/test_loader.py tests/test_errors.py tests/test_eval_stats.py \
	tests/test_cdr.py tests/test_joint_states.py tests/test_layers.py tests/test_import_cycles.py tests/test_docs.py
.PHONY: test-fast
test-fast: setup
	$(PY) -m pytest -q -rs $(FAST_TESTS)

test-all: setup
	$(PY) -m pytest -q -m ''

bench: setup
	@ls benchmarks/bench_*.py >/dev/null 2>&1 || { echo "no benchmarks yet"; exit 0; }; \
	for b in benchmarks/bench_*.py; do \
	  case $$b in */bench_success_under_latency.py) echo "== $$b: hours at its defaults, run it on its own (docs/evaluation.md)"; continue;; esac; \
	  echo "== $$b"; $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) build
