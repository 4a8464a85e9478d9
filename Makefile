# humanoid-bc: every target builds .venv on first use (Python >= 3.12 from the package registries).
# Stage settings are Make variables passed on as flags; an unset one leaves the stage's default
# (`make help` lists each target's variables, flags and defaults).
SHELL := /bin/bash
.DEFAULT_GOAL := help

# The checkout this Makefile is in: the stage targets run in the current folder (`make -f path/Makefile record` in
# an empty one writes datasets/ and policies/ there), the project's own targets in the checkout.
ROOT := $(patsubst %/,%,$(dir $(abspath $(lastword $(MAKEFILE_LIST)))))
VENV := $(ROOT)/.venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
UV := $(VENV)/bin/uv
LOCK := $(ROOT)/requirements.lock
UV_VERSION = $(shell sed -n 's/^uv==\([^ ]*\).*/\1/p' $(LOCK))
# First interpreter >= 3.12 found: on PATH, then pyenv's versions (a pyenv shim alone may refuse).
PYTHON312 ?= $(shell for p in python3.12 python3.13 python3 $(HOME)/.pyenv/versions/3.1[2-9]*/bin/python3; do \
	command -v $$p >/dev/null 2>&1 && $$p -c 'import sys; sys.exit(sys.version_info < (3, 12))' 2>/dev/null \
	&& { command -v $$p; break; }; done)

# One OpenBLAS kernel, one MKL path and numpy's AVX2 loops on every x86-64 CPU with AVX2, Intel's and AMD's, so that
# results are the same on any of them (common/threads.py's PINNED; docs/decisions/cpu-kernels.md). Set before the
# libraries load, hence here; a value already in the environment wins.
ifneq ($(shell grep -m1 -ow avx2 /proc/cpuinfo 2>/dev/null),)
export OPENBLAS_CORETYPE ?= Haswell
export MKL_CBWR ?= AVX2,STRICT
export NPY_DISABLE_CPU_FEATURES ?= AVX512F,AVX512CD,AVX512_KNL,AVX512_KNM,AVX512_SKX,AVX512_CLX,AVX512_CNL,AVX512_ICL
endif
export HF_HUB_OFFLINE := 1
export HF_DATASETS_OFFLINE := 1
export MUJOCO_GL ?= egl
export PYTHONUNBUFFERED := 1

# A stage target's Make variables are its config's fields in capitals (MAX_STEPS=v is --max-steps v),
# passed only when set, so an unset one keeps the default of the stage's config: no default is typed
# here. Which target takes which variable is pipeline/targets.py's table (`make help` prints it, with each
# flag's help and default); tests/test_makefile.py holds the lists below to it. ARGS: any other flag
# of the PPO stages (`python -m rl.finetune --help`), e.g. ARGS="--learning-rate 1e-4 --target-kl 0.01".
# REMOVED.<target>: variables an earlier version had, still passed so that the stage refuses them in one
# line saying what to use instead (common/cli.py's REMOVED_FLAGS) rather than make ignoring them.
VARS.record := DATASET EPISODES SEED CONTROLLER TASK KICK NOISE RANDOMIZE LATENCY MAX_STEPS WORKERS BACKEND RAY_ADDRESS FRONT_END PACE LIVE LIVE_PORT LIVE_HOST CAMERAS
VARS.inspect := DATASET PLOT PLOT_PATH
VARS.merge := SHARDS DATASET
VARS.export := FORMAT DATASET OUT REFERENCE_EPISODES
VARS.train-bc := DATASET POLICY INPUTS EPOCHS MIN_UPDATES SEED EVAL_EPISODES OVERWRITE
VARS.eval := POLICY EPISODES SEED TASK PUSH KICK NOISE CONDITION VIDEO PLOT HOLD LIVE LIVE_PORT LIVE_HOST
VARS.play := POLICY DATASET EPISODES NOISE FRONT_END PACE LIVE LIVE_PORT LIVE_HOST CAMERAS
VARS.robustness := POLICY EPISODES SEED CONDITIONS TASK WORKERS
VARS.tune-walker := GENERATIONS POPULATION WALKS KICKS KICK NOISE SEED CMA_SEED SIGMA BOUNDS TURN_WEIGHT SENSED WORKERS \
	START RUN OUT
VARS.dagger := DATASET OUTPUT POLICY INPUTS EXPERT RANDOMIZE LATENCY KICK NOISE ROUNDS EPISODES EPOCHS MIN_UPDATES \
	EVAL_EPISODES WORKERS SEED OVERWRITE
