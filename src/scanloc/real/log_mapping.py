"""An occupancy grid from a log with known (corrected) laser poses: log-odds mapping.

Thrun, Burgard & Fox, Probabilistic Robotics, ch. 9: every cell keeps the log-odds
l = log(p / (1 - p)) of being occupied, starting at 0 (p = 0.5). Each beam adds `l_free` to
every cell it crosses from the laser to its end point, found by an exact grid traversal
(Amanatides & Woo 1987), and `l_occ` to the end point's cell when the beam hit something
(reading < max_range); after every update l is clamped to `clamp`, so a cell can change its
mind after a bounded number of contrary beams. Beams with no return (reading >= max_range) and
hits beyond `usable_range` only clear free space up to `usable_range`. Unusable readings (<= 0,
NaN) are ignored. Beams are applied one by one in log order (serial, so the bytes are
reproducible).

The grid covers the laser positions and the hit end points plus `margin`; its origin lies on
a multiple of the resolution. Final cells: p = 1 - 1 / (1 + e^l) > occupied_thresh is
OCCUPIED, p < free_thresh FREE, anything else (and every cell no beam reached) UNKNOWN. With
the defaults one hit makes a cell occupied (p = 0.70), two crossings make it free (p = 0.31).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numba
import numpy as np

from scanloc.world.build import render_map_preview
from scanloc.world.map_server import save_map
from scanloc.world.occupancy_grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid

MAX_CELLS = 200_000_000  # ~1.2 GB of working arrays (float32 log-odds + seen + cells)
# A hit is moved this far (in cells) past the reading along its beam. The surface that
# returned it is the near face of the obstacle's cell: an exact caster's hits lie on that
# face, and rounding must not put them in the free cell in front of it. 1e-3 cells (50 µm at
# 5 cm) is far below any laser's accuracy and far above float32 rounding of an 80 m reading.
FACE_NUDGE_CELLS = 1e-3


@numba.njit(cache=True)
def trace_cells(
    x0: float, y0: float, x1: float, y1: float, cols: np.ndarray, rows: np.ndarray
) -> int:
    """Cells crossed by the segment (x0, y0)-(x1, y1), in cell units, in order of travel.

    Writes them to cols / rows (each at least 1 + |Δ floor x| + |Δ floor y| long) and returns
    their number: a 4-connected path from the start point's cell to the end point's cell
    (Amanatides & Woo), one step per crossed cell boundary. Counting the steps instead of
    testing for the end cell keeps rounding at a corner from overshooting the end.
    """
    ix, iy = math.floor(x0), math.floor(y0)
    end_x, end_y = math.floor(x1), math.floor(y1)
    dx, dy = x1 - x0, y1 - y0
    step_x = 1 if dx > 0 else -1
    step_y = 1 if dy > 0 else -1
    next_x, delta_x = np.inf, np.inf  # segment parameter of the next x boundary, and per cell
    if dx != 0.0:
        next_x = (ix + (1 if dx > 0 else 0) - x0) / dx
        delta_x = abs(1.0 / dx)
    next_y, delta_y = np.inf, np.inf
    if dy != 0.0:
        next_y = (iy + (1 if dy > 0 else 0) - y0) / dy
        delta_y = abs(1.0 / dy)
    n = abs(end_x - ix) + abs(end_y - iy)
    cols[0], rows[0] = ix, iy
    for k in range(1, n + 1):
        if iy == end_y or (ix != end_x and next_x < next_y):
            ix += step_x
            next_x += delta_x
        else:
            iy += step_y
            next_y += delta_y
        cols[k], rows[k] = ix, iy
    return n + 1


@numba.njit(cache=True)
def _integrate(
    logodds: np.ndarray,
    seen: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    hit: np.ndarray,
    buffer_len: int,
    l_occ: float,
    l_free: float,
    lo: float,
    hi: float,
) -> None:
    """Apply every beam (start / end points in cell units) to the log-odds grid, in order."""
    height, width = logodds.shape
    cols = np.empty(buffer_len, np.int64)
    rows = np.empty(buffer_len, np.int64)
    for k in range(starts.shape[0]):
        n = trace_cells(starts[k, 0], starts[k, 1], ends[k, 0], ends[k, 1], cols, rows)
        for j in range(n):
            c, r = cols[j], rows[j]
            if c < 0 or c >= width or r < 0 or r >= height:
                break  # a clearing beam leaving the grid (it is convex: no way back)
            delta = l_occ if hit[k] and j == n - 1 else l_free
            logodds[r, c] = min(max(logodds[r, c] + delta, lo), hi)
            seen[r, c] = True


def _check_inputs(
    poses: np.ndarray, ranges: np.ndarray, angles: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    poses = np.asarray(poses, dtype=np.float64)
    ranges = np.asarray(ranges, dtype=np.float64)
    angles = np.asarray(angles, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3 or not np.isfinite(poses).all():
        raise ValueError(f"poses must be finite with shape (N, 3), got shape {poses.shape}")
    if angles.ndim != 1 or not np.isfinite(angles).all():
        raise ValueError(f"angles must be finite with shape (B,), got shape {angles.shape}")
    if ranges.shape != (len(poses), len(angles)):
        raise ValueError(
            f"ranges must have shape (N={len(poses)}, B={len(angles)}), got {ranges.shape}"
        )
    return poses, ranges, angles


def build_map_from_log(
    poses: np.ndarray,
    ranges: np.ndarray,
    angles: np.ndarray,
    max_range: float,
    resolution: float = 0.05,
    margin: float = 1.0,
    usable_range: float | None = None,
    l_occ: float = 0.85,
    l_free: float = -0.4,
    occupied_thresh: float = 0.65,
    free_thresh: float = 0.35,
    clamp: tuple[float, float] = (-5.0, 5.0),
    max_cells: int = MAX_CELLS,
) -> OccupancyGrid:
    """The occupancy grid of scans `ranges` (N, B) taken at laser poses (N, 3) (module doc).

    `angles` (B,) are the beam angles in the laser frame. Raises ValueError for inconsistent
    shapes or settings, and when the grid would exceed `max_cells` cells.
    """
    poses, ranges, angles = _check_inputs(poses, ranges, angles)
    usable = float(max_range) if usable_range is None else float(usable_range)
    if not (max_range > 0 and usable > 0 and resolution > 0 and margin >= 0):
        raise ValueError(
            f"need max_range > 0, usable_range > 0, resolution > 0, margin >= 0; got "
            f"{max_range}, {usable}, {resolution}, {margin}"
        )
    if not (l_occ > 0 > l_free and clamp[0] < 0 < clamp[1]):
        raise ValueError(f"need l_occ > 0 > l_free and clamp lo < 0 < hi, got {l_occ}, {l_free}")
    if not 0.0 <= free_thresh < occupied_thresh <= 1.0:
        raise ValueError(
            f"need 0 <= free_thresh < occupied_thresh <= 1, got {free_thresh}, {occupied_thresh}"
        )

    with np.errstate(invalid="ignore"):
        valid = ranges > 0  # False for NaN
        hit = valid & (ranges < max_range) & (ranges <= usable)
    heading = poses[:, 2:3] + angles[None, :]
    length = np.where(hit, ranges + FACE_NUDGE_CELLS * resolution, usable)
    end_x = poses[:, 0:1] + length * np.cos(heading)
    end_y = poses[:, 1:2] + length * np.sin(heading)

    xs = np.concatenate([poses[:, 0], end_x[hit]])
    ys = np.concatenate([poses[:, 1], end_y[hit]])
    origin_x = math.floor((xs.min() - margin) / resolution + 1e-9) * resolution
    origin_y = math.floor((ys.min() - margin) / resolution + 1e-9) * resolution
    width = math.floor((xs.max() + margin - origin_x) / resolution) + 1
    height = math.floor((ys.max() + margin - origin_y) / resolution) + 1
    if width * height > max_cells:
        raise ValueError(
            f"the map would have {width} x {height} = {width * height:,} cells at "
            f"{resolution} m (x {origin_x:.1f}..{origin_x + width * resolution:.1f} m, y "
            f"{origin_y:.1f}..{origin_y + height * resolution:.1f} m), over the limit of "
            f"{max_cells:,}: use a coarser resolution or fewer far hits (usable_range)"
        )

    # beams in log order, start and end points in cell units
    starts = np.repeat((poses[:, :2] - (origin_x, origin_y)) / resolution, len(angles), axis=0)
    ends = np.column_stack([(end_x - origin_x).ravel(), (end_y - origin_y).ravel()]) / resolution
    keep = valid.ravel()
    starts, ends, hit_flat = starts[keep], ends[keep], hit.ravel()[keep]
    span = np.abs(np.floor(ends) - np.floor(starts)).sum(axis=1)
    longest = int(span.max()) + 1 if len(span) else 1

    logodds = np.zeros((height, width), dtype=np.float32)
    seen = np.zeros((height, width), dtype=np.bool_)
    _integrate(
        logodds,
        seen,
        np.ascontiguousarray(starts),
        np.ascontiguousarray(ends),
        np.ascontiguousarray(hit_flat),
        longest,
        float(l_occ),
        float(l_free),
        float(clamp[0]),
        float(clamp[1]),
    )
    # e^l through libm, one value at a time: numpy's AVX-512 exp differs from its AVX2 (libm)
    # one in the last bits, and the map must not depend on the CPU (few distinct l values).
    levels, which = np.unique(logodds.astype(np.float64), return_inverse=True)
    odds = np.array([math.exp(level) for level in levels.tolist()], dtype=np.float64)
    p = (1.0 - 1.0 / (1.0 + odds))[which.reshape(logodds.shape)]
    cells = np.full((height, width), UNKNOWN, dtype=np.int8)
    cells[seen & (p > occupied_thresh)] = OCCUPIED
    cells[seen & (p < free_thresh)] = FREE
    return OccupancyGrid(cells, float(resolution), (origin_x, origin_y, 0.0))


def save_log_map(
    grid: OccupancyGrid,
    yaml_path: str | os.PathLike[str],
    preview_path: str | os.PathLike[str] | None = None,
) -> tuple[Path, Path]:
    """Write the map as map_server files (YAML + PGM next to it) and a PNG preview (default:
    the YAML's name with .png), each atomically. Returns (yaml path, preview path)."""
    yaml_path = Path(yaml_path)
    preview = yaml_path.with_suffix(".png") if preview_path is None else Path(preview_path)
    saved = save_map(grid, yaml_path, image_name=f"{yaml_path.stem}.pgm")
    return saved, render_map_preview(grid, preview)
