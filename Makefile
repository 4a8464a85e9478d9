# humanoid-bc: every target builds .venv on first use (Python >= 3.12 from the package registries).
# Stage settings are Make variables passed on as flags; an empty one leaves the stage's default
# (`python -m teleop.record --help`, `python -m bc.train --help`, `python -m bc.evaluate --help`).
SHELL := /bin/bash
.DEFAULT_GOAL := help

VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
UV := $(VENV)/bin/uv
LOCK := requirements.lock
UV_VERSION = $(shell sed -n 's/^uv==\([^ ]*\).*/\1/p' $(LOCK))
# First interpreter >= 3.12 found: on PATH, then pyenv's versions (a pyenv shim alone may refuse).
PYTHON312 ?= $(shell for p in python3.12 python3.13 python3 $(HOME)/.pyenv/versions/3.1[2-9]*/bin/python3; do \
	command -v $$p >/dev/null 2>&1 && $$p -c 'import sys; sys.exit(sys.version_info < (3, 12))' 2>/dev/null \
	&& { command -v $$p; break; }; done)

export HF_HUB_OFFLINE := 1
export HF_DATASETS_OFFLINE := 1
export MUJOCO_GL ?= egl
export PYTHONUNBUFFERED := 1

# The pipeline's folders (the stages' own defaults are the same; a test checks it). POLICY is each
# stage's output (or, for eval, its input): empty means that stage's default folder below.
DATASET ?= datasets/humanoid_stand
BC_DEFAULT := policies/bc_humanoid_stand
PPO_DEFAULT := policies/ppo_humanoid_stand
SCRATCH_DEFAULT := policies/ppo_scratch_humanoid_stand
POLICY ?=
BC_POLICY ?= $(BC_DEFAULT)
EPISODES ?=
SEED ?=
CONTROLLER ?=
NOISE ?=
MAX_STEPS ?=
PUSH ?=
VIDEO ?=
EPOCHS ?=
OVERWRITE ?=
ROUNDS ?=
TIMESTEPS ?=
WORKERS ?=
ENVS ?=
PLOT ?=
# Any other flag of the PPO stages (`python -m bc.finetune --help`), e.g. ARGS="--learning-rate 1e-4 --keep last"
ARGS ?=

opt = $(if $($(1)),--$(2) $($(1)))
RECORD_ARGS = --dataset $(DATASET) $(call opt,EPISODES,episodes) $(call opt,SEED,seed) \
	$(call opt,CONTROLLER,controller) $(call opt,NOISE,noise) $(call opt,MAX_STEPS,max-steps) $(call opt,WORKERS,workers)
TRAIN_ARGS = --dataset $(DATASET) --policy $(or $(POLICY),$(BC_DEFAULT)) $(call opt,EPOCHS,epochs) \
	$(call opt,OVERWRITE,overwrite)
DAGGER_ARGS = --dataset $(DATASET) $(call opt,ROUNDS,rounds) $(call opt,EPISODES,episodes) \
	$(call opt,OVERWRITE,overwrite)
RL_ARGS = --bc-policy $(BC_POLICY) $(call opt,TIMESTEPS,timesteps) $(call opt,WORKERS,workers) $(call opt,ENVS,envs) \
	$(call opt,PUSH,push) $(call opt,OVERWRITE,overwrite) $(ARGS)
EVAL_ARGS = --policy $(or $(POLICY),$(BC_DEFAULT)) $(call opt,EPISODES,episodes) $(call opt,SEED,seed) $(call opt,PUSH,push) \
	$(call opt,NOISE,noise) $(call opt,VIDEO,video)

.PHONY: help venv record inspect train-bc eval dagger finetune-rl baseline-rl pipeline test test-fast lint lock bench clean-venv

help:  ## list the targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-12s %s\n", $$1, $$2}'

# Installed from the lock (exact versions and hashes), never by resolving pyproject.toml afresh;
# `make lock` re-resolves it. uv installs (pinned to the lock's own uv); pip only bootstraps it.
$(STAMP): $(LOCK) pyproject.toml
	@test -n "$(PYTHON312)" || { echo "error: no Python >= 3.12 found (set PYTHON312=/path/to/python3.12)" >&2; exit 1; }
	@test -x $(PY) || $(PYTHON312) -m venv $(VENV)
	$(PY) -m pip install --quiet uv==$(UV_VERSION)
	$(UV) pip install --quiet --python $(PY) --require-hashes -r $(LOCK)
	$(UV) pip install --quiet --python $(PY) --no-deps -e .
	@touch $@

