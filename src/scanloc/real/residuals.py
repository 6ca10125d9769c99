"""How a real laser differs from the map: its scans against the scans rendered at their poses.

On the mapping part of a log (the evaluation part is never looked at), every real scan is
compared with the noise-free scan rendered in the built map at the same laser pose; the
differences are classified and fitted (scanloc.sensor.corruptions.measure_corruptions) into
the corruptions the learned localizer's training stream then reproduces. Beside the fit, the
histograms of the residual (reading − rendered range) of the real scans, of scans simulated
with the log's noise model alone (the twin's) and of simulated scans with the fitted
corruptions: the report's "real vs simulated residuals" figure.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from scanloc.sensor.corruptions import LaserCorruptions, measure_corruptions
from scanloc.sensor.noise import NoiseModel, NoNoise
from scanloc.sensor.simulate import ScanSimulator
from scanloc.world.occupancy_grid import OccupancyGrid

HISTOGRAM_EDGES = np.linspace(-1.0, 1.0, 81)  # residual bins (m), 2.5 cm wide


def _histogram(readings: np.ndarray, rendered: np.ndarray, range_max: float) -> list[float]:
    """Share of the mapped beams (rendered within range_max) in each residual bin; the shares
    of no returns and of residuals off the histogram make up the rest."""
    mapped = np.isfinite(rendered) & (rendered < range_max)
    returned = np.isfinite(readings) & (readings < range_max)
    residual = (readings - rendered)[mapped & returned]
    counts, _ = np.histogram(residual, HISTOGRAM_EDGES)
    return (counts / max(int(mapped.sum()), 1)).round(6).tolist()


def laser_residuals(
    grid: OccupancyGrid,
    simulator_args: dict[str, Any],
    noise: NoiseModel,
    laser_poses: np.ndarray,
    ranges: np.ndarray,
    seed: int,
) -> tuple[LaserCorruptions, dict[str, Any]]:
    """(fitted corruptions, {measured figures, residual histograms}) of real `ranges` (N, B) at
    `laser_poses` (N, 3); `simulator_args`: ScanSimulator's spec, mode and unknown_blocks."""
    simulator = ScanSimulator(grid, noise=NoNoise(), **simulator_args)
    spec = simulator.spec
    rendered = simulator.cast(laser_poses)
    fitted, measured = measure_corruptions(ranges, rendered, spec.range_max)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0,)))
    twin = ScanSimulator(grid, noise=noise, **simulator_args).finish(rendered, rng)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1,)))
    corrupted = simulator.finish(fitted.apply(rendered, rng), rng)
    doc = {
        "measured": measured,
        "histogram": {
            "edges_m": HISTOGRAM_EDGES.round(6).tolist(),
            "real": _histogram(ranges, rendered, spec.range_max),
            "noise_model": _histogram(twin, rendered, spec.range_max),
            "corrupted": _histogram(corrupted, rendered, spec.range_max),
        },
    }
    return fitted, doc
