"""Look-alike places: the stretches of a run that no localizer can resolve in time.

A kidnapped robot can be re-localized only as fast as its scans tell the true place from the
places that look like it. On a map of copied rooms (map 2, `simple_rooms`) a pose and its copy
one room over render the same scan, beam for beam, for as long as the laser sees nothing but
the copied part. No sensor model, particle count or network can tell them apart then, so a
goal such as "every kidnap recovered within 20 steps" is out of reach for such a stretch.

What is measured, for each stretch of a run (its start and each kidnap):
1. The map's **symmetries**: rigid motions g (a rotation by 0°, 90°, 180° or 270°, then a
   translation by whole cells) that carry many occupied cells onto occupied cells. Found by
   cross-correlating the occupied mask with each rotation of itself (FFT); peaks that cover at
   least `min_overlap` of the occupied cells, `min_separation_m` or more from the identity,
   at most `max_candidates` of them.
2. For each g, the **look-alike track** g ⊕ truth_t over the stretch's first `window` steps:
   the noise-free scan rendered there (exact ray casting) is compared with the one rendered at
   the truth. It *looks alike* at a step when every beam agrees within `tolerance_m` (both
   without a return counts as agreeing); a track pose outside the map or in a cell that is not
   free does not.
3. The stretch **resolves** at the first step by which every look-alike track has differed at
   least once (that many steps of scans are needed, and enough, to rule all of them out); it
   is **ambiguous** when some track looks alike at every step of the window.
Noise-free scans make this an upper bound on what the scans can tell: a real localizer also
needs the difference to stand out of the noise.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.signal import fftconvolve

from scanloc.evaluate.metrics import RECOVERED_WITHIN_STEPS
from scanloc.io import read_json
from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.raycast import CastMap, cast_exact
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.trajectory.format import load_trajectory
from scanloc.world.map_server import load_map
from scanloc.world.occupancy_grid import OccupancyGrid

SNAP_CELLS = 2  # how far a symmetry's image may be moved to meet the exact copy (cells)


@dataclass(frozen=True)
class LookAlikeParams:
    """How symmetries are found and scans compared (module docstring; conf/evaluate.yaml)."""

    window: int = RECOVERED_WITHIN_STEPS
    tolerance_m: float = 0.05
    min_overlap: float = 0.3
    min_separation_m: float = 1.0
    max_candidates: int = 8

    def __post_init__(self) -> None:
        if self.window < 1 or self.max_candidates < 1:
            raise ValueError(
                f"need window >= 1 and max_candidates >= 1, got {self.window}, "
                f"{self.max_candidates}"
            )
        if not 0.0 < self.min_overlap <= 1.0:
            raise ValueError(f"min_overlap must lie in (0, 1], got {self.min_overlap}")
        if self.tolerance_m < 0 or self.min_separation_m < 0:
            raise ValueError("tolerance_m and min_separation_m must be >= 0")

    @classmethod
    def from_config(cls, config: Mapping[str, Any], source: str) -> LookAlikeParams:
        """The parameters of a config mapping; an unknown key is an error naming `source`."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(config) - known)
        if unknown:
            raise ValueError(
                f"{source}: unknown fields {unknown}; expected some of {sorted(known)}"
            )
        return cls(**{k: type(getattr(cls, k))(v) for k, v in config.items()})


@dataclass(frozen=True)
class Symmetry:
    """A rigid motion of the map frame: p ↦ R(quarter_turns · 90°) p + (tx, ty), headings
    turned by the same angle; `overlap`: the share of occupied cells it carries onto
    occupied cells."""

    quarter_turns: int
    tx: float
    ty: float
    overlap: float

    def apply(self, poses: np.ndarray) -> np.ndarray:
        """The motion applied to poses (N, 3)."""
        angle = self.quarter_turns * math.pi / 2.0
        c, s = round(math.cos(angle)), round(math.sin(angle))
        x, y = poses[:, 0], poses[:, 1]
        heading = np.remainder(poses[:, 2] + angle + math.pi, 2.0 * math.pi) - math.pi
        return np.column_stack([c * x - s * y + self.tx, s * x + c * y + self.ty, heading])


def _rotated_cells(cols: np.ndarray, rows: np.ndarray, quarter_turns: int):
    """Cell indices after rotating the cell centres (c + ½, r + ½) by quarter_turns · 90°
    about the grid's corner: the centres stay on the half-integer lattice."""
    u, v = cols + 0.5, rows + 0.5
    for _ in range(quarter_turns % 4):
        u, v = -v, u
    return np.round(u - 0.5).astype(np.int64), np.round(v - 0.5).astype(np.int64)


