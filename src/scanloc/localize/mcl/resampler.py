"""Resamplers as parts, chosen by the `filter` section's `resampler` (KLD or fixed size), with
amcl's random-pose injection, and `selective_resampling` (resample only while the effective
sample size is below half the particles, Beluga's `on_effective_size_drop`) around either."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

from scanloc.localize.kld_resampling import pick_indices, resample_kld

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


def _draws(
    m: int, w_diff: float, inject: Injector, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(u_inject, u_pick, inject poses, inject weights) for up to m draws, in amcl's order."""
    u_inject = rng.random(m)
    u_pick = rng.random(m)
    if w_diff > 0.0:
        inject_poses, inject_weights = inject(m)
    else:
        inject_poses, inject_weights = np.zeros((m, 3)), np.zeros(m)
    return u_inject, u_pick, inject_poses, inject_weights


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
    ) -> None:
        self.dims = dims
        self.min_particles, self.max_particles = min_particles, max_particles
        self.kld_err, self.kld_z = kld_err, kld_z
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
        m = self.max_particles
        u_inject, u_pick, inject_poses, inject_weights = _draws(m, w_diff, inject, rng)
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


class FixedResampler:
    """Always `max_particles` draws (multinomial, as amcl picks), with the same injection."""

    def __init__(self, max_particles: int = 5000) -> None:
        self.max_particles = max_particles
        self.injected = 0

    def resample(
        self,
        poses: np.ndarray,
        weights: np.ndarray,
        w_diff: float,
        inject: Injector,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray] | None:
        m = self.max_particles
        u_inject, u_pick, inject_poses, inject_weights = _draws(m, w_diff, inject, rng)
        injected = u_inject < w_diff
        out = poses[pick_indices(weights, u_pick)]
        out_weights = np.ones(m)
        out[injected] = inject_poses[injected]
        out_weights[injected] = inject_weights[injected]
        self.injected += int(np.count_nonzero(injected))
        return np.ascontiguousarray(out), out_weights / out_weights.sum()


class SelectiveResampling:
    """Resample only while the effective sample size 1 / Σw² is at most half the particles
    (amcl's `selective_resampling`), with the resampler it wraps."""

    def __init__(self, resampler: Resampler) -> None:
        self.resampler = resampler

    @property
    def injected(self) -> int:
        return self.resampler.injected

    def resample(
        self,
        poses: np.ndarray,
        weights: np.ndarray,
        w_diff: float,
        inject: Injector,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray] | None:
        if 1.0 / float(np.sum(weights**2)) > 0.5 * len(weights):
            return None
        return self.resampler.resample(poses, weights, w_diff, inject, rng)


# name -> resampler from (the estimator's bins, min_particles, max_particles, kld_err, kld_z)
RESAMPLERS: dict[str, Callable[[np.ndarray, int, int, float, float], Resampler]] = {
    "kld": KldResampler,
    "fixed": lambda dims, min_particles, max_particles, kld_err, kld_z: FixedResampler(
        max_particles
    ),
}
