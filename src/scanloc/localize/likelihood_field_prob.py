"""nav2's (and ROS 1 noetic's) `likelihood_field_prob` laser model, with beam skipping.

The same per-beam probability as amcl's likelihood field (`likelihood_field.py`),
pz = z_hit·exp(-d²/2σ²) + z_rand/range_max with d the distance from the beam's end point to the
nearest occupied cell (capped; end points off the map get the cap), but combined as the
textbook does: a particle's weight is multiplied by Π pz = exp(Σ log pz) instead of amcl's ad-hoc
1 + Σ pz³. That makes the weights a true (if overconfident) likelihood, far sharper than amcl's.

Beam selection as nav2's LikelihoodFieldModelProb: every step-th beam from beam 0 with
step = ceil(range_count / max_beams) (not amcl's (range_count - 1) // (max_beams - 1)); readings
at or above range_max and NaN readings are skipped.

Beam skipping (`do_beamskip`, only once the filter has converged: every particle within 0.5 m of
the particles' mean in x and y, amcl's pf_update_converged): a beam is integrated only if more
than `beam_skip_threshold` of the particles see its end point within `beam_skip_distance` of an
obstacle, so a beam that hits an unmapped obstacle (a person) does not punish the right
particles. If `beam_skip_error_threshold` or more of the beams would be skipped, the filter has
probably converged to a wrong pose and all beams are integrated.

Departures from nav2, for the better and documented:
- nav2 counts the beams it never evaluates (max-range and NaN readings, and the slots up to
  max_beams that its step leaves empty) as skipped, and in the error case integrates their stale
  (or zero: log 0 = -inf) buffer values; here only evaluated beams exist for beam skipping.
- nav2 has an `importance_factor` exponent in its newest releases (1 by default); not modelled.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from scanloc.localize.likelihood_field import distance_map
from scanloc.world.occupancy_grid import OccupancyGrid

CONVERGED_DIST = 0.5  # metres; amcl's pf->dist_threshold


@dataclass(frozen=True)
class LikelihoodFieldProb:
    """Per-cell log pz of the likelihood field and which cells count as "near" for beam skipping.

    Attributes:
        log_pz: (H, W) float64, log(z_hit·exp(-d²/2σ²) + z_rand/range_max).
        log_pz_outside: log pz for end points off the map (d = max_dist).
        near: (H, W) bool, distance to the nearest obstacle below beam_skip_distance.
        origin_x, origin_y, resolution, cell_offset: the map placement (as LikelihoodField).
    """

    log_pz: np.ndarray
    log_pz_outside: float
    near: np.ndarray
    origin_x: float
    origin_y: float
    resolution: float
    cell_offset: float


def build_likelihood_field_prob(
    grid: OccupancyGrid,
    z_hit: float,
    z_rand: float,
    sigma_hit: float,
    max_dist: float,
    range_max: float,
    beam_skip_distance: float,
    half_cell_offset: bool = False,
) -> LikelihoodFieldProb:
    """Tabulate log pz and the beam-skip "near" mask for every cell of `grid`."""
    if not (sigma_hit > 0 and max_dist > 0 and range_max > 0):
        raise ValueError(
            "need sigma_hit, laser_likelihood_max_dist and range_max > 0, got "
            f"{sigma_hit}, {max_dist}, {range_max}"
        )
    if not z_hit + z_rand / range_max > 0:
        raise ValueError(f"z_hit + z_rand / range_max must be > 0, got {z_hit}, {z_rand}")
    dist = distance_map(grid, max_dist)
    denom = 2.0 * sigma_hit * sigma_hit
    with np.errstate(divide="ignore"):  # z_rand = 0 far from walls: log 0 = -inf, as in nav2
        log_pz = np.log(z_hit * np.exp(-(dist * dist) / denom) + z_rand / range_max)
        outside = math.log(z_hit * math.exp(-(max_dist * max_dist) / denom) + z_rand / range_max)
    return LikelihoodFieldProb(
        log_pz=np.ascontiguousarray(log_pz),
        log_pz_outside=outside,
        near=np.ascontiguousarray(dist < beam_skip_distance),
        origin_x=float(grid.origin[0]),
        origin_y=float(grid.origin[1]),
        resolution=float(grid.resolution),
        cell_offset=0.5 if half_cell_offset else 0.0,
    )


def select_beams_prob(
    ranges: np.ndarray, angles: np.ndarray, range_min: float, range_max: float, max_beams: int
) -> tuple[np.ndarray, np.ndarray]:
    """(range, bearing) of the beams nav2's model evaluates: step = ceil(count / max_beams),
    readings at or above range_max (short ones count as range_max) and NaN skipped."""
    step = max(1, math.ceil(len(ranges) / max_beams))
    raw = np.asarray(ranges)[::step]
    dtype = raw.dtype if np.issubdtype(raw.dtype, np.floating) else np.float64
    lo, hi = np.asarray(range_min, dtype=dtype), np.asarray(range_max, dtype=dtype)
    keep = (raw > lo) & (raw < hi)  # False for NaN
    return raw[keep].astype(np.float64), np.asarray(angles, dtype=np.float64)[::step][keep]


@numba.njit(cache=True, parallel=True)
def _log_terms_kernel(
    poses: np.ndarray,
    beam_x: np.ndarray,
    beam_y: np.ndarray,
    log_pz: np.ndarray,
    log_pz_outside: float,
    near: np.ndarray,
    origin_x: float,
    origin_y: float,
    inv_res: float,
    cell_offset: float,
    terms: np.ndarray,
    is_near: np.ndarray,
) -> None:
    height, width = log_pz.shape
    for i in numba.prange(poses.shape[0]):
        c = math.cos(poses[i, 2])
        s = math.sin(poses[i, 2])
        for j in range(beam_x.shape[0]):
            hx = poses[i, 0] + c * beam_x[j] - s * beam_y[j]
            hy = poses[i, 1] + s * beam_x[j] + c * beam_y[j]
            col = math.floor((hx - origin_x) * inv_res + cell_offset)
            row = math.floor((hy - origin_y) * inv_res + cell_offset)
            if 0 <= col < width and 0 <= row < height:
                terms[i, j] = log_pz[int(row), int(col)]
                is_near[i, j] = near[int(row), int(col)]
            else:
                terms[i, j] = log_pz_outside
                is_near[i, j] = False


@numba.njit(cache=True)
def converged(poses: np.ndarray, dist_threshold: float = CONVERGED_DIST) -> bool:
    """amcl's pf_update_converged: every particle within dist_threshold of the mean in x and y."""
    n = poses.shape[0]
    mean_x = 0.0
    mean_y = 0.0
    for i in range(n):
        mean_x += poses[i, 0]
        mean_y += poses[i, 1]
    mean_x /= n
    mean_y /= n
    for i in range(n):
        if abs(poses[i, 0] - mean_x) > dist_threshold or abs(poses[i, 1] - mean_y) > dist_threshold:
            return False
    return True