VARS.finetune-rl := BC_POLICY POLICY TIMESTEPS WORKERS BACKEND RAY_ADDRESS ENVS PUSH KICK CURRICULUM RANDOMIZE OVERWRITE
VARS.scratch-rl := $(VARS.finetune-rl)
VARS.tutorial-rl := LEARNERS TIMESTEPS OVERWRITE
# The pipeline nests each stage's config: a stage's variable keeps its stage (RECORD.EPISODES is --record.episodes).
VARS.pipeline := RECORD.DATASET RECORD.EPISODES RECORD.SEED RECORD.CONTROLLER RECORD.NOISE RECORD.LATENCY \
	RECORD.MAX_STEPS BC.POLICY BC.EPOCHS BLIND_POLICY DAGGER.OUTPUT DAGGER.POLICY DAGGER.ROUNDS DAGGER.EPISODES \
	DAGGER.EPOCHS PPO.POLICY PPO.TIMESTEPS PPO.ENVS PPO.PUSH PPO.CURRICULUM PPO.RANDOMIZE SCRATCH_POLICY WORKERS BACKEND \
	RAY_ADDRESS OVERWRITE ROBUSTNESS_EPISODES CONDITIONS
REMOVED.record := SCHEDULES WALKING
REMOVED.eval := SCHEDULES WALKING
REMOVED.robustness := SCHEDULES WALKING
REMOVED.pipeline := DATASET EPISODES SEED CONTROLLER NOISE LATENCY MAX_STEPS BC_POLICY EPOCHS DAGGER_OUTPUT \
	DAGGER_POLICY ROUNDS DAGGER_EPISODES DAGGER_EPOCHS PPO_POLICY TIMESTEPS ENVS PUSH CURRICULUM RANDOMIZE DEPLOYABLE \
	PPO_FROM ODOMETRY_INPUTS TUTORIAL PROPRIO_POLICY SENSED_DATASET SENSED_NOISE SENSED_LATENCY ODOMETRY_POLICY
# Variables any target reads: the interpreter and .venv's places, the suite's processes, the pinned kernels, the GL
# backend; ARGS, the targets that pass it on.
COMMON_VARS := PYTHON312 VENV PY STAMP TEST_WORKERS OPENBLAS_CORETYPE MKL_CBWR NPY_DISABLE_CPU_FEATURES MUJOCO_GL
ARGS_TARGETS := finetune-rl scratch-rl pipeline
# A variable given on the command line that the target being made ($@) does not take: a typo (EPOCH=1), refused;
# not in a make run by another (MAKELEVEL > 0), whose command line's variables reach every target it makes.
given = $(foreach v,$(.VARIABLES),$(if $(filter command line,$(origin $(v))),$(v)))
takes = $(VARS.$@) $(REMOVED.$@) $(COMMON_VARS) $(if $(filter $@,$(ARGS_TARGETS)),ARGS)
unknown = $(if $(filter 0,$(MAKELEVEL)),$(filter-out $(takes),$(given)))
# --name='value' for each variable (or removed one) of the target being made ($@) that is set.
flags = $(if $(unknown),$(error make $@ takes no $(firstword $(unknown)); its variables: make help))$(strip \
	$(foreach v,$(VARS.$@) $(REMOVED.$@),$(if $($(v)),--$(shell echo $(v) | tr A-Z_ a-z-)='$($(v))')))

.PHONY: help venv record play merge inspect export train-bc eval robustness tune-walker dagger finetune-rl scratch-rl baseline-rl tutorial-rl pipeline test test-fast lint lock bench clean-venv

# The variables come from the stages' configs (pipeline/targets.py), so they need .venv.
help:  ## list the targets and their variables
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-12s %s\n", $$1, $$2}'
	@echo
	@if [ -x $(PY) ]; then $(PY) -m pipeline.targets; \
	else echo "Each target's variables are listed here once .venv exists (make venv)."; fi

# Installed from the lock (exact versions and hashes), never by resolving pyproject.toml afresh;
# `make lock` re-resolves it. uv installs (pinned to the lock's own uv); pip only bootstraps it. torchcodec is
# left out of the lock (pyproject.toml's [tool.uv]), and removed from a .venv built before that.
# --compile-bytecode, as pip does by default: where PYTHONDONTWRITEBYTECODE is set (as on these machines), every
# Python process would otherwise compile torch, SB3 and the rest again (docs/decisions/bytecode.md).
$(STAMP): $(LOCK) $(ROOT)/pyproject.toml
	@test -n "$(PYTHON312)" || { echo "error: no Python >= 3.12 found (set PYTHON312=/path/to/python3.12)" >&2; exit 1; }
	@test -x $(PY) || $(PYTHON312) -m venv $(VENV)
	$(PY) -m pip install --quiet uv==$(UV_VERSION)
	$(UV) pip install --quiet --python $(PY) --require-hashes --compile-bytecode -r $(LOCK)
	$(UV) pip uninstall --quiet --python $(PY) torchcodec
	$(UV) pip install --quiet --python $(PY) --no-deps -e $(ROOT)
	@touch $@

venv: $(STAMP)  ## build .venv and install the project

record: $(STAMP)  ## record demonstrations (LeRobot v3.0 + MCAP), appended to the dataset
	$(PY) -m teleop.record $(flags)