def map_symmetries(grid: OccupancyGrid, params: LookAlikeParams) -> list[Symmetry]:
    """The map's strongest symmetries other than the identity (module docstring, step 1)."""
    occupied = grid.occupied
    rows, cols = np.nonzero(occupied)
    if len(rows) == 0:
        return []
    res = float(grid.resolution)
    ox, oy = float(grid.origin[0]), float(grid.origin[1])
    found: list[tuple[float, int, int, int]] = []  # (overlap, turns, shift col, shift row)
    min_cells = params.min_separation_m / res
    for turns in range(4):
        rc, rr = _rotated_cells(cols, rows, turns)
        c0, r0 = rc.min(), rr.min()
        image = np.zeros((rr.max() - r0 + 1, rc.max() - c0 + 1))
        image[rr - r0, rc - c0] = 1.0
        # overlap[i, j]: occupied cells of the rotated map shifted so that its cell (r0, c0)
        # lands on (i - (image rows - 1), j - (image cols - 1)) of the original
        overlap = fftconvolve(occupied.astype(np.float64), image[::-1, ::-1], mode="full")
        overlap = np.rint(overlap) / len(rows)
        shift_r = np.arange(overlap.shape[0]) - (image.shape[0] - 1) - r0
        shift_c = np.arange(overlap.shape[1]) - (image.shape[1] - 1) - c0
        if turns == 0:  # not the identity, nor a shift too small to be another place
            near = (np.abs(shift_r)[:, None] < min_cells) & (np.abs(shift_c)[None, :] < min_cells)
            overlap[near] = 0.0
        for i, j in zip(*np.nonzero(overlap >= params.min_overlap), strict=True):
            found.append((float(overlap[i, j]), turns, int(shift_c[j]), int(shift_r[i])))
    found.sort(key=lambda f: (-f[0], f[1], f[2], f[3]))
    kept: list[tuple[float, int, int, int]] = []
    for f in found:  # one per peak: thick walls make broad peaks, keep their strongest cell
        if all(g[1] != f[1] or max(abs(g[2] - f[2]), abs(g[3] - f[3])) >= min_cells for g in kept):
            kept.append(f)
        if len(kept) == params.max_candidates:
            break
    out = []
    for share, turns, dc, dr in kept:
        # cell (c, r) → rotated (c', r') + (dc, dr); in world units about the origin corner
        angle = turns * math.pi / 2.0
        c, s = round(math.cos(angle)), round(math.sin(angle))
        tx = ox + res * dc - (c * ox - s * oy)
        ty = oy + res * dr - (s * ox + c * oy)
        out.append(Symmetry(turns, tx, ty, share))
    return out


def _renderable(grid: OccupancyGrid, poses: np.ndarray) -> np.ndarray:
    """Whether each pose lies in a free cell of the grid."""
    col, row = grid.world_to_cell(poses[:, 0], poses[:, 1])
    inside = (col >= 0) & (col < grid.width) & (row >= 0) & (row < grid.height)
    ok = np.zeros(len(poses), dtype=bool)
    ok[inside] = grid.free[row[inside], col[inside]]
    return ok


def _scans_agree(a: np.ndarray, b: np.ndarray, tolerance: float) -> np.ndarray:
    """Per row: every beam of two rendered scans agrees (within tolerance, or both no return)."""
    both_none = np.isinf(a) & np.isinf(b)
    with np.errstate(invalid="ignore"):
        close = np.abs(a - b) <= tolerance
    return np.all(both_none | close, axis=1)


def _look_alike_at(
    grid: OccupancyGrid,
    cast_map: CastMap,
    laser: LaserSpec,
    pose: np.ndarray,
    scan: np.ndarray,
    symmetry: Symmetry,
    params: LookAlikeParams,
) -> Symmetry | None:
    """The symmetry, or one shifted by up to `SNAP_CELLS` cells, whose image of `pose` renders
    `scan` (the correlation peak of a copied room can sit a cell or two off the exact copy);
    the nearest such shift, or None."""
    res = float(grid.resolution)
    offsets = range(-SNAP_CELLS, SNAP_CELLS + 1)
    shifts = sorted(((dx, dy) for dx in offsets for dy in offsets), key=lambda d: math.hypot(*d))
    variants = [
        Symmetry(symmetry.quarter_turns, symmetry.tx + dx * res, symmetry.ty + dy * res, 0.0)
        for dx, dy in shifts
    ]
    moved = np.vstack([v.apply(pose[None]) for v in variants])
    ok = np.flatnonzero(_renderable(grid, moved))
    if not len(ok):
        return None
    rendered = cast_exact(cast_map, moved[ok], laser.beam_angles(), laser.range_max)
    alike = _scans_agree(rendered, np.broadcast_to(scan, rendered.shape), params.tolerance_m)
    if not alike.any():
        return None
    best = variants[int(ok[np.flatnonzero(alike)[0]])]
    return Symmetry(best.quarter_turns, best.tx, best.ty, symmetry.overlap)


