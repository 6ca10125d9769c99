"""amcl's beam laser model (ROS 1 navigation, amcl_laser.cpp `BeamModel`), over a range table.

Per used beam the range the map predicts from the particle (`map_range`) is compared with the
reading (`obs`), and ROS's four-part mixture gives
    pz = z_hit·exp(-(obs - map_range)²/2σ²)
       + z_short·λ·exp(-λ·obs)      if obs < map_range   (an unexpected obstacle)
       + z_max                      if obs == range_max  (a missed obstacle)
       + z_rand / range_max         if obs <  range_max  (a random reading)
and, as amcl does, a particle's weight is multiplied by 1 + Σ pz³. Beams: every step-th from beam
0 with amcl's integer step (range_count - 1) // (max_beams - 1); readings at or below range_min
count as range_max (amcl's laserReceived); NaN readings are skipped (ROS would give the particle
a NaN weight). Readings above range_max (scanloc's "no return" fill value, like ROS's +inf) match
none of the cases but the vanishing z_hit tail, so they add ≈ 0, as in ROS.

The map's ranges: amcl casts each ray in the map per particle and beam (map_calc_range:
Bresenham to the first cell that is occupied or unknown, or off the map, capped at range_max).
That is 300k casts per update at 10k particles, 70 ms even with scanloc's exact caster. Instead,
as range_libc's "giant lookup table" does, the exact caster (`scanloc.sensor.raycast`, unknown
cells blocking, leaving the map counting as a hit at its border) fills once a table of ranges
for every `lut_resolution` cell centre in free space and every one of `lut_angles` headings;
an update then reads one table row per particle. The table quantises position to the cell
(±lut_resolution/2) and angle to the bin (±180°/lut_angles): at the defaults, 0.05 m and 360
bins, a range is off by a few centimetres, far below σ_hit = 0.2 m. A particle outside the free
space sees range 0 on every beam, as amcl's caster (which starts inside a blocked cell) does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from scanloc.sensor.raycast import CastMap, cast_exact
from scanloc.world.occupancy_grid import OccupancyGrid

RANGE_UNIT = 1e-3  # metres per table step: ranges are stored as uint16 millimetres
MAX_TABLE_BYTES = 1 << 30


@dataclass(frozen=True)
class BeamMixture:
    """The four-part mixture's parameters (ROS 1's laser_z_hit ... laser_lambda_short)."""

    z_hit: float = 0.95
    z_short: float = 0.1
    z_max: float = 0.05
    z_rand: float = 0.05
    sigma_hit: float = 0.2
    lambda_short: float = 0.1


@dataclass(frozen=True)
class RangeTable:
    """Expected ranges from lut cell centres in every heading bin.

    Attributes:
        ranges: (n_free, n_angles) uint16, range in RANGE_UNIT from the centre of a free
            lut cell along world angle -π + 2π·k / n_angles.
        index: (rows, cols) int32, the row of `ranges` for each lut cell; -1 outside free space.
        origin_x, origin_y: world position of lut cell (0, 0)'s corner (the map's origin);
            shifted by half a map cell with `half_cell_offset`, where amcl's map sits.
        resolution: lut cell size in metres.
        range_max: the cap of every range.
    """

    ranges: np.ndarray
    index: np.ndarray
    origin_x: float
    origin_y: float
    resolution: float
    range_max: float

    @property
    def n_angles(self) -> int:
        return int(self.ranges.shape[1])


def table_bytes(grid: OccupancyGrid, lut_resolution: float, lut_angles: int) -> int:
    """An upper bound of the table's size (every lut cell free), for a check before building."""
    width_m, height_m = grid.size_m
    cells = math.ceil(width_m / lut_resolution) * math.ceil(height_m / lut_resolution)
    return cells * (2 * lut_angles + 4)


def exit_distance(px: np.ndarray, py: np.ndarray, angle: np.ndarray, box: tuple) -> np.ndarray:
    """Distance from points inside `box` (x0, y0, x1, y1) along world angles to its border."""
    x0, y0, x1, y1 = box
    dx, dy = np.cos(angle), np.sin(angle)
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(dx > 0, (x1 - px) / dx, np.where(dx < 0, (x0 - px) / dx, np.inf))
        ty = np.where(dy > 0, (y1 - py) / dy, np.where(dy < 0, (y0 - py) / dy, np.inf))
    return np.maximum(np.minimum(tx, ty), 0.0)


