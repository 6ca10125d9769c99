"""amcl's resampler as a part: KLD sampling with random-pose injection (kernels in
localize/kld_resampling.py), and selective resampling (skip while the effective sample size
exceeds half the particles)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

from scanloc.localize.kld_resampling import resample_kld

# m -> (poses (m, 3), weights (m,)): where injected draws come from (the filter's proposal).
Injector = Callable[[int], tuple[np.ndarray, np.ndarray]]


class Resampler(Protocol):
    """Draws a new particle set; None when it decides not to resample. `injected` counts the
    injected draws so far."""

    injected: int

    def resample(
        self,
        poses: np.ndarray,
        weights: np.ndarray,
        w_diff: float,
        inject: Injector,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The new (poses, normalised weights); each draw is injected with probability w_diff."""
        ...


class KldResampler:
    """amcl's pf_update_resample: draws until the KLD bound of the occupied bins (`dims`, the
    estimator's histogram) is exceeded, clamped to [min_particles, max_particles]."""

    def __init__(
        self,
        dims: np.ndarray,
        min_particles: int = 100,
        max_particles: int = 5000,
        kld_err: float = 0.01,
        kld_z: float = 0.99,
        selective: bool = False,
    ) -> None:
        self.dims = dims
        self.min_particles, self.max_particles = min_particles, max_particles
        self.kld_err, self.kld_z, self.selective = kld_err, kld_z, selective
        self._bin_occupied = np.zeros(int(np.prod(dims[2:])), dtype=np.uint8)
        self.injected = 0

    def resample(
        self,
        poses: np.ndarray,
        weights: np.ndarray,
        w_diff: float,
        inject: Injector,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray] | None:
        n_eff = 1.0 / float(np.sum(weights**2))
        if self.selective and n_eff > 0.5 * len(weights):
            return None
        m = self.max_particles
        u_inject = rng.random(m)
        u_pick = rng.random(m)
        if w_diff > 0.0:
            inject_poses, inject_weights = inject(m)
        else:
            inject_poses, inject_weights = np.zeros((m, 3)), np.zeros(m)
        out, out_weights = np.empty((m, 3)), np.empty(m)
        count = resample_kld(
            poses,
            weights,
            u_pick,
            u_inject,
            w_diff,
            inject_poses,
            inject_weights,
            self.min_particles,
            m,
            self.kld_err,
            self.kld_z,
            self.dims,
            self._bin_occupied,
            out,
            out_weights,
        )
        if w_diff > 0.0:
            self.injected += int(np.count_nonzero(u_inject[:count] < w_diff))
        return np.ascontiguousarray(out[:count]), out_weights[:count] / out_weights[:count].sum()