def stretch_resolution(
    grid: OccupancyGrid,
    cast_map: CastMap,
    laser: LaserSpec,
    truth: np.ndarray,
    symmetries: Sequence[Symmetry],
    params: LookAlikeParams,
) -> dict[str, int | bool]:
    """One stretch's poses (its first `window` steps are used): how many symmetries give a
    look-alike at its first step, whether one lasts the window, and the step at which the last
    one has been told apart (module docstring, steps 2-3; `resolved_at` = window when
    ambiguous)."""
    poses = np.asarray(truth[: params.window], dtype=np.float64)
    angles = laser.beam_angles()
    at_truth = cast_exact(cast_map, poses, angles, laser.range_max)
    first_difference = []
    for candidate in symmetries:
        symmetry = _look_alike_at(grid, cast_map, laser, poses[0], at_truth[0], candidate, params)
        if symmetry is None:
            continue
        moved = symmetry.apply(poses)
        alike = np.zeros(len(poses), dtype=bool)
        ok = _renderable(grid, moved)
        rendered = cast_exact(cast_map, moved[ok], angles, laser.range_max)
        alike[ok] = _scans_agree(rendered, at_truth[ok], params.tolerance_m)
        differs = np.flatnonzero(~alike)
        first_difference.append(int(differs[0]) if len(differs) else len(poses))
    ambiguous = any(step >= len(poses) for step in first_difference)
    return {
        "look_alikes": len(first_difference),
        "ambiguous": ambiguous,
        "resolved_at": max(first_difference, default=0),
    }


def run_look_alikes(
    grid: OccupancyGrid,
    laser: LaserSpec,
    truth: np.ndarray,
    kidnap_steps: Sequence[int],
    params: LookAlikeParams,
    symmetries: Sequence[Symmetry] | None = None,
) -> list[dict[str, int | bool]]:
    """Every stretch of a run (the start, then each kidnap), with its first step."""
    symmetries = map_symmetries(grid, params) if symmetries is None else symmetries
    cast_map = CastMap.from_grid(grid)
    bounds = [0, *kidnap_steps, len(truth)]
    out = []
    for start, stop in itertools.pairwise(bounds):
        result = stretch_resolution(grid, cast_map, laser, truth[start:stop], symmetries, params)
        out.append({"start": int(start), **result})
    return out


def run_laser(run_dir: Path) -> LaserSpec:
    """The laser a run was rendered with (its meta.json `sensor`)."""
    meta_path = run_dir / "meta.json"
    try:
        return laser_spec_from_config(read_json(meta_path).get("sensor"))
    except ValueError as err:
        raise ValueError(f"{meta_path}: field 'sensor': {err}") from None


def map_look_alikes(
    map_yaml: Path, runs: Mapping[str, Path], params: LookAlikeParams
) -> dict[str, Any]:
    """One map's symmetries and, per run directory, its stretches (run_look_alikes, with the
    run's own laser), with the counts of ambiguous starts and kidnaps."""
    grid = load_map(map_yaml)
    symmetries = map_symmetries(grid, params)
    per_run = {}
    for name, run_dir in runs.items():
        traj, _ = load_trajectory(run_dir)
        per_run[name] = run_look_alikes(
            grid, run_laser(run_dir), traj.truth, traj.kidnap_steps, params, symmetries
        )
    kidnaps = [s for run in per_run.values() for s in run[1:]]
    return {
        "window": params.window,
        "tolerance_m": params.tolerance_m,
        "symmetries": [
            {k: round(v, 6) for k, v in dataclasses.asdict(s).items()} for s in symmetries
        ],
        "starts": len(per_run),
        "starts_ambiguous": sum(bool(run[0]["ambiguous"]) for run in per_run.values()),
        "kidnaps": len(kidnaps),
        "kidnaps_ambiguous": sum(bool(s["ambiguous"]) for s in kidnaps),
        "runs": per_run,
    }


def look_alikes_json(doc: Mapping[str, Any]) -> str:
    """Stable JSON text of {map: map_look_alikes(...)}."""
    return json.dumps(doc, sort_keys=True, indent=2, allow_nan=False) + "\n"