def build_range_table(
    grid: OccupancyGrid,
    range_max: float,
    lut_resolution: float = 0.05,
    lut_angles: int = 360,
    max_bytes: int = MAX_TABLE_BYTES,
    half_cell_offset: bool = False,
) -> RangeTable:
    """Cast every heading bin from every free lut cell centre (see the module docstring).

    `half_cell_offset` places the map as amcl does, half a cell towards -x and -y (amcl's
    world→cell lookup floor((x - origin) / resolution + 0.5)).

    Raises ValueError, with the numbers, when the table would exceed `max_bytes`.
    """
    if not (lut_resolution > 0 and lut_angles >= 8 and range_max > 0):
        raise ValueError(
            f"need lut_resolution > 0, lut_angles >= 8, range_max > 0, got {lut_resolution}, "
            f"{lut_angles}, {range_max}"
        )
    if range_max / RANGE_UNIT > np.iinfo(np.uint16).max:
        raise ValueError(f"range_max {range_max} m exceeds the table's {65.535} m")
    need = table_bytes(grid, lut_resolution, lut_angles)
    if need > max_bytes:
        raise ValueError(
            f"beam model range table for a {grid.width} x {grid.height}-cell map at "
            f"{lut_resolution} m and {lut_angles} angles needs up to {need / 2**20:.0f} MiB "
            f"(limit {max_bytes / 2**20:.0f} MiB): raise beam_lut_resolution or lower "
            "beam_lut_angles"
        )
    width_m, height_m = grid.size_m
    cols = math.ceil(width_m / lut_resolution)
    rows = math.ceil(height_m / lut_resolution)
    cx = grid.origin[0] + (np.arange(cols) + 0.5) * lut_resolution
    cy = grid.origin[1] + (np.arange(rows) + 0.5) * lut_resolution
    xx, yy = np.meshgrid(np.minimum(cx, grid.origin[0] + width_m - 1e-9), cy)
    yy = np.minimum(yy, grid.origin[1] + height_m - 1e-9)
    map_col, map_row = grid.world_to_cell(xx, yy)
    free = grid.free[map_row, map_col]
    index = np.full((rows, cols), -1, dtype=np.int32)
    index[free] = np.arange(int(free.sum()), dtype=np.int32)
    centres = np.column_stack([xx[free], yy[free], np.zeros(int(free.sum()))])
    angles = -math.pi + 2.0 * math.pi * np.arange(lut_angles) / lut_angles
    cast_map = CastMap.from_grid(grid, unknown_blocks=True)
    box = (grid.origin[0], grid.origin[1], grid.origin[0] + width_m, grid.origin[1] + height_m)
    table = np.empty((len(centres), lut_angles), dtype=np.uint16)
    for start in range(0, len(centres), 4096):
        part = centres[start : start + 4096]
        hit = cast_exact(cast_map, part, angles, range_max)
        leave = exit_distance(part[:, :1], part[:, 1:2], angles[None, :], box)
        ranges = np.where(np.isfinite(hit), hit, np.where(leave < range_max, leave, range_max))
        table[start : start + 4096] = np.rint(np.minimum(ranges, range_max) / RANGE_UNIT)
    shift = 0.5 * grid.resolution if half_cell_offset else 0.0
    return RangeTable(
        ranges=table,
        index=index,
        origin_x=float(grid.origin[0]) - shift,
        origin_y=float(grid.origin[1]) - shift,
        resolution=float(lut_resolution),
        range_max=float(range_max),
    )


@numba.njit(cache=True, inline="always")
def beam_pz(
    obs: float,
    map_range: float,
    range_max: float,
    z_hit: float,
    z_short: float,
    z_max: float,
    z_rand: float,
    sigma_hit: float,
    lambda_short: float,
) -> float:
    """ROS's per-beam probability of reading `obs` where the map predicts `map_range`."""
    z = obs - map_range
    pz = z_hit * math.exp(-(z * z) / (2.0 * sigma_hit * sigma_hit))
    if z < 0.0:
        pz += z_short * lambda_short * math.exp(-lambda_short * obs)
    if obs == range_max:
        pz += z_max
    if obs < range_max:
        pz += z_rand / range_max
    return pz