# The keys command a learned policy (one that takes a command): pipeline/targets.py's preset flags, then the variables.
play: $(STAMP)  ## drive a learned policy with the keyboard (POLICY: the newest of the chain's, a folder, or a teacher such as walker-sensed)
	$(PY) -m teleop.record --controller=keyboard --policy=newest --dataset=datasets/play --noise=0 $(flags)

merge: $(STAMP)  ## merge datasets recorded apart (SHARDS, disjoint seeds) into DATASET, as one recorder writes it
	$(PY) -m teleop.merge $(flags)

inspect: $(STAMP)  ## summarise and verify a dataset (LeRobot + MCAP); PLOT=1 also draws DATASET/inspect.png
	$(PY) -m teleop.inspect_dataset $(flags)

export: $(STAMP)  ## write a dataset in another format (FORMAT=minari: a new Minari datasets root at OUT)
	$(PY) -m teleop.export $(flags)

train-bc: $(STAMP)  ## behaviour cloning, then evaluation
	$(PY) -m bc.train $(flags)

eval: $(STAMP)  ## evaluate a policy (or POLICY=expert), print JSON
	$(PY) -m evaluation.evaluate $(flags)

robustness: $(STAMP)  ## a policy (or POLICY=expert) under every condition of the robustness suite
	$(PY) -m evaluation.robustness $(flags)

tune-walker: $(STAMP)  ## tune the walker's gait by CMA-ES on selection seeds (resumes RUN; writes OUT, the walker's gait file)
	$(PY) -m evaluation.tune_walker $(flags)

dagger: $(STAMP)  ## DAgger with the expert as oracle, on a copy of the dataset
	$(PY) -m bc.dagger $(flags)

finetune-rl: $(STAMP)  ## PPO refinement of the BC policy
	$(PY) -m rl.finetune $(flags) $(ARGS)

scratch-rl: $(STAMP)  ## PPO from scratch, same network and budget
	$(PY) -m rl.scratch $(flags) $(ARGS)

tutorial-rl: $(STAMP)  ## the seed tutorial's learners (preferred action, SB3 PPO), same budget
	$(PY) -m rl.tutorial $(flags)

# A target an earlier version had: refused in one line naming the new one, rather than make's "No rule".
baseline-rl:
	@echo "error: make baseline-rl is now make scratch-rl (PPO from scratch, same task and budget)" >&2; exit 2

# Reuses an output only if it was made from the same inputs (`python -m pipeline.run --help`).
pipeline: $(STAMP)  ## follow the operator: record schedules -> train-bc (with and without the command), dagger -> scratch-rl, finetune-rl -> the table
	$(PY) -m pipeline.run $(flags) $(ARGS)

# pytest-xdist: TEST_WORKERS processes, each taking whole test files (their module fixtures are built once);
# on these 2-core machines 2 finish first (docs/decisions/test-workers.md).
TEST_WORKERS ?= 2
test: $(STAMP)  ## run the whole test suite (about 6½ minutes on 2 cores; TEST_WORKERS processes)
	cd $(ROOT) && $(PY) -m pytest -n $(TEST_WORKERS) --dist loadfile

test-fast: $(STAMP)  ## the tests not marked slow, in one process (about 2 minutes)
	cd $(ROOT) && $(PY) -m pytest -m "not slow"

lint: $(STAMP)  ## ruff: lint and format check (configured in pyproject.toml)
	cd $(ROOT) && $(VENV)/bin/ruff check .
	cd $(ROOT) && $(VENV)/bin/ruff format --check .

lock: $(STAMP)  ## re-resolve requirements.lock from pyproject.toml at the newest allowed versions
	cd $(ROOT) && $(UV) pip compile pyproject.toml --extra dev --python-version 3.12 --generate-hashes --upgrade --quiet \
		--custom-compile-command "make lock" -o $(LOCK)

bench: $(STAMP)  ## run the benchmarks of docs/benchmarks.md (about 2 hours)
	$(PY) -m bench.expert_check --episodes 20 --noise 0 0.02 0.05
	$(PY) -m bench.record_throughput
	$(PY) -m bench.dagger_workers
	$(PY) -m bench.bc_benchmark
	$(PY) -m bench.data_efficiency
	$(PY) -m bench.latency_students
	$(PY) -m bench.live_cost
	$(PY) -m bench.camera_cost
	$(PY) -m bench.walker
	$(PY) -m bench.stepping
	$(PY) -m bench.posture_solves
	$(PY) -m bench.ppo_throughput
	$(PY) -m bench.training_seeds
	$(PY) -m bench.ray_backend
	$(PY) -m bench.shard_merge
	$(PY) -m bench.worker_overhead

# The flag reference is generated from the stages' configs, as `make help` is; tests/test_docs.py checks it is current.
.PHONY: docs
docs: $(STAMP)  ## regenerate docs/reference/flags.md from the stages' configs
	$(PY) -m pipeline.targets --markdown > $(ROOT)/docs/reference/flags.md.tmp
	mv $(ROOT)/docs/reference/flags.md.tmp $(ROOT)/docs/reference/flags.md

clean-venv:  ## remove .venv
	rm -rf $(VENV)
