"""Where amcl puts particles that do not descend from its own: the proposal distribution.

amcl uses it to initialise without a pose (global localization) and to inject random poses
when its recovery averages say the filter may be lost. `UniformProposal` is amcl's: free cell
centres drawn uniformly, headings uniform. A proposal also knows its density q(x) (per m² and
radian), which importance sampling needs to weight what it proposes against the prior.

`Weighting` says how proposed particles are weighted; `PriorWeights` is amcl's: the uniform
proposal samples the prior itself, so proposed particles weigh as much as resampled ones.
The hybrid's importance weights (localize/hybrid.py) are the other implementation. How many
particles are proposed at an update is the mixing's (mixing.py).
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from scanloc.world.occupancy_grid import OccupancyGrid


class Proposal(Protocol):
    """A distribution over poses (x, y, θ) that can be sampled and evaluated, possibly
    conditioned on the current scan (`needs_scan`: the filter then calls `observe(scan)` with
    every scan and defers a global initialisation to the first scan)."""

    needs_scan: bool

    def observe(self, scan: np.ndarray) -> None:
        """Condition on the scan of the coming update."""
        ...

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """n poses (n, 3), θ in (-π, π]."""
        ...

    def density(self, poses: np.ndarray) -> np.ndarray:
        """q at each pose (N, 3), per m² and radian."""
        ...

    def counts(self) -> dict[str, int]:
        """What the proposal did over the run, for the localize stage's timing record."""
        ...


class UniformProposal:
    """Uniform over the free cells (amcl's uniformPoseGenerator with its free-cell list):
    a free cell's centre, heading uniform; 0.5 of a cell off when `half_cell_offset` (amcl)."""

    needs_scan = False

    def __init__(self, grid: OccupancyGrid, half_cell_offset: bool = False) -> None:
        free_rows, free_cols = np.nonzero(grid.free)
        if free_rows.size == 0:
            raise ValueError("the map has no free cell: amcl needs free space to place particles")
        offset = 0.5 if half_cell_offset else 0.0
        self.free_xy = np.column_stack(
            [
                grid.origin[0] + (free_cols + 0.5 - offset) * grid.resolution,
                grid.origin[1] + (free_rows + 0.5 - offset) * grid.resolution,
            ]
        )
        self.grid = grid
        self.free = grid.free  # (the grid's property recomputes the mask on every call)
        # per m² and radian: 1 / (free area · 2π)
        self.uniform_density = 1.0 / (free_rows.size * grid.resolution**2 * 2.0 * math.pi)

    def observe(self, scan: np.ndarray) -> None:
        """The uniform proposal ignores the scan."""

    def counts(self) -> dict[str, int]:
        """Nothing to count: sampling free cells costs no network run."""
        return {}

    def poses_from_uniforms(self, u: np.ndarray) -> np.ndarray:
        """Poses from uniforms u (n, 2) in [0, 1): u[:, 0] picks the cell, u[:, 1] the heading."""
        n_free = len(self.free_xy)
        cells = np.minimum((u[:, 0] * n_free).astype(np.int64), n_free - 1)
        return np.column_stack([self.free_xy[cells], u[:, 1] * 2.0 * math.pi - math.pi])

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        return self.poses_from_uniforms(rng.random((n, 2)))

    def density(self, poses: np.ndarray) -> np.ndarray:
        col, row = self.grid.world_to_cell(poses[:, 0], poses[:, 1])
        g = self.grid
        inside = (col >= 0) & (col < g.width) & (row >= 0) & (row < g.height)
        free = np.zeros(len(poses), dtype=bool)
        free[inside] = self.free[row[inside], col[inside]]
        return np.where(free, self.uniform_density, 0.0)


class Weighting(Protocol):
    """How the filter weights particles its proposal put there."""

    def initial_weights(self, poses: np.ndarray) -> np.ndarray:
        """Weights of a global initialisation's particles (normalised by the filter)."""
        ...

    def injection_weights(self, poses: np.ndarray) -> np.ndarray:
        """Weights of the poses a recovery injects while resampling (a resampled one: 1)."""
        ...

    def mixed_weights(
        self, poses: np.ndarray, weights: np.ndarray, proposed: np.ndarray
    ) -> np.ndarray:
        """Weights (normalised) of the union of the motion-predicted particles `poses` with
        their `weights` and the `proposed` ones the mixing drew, in that order."""
        ...


class PriorWeights:
    """amcl's weighting: proposed particles sample the prior (uniform) directly, and a mixed
    union keeps each part's share (N / (N + m) for the predicted, m / (N + m) for the
    proposed), without correcting for where the proposal put them."""

    def initial_weights(self, poses: np.ndarray) -> np.ndarray:
        return np.full(len(poses), 1.0 / len(poses))

    def injection_weights(self, poses: np.ndarray) -> np.ndarray:
        return np.ones(len(poses))

    def mixed_weights(
        self, poses: np.ndarray, weights: np.ndarray, proposed: np.ndarray
    ) -> np.ndarray:
        n, m = len(poses), len(proposed)
        return np.concatenate([weights * n, np.ones(m)]) / (n + m)