@numba.njit(cache=True, parallel=True)
def _beam_kernel(
    poses: np.ndarray,
    obs: np.ndarray,
    bin_offsets: np.ndarray,
    constant: np.ndarray,
    short: np.ndarray,
    table: np.ndarray,
    index: np.ndarray,
    origin_x: float,
    origin_y: float,
    inv_res: float,
    z_hit: float,
    inv_denom: float,
    out: np.ndarray,
) -> None:
    """beam_pz per particle and beam, with what depends on the beam alone precomputed:
    `constant` (z_max and z_rand terms), `short` (the z_short term, added when obs < map)."""
    rows, cols = index.shape
    n_angles = table.shape[1]
    bins_per_rad = n_angles / (2.0 * math.pi)
    for i in numba.prange(poses.shape[0]):
        col = math.floor((poses[i, 0] - origin_x) * inv_res)
        row = math.floor((poses[i, 1] - origin_y) * inv_res)
        k = -1
        if 0 <= col < cols and 0 <= row < rows:
            k = index[int(row), int(col)]
        heading_bin = (poses[i, 2] + math.pi) * bins_per_rad + 0.5
        p = 1.0
        for j in range(obs.shape[0]):
            map_range = 0.0
            if k >= 0:
                b = int(heading_bin + bin_offsets[j] + n_angles) - n_angles  # floor, for > -n
                if b >= n_angles:
                    b -= n_angles
                elif b < 0:
                    b += n_angles
                map_range = table[k, b] * RANGE_UNIT
            z = obs[j] - map_range
            pz = z_hit * math.exp(-z * z * inv_denom) + constant[j]
            if z < 0.0:
                pz += short[j]
            p += pz * pz * pz
        out[i] = p


def select_beams_beam_model(
    ranges: np.ndarray, angles: np.ndarray, range_min: float, range_max: float, max_beams: int
) -> tuple[np.ndarray, np.ndarray]:
    """(reading, bearing) of the beams amcl's beam model evaluates: the integer step from beam 0,
    readings at or below range_min set to range_max, NaN readings skipped."""
    step = max(1, (len(ranges) - 1) // (max_beams - 1)) if max_beams >= 2 else 1
    raw = np.asarray(ranges, dtype=np.float64)[::step]
    bearings = np.asarray(angles, dtype=np.float64)[::step]
    keep = ~np.isnan(raw)
    raw, bearings = raw[keep], bearings[keep]
    dtype = np.asarray(ranges).dtype
    short = raw.astype(dtype) <= np.asarray(range_min, dtype=dtype)
    return np.where(short, range_max, raw), bearings


def beam_model_weights(
    table: RangeTable,
    poses: np.ndarray,
    obs: np.ndarray,
    bearings: np.ndarray,
    mixture: BeamMixture,
) -> np.ndarray:
    """1 + Σ pz³ for every pose (N, 3) given the selected beams (`select_beams_beam_model`)."""
    poses = np.ascontiguousarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValueError(f"poses must have shape (N, 3), got {poses.shape}")
    out = np.empty(poses.shape[0])
    obs = np.ascontiguousarray(obs, dtype=np.float64)
    bearings = np.asarray(bearings, dtype=np.float64)
    m, range_max = mixture, table.range_max
    # The parts of beam_pz that depend on the reading alone.
    constant = np.where(obs == range_max, m.z_max, 0.0)
    constant += np.where(obs < range_max, m.z_rand / range_max, 0.0)
    short = m.z_short * m.lambda_short * np.exp(-m.lambda_short * obs)
    _beam_kernel(
        poses,
        obs,
        bearings * (table.n_angles / (2.0 * math.pi)),
        constant,
        short,
        table.ranges,
        table.index,
        table.origin_x,
        table.origin_y,
        1.0 / table.resolution,
        m.z_hit,
        1.0 / (2.0 * m.sigma_hit * m.sigma_hit),
        out,
    )
    return out
