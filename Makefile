# humanoid-bc: every target builds .venv on first use (Python >= 3.12 from the package registries).
# Stage settings are Make variables passed on as flags; an empty one leaves the stage's default
# (`python -m teleop.record --help`, `python -m bc.train --help`, `python -m bc.evaluate --help`).
SHELL := /bin/bash
.DEFAULT_GOAL := help

VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# First interpreter >= 3.12 found: on PATH, then pyenv's versions (a pyenv shim alone may refuse).
PYTHON312 ?= $(shell for p in python3.12 python3.13 python3 $(HOME)/.pyenv/versions/3.1[2-9]*/bin/python3; do \
	command -v $$p >/dev/null 2>&1 && $$p -c 'import sys; sys.exit(sys.version_info < (3, 12))' 2>/dev/null \
	&& { command -v $$p; break; }; done)

export HF_HUB_OFFLINE := 1
export HF_DATASETS_OFFLINE := 1
export MUJOCO_GL ?= egl
export PYTHONUNBUFFERED := 1

# The pipeline's folders (the stages' own defaults are the same).
DATASET ?= datasets/humanoid_stand
POLICY ?= policies/bc_humanoid_stand
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

opt = $(if $($(1)),--$(2) $($(1)))
RECORD_ARGS = --dataset $(DATASET) $(call opt,EPISODES,episodes) $(call opt,SEED,seed) \
	$(call opt,CONTROLLER,controller) $(call opt,NOISE,noise) $(call opt,MAX_STEPS,max-steps)
TRAIN_ARGS = --dataset $(DATASET) --policy $(POLICY) $(call opt,EPOCHS,epochs) $(call opt,OVERWRITE,overwrite)
DAGGER_ARGS = --dataset $(DATASET) $(call opt,ROUNDS,rounds) $(call opt,EPISODES,episodes) \
	$(call opt,OVERWRITE,overwrite)
EVAL_ARGS = --policy $(POLICY) $(call opt,EPISODES,episodes) $(call opt,SEED,seed) $(call opt,PUSH,push) \
	$(call opt,NOISE,noise) $(call opt,VIDEO,video)

.PHONY: help venv record train-bc eval dagger pipeline test bench clean-venv

help:  ## list the targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-12s %s\n", $$1, $$2}'

$(STAMP): pyproject.toml
	@test -n "$(PYTHON312)" || { echo "error: no Python >= 3.12 found (set PYTHON312=/path/to/python3.12)" >&2; exit 1; }
	@test -x $(PY) || $(PYTHON312) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	@touch $@

venv: $(STAMP)  ## build .venv and install the project

record: $(STAMP)  ## record demonstrations: DATASET EPISODES SEED CONTROLLER NOISE MAX_STEPS
	$(PY) -m teleop.record $(RECORD_ARGS)

train-bc: $(STAMP)  ## behaviour cloning, then evaluation: DATASET POLICY EPOCHS OVERWRITE
	$(PY) -m bc.train $(TRAIN_ARGS)

eval: $(STAMP)  ## evaluate a policy (or POLICY=expert): POLICY EPISODES SEED PUSH NOISE VIDEO
	$(PY) -m bc.evaluate $(EVAL_ARGS)

dagger: $(STAMP)  ## DAgger with the expert as oracle: DATASET ROUNDS EPISODES OVERWRITE
	$(PY) -m bc.dagger $(DAGGER_ARGS)

# Each stage runs only if its output is missing, so the pipeline can be re-run (or resumed)
# without growing the dataset or refusing to overwrite the checkpoint.
pipeline: $(STAMP)  ## record -> train-bc at their default sizes (stages whose output exists are skipped)
	@if [ -f $(DATASET)/meta/info.json ]; then echo "pipeline: $(DATASET) exists, not recording"; \
	else $(MAKE) --no-print-directory record; fi
	@if [ -f $(POLICY)/model.safetensors ]; then echo "pipeline: $(POLICY) exists, not training"; \
	else $(MAKE) --no-print-directory train-bc; fi
	@$(PY) -m bc.report $(POLICY)

test: $(STAMP)  ## run the test suite
	$(PY) -m pytest

bench: $(STAMP)  ## run the benchmarks whose figures are in the README
	$(PY) -m bench.expert_check --episodes 20 --noise 0 0.02 0.05
	$(PY) -m bench.record_throughput
	$(PY) -m bench.bc_benchmark

clean-venv:  ## remove .venv
	rm -rf $(VENV)
