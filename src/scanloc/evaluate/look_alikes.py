"""Look-alike places: the stretches of a run whose scans cannot tell the true place from a copy
in time.

A kidnapped robot can be re-localized only as fast as its scans tell the true place from the
places that look like it. On a map of copied rooms (map 2, `simple_rooms`) a pose and its copy
one room over render the same scan, beam for beam, for as long as the laser sees nothing but
the copied part. Within the laser's noise no sensor model can tell them apart then, so a goal
such as "every kidnap recovered within 20 steps" is out of reach for such a stretch; a copy
that differs by a few centimetres on many beams can be told apart, by a model that uses them.

What is measured, for each stretch of a run (its start and each kidnap):
1. The map's **symmetries**: rigid motions g (a rotation by 0°, 90°, 180° or 270°, then a
   translation by whole cells) that carry many occupied cells onto occupied cells. Found by
   cross-correlating the occupied mask with each rotation of itself (FFT); peaks that cover at
   least `min_overlap` of the occupied cells, `min_separation_m` or more from the identity,
   at most `max_candidates` of them.
2. For each g, the **copy's track** over the stretch's first `window` steps: the truth moved
   rigidly so that its first pose lands on g's image of it, then *posed by optimisation*
   (Nelder-Mead over a shift and a turn of the whole track, within `refine_radius_m` and
   `refine_angle_deg` of g): the copy that best imitates the truth's scans, since a
   correlation peak can sit a cell off the exact copy.
3. The **evidence** against the copy: the expected log-likelihood ratio of the truth's scans
   at the truth over at the copy, under the run's own range-noise model (its meta.json
   `noise`; Gaussian, so a beam's expectation is the KL divergence of the two Gaussians) and
   every beam, summed over the steps. A beam gives at most `beam_cap_nats` (a real scanner has
   outliers: no single beam is decisive beyond that), a no-return beam against a return the
   cap, a copy pose outside the free space the cap on every beam. Noise-free scans are
   rendered at both (exact ray casting); sigma is at least half a map cell (the map's own
   quantisation).
4. The stretch **resolves** at the first step at which the evidence against every copy has
   reached `llr_threshold_nats` (ln 99: the truth then holds 99 % of the two's posterior
   from even odds, the confidence a localizer needs to settle); it is **ambiguous** when a
   copy's evidence stays below it over the whole window. An expectation: a localizer with a
   coarser sensor model (fewer beams, a wider likelihood field) needs more steps than this.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import minimize
from scipy.signal import fftconvolve

from scanloc.evaluate.metrics import RECOVERED_WITHIN_STEPS
from scanloc.io import read_json
from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.noise import NoiseModel, RangeGaussianNoise, noise_from_config
from scanloc.sensor.raycast import CastMap, cast_exact
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.trajectory.format import load_trajectory
from scanloc.world.map_server import load_map
from scanloc.world.occupancy_grid import OccupancyGrid


@dataclass(frozen=True)
class LookAlikeParams:
    """How symmetries are found and scans compared (module docstring; conf/evaluate.yaml)."""

    window: int = RECOVERED_WITHIN_STEPS
    llr_threshold_nats: float = math.log(99.0)
    beam_cap_nats: float = math.log(100.0)
    refine_radius_m: float = 0.15
    refine_angle_deg: float = 3.0
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
        if min(self.llr_threshold_nats, self.beam_cap_nats) <= 0:
            raise ValueError("llr_threshold_nats and beam_cap_nats must be > 0")
        if min(self.refine_radius_m, self.refine_angle_deg, self.min_separation_m) < 0:
            raise ValueError("refine_radius_m, refine_angle_deg and min_separation_m must be >= 0")

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


def beam_evidence(
    at_truth: np.ndarray, at_copy: np.ndarray, noise: NoiseModel, floor_m: float, cap: float
) -> np.ndarray:
    """Per row, the expected log-likelihood ratio of a scan rendered at the truth over one
    rendered at the copy, summed over beams (module docstring, step 3): each finite pair the KL
    divergence of N(a, σ(a)²) from N(b, σ(b)²), capped at `cap`; no return against a return
    the cap; no return at both nothing."""
    a, b = np.asarray(at_truth, np.float64), np.asarray(at_copy, np.float64)
    finite_a, finite_b = np.isfinite(a), np.isfinite(b)
    both = finite_a & finite_b
    sigma = noise.sigma if isinstance(noise, RangeGaussianNoise) else np.zeros_like
    sa = np.maximum(sigma(np.where(both, a, 0.0)), floor_m)
    sb = np.maximum(sigma(np.where(both, b, 0.0)), floor_m)
    diff = np.where(both, a, 0.0) - np.where(both, b, 0.0)
    kl = np.log(sb / sa) + (sa**2 + diff**2) / (2.0 * sb**2) - 0.5
    per_beam = np.where(both, np.minimum(kl, cap), np.where(finite_a != finite_b, cap, 0.0))
    return per_beam.sum(axis=1)


def copy_track(poses: np.ndarray, symmetry: Symmetry, correction: Sequence[float]) -> np.ndarray:
    """The truth moved rigidly so that its first pose lands on the symmetry's image of it,
    shifted by correction[:2] and turned by correction[2] about that image (step 2)."""
    dx, dy, dtheta = (float(c) for c in correction)
    anchor = symmetry.apply(poses[:1])[0]
    angle = symmetry.quarter_turns * math.pi / 2.0 + dtheta
    c, s = math.cos(angle), math.sin(angle)
    rel = poses[:, :2] - poses[0, :2]
    x = anchor[0] + dx + c * rel[:, 0] - s * rel[:, 1]
    y = anchor[1] + dy + s * rel[:, 0] + c * rel[:, 1]
    heading = np.remainder(poses[:, 2] + angle + math.pi, 2.0 * math.pi) - math.pi
    return np.column_stack([x, y, heading])


OUT_OF_BOUNDS = 1e12  # nats: the optimisation's value outside its bounds


@dataclass(frozen=True)
class EvidenceModel:
    """What the evidence against a copy needs: the map, its ray caster, the run's laser and
    noise, and the parameters."""

    grid: OccupancyGrid
    cast_map: CastMap
    laser: LaserSpec
    noise: NoiseModel
    params: LookAlikeParams

    def per_step(self, copy: np.ndarray, at_truth: np.ndarray) -> np.ndarray:
        """The evidence against the copy at each step (a pose outside the free space: the cap
        on every beam)."""
        cap = self.params.beam_cap_nats
        out = np.full(len(copy), cap * self.laser.num_beams)
        ok = _renderable(self.grid, copy)
        if ok.any():
            rendered = cast_exact(self.cast_map, copy[ok], self.laser.beam_angles(),
                                  self.laser.range_max)  # fmt: skip
            floor = 0.5 * float(self.grid.resolution)
            out[ok] = beam_evidence(at_truth[ok], rendered, self.noise, floor, cap)
        return out

    def best_copy(self, poses: np.ndarray, at_truth: np.ndarray, symmetry: Symmetry) -> np.ndarray:
        """The evidence per step against the copy that imitates the truth best over `poses`
        (step 2's optimisation, kept within its bounds: the truth itself, a few cells away,
        would imitate better still)."""
        radius = self.params.refine_radius_m
        max_turn = math.radians(self.params.refine_angle_deg)

        def total(correction: np.ndarray) -> float:
            excess = max(0.0, math.hypot(correction[0], correction[1]) - radius)
            excess += max(0.0, abs(correction[2]) - max_turn)
            if excess > 0.0:  # outside the bounds: worse than any copy inside them
                return OUT_OF_BOUNDS * (1.0 + excess)
            copy = copy_track(poses, symmetry, correction)
            return float(self.per_step(copy, at_truth).sum())

        res = float(self.grid.resolution)
        simplex = np.array([[0, 0, 0], [res, 0, 0], [0, res, 0], [0, 0, math.radians(1.0)]])
        found = minimize(total, np.zeros(3), method="Nelder-Mead",
                         options={"initial_simplex": simplex, "xatol": 1e-3, "fatol": 1e-2,
                                  "maxfev": 120})  # fmt: skip
        best = found.x if found.fun <= total(np.zeros(3)) else np.zeros(3)
        return self.per_step(copy_track(poses, symmetry, best), at_truth)


def stretch_resolution(
    model: EvidenceModel, truth: np.ndarray, symmetries: Sequence[Symmetry]
) -> dict[str, int | bool]:
    """One stretch's poses (its first `window` steps are used): how many copies are look-alikes
    at its first step (their evidence below the threshold there), whether one stays below it
    over the window, and the step at which the evidence against every copy has reached it
    (module docstring, steps 2-4; `resolved_at` = window when ambiguous). The evidence only
    grows with steps, so a copy already told apart at the first step, posed at its best for
    that step alone, is told apart over any window."""
    params = model.params
    poses = np.asarray(truth[: params.window], dtype=np.float64)
    at_truth = cast_exact(model.cast_map, poses, model.laser.beam_angles(), model.laser.range_max)
    threshold = params.llr_threshold_nats
    resolved_steps = []
    for symmetry in symmetries:
        if model.best_copy(poses[:1], at_truth[:1], symmetry)[0] >= threshold:
            continue
        evidence = np.cumsum(model.best_copy(poses, at_truth, symmetry))
        reached = np.flatnonzero(evidence >= threshold)
        resolved_steps.append(int(reached[0]) if len(reached) else len(poses))
    return {
        "look_alikes": len(resolved_steps),
        "ambiguous": any(step >= len(poses) for step in resolved_steps),
        "resolved_at": max(resolved_steps, default=0),
    }


def run_look_alikes(
    grid: OccupancyGrid,
    laser: LaserSpec,
    noise: NoiseModel,
    truth: np.ndarray,
    kidnap_steps: Sequence[int],
    params: LookAlikeParams,
    symmetries: Sequence[Symmetry] | None = None,
) -> list[dict[str, int | bool]]:
    """Every stretch of a run (the start, then each kidnap), with its first step."""
    symmetries = map_symmetries(grid, params) if symmetries is None else symmetries
    model = EvidenceModel(grid, CastMap.from_grid(grid), laser, noise, params)
    bounds = [0, *kidnap_steps, len(truth)]
    out = []
    for start, stop in itertools.pairwise(bounds):
        result = stretch_resolution(model, truth[start:stop], symmetries)
        out.append({"start": int(start), **result})
    return out


def _from_run_meta(run_dir: Path, field: str, build: Callable[[Any], Any]) -> Any:
    """`build` applied to a field of a run's meta.json; its error names the file and field."""
    meta_path = run_dir / "meta.json"
    try:
        return build(read_json(meta_path).get(field))
    except ValueError as err:
        raise ValueError(f"{meta_path}: field '{field}': {err}") from None


def run_laser(run_dir: Path) -> LaserSpec:
    """The laser a run was rendered with (its meta.json `sensor`)."""
    return _from_run_meta(run_dir, "sensor", laser_spec_from_config)


def run_noise(run_dir: Path) -> NoiseModel:
    """The range noise a run's scans were rendered with (its meta.json `noise`)."""
    return _from_run_meta(run_dir, "noise", noise_from_config)


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
            grid, run_laser(run_dir), run_noise(run_dir), traj.truth, traj.kidnap_steps,
            params, symmetries,
        )  # fmt: skip
    kidnaps = [s for run in per_run.values() for s in run[1:]]
    return {
        "window": params.window,
        "llr_threshold_nats": round(params.llr_threshold_nats, 6),
        "beam_cap_nats": round(params.beam_cap_nats, 6),
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
