"""Shared fixtures: where the paper's STDR maps live, small worlds built in memory, a tiny scan
dataset for training tests, and the benchmarks' quick runs."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import torch

from synthetic_scans import write_synthetic_scans

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO_ROOT.parent / "shared" / "data" / "stdr_maps"


@pytest.fixture(scope="session")
def stdr_maps_dir() -> Path:
    """The STDR originals (GPL-3, never copied into the repo); skip when ../shared is absent."""
    if not (SHARED_DATA / "sparse_obstacles.yaml").is_file():
        pytest.skip(f"STDR maps not available at {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture(scope="module")
def one_torch_thread() -> Iterator[None]:
    """Tiny models train fastest on one thread, which also keeps OpenMP barriers from
    stalling when other processes share the cores. Modules opt in with
    `pytestmark = pytest.mark.usefixtures("one_torch_thread")`."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def scans(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """256 synthetic 64-beam scans in the dataset format (tests/synthetic_scans.py)."""
    return write_synthetic_scans(tmp_path_factory.mktemp("scans") / "tiny", count=256, beams=64)


@pytest.fixture
def quick_benchmark() -> Callable[[str], dict]:
    """Run benchmarks/<script> --quick in a subprocess; its figures (the JSON last line)."""

    def run(script: str) -> dict:
        out = subprocess.run(
            [sys.executable, str(REPO_ROOT / "benchmarks" / script), "--quick"],
            check=True,
            capture_output=True,
            text=True,
            timeout=300,
        )
        return json.loads(out.stdout.strip().splitlines()[-1])

    return run
