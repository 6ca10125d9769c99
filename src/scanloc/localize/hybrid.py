"""Hybrid localization: amcl with the learned localizer's hypotheses as its proposal.

Two parts plugged into amcl's particle filter (localize/mcl/): `LearnedProposal`, the
proposal, and `ImportanceWeights`, how the particles it proposes are weighted; conf/localizer/
hybrid.yaml sets the rest (resample and estimate on every update).

amcl finds itself slowly (global localization from a uniform cloud) and rarely recovers from a
kidnap (random free poses seldom land near the truth); the learned localizer is global but
coarse. Here amcl keeps its parts (motion model, sensor model, KLD resampling, clusters) and
the learned model supplies the proposal q(x | scan): a mixture of Gaussians at its k best
hypotheses of the current scan (weights, and predicted standard deviations inflated and
floored), with a defensive share `uniform_share` of amcl's uniform proposal, so that a
useless network cannot leave the filter worse off than uniform sampling would.

The proposal is used where amcl draws particles that do not descend from its own, and every
proposed particle is importance-weighted, so that the filter stays a consistent estimator
(Akai et al., ICRA 2020; the mixture proposal of Thrun et al., "Robust Monte Carlo localization
for mobile robots", 2001):
- initialisation without a pose (on the first scan): particles from q, weighted by the prior
  over q, u(x) / q(x), u uniform over the free space;
- recovery (amcl's w_slow / w_fast injection): injected poses from q, weighted u(x) / q(x);
- every update, `mixture_share` · N extra particles from q. All particles are then weighted by
  the balance heuristic of multiple importance sampling: w = p(z|x) · bel⁻(x) / m(x), with
  m = (1 - φ) · bel⁻_motion(x) + φ · q(x) the density they were drawn from, and bel⁻ =
  (1 - ε) · bel⁻_motion + ε · u the prediction with a kidnap probability ε; bel⁻_motion is the
  motion-predicted particles' density, histogrammed in amcl's 0.5 m × 0.5 m × 10° bins.
  These weights are approximate (they replace the predicted particles' weights rather than
  multiply them); they are kept as they are here.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numba
import numpy as np

from scanloc.localize.clustering import BIN_THETA, BIN_XY, particle_bins
from scanloc.localize.config_params import params_from_config
from scanloc.localize.mcl.proposals import UniformProposal
from scanloc.pose import wrap_angle, wrap_pi

BIN_VOLUME = BIN_XY * BIN_XY * BIN_THETA  # m² rad


@dataclass(frozen=True)
class HybridParams:
    """The learned proposal and how the filter uses it (see the module docstring)."""

    k: int = 20
    std_inflation: float = 1.5
    min_std_xy: float = 0.1
    min_std_theta: float = 0.05
    uniform_share: float = 0.1
    mixture_share: float = 0.05
    kidnap_probability: float = 0.1

    def __post_init__(self) -> None:
        if self.k < 1 or self.std_inflation <= 0 or min(self.min_std_xy, self.min_std_theta) <= 0:
            raise ValueError(
                "need k >= 1, std_inflation > 0 and positive standard-deviation floors"
            )
        for name in ("uniform_share", "mixture_share", "kidnap_probability"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise ValueError(f"{name} must lie in [0, 1), got {getattr(self, name)}")

    @classmethod
    def from_config(cls, config: Mapping[str, object]) -> HybridParams:
        return params_from_config(cls, config, "hybrid proposal")


@numba.njit(cache=True, parallel=True)
def _mixture_density(
    poses: np.ndarray, means: np.ndarray, stds: np.ndarray, weights: np.ndarray
) -> np.ndarray:
    """Σ_k w_k N(x; μ_k, diag σ_k²) at each pose, the heading difference wrapped; terms below
    e⁻²⁵ of their component's peak are dropped."""
    k_count = means.shape[0]
    inv = 1.0 / stds
    scale = np.empty(k_count)
    for k in range(k_count):
        scale[k] = weights[k] / ((2.0 * math.pi) ** 1.5 * stds[k, 0] * stds[k, 1] * stds[k, 2])
    out = np.zeros(poses.shape[0])
    for i in numba.prange(poses.shape[0]):
        total = 0.0
        for k in range(k_count):
            dx = (poses[i, 0] - means[k, 0]) * inv[k, 0]
            q = dx * dx
            if q >= 50.0:
                continue
            dy = (poses[i, 1] - means[k, 1]) * inv[k, 1]
            q += dy * dy
            if q >= 50.0:
                continue
            dt = wrap_pi(poses[i, 2] - means[k, 2]) * inv[k, 2]
            q += dt * dt
            if q < 50.0:
                total += scale[k] * math.exp(-0.5 * q)
        out[i] = total
    return out


