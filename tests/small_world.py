"""The small world the localizer tests drive in: a 6 m x 5 m asymmetric room and URG-04LX
scans with UG01-like noise. One definition for conftest.py's fixtures and the test modules
that need the room at import time."""

from __future__ import annotations

import numpy as np

from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.raycast import CastMap, cast_exact
from scanloc.world.occupancy_grid import OCCUPIED, OccupancyGrid

SPEC = LaserSpec()  # the URG-04LX the localizer tests simulate


def small_map(res: float = 0.05) -> OccupancyGrid:
    """A 6 m x 5 m room with an L-shaped wall, a wall stub and a block: no symmetry, so a
    localizer can converge to one pose (a fresh grid per call, free to edit)."""
    cells = np.zeros((round(5.0 / res), round(6.0 / res)), dtype=np.int8)
    for x0, y0, x1, y1 in [
        (0, 0, 6, 0.1),
        (0, 4.9, 6, 5),
        (0, 0, 0.1, 5),
        (5.9, 0, 6, 5),
        (1.5, 1.2, 1.6, 3.4),
        (1.5, 3.3, 2.8, 3.4),
        (4.0, 0.1, 4.1, 1.8),
        (3.8, 3.0, 4.6, 3.6),
    ]:
        cells[round(y0 / res) : round(y1 / res), round(x0 / res) : round(x1 / res)] = OCCUPIED
    return OccupancyGrid(cells, res)


def ug01_scans(grid: OccupancyGrid, poses: np.ndarray, seed: int) -> np.ndarray:
    """URG-04LX scans of `grid` at `poses` (N, 3): exact ranges with UG01-like noise (1σ 30 mm
    under 1 m, 3 % beyond), no return = 7.0."""
    exact = cast_exact(CastMap.from_grid(grid), poses, SPEC.beam_angles(), SPEC.range_max)
    hit = np.isfinite(exact)
    r = np.where(hit, exact, 0.0)
    sigma = np.where(r < 1.0, 0.03, 0.03 * r)
    noisy = r + sigma * np.random.default_rng(seed).standard_normal(r.shape)
    noisy = np.clip(noisy, SPEC.range_min, SPEC.range_max)
    return np.where(hit, noisy, SPEC.no_return_value).astype(np.float32)