def prob_weights(
    field: LikelihoodFieldProb,
    poses: np.ndarray,
    ranges: np.ndarray,
    bearings: np.ndarray,
    do_beamskip: bool = False,
    beam_skip_threshold: float = 0.3,
    beam_skip_error_threshold: float = 0.9,
    filter_converged: bool = False,
) -> np.ndarray:
    """Π pz over the selected beams for every pose (N, 3), with nav2's beam skipping when
    `do_beamskip` and the filter has converged (see the module docstring)."""
    poses = np.ascontiguousarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValueError(f"poses must have shape (N, 3), got {poses.shape}")
    ranges = np.asarray(ranges, dtype=np.float64)
    bearings = np.asarray(bearings, dtype=np.float64)
    terms = np.empty((poses.shape[0], ranges.shape[0]))
    is_near = np.empty((poses.shape[0], ranges.shape[0]), dtype=np.bool_)
    _log_terms_kernel(
        poses,
        ranges * np.cos(bearings),
        ranges * np.sin(bearings),
        field.log_pz,
        field.log_pz_outside,
        field.near,
        field.origin_x,
        field.origin_y,
        1.0 / field.resolution,
        field.cell_offset,
        terms,
        is_near,
    )
    if do_beamskip and filter_converged and ranges.size:
        agree = is_near.mean(axis=0) > beam_skip_threshold
        skipped = int((~agree).sum())
        if skipped < beam_skip_error_threshold * ranges.size:
            terms = terms[:, agree]
    return np.exp(terms.sum(axis=1))
