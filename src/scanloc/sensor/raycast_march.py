"""The "march" exact caster: sphere tracing over a distance transform, as range_libc's ray
marching. From any point of a free cell a ray may advance by (distance between cell centres to
the nearest blocked cell - sqrt(2)) without touching a blocked cell; near obstacles it walks cell
by cell with exact boundary crossings. Its speed does not depend on how blocked cells are shaped.
Contract: scanloc.sensor.raycast.cast_exact.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from scipy.ndimage import distance_transform_edt

from scanloc.sensor.ray_grid import beam_direction

# A jump shorter than this many cells is not worth its floor() and lookup: walk instead.
_MIN_JUMP_CELLS = 1.0
# Kept off every obstacle after a jump (cells): far more than any rounding in the jump.
_JUMP_MARGIN_CELLS = 1e-3


def march_safe(blocked: np.ndarray) -> np.ndarray:
    """Per free cell the distance (cells) a ray may advance from any of its points; -1 blocked.

    A point p of cell c lies within sqrt(2)/2 of c's centre and every point q of a blocked
    cell b within sqrt(2)/2 of b's centre, so |p - q| >= |c - b| - sqrt(2).
    """
    if blocked.any():
        centre_dist = distance_transform_edt(~blocked)
    else:  # nothing to hit: rays end at the grid's edge or at range_max
        centre_dist = np.full(blocked.shape, float(sum(blocked.shape)))
    safe = np.maximum(centre_dist - math.sqrt(2.0) - _JUMP_MARGIN_CELLS, 0.0).astype(np.float32)
    # float32 rounding must not lengthen a jump (nextafter(0, 0) stays 0)
    safe = np.nextafter(safe, np.float32(0))
    return np.ascontiguousarray(np.where(blocked, np.float32(-1.0), safe))


@numba.njit(cache=True, error_model="numpy")
def _march(safe: np.ndarray, ox: float, oy: float, dx: float, dy: float, t_max: float) -> float:
    """Entry distance (cells) of the first blocked cell along o + t·d, or inf past t_max/grid."""
    height, width = safe.shape
    ix = math.floor(ox)
    iy = math.floor(oy)
    step_x = 1 if dx > 0 else -1
    step_y = 1 if dy > 0 else -1
    edge_x = 1 if dx > 0 else 0  # which side of the cell the ray leaves through
    edge_y = 1 if dy > 0 else 0
    inv_dx = 1.0 / dx
    inv_dy = 1.0 / dy
    t = 0.0
    while True:
        s = safe[iy, ix]
        if s < 0.0:
            return t
        if s >= _MIN_JUMP_CELLS:
            t += s
            if t > t_max:
                return np.inf
            ix = math.floor(ox + t * dx)
            iy = math.floor(oy + t * dy)
            # the jumped segment is clear and a convex grid is never re-entered
            if ix < 0 or ix >= width or iy < 0 or iy >= height:
                return np.inf
        else:
            # boundary crossings from the origin, not accumulated: exact to rounding; a cell
            # misidentified by floor() after a jump (only ever within rounding of a boundary,
            # and clear by the jump margin) is left again at once with no cell skipped
            tx = (ix + edge_x - ox) * inv_dx
            ty = (iy + edge_y - oy) * inv_dy
            if tx < ty:
                t = tx
                ix += step_x
                if ix < 0 or ix >= width:
                    return np.inf
            else:
                t = ty
                iy += step_y
                if iy < 0 or iy >= height:
                    return np.inf
            if t > t_max:
                return np.inf


@numba.njit(cache=True, parallel=True, error_model="numpy")
def cast_march_kernel(
    safe: np.ndarray,
    origin_x: float,
    origin_y: float,
    resolution: float,
    poses: np.ndarray,
    angles: np.ndarray,
    range_max: float,
    out: np.ndarray,
) -> None:
    """Ranges of every beam of every pose into `out` (N, B) metres, +inf past range_max."""
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
            out[i, j] = _march(safe, ox, oy, dx, dy, t_max) * resolution
