"""Simulated laser scans: cast the beams, add range noise, apply the range limits, encode
"no return".

A reading is kept when range_min <= reading <= range_max after noise (compared in float32,
the stored precision); anything else, a beam that hit nothing included, becomes
spec.no_return_value (7.0 m by default, as the paper's author did with STDR's +inf). In
"stdr" mode a reading STDR reports as -inf (closer than range_min) becomes 0.0, which is what
the author's loaders did with it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from typing import Any

import numpy as np

from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.noise import NoiseModel, NoNoise
from scanloc.sensor.raycast import CastMap, cast_exact
from scanloc.sensor.raycast_stdr import cast_stdr
from scanloc.world.occupancy_grid import OccupancyGrid

__all__ = [
    "MODES",
    "ScanSimulator",
    "laser_spec_from_config",
    "simulate_scans",
]

MODES = ("exact", "stdr")
STDR_TOO_CLOSE_VALUE = 0.0
_SENSOR_EXTRAS = ("mode", "unknown_blocks")

Seed = int | np.random.SeedSequence | np.random.Generator


class ScanSimulator:
    """A laser in a fixed map: prepares the map once, then simulates scans at any poses.

    Args:
        grid: the map.
        spec: the laser.
        noise: range noise model (default: none).
        mode: "exact" (distance to the first blocked cell's boundary) or "stdr" (STDR's
            whole-cell stepping, paper-spec §2).
        unknown_blocks: whether unknown cells stop a beam (STDR: no).
    """

    def __init__(
        self,
        grid: OccupancyGrid,
        spec: LaserSpec,
        noise: NoiseModel | None = None,
        mode: str = "exact",
        unknown_blocks: bool = False,
    ) -> None:
        if mode not in MODES:
            raise ValueError(f"sensor field 'mode': expected one of {MODES}, got {mode!r}")
        self.grid = grid
        self.spec = spec
        self.noise = NoNoise() if noise is None else noise
        self.mode = mode
        self.unknown_blocks = bool(unknown_blocks)
        self._cast_map = CastMap.from_grid(grid, self.unknown_blocks) if mode == "exact" else None

    def cast(self, poses: np.ndarray) -> np.ndarray:
        """Noise-free ranges, float64 (N, B): metres, +inf for no hit (-inf: STDR's too close)."""
        if self._cast_map is not None:
            return cast_exact(self._cast_map, poses, self.spec.beam_angles(), self.spec.range_max)
        return cast_stdr(self.grid, poses, self.spec, self.unknown_blocks).astype(np.float64)

    def finish(self, ranges: np.ndarray, rng: Seed) -> np.ndarray:
        """Noise, range limits and "no return" fill on cast ranges: float32 (N, B) readings."""
        readings = self.noise.apply(ranges, np.random.default_rng(rng)).astype(np.float32)
        keep = (readings >= np.float32(self.spec.range_min)) & (
            readings <= np.float32(self.spec.range_max)
        )
        fill = np.where(
            np.isneginf(ranges), STDR_TOO_CLOSE_VALUE, self.spec.no_return_value
        ).astype(np.float32)
        return np.where(keep, readings, fill)

    def simulate(self, poses: np.ndarray, rng: Seed) -> np.ndarray:
        """Readings at `poses` (N, 3): float32 (N, B), deterministic for a given seed."""
        return self.finish(self.cast(poses), rng)


def simulate_scans(
    grid: OccupancyGrid,
    spec: LaserSpec,
    poses: np.ndarray,
    noise: NoiseModel | None,
    rng_seed: Seed,
    mode: str = "exact",
    unknown_blocks: bool = False,
) -> np.ndarray:
    """One-shot `ScanSimulator(grid, spec, noise, mode, unknown_blocks).simulate(poses, seed)`.

    For many calls on one map build a ScanSimulator once: it keeps the prepared map.
    """
    return ScanSimulator(grid, spec, noise, mode, unknown_blocks).simulate(poses, rng_seed)


def laser_spec_from_config(cfg: Mapping[str, Any]) -> LaserSpec:
    """LaserSpec from a sensor config (conf/sensor/*.yaml); `mode` and `unknown_blocks` are
    allowed alongside and ignored here. Missing fields take LaserSpec's defaults."""
    if not isinstance(cfg, Mapping):
        raise ValueError(f"sensor config must be a mapping, got {type(cfg).__name__}")
    names = {f.name for f in fields(LaserSpec)}
    unknown = sorted(set(cfg) - names - set(_SENSOR_EXTRAS))
    if unknown:
        raise ValueError(f"sensor config: unknown field(s) {unknown}; expected {sorted(names)}")
    values: dict[str, Any] = {}
    for name in names & set(cfg):
        value = cfg[name]
        if name == "num_beams":
            ok = isinstance(value, int) and not isinstance(value, bool)
            expected = "an integer"
        else:
            ok = isinstance(value, int | float) and not isinstance(value, bool)
            ok = ok and bool(np.isfinite(value))
            expected = "a finite number"
        if not ok:
            raise ValueError(f"sensor field '{name}': expected {expected}, got {value!r}")
        values[name] = value
    try:
        return LaserSpec(**values)
    except ValueError as err:
        raise ValueError(f"sensor config: {err}") from None
