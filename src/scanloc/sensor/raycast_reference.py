"""The plain reference caster: Amanatides & Woo's (1987) cell-by-cell traversal, the textbook
method that the exact casters of scanloc.sensor.raycast are tested against."""

from __future__ import annotations

import math

import numba
import numpy as np

from scanloc.sensor.ray_grid import beam_direction, blocked_mask, check_cast_inputs
from scanloc.world.occupancy_grid import OccupancyGrid


@numba.njit(cache=True, error_model="numpy")
def _traverse(
    blocked: np.ndarray, ox: float, oy: float, dx: float, dy: float, t_max: float
) -> float:
    """Amanatides & Woo's traversal, cell by cell: the textbook method, no shortcuts."""
    height, width = blocked.shape
    ix = math.floor(ox)
    iy = math.floor(oy)
    if blocked[iy, ix]:
        return 0.0
    step_x = 1 if dx > 0 else -1
    step_y = 1 if dy > 0 else -1
    delta_x = abs(1.0 / dx)
    delta_y = abs(1.0 / dy)
    next_x = (ix + (1 if dx > 0 else 0) - ox) / dx
    next_y = (iy + (1 if dy > 0 else 0) - oy) / dy
    while True:
        if next_x < next_y:
            t = next_x
            next_x += delta_x
            ix += step_x
        else:
            t = next_y
            next_y += delta_y
            iy += step_y
        if t > t_max or ix < 0 or ix >= width or iy < 0 or iy >= height:
            return np.inf
        if blocked[iy, ix]:
            return t


@numba.njit(cache=True, parallel=True, error_model="numpy")
def _cast_reference_kernel(
    blocked: np.ndarray,
    origin_x: float,
    origin_y: float,
    resolution: float,
    poses: np.ndarray,
    angles: np.ndarray,
    range_max: float,
    out: np.ndarray,
) -> None:
    cos_a = np.cos(angles)
    sin_a = np.sin(angles)
    t_max = range_max / resolution
    for i in numba.prange(poses.shape[0]):
        ox = (poses[i, 0] - origin_x) / resolution
        oy = (poses[i, 1] - origin_y) / resolution
        cos_t = math.cos(poses[i, 2])
        sin_t = math.sin(poses[i, 2])
        for j in range(angles.shape[0]):
            dx, dy = beam_direction(cos_t, sin_t, cos_a[j], sin_a[j])
            out[i, j] = _traverse(blocked, ox, oy, dx, dy, t_max) * resolution


def cast_reference(
    grid: OccupancyGrid,
    poses: np.ndarray,
    angles: np.ndarray,
    range_max: float,
    unknown_blocks: bool = False,
) -> np.ndarray:
    """The plain cell-by-cell traversal; same contract and results as `cast_exact`."""
    origin_xy = (float(grid.origin[0]), float(grid.origin[1]))
    poses, angles = check_cast_inputs(grid.cells.shape, grid.resolution, origin_xy, poses, angles)
    blocked = np.ascontiguousarray(blocked_mask(grid, unknown_blocks))
    out = np.empty((poses.shape[0], angles.shape[0]), dtype=np.float64)
    _cast_reference_kernel(
        blocked, *origin_xy, float(grid.resolution), poses, angles, float(range_max), out
    )
    return out
