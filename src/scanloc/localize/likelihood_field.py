"""amcl's likelihood-field laser model (ROS 1 navigation, amcl_laser.cpp `LikelihoodFieldModel`).

For each used beam the end point is looked up in a map of distances to the nearest occupied
cell (capped at `laser_likelihood_max_dist`), giving pz = z_hit·exp(-d²/2σ²) + z_rand/range_max.
amcl does not multiply the beam probabilities: a particle's weight is multiplied by
p = 1 + Σ pz³ (its "ad-hoc weighting scheme"), which is reproduced here.

Details as in amcl:
- beams are subsampled with the integer step (range_count - 1) // (max_beams - 1), starting at
  beam 0 (667 beams and max_beams 30 give step 22 and 31 beams);
- readings at or above range_max are skipped, readings at or below range_min count as range_max
  (so they are skipped too), NaN readings are skipped;
- end points outside the map get the maximum distance.

The distance of a cell is the Euclidean distance between its centre and the nearest occupied
cell's centre (amcl's map_cspace brushfire computes the same, capped). Since pz depends on the
cell only, pz³ is tabulated once per cell: the same numbers amcl computes, without an exp per beam.

World → cell convention: amcl (through MAP_GXWX and the origin shift in its map conversion)
maps x to floor((x - origin_x)/resolution + 0.5), i.e. it treats cell i as centred on
origin + i·resolution, half a cell off the map's true cell i = floor((x - origin_x)/resolution).
scanloc uses the correct mapping by default; `half_cell_offset=True` reproduces amcl's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from scipy.ndimage import distance_transform_edt

from scanloc.world.occupancy_grid import OccupancyGrid


@dataclass(frozen=True)
class LikelihoodField:
    """Per-cell pz³ of amcl's likelihood-field model and the map placement to look it up.

    Attributes:
        pz3: (H, W) float64, (z_hit·exp(-d²/2σ²) + z_rand/range_max)³ per cell.
        pz3_outside: pz³ for end points off the map (distance = max_dist).
        origin_x, origin_y, resolution: the map placement.
        cell_offset: 0.5 reproduces amcl's half-cell world→cell offset, 0.0 is the exact mapping.
    """

    pz3: np.ndarray
    pz3_outside: float
    origin_x: float
    origin_y: float
    resolution: float
    cell_offset: float


def distance_map(grid: OccupancyGrid, max_dist: float) -> np.ndarray:
    """Distance (m) from every cell centre to the nearest OCCUPIED cell centre, capped at max_dist.

    Unknown cells do not count as obstacles (amcl's map conversion marks only value 100 as
    occupied). A map without any occupied cell is max_dist everywhere.
    """
    occupied = grid.occupied
    if not occupied.any():
        return np.full(occupied.shape, float(max_dist))
    dist = distance_transform_edt(~occupied) * grid.resolution
    return np.minimum(dist, max_dist)


def build_likelihood_field(
    grid: OccupancyGrid,
    z_hit: float,
    z_rand: float,
    sigma_hit: float,
    max_dist: float,
    range_max: float,
    half_cell_offset: bool = False,
) -> LikelihoodField:
    """Tabulate amcl's per-beam probability pz (cubed) for every cell of `grid`."""
    if not sigma_hit > 0 or not max_dist > 0 or not range_max > 0:
        raise ValueError(
            "need sigma_hit, laser_likelihood_max_dist and range_max > 0, got "
            f"{sigma_hit}, {max_dist}, {range_max}"
        )
    dist = distance_map(grid, max_dist)
    denom = 2.0 * sigma_hit * sigma_hit
    pz = z_hit * np.exp(-(dist * dist) / denom) + z_rand / range_max
    pz_out = z_hit * math.exp(-(max_dist * max_dist) / denom) + z_rand / range_max
    return LikelihoodField(
        pz3=np.ascontiguousarray(pz**3),
        pz3_outside=pz_out**3,
        origin_x=float(grid.origin[0]),
        origin_y=float(grid.origin[1]),
        resolution=float(grid.resolution),
        cell_offset=0.5 if half_cell_offset else 0.0,
    )


def beam_step(range_count: int, max_beams: int) -> int:
    """amcl's integer beam step (range_count - 1) / (max_beams - 1), at least 1."""
    if max_beams < 2:
        return 1
    return max(1, (range_count - 1) // (max_beams - 1))


def select_beams(
    ranges: np.ndarray,
    angles: np.ndarray,
    range_min: float,
    range_max: float,
    max_beams: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The (range, bearing) pairs of the beams amcl evaluates: every step-th, max-range and NaN out.

    Readings at or below range_min are amcl's "short" readings, mapped to range_max and so skipped.
    """
    step = beam_step(len(ranges), max_beams)
    raw = np.asarray(ranges)[::step]
    # Compare at the scan's own precision, as amcl compares float32 readings with the float32
    # range_max of the LaserScan message: a float32 reading of 5.6 is a max-range reading.
    dtype = raw.dtype if np.issubdtype(raw.dtype, np.floating) else np.float64
    lo, hi = np.asarray(range_min, dtype=dtype), np.asarray(range_max, dtype=dtype)
    keep = (raw > lo) & (raw < hi)  # also False for NaN
    return raw[keep].astype(np.float64), np.asarray(angles, dtype=np.float64)[::step][keep]


@numba.njit(cache=True, parallel=True, fastmath=False)
def _weights_kernel(
    poses: np.ndarray,
    beam_x: np.ndarray,
    beam_y: np.ndarray,
    pz3: np.ndarray,
    pz3_outside: float,
    origin_x: float,
    origin_y: float,
    inv_res: float,
    cell_offset: float,
    out: np.ndarray,
) -> None:
    height, width = pz3.shape
    for i in numba.prange(poses.shape[0]):
        x = poses[i, 0]
        y = poses[i, 1]
        c = math.cos(poses[i, 2])
        s = math.sin(poses[i, 2])
        p = 1.0
        for j in range(beam_x.shape[0]):
            hx = x + c * beam_x[j] - s * beam_y[j]
            hy = y + s * beam_x[j] + c * beam_y[j]
            col = math.floor((hx - origin_x) * inv_res + cell_offset)
            row = math.floor((hy - origin_y) * inv_res + cell_offset)
            if 0 <= col < width and 0 <= row < height:
                p += pz3[int(row), int(col)]
            else:
                p += pz3_outside
        out[i] = p


def beam_weights(
    field: LikelihoodField, poses: np.ndarray, ranges: np.ndarray, bearings: np.ndarray
) -> np.ndarray:
    """p = 1 + Σ_beams pz³ for every pose (N, 3), given the selected beams (see `select_beams`).

    The laser sits at the robot centre (the paper's setup), so beam end points are
    pose ⊕ (r·cos b, r·sin b).
    """
    poses = np.ascontiguousarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValueError(f"poses must have shape (N, 3), got {poses.shape}")
    ranges = np.asarray(ranges, dtype=np.float64)
    bearings = np.asarray(bearings, dtype=np.float64)
    out = np.empty(poses.shape[0])
    _weights_kernel(
        poses,
        ranges * np.cos(bearings),
        ranges * np.sin(bearings),
        field.pz3,
        field.pz3_outside,
        field.origin_x,
        field.origin_y,
        1.0 / field.resolution,
        field.cell_offset,
        out,
    )
    return out
