"""What every laser ray caster shares (scanloc.sensor.raycast and its siblings): which cells
stop a beam, the checks on poses and beam angles, and a beam's direction in the grid."""

from __future__ import annotations

import math

import numba
import numpy as np

from scanloc.sensor.laser import ANGLE_SLACK_RAD
from scanloc.world.occupancy_grid import OccupancyGrid


def blocked_mask(grid: OccupancyGrid, unknown_blocks: bool = False) -> np.ndarray:
    """Cells that stop a beam: occupied ones, plus unknown ones when `unknown_blocks`."""
    return grid.occupied | grid.unknown if unknown_blocks else grid.occupied


def check_cast_inputs(
    grid_shape: tuple[int, ...],
    resolution: float,
    origin_xy: tuple[float, float],
    poses: np.ndarray,
    angles: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Poses (N, 3) and beam angles (B,) as contiguous float64, or ValueError saying what is
    wrong: shapes, ascending angles within [-pi, pi], finite poses inside the grid."""
    poses = np.ascontiguousarray(poses, dtype=np.float64)
    angles = np.ascontiguousarray(angles, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValueError(f"poses must have shape (N, 3), got {poses.shape}")
    if angles.ndim != 1 or angles.size == 0:
        raise ValueError(f"beam angles must have shape (B,) with B >= 1, got {angles.shape}")
    limit = math.pi + ANGLE_SLACK_RAD
    if not (np.all(np.diff(angles) >= 0) and angles[0] >= -limit and angles[-1] <= limit):
        raise ValueError(
            f"beam angles must be ascending and within [-pi, pi], got {angles[0]!r} to "
            f"{angles[-1]!r} rad"
        )
    if not np.isfinite(poses).all():
        raise ValueError("poses must be finite")
    height, width = grid_shape
    col = (poses[:, 0] - origin_xy[0]) / resolution
    row = (poses[:, 1] - origin_xy[1]) / resolution
    outside = (col < 0) | (col >= width) | (row < 0) | (row >= height)
    if outside.any():
        first = int(np.flatnonzero(outside)[0])
        raise ValueError(
            f"{int(outside.sum())} pose(s) lie outside the grid, first: index {first} at "
            f"({poses[first, 0]:.4f}, {poses[first, 1]:.4f})"
        )
    return poses, angles


@numba.njit(inline="always")
def beam_direction(cos_t: float, sin_t: float, cos_a: float, sin_a: float) -> tuple[float, float]:
    """Unit direction of beam angle a on heading t, shared by all exact casters.

    A zero component becomes 1e-300, so that no caster needs a division-by-zero branch: the
    boundary crossings along that axis move to ~1e300 cells, i.e. never.
    """
    dx = cos_t * cos_a - sin_t * sin_a
    dy = sin_t * cos_a + cos_t * sin_a
    if dx == 0.0:
        dx = 1e-300
    if dy == 0.0:
        dy = 1e-300
    return dx, dy
