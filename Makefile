# humanoid-bc: every target builds .venv on first use (Python >= 3.12 from the package registries).
SHELL := /bin/bash
.DEFAULT_GOAL := help

VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# First interpreter >= 3.12 found: PATH, then pyenv's versions (the pyenv shim alone may refuse).
PYTHON312 ?= $(shell for p in python3.12 python3.13 $(HOME)/.pyenv/versions/3.1[2-9]*/bin/python3; do \
	command -v $$p >/dev/null 2>&1 && $$p -c 'import sys; sys.exit(sys.version_info < (3, 12))' 2>/dev/null && { command -v $$p; break; }; done)

export HF_HUB_OFFLINE := 1
export HF_DATASETS_OFFLINE := 1
export MUJOCO_GL ?= egl
export PYTHONUNBUFFERED := 1

# Stage variables: empty means "use the default in the stage's config dataclass".
DATASET ?=
EPISODES ?=
SEED ?=
CONTROLLER ?=
NOISE ?=
MAX_STEPS ?=

opt = $(if $($(1)),--$(2) $($(1)))
RECORD_ARGS = $(call opt,DATASET,dataset) $(call opt,EPISODES,episodes) $(call opt,SEED,seed) \
	$(call opt,CONTROLLER,controller) $(call opt,NOISE,noise) $(call opt,MAX_STEPS,max-steps)

.PHONY: help venv record pipeline test bench clean-venv

help:  ## list the targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-14s %s\n", $$1, $$2}'

$(STAMP): pyproject.toml
	@test -n "$(PYTHON312)" || { echo "error: no Python >= 3.12 found (set PYTHON312=/path/to/python3.12)" >&2; exit 1; }
	@test -x $(PY) || $(PYTHON312) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	@touch $@

venv: $(STAMP)  ## build .venv and install the project

record: $(STAMP)  ## record demonstrations: DATASET EPISODES SEED CONTROLLER NOISE
	$(PY) -m teleop.record $(RECORD_ARGS)

pipeline: record  ## the whole pipeline at its default sizes

test: $(STAMP)  ## run the test suite
	$(PY) -m pytest

bench: $(STAMP)  ## run the benchmarks (figures for the README)
	$(PY) -m bench.record_throughput

clean-venv:  ## remove .venv
	rm -rf $(VENV)
