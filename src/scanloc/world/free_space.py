"""Robot poses drawn uniformly over a map's free space, with the robot's footprint clear.

A position is valid when no occupied or unknown cell (and nothing outside the grid) lies
within `clearance_radius` of it, i.e. a disc robot of that radius centred there touches only
free cells. Positions are uniform over the valid region of the plane, headings uniform in
(-pi, pi].

The radius is the caller's choice. STDR's robot creator gives a new robot a 0.15 m footprint
radius (stdr_gui robot_creator_connector.cpp); the paper's "simple robot" is not specified
further. STDR refused to place a robot whose footprint touched an occupied cell or whose
centre was unknown; we also keep unknown cells out of the footprint, so that no scan is taken
from where the map does not say the robot could stand.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from scipy.ndimage import distance_transform_edt

from scanloc.world.occupancy_grid import OccupancyGrid

# Give up when this many candidate points in a row fail the exact clearance test.
_MAX_FRUITLESS_DRAWS = 1_000_000


def centre_clearance(grid: OccupancyGrid) -> np.ndarray:
    """Distance (cells) from each cell centre to the nearest non-free cell centre, counting a
    ring of non-free cells around the grid (the outside is not free)."""
    padded = np.pad(grid.free, 1, constant_values=False)
    return distance_transform_edt(padded)[1:-1, 1:-1]


@numba.njit(cache=True)
def _clear(free: np.ndarray, px: np.ndarray, py: np.ndarray, radius: float) -> np.ndarray:
    """Exact test per point (cell units): is every cell square within `radius` free?"""
    height, width = free.shape
    ok = np.ones(px.shape[0], dtype=np.bool_)
    reach = math.ceil(radius) + 1
    for k in range(px.shape[0]):
        cx = math.floor(px[k])
        cy = math.floor(py[k])
        for row in range(cy - reach, cy + reach + 1):
            gap_y = max(row - py[k], 0.0, py[k] - (row + 1))
            for col in range(cx - reach, cx + reach + 1):
                if 0 <= row < height and 0 <= col < width and free[row, col]:
                    continue
                gap_x = max(col - px[k], 0.0, px[k] - (col + 1))
                if gap_x * gap_x + gap_y * gap_y < radius * radius:
                    ok[k] = False
                    break
            if not ok[k]:
                break
    return ok


def sample_free_poses(
    grid: OccupancyGrid,
    n: int,
    clearance_radius: float,
    rng: np.random.Generator,
    map_name: str = "<unnamed>",
) -> np.ndarray:
    """n poses (x, y, θ) float64 (n, 3), uniform over the positions with `clearance_radius` (m)
    of free space around them, θ uniform in (-pi, pi].

    Cells that may hold a valid point are drawn uniformly, then a uniform point inside the
    cell; points failing the exact clearance test are redrawn (rejection keeps uniformity).
    """
    if n < 0:
        raise ValueError(f"number of poses must be >= 0, got {n}")
    if not (math.isfinite(clearance_radius) and clearance_radius >= 0):
        raise ValueError(f"clearance_radius must be a finite number >= 0, got {clearance_radius}")
    radius = clearance_radius / grid.resolution
    clearance = centre_clearance(grid)
    # a point of cell c is at most sqrt(2)/2 from c's centre, a non-free square at most
    # sqrt(2)/2 from its own centre: below radius - sqrt(2)/2 no point of c can be valid, at
    # radius + sqrt(2) or more every point is
    maybe = grid.free & (clearance >= radius - math.sqrt(0.5))
    candidates = np.flatnonzero(maybe)
    if candidates.size == 0:
        raise ValueError(f"map {map_name} has no free cell with clearance {clearance_radius} m")
    surely = (clearance >= radius + math.sqrt(2.0)).ravel()
    free = np.ascontiguousarray(grid.free)
    width = grid.width
    xs: list[np.ndarray] = [np.empty(0)]
    ys: list[np.ndarray] = [np.empty(0)]
    found = 0
    fruitless = 0
    while found < n:
        batch = max(1024, 2 * (n - found))
        cells = candidates[rng.integers(candidates.size, size=batch)]
        px = cells % width + rng.random(batch)
        py = cells // width + rng.random(batch)
        ok = surely[cells]
        check = ~ok
        ok[check] = _clear(free, px[check], py[check], radius)
        px, py = px[ok][: n - found], py[ok][: n - found]
        xs.append(px)
        ys.append(py)
        found += px.size
        fruitless = 0 if px.size else fruitless + batch
        if fruitless >= _MAX_FRUITLESS_DRAWS:
            raise ValueError(
                f"map {map_name} has no free cell with clearance {clearance_radius} m "
                f"(no valid point in {fruitless} draws)"
            )
    x = grid.origin[0] + np.concatenate(xs) * grid.resolution
    y = grid.origin[1] + np.concatenate(ys) * grid.resolution
    theta = math.pi - 2.0 * math.pi * rng.random(n)  # random() is in [0, 1): theta in (-pi, pi]
    return np.column_stack([x, y, theta])
