# Two entry points on a fresh machine (each sets up .venv first):
#   make repro      set up, then run the whole pipeline (sites.yaml from params.yaml, then
#                   `dvc repro`, profile from params.yaml)
#   make test       set up, then the fast suite: unit and contract tests (minutes on 2 cores);
#                   run it before every commit
# Before a release, and in CI (.ci/run):
#   make test-all   everything: the fast suite, the slow tests (DDP spawn, torch.compile
#                   equivalence, launcher sweeps, ...) and the end-to-end ones (a smoke
#                   `dvc repro` in a copy, docs/experiments.md's sweeps, dvc.lock against the tree)
#   make test-slow / make test-e2e   one of those two kinds alone
# The tests run in parallel (pytest-xdist, one worker per core, one file per worker at a time:
# module fixtures are built once), in collection order, not xdist's largest-file-first: the
# longest file (the smoke repro) goes first (tests/conftest.py); `make test XDIST=` runs them
# in one process.
PYTHON ?= python3
VENV := .venv
BIN := $(abspath $(VENV)/bin)
# The CPU build of torch first: a bare `torch` requirement can pull a CUDA build of several GB.
TORCH_SPEC ?= torch==2.13.0
XDIST ?= -n auto --dist loadfile --no-loadscope-reorder
PYTEST := PATH="$(BIN):$$PATH" python -m pytest $(XDIST)

.PHONY: setup repro sites readme test test-slow test-e2e test-all lint bench

setup: $(VENV)/.ready

$(VENV)/.ready: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet "$(TORCH_SPEC)"
	$(BIN)/python -m pip install --quiet -e ".[dev]"
	touch $@

# sites.yaml first: the sites and jobs of params.yaml written down for dvc.yaml (scanloc.sites).
repro: setup sites
	PATH="$(BIN):$$PATH" dvc repro

sites: setup
	$(BIN)/python -m scanloc.sites

# The README's results table from the committed metrics (reports/summary.json); after a repro
# whose metrics are committed (tests/test_committed_metrics.py checks the two agree).
readme: setup
	$(BIN)/python -m scanloc.report.readme_results README.md

# The markers' default selection (pyproject.toml addopts): not slow and not e2e.
test: setup
	$(PYTEST)

test-slow: setup
	$(PYTEST) -m slow

test-e2e: setup
	$(PYTEST) -m e2e

# -m "": no marker filter, so every test runs (one pytest run keeps both cores busy).
test-all: setup
	$(PYTEST) -m ""

# ruff, and the import contracts of pyproject.toml [tool.importlinter] (layers, no cycles).
lint: setup
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks
	$(BIN)/lint-imports --no-cache

bench: setup
	for b in benchmarks/*.py; do PATH="$(BIN):$$PATH" python $$b || exit 1; done