venv: $(STAMP)  ## build .venv and install the project

record: $(STAMP)  ## record demonstrations: DATASET EPISODES SEED CONTROLLER NOISE MAX_STEPS WORKERS
	$(PY) -m teleop.record $(RECORD_ARGS)

inspect: $(STAMP)  ## summarise and verify a dataset (LeRobot + MCAP); PLOT=1 writes DATASET/inspect.png: DATASET PLOT
	$(PY) -m teleop.inspect_dataset --dataset $(DATASET) $(call opt,PLOT,plot)

train-bc: $(STAMP)  ## behaviour cloning, then evaluation: DATASET POLICY EPOCHS OVERWRITE
	$(PY) -m bc.train $(TRAIN_ARGS)

eval: $(STAMP)  ## evaluate a policy (or POLICY=expert): POLICY EPISODES SEED PUSH NOISE VIDEO
	$(PY) -m bc.evaluate $(EVAL_ARGS)

dagger: $(STAMP)  ## DAgger with the expert as oracle: DATASET ROUNDS EPISODES OVERWRITE
	$(PY) -m bc.dagger $(DAGGER_ARGS)

finetune-rl: $(STAMP)  ## PPO refinement of the BC policy: BC_POLICY POLICY TIMESTEPS WORKERS ENVS PUSH OVERWRITE ARGS
	$(PY) -m bc.finetune --policy $(or $(POLICY),$(PPO_DEFAULT)) $(RL_ARGS)

baseline-rl: $(STAMP)  ## PPO from scratch, same network and budget: POLICY TIMESTEPS WORKERS ENVS PUSH OVERWRITE ARGS
	$(PY) -m bc.baseline --policy $(or $(POLICY),$(SCRATCH_DEFAULT)) $(RL_ARGS)

# Each stage runs only if its output is missing, so the pipeline can be re-run (or resumed)
# without growing the dataset or refusing to overwrite the checkpoint.
pipeline: $(STAMP)  ## record -> train-bc -> baseline-rl -> finetune-rl, then the table (existing outputs are reused)
	@if [ -f $(DATASET)/meta/info.json ]; then echo "pipeline: $(DATASET) exists, not recording"; \
	else $(MAKE) --no-print-directory record; fi
	@if [ -f $(BC_DEFAULT)/eval.json ]; then echo "pipeline: $(BC_DEFAULT) exists, not training"; \
	else $(MAKE) --no-print-directory train-bc POLICY=$(BC_DEFAULT); fi
	@if [ -f $(SCRATCH_DEFAULT)/eval.json ]; then echo "pipeline: $(SCRATCH_DEFAULT) exists, not training"; \
	else $(MAKE) --no-print-directory baseline-rl POLICY=$(SCRATCH_DEFAULT) BC_POLICY=$(BC_DEFAULT); fi
	@if [ -f $(PPO_DEFAULT)/eval.json ]; then echo "pipeline: $(PPO_DEFAULT) exists, not fine-tuning"; \
	else $(MAKE) --no-print-directory finetune-rl POLICY=$(PPO_DEFAULT) BC_POLICY=$(BC_DEFAULT); fi
	@$(PY) -m bc.report $(BC_DEFAULT) $(PPO_DEFAULT) $(SCRATCH_DEFAULT)

test: $(STAMP)  ## run the whole test suite (a few minutes)
	$(PY) -m pytest

test-fast: $(STAMP)  ## the tests that take well under a second each (under 30 s in all)
	$(PY) -m pytest -m "not slow"

lint: $(STAMP)  ## ruff: lint and format check (configured in pyproject.toml)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

lock: $(STAMP)  ## re-resolve requirements.lock from pyproject.toml at the newest allowed versions
	$(UV) pip compile pyproject.toml --extra dev --python-version 3.12 --generate-hashes --upgrade --quiet \
		--custom-compile-command "make lock" -o $(LOCK)

bench: $(STAMP)  ## run the benchmarks whose figures are in the README
	$(PY) -m bench.expert_check --episodes 20 --noise 0 0.02 0.05
	$(PY) -m bench.record_throughput
	$(PY) -m bench.bc_benchmark
	$(PY) -m bench.ppo_throughput

clean-venv:  ## remove .venv
	rm -rf $(VENV)
