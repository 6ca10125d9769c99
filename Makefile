# Two entry points on a fresh machine (each sets up .venv first):
#   make repro   set up, then run the whole pipeline (`dvc repro`, profile from params.yaml)
#   make test    set up, then run the test suite (fast: the slow tests are deselected)
# CI (.ci/run) also runs `make test-slow` (DDP spawn, torch.compile equivalence, ...).
PYTHON ?= python3
VENV := .venv
BIN := $(abspath $(VENV)/bin)
# The CPU build of torch first: a bare `torch` requirement can pull a CUDA build of several GB.
TORCH_SPEC ?= torch==2.13.0

.PHONY: setup repro test test-slow lint bench

setup: $(VENV)/.ready

$(VENV)/.ready: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet "$(TORCH_SPEC)"
	$(BIN)/python -m pip install --quiet -e ".[dev]"
	touch $@

repro: setup
	PATH="$(BIN):$$PATH" dvc repro

test: setup
	PATH="$(BIN):$$PATH" python -m pytest

test-slow: setup
	PATH="$(BIN):$$PATH" python -m pytest -m slow

lint: setup
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks

bench: setup
	for b in benchmarks/*.py; do PATH="$(BIN):$$PATH" python $$b || exit 1; done
