"""Shared fixtures: where the paper's STDR maps live, small worlds built in memory (a walled box,
the asymmetric room the localizer tests drive in) with UG01-like scans and drives, a tiny scan
dataset for training tests, and the benchmarks' quick runs."""

from __future__ import annotations

import copy
import json
import os
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from scanloc.trajectory.drive import drive_trajectory
from scanloc.trajectory.format import Trajectory
from scanloc.world.occupancy_grid import FREE, OCCUPIED, OccupancyGrid
from small_world import small_map, ug01_scans
from synthetic_scans import write_synthetic_scans

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO_ROOT.parent / "shared" / "data" / "stdr_maps"

WalledRoom = Callable[[float, float, float], OccupancyGrid]
Ug01Scans = Callable[[OccupancyGrid, np.ndarray, int], np.ndarray]
Drive = Callable[..., tuple[Trajectory, np.ndarray]]


def pytest_configure(config: pytest.Config) -> None:
    """Under pytest-xdist every worker trains its tiny models on one torch thread: two workers
    with a thread per core each would spin in OpenMP barriers against each other."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        torch.set_num_threads(1)


# The critical path of `make test-all`: the smoke `dvc repro` of this file takes most of CI's
# time on one worker. pytest-xdist (--dist loadfile --no-loadscope-reorder, the Makefile) hands
# out whole files in collection order, so the longest go first (longest-processing-time-first):
# this file, the other end-to-end ones, the slow ones; the fast suite fills the other worker.
# (xdist's own reorder puts the files with the most tests first: the smoke repro started last.)
CRITICAL_PATH = "test_pipeline_e2e.py"


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    def rank(item: pytest.Item) -> int:
        if item.path.name == CRITICAL_PATH:
            return 0
        if item.get_closest_marker("e2e"):
            return 1
        return 2 if item.get_closest_marker("slow") else 3

    items.sort(key=rank)  # stable: each file's tests keep their order


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


# ---------------------------------------------------------------- small worlds


def _walled_room(width: float, height: float, resolution: float) -> OccupancyGrid:
    cells = np.full((round(height / resolution), round(width / resolution)), FREE, np.int8)
    cells[[0, -1], :] = OCCUPIED
    cells[:, [0, -1]] = OCCUPIED
    return OccupancyGrid(cells, resolution)


@pytest.fixture(scope="session")
def walled_room() -> WalledRoom:
    """walled_room(width_m, height_m, resolution): a box of free space whose border cells are
    wall (a fresh grid per call, free to edit)."""
    return _walled_room


@pytest.fixture(scope="session")
def room() -> OccupancyGrid:
    """A 6 m x 5 m room at 0.05 m with an L-shaped wall, a wall stub and a block: no symmetry,
    so a localizer can converge to one pose (read-only: copy `cells` to edit)."""
    grid = small_map()
    grid.cells.setflags(write=False)  # shared by every test of the session
    return grid


@pytest.fixture(scope="session", name="ug01_scans")
def ug01_scans_fixture() -> Ug01Scans:
    """ug01_scans(grid, poses, seed): URG-04LX scans of `grid` at `poses` (N, 3), exact ranges
    with UG01-like noise (1σ 30 mm under 1 m, 3 % beyond), no return = 7.0."""
    return ug01_scans


@pytest.fixture(scope="session")
def drive(room: OccupancyGrid) -> Drive:
    """drive(steps, seed=..., scan_seed=..., **drive_trajectory options) -> (trajectory, UG01
    scans) in `room`. Each distinct drive is simulated once per session; every call gets its
    own copy, free to edit."""
    made: dict[tuple[Any, ...], tuple[Trajectory, np.ndarray]] = {}

    def make(
        steps: int, *, seed: int, scan_seed: int, **options: Any
    ) -> tuple[Trajectory, np.ndarray]:
        key = (steps, seed, scan_seed, *sorted(options.items()))
        if key not in made:
            traj = drive_trajectory(room, steps, seed=seed, **options)
            made[key] = traj, ug01_scans(room, traj.truth, scan_seed)
        traj, ranges = made[key]
        return copy.deepcopy(traj), ranges.copy()

    return make