class LearnedProposal:
    """q(x | scan): the learned localizer's hypotheses as a Gaussian mixture, with a defensive
    uniform share. `observe(scan)` conditions it on a scan; the network runs only when the
    filter first samples or evaluates q for that scan (not on scans amcl skips)."""

    needs_scan = True

    def __init__(
        self,
        hypotheses_of: Callable[[np.ndarray], object],
        uniform: UniformProposal,
        params: HybridParams,
    ) -> None:
        self.hypotheses_of, self.uniform, self.params = hypotheses_of, uniform, params
        self.means = np.zeros((0, 3))
        self.stds = np.zeros((0, 3))
        self.weights = np.zeros(0)
        self._scan: np.ndarray | None = None
        self.inferences = 0

    def observe(self, scan: np.ndarray) -> None:
        self._scan = scan

    def _condition(self) -> None:
        """Run the network on the observed scan, once."""
        if self._scan is None:
            if not len(self.weights):
                raise RuntimeError("LearnedProposal: observe(scan) before sampling")
            return
        p = self.params
        hyp = self.hypotheses_of(self._scan)
        self._scan = None
        self.inferences += 1
        weights = np.asarray(hyp.weights[0][: p.k], dtype=np.float64)
        keep = weights > 0
        self.means = np.ascontiguousarray(hyp.poses[0][: p.k][keep])
        floor = np.array([p.min_std_xy, p.min_std_xy, p.min_std_theta])
        self.stds = np.ascontiguousarray(
            np.maximum(p.std_inflation * hyp.stds[0][: p.k][keep], floor)
        )
        self.weights = weights[keep] / weights[keep].sum()

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """n poses: each from the uniform share with probability uniform_share, else from a
        hypothesis picked by weight."""
        self._condition()
        uniform = rng.random(n) < self.params.uniform_share
        component = rng.choice(len(self.weights), size=n, p=self.weights)
        poses = self.means[component] + self.stds[component] * rng.standard_normal((n, 3))
        poses[:, 2] = wrap_angle(poses[:, 2])
        poses[uniform] = self.uniform.sample(int(uniform.sum()), rng)
        return poses

    def density(self, poses: np.ndarray) -> np.ndarray:
        self._condition()
        poses = np.ascontiguousarray(poses, dtype=np.float64)
        share = self.params.uniform_share
        mixture = _mixture_density(poses, self.means, self.stds, self.weights)
        return (1.0 - share) * mixture + share * self.uniform.density(poses)


class ImportanceWeights:
    """The hybrid's weighting of proposed particles (see the module docstring): u(x) / q(x) for
    the initialisation's and the recovery's, and the balance heuristic over the motion-predicted
    particles plus `mixture_share` · N from q at every update."""

    def __init__(self, proposal: LearnedProposal, params: HybridParams, dims: np.ndarray) -> None:
        self.proposal, self.params, self.dims = proposal, params, dims
        self.uniform = proposal.uniform

    def _prior_over_proposal(self, poses: np.ndarray) -> np.ndarray:
        q = self.proposal.density(poses)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(q > 0, self.uniform.density(poses) / q, 0.0)

    def initial_weights(self, poses: np.ndarray) -> np.ndarray:
        return self.uniform.density(poses) / self.proposal.density(poses)

    def injection_weights(self, poses: np.ndarray) -> np.ndarray:
        """Recovery poses stand for amcl's uniform injection: weighted u(x) / q(x)."""
        return self._prior_over_proposal(poses)

    def predict(
        self, poses: np.ndarray, weights: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """Add the proposal's share of particles and weight every particle by the balance
        heuristic (the sensor update follows)."""
        h = self.params
        if h.mixture_share <= 0:
            return poses, weights
        extra = self.proposal.sample(max(1, round(h.mixture_share * len(poses))), rng)
        motion = np.concatenate([poses, extra])
        bel_motion = self.motion_density(poses, weights, motion)
        prior = (1.0 - h.kidnap_probability) * bel_motion
        prior += h.kidnap_probability * self.uniform.density(motion)
        drawn = (1.0 - h.mixture_share) * bel_motion + h.mixture_share * self.proposal.density(
            motion
        )
        with np.errstate(divide="ignore", invalid="ignore"):
            new = np.where(drawn > 0, prior / drawn, 0.0)
        total = new.sum()
        new = new / total if total > 0 else np.full(len(motion), 1.0 / len(motion))
        return np.ascontiguousarray(motion), new

    def motion_density(self, poses: np.ndarray, weights: np.ndarray, at: np.ndarray) -> np.ndarray:
        """The density (per m² rad) of the weighted particles `poses` at `at`, histogrammed in
        amcl's bins."""
        hist = np.zeros(int(np.prod(self.dims[2:])))
        np.add.at(hist, particle_bins(poses, self.dims), weights)
        return hist[particle_bins(np.ascontiguousarray(at), self.dims)] / BIN_VOLUME
