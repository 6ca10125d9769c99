"""Hybrid localization: amcl with the learned localizer's hypotheses as its proposal.

Parts plugged into amcl's particle filter (localize/mcl/), each registered under the `type` a
localizer config names: `LearnedProposal`, the proposal (`proposal: {type: learned}`);
`ImportanceWeights`, how the particles it proposes are weighted (`weighting: {type:
importance}`); and how many it proposes at an update, the mixing (`mixing: {type: constant}`,
`adaptive` or `verified_gate`). conf/localizer/hybrid.yaml sets the rest (resample and estimate
on every update).

amcl finds itself slowly (global localization from a uniform cloud) and rarely recovers from a
kidnap (random free poses seldom land near the truth); the learned localizer is global but
coarse. Here amcl keeps its parts (motion model, sensor model, KLD resampling, clusters) and
the learned model supplies the proposal q(x | scan): a mixture of Gaussians at its k best
hypotheses of the current scan (their probabilities as weights, or with `weights_from: score`
their calibrated scores after verification against the map; predicted standard deviations
inflated and floored), with a defensive share `uniform_share` of amcl's uniform proposal, so that a
useless network cannot leave the filter worse off than uniform sampling would.

The proposal is used where amcl draws particles that do not descend from its own, and every
proposed particle is importance-weighted, so that the filter stays a consistent estimator
(Akai et al., ICRA 2020; the mixture proposal of Thrun et al., "Robust Monte Carlo localization
for mobile robots", 2001):
- initialisation without a pose (on the first scan): particles from q, weighted by the prior
  over q, u(x) / q(x), u uniform over the free space;
- recovery (amcl's w_slow / w_fast injection): injected poses from q, weighted u(x) / q(x);
- at an update, m = round(φ N) extra particles from q beside the N motion-predicted ones.

The weights of an update with m > 0 (the derivation). The motion-predicted particles x̃_j with
their carried weights w_j (normalised) are a weighted sample of the motion prediction
b(x) = Σ_i w_i p(x | x_i, u); the m proposed y_l, each weighing 1/m, are a sample of q. With
the shares α = N/(N+m) and β = m/(N+m) the union {(x̃_j, α w_j), (y_l, β/m)} is a weighted
sample of the mixture d = α b + β q, which is what the particles were drawn from. The target
is the posterior p(z|x) bel⁻(x), bel⁻ = (1 - ε) b + ε u (ε: the kidnap probability per
update), so each particle's weight is multiplied by r(x) = bel⁻(x) / d(x), then by the sensor
model's p(z|x) (the filter's sensor update):
    w_j ← α w_j r(x̃_j) p(z|x̃_j),   w_l ← (β/m) r(y_l) p(z|y_l).
With m = 0 (no proposal particle) the union is the motion sample alone and the update is
amcl's, w_j ← w_j p(z|x̃_j): the kidnap share ε then has no particle to weigh.
b is evaluated as a Gaussian kernel density of the predicted particles with their carried
weights, b̂(x) = Σ_j w_j N(x; x̃_j, diag(h_xy², h_xy², h_θ²)) (numba), not histogrammed; its
kernels sit at `kernel_centres` (M) of the particles picked by weight, which keeps the cost at
O((N + m) M).
The error this leaves is bounded: r is a ratio of two functions affine in b, so
|ln r(b̂) - ln r(b)| ≤ |ln(b̂ / b)| (its logarithmic derivative in ln b is a difference of
two numbers in [0, 1]); and r always lies between (1 - ε)/α and ε u / (β q), whatever b̂.
tests/test_hybrid_posterior.py checks the weights against a brute-force Bayes filter on a grid.

Adaptive mixing (`mixing: {type: adaptive}`): the share follows the scan likelihood as in
augmented MCL. Short- and long-term averages of the mean sensor factor (rates `alpha_fast` /
`alpha_slow`, mcl/averages.py) give lost = 1 - w_fast / w_slow; the share is
φ · clip((lost - τ) / (1 - τ), 0, 1) with the threshold τ = `threshold`, so while the filter
is localized (lost ≤ τ) no proposal particle is drawn, the update is amcl's, and the network
does not run.

The verified gate (`mixing: {type: verified_gate}`): the share is φ only when the map says the
filter is elsewhere, else 0. At each update the filter's estimate (the predicted particles' weighted
mean) and the network's hypotheses are refined against the map and scored by the share of the
scan they explain (the verifier of hypothesis_verification.py); the gate opens when a
hypothesis away from the estimate explains at least `margin` more of the scan, on
`persistence` updates in a row. On real logs the likelihood ratio is no such signal: a
peaky sensor model's likelihood falls at every pose the map covers poorly. One scan is not
enough either: where the map misses what the laser sees, a look-alike elsewhere can explain
more of a scan than the true pose for a scan or two, and proposed particles there capture the
filter (120 beams' likelihood ratio outweighs any kidnap prior). After a kidnap the mismatch
lasts. For the first `warmup` updates the gate stays open (the share is φ): at a global
start the filter may settle on a look-alike that explains the scan almost as well as the
truth (fr079's parallel corridors), which no margin tells apart but a few more scans of
proposals do. The network runs on every update (its cost is not amortised).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np

from scanloc.localize.hypothesis_verification import HypothesisVerifier, VerifierParams
from scanloc.localize.mcl.averages import LikelihoodAverages
from scanloc.localize.mcl.parts import MIXINGS, PROPOSALS, WEIGHTINGS, PartsContext
from scanloc.localize.mcl.proposals import UniformProposal
from scanloc.pose import compose, wrap_angle, wrap_pi


@dataclass(frozen=True)
class LearnedProposalParams:
    """The `proposal` section of type `learned`: the network's standard deviations times
    `std_inflation`, at least `min_std_xy` / `min_std_theta` (m, rad); a defensive
    `uniform_share` of amcl's uniform proposal; the components weighted by the network's
    probabilities (`weights_from: network`) or by their verified scores (`score`, with
    `learned.verified`). The hypotheses are the `learned` section's k best."""

    std_inflation: float = 1.5
    min_std_xy: float = 0.1
    min_std_theta: float = 0.05
    uniform_share: float = 0.1
    weights_from: str = "network"

    def __post_init__(self) -> None:
        if self.weights_from not in ("network", "score"):
            raise ValueError(
                f"weights_from must be 'network' or 'score', got {self.weights_from!r}"
            )
        if self.std_inflation <= 0 or min(self.min_std_xy, self.min_std_theta) <= 0:
            raise ValueError("need std_inflation > 0 and positive standard-deviation floors")
        if not 0.0 <= self.uniform_share < 1.0:
            raise ValueError(f"uniform_share must lie in [0, 1), got {self.uniform_share}")


@dataclass(frozen=True)
class ImportanceWeightParams:
    """The `weighting` section of type `importance`: the prior probability per update of having
    been carried elsewhere (`kidnap_probability`, ε), and the kernel density of the
    motion-predicted particles (`kernel_std_xy` / `_theta`, at `kernel_centres` of them)."""

    kidnap_probability: float = 0.3
    kernel_std_xy: float = 0.05
    kernel_std_theta: float = 0.05
    kernel_centres: int = 500

    def __post_init__(self) -> None:
        if not 0.0 <= self.kidnap_probability < 1.0:
            raise ValueError(
                f"kidnap_probability must lie in [0, 1), got {self.kidnap_probability}"
            )
        if min(self.kernel_std_xy, self.kernel_std_theta) <= 0 or self.kernel_centres < 1:
            raise ValueError("need kernel_std_xy, kernel_std_theta > 0 and kernel_centres >= 1")


def _check_share(share: float) -> None:
    if not 0.0 <= share < 1.0:
        raise ValueError(f"share must lie in [0, 1), got {share}")


@dataclass(frozen=True)
class ConstantMixingParams:
    """The `mixing` section of type `constant`: φ, the share of the particle count drawn from
    the proposal at every update."""

    share: float = 0.05

    def __post_init__(self) -> None:
        _check_share(self.share)


@dataclass(frozen=True)
class AdaptiveMixingParams:
    """The `mixing` section of type `adaptive`: φ scaled by how far the likelihood fell,
    clip((lost - `threshold`) / (1 - `threshold`), 0, 1), lost from averages with rates
    `alpha_slow` / `alpha_fast` (conf/localizer/hybrid_adaptive.yaml: how they were chosen)."""

    share: float = 0.05
    threshold: float = 0.3
    alpha_slow: float = 0.05
    alpha_fast: float = 0.8

    def __post_init__(self) -> None:
        _check_share(self.share)
        if not 0.0 <= self.threshold < 1.0:
            raise ValueError(f"threshold must lie in [0, 1), got {self.threshold}")
        if not (0 < self.alpha_slow <= 1 and 0 < self.alpha_fast <= 1):
            raise ValueError("alpha_slow / alpha_fast must lie in (0, 1]")


@dataclass(frozen=True)
class VerifiedGateParams:
    """The `mixing` section of type `verified_gate`: φ while the gate is open, else 0; open when
    a hypothesis away from the estimate explains `margin` more of the scan on `persistence`
    updates in a row, and on the first `warmup` updates (conf/localizer/hybrid_real.yaml: how
    they were chosen). Its verifier is the `verifier` section's."""

    share: float = 0.2
    margin: float = 0.4
    persistence: int = 3
    warmup: int = 20

    def __post_init__(self) -> None:
        _check_share(self.share)
        if not 0.0 < self.margin < 1.0:
            raise ValueError(f"margin must lie in (0, 1), got {self.margin}")
        if self.persistence < 1 or self.warmup < 0:
            raise ValueError(
                f"need persistence >= 1 and warmup >= 0, got {self.persistence}, {self.warmup}"
            )


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
        params: LearnedProposalParams,
    ) -> None:
        self.hypotheses_of, self.uniform, self.params = hypotheses_of, uniform, params
        self.means = np.zeros((0, 3))
        self.stds = np.zeros((0, 3))
        self.weights = np.zeros(0)
        self._scan: np.ndarray | None = None
        self.scan: np.ndarray | None = None  # the last observed scan
        self.inferences = 0

    def observe(self, scan: np.ndarray) -> None:
        self._scan = self.scan = scan

    def condition(self) -> None:
        """Run the network on the observed scan, once."""
        if self._scan is None:
            if not len(self.weights):
                raise RuntimeError("LearnedProposal: observe(scan) before sampling")
            return
        p = self.params
        hyp = self.hypotheses_of(self._scan)
        self._scan = None
        self.inferences += 1
        keep = np.asarray(hyp.weights[0]) > 0
        if p.weights_from == "score":
            if hyp.scores is None:
                raise ValueError(
                    "proposal: weights_from 'score' needs verified hypotheses (`verified: true` "
                    "in the localizer's `learned` section)"
                )
            weights = np.asarray(hyp.scores[0], dtype=np.float64)
            keep &= weights > 0
        else:
            weights = np.asarray(hyp.weights[0], dtype=np.float64)
        self.means = np.ascontiguousarray(hyp.poses[0][keep])
        floor = np.array([p.min_std_xy, p.min_std_xy, p.min_std_theta])
        self.stds = np.ascontiguousarray(np.maximum(p.std_inflation * hyp.stds[0][keep], floor))
        self.weights = weights[keep] / weights[keep].sum()

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """n poses: each from the uniform share with probability uniform_share, else from a
        hypothesis picked by weight."""
        self.condition()
        uniform = rng.random(n) < self.params.uniform_share
        component = rng.choice(len(self.weights), size=n, p=self.weights)
        poses = self.means[component] + self.stds[component] * rng.standard_normal((n, 3))
        poses[:, 2] = wrap_angle(poses[:, 2])
        poses[uniform] = self.uniform.sample(int(uniform.sum()), rng)
        return poses

    def density(self, poses: np.ndarray) -> np.ndarray:
        self.condition()
        poses = np.ascontiguousarray(poses, dtype=np.float64)
        share = self.params.uniform_share
        mixture = _mixture_density(poses, self.means, self.stds, self.weights)
        return (1.0 - share) * mixture + share * self.uniform.density(poses)

    def counts(self) -> dict[str, int]:
        """The network's runs."""
        return {"n_network_runs": self.inferences}


class VerifiedGate:
    """Opens when, on `persistence` calls in a row, a hypothesis away from the filter's
    estimate explains `margin` more of the scan than the estimate does, both refined against
    the map (the module docstring). The estimate and the hypotheses are poses of the robot's
    base; the verifier scores laser poses (base ⊕ `laser_mount`)."""

    def __init__(
        self,
        verifier: HypothesisVerifier,
        margin: float,
        laser_mount: tuple[float, float, float] = (0.0, 0.0, 0.0),
        persistence: int = 1,
    ) -> None:
        self.verifier, self.margin, self.persistence = verifier, margin, persistence
        self.laser_mount = np.asarray(laser_mount, dtype=np.float64)
        self.in_a_row = 0

    def opens(
        self, scan: np.ndarray, poses: np.ndarray, weights: np.ndarray, hypotheses: np.ndarray
    ) -> bool:
        self.in_a_row = self.in_a_row + 1 if self.elsewhere(scan, poses, weights, hypotheses) else 0
        return self.in_a_row >= self.persistence

    def elsewhere(
        self, scan: np.ndarray, poses: np.ndarray, weights: np.ndarray, hypotheses: np.ndarray
    ) -> bool:
        """Whether this scan alone says the filter is elsewhere."""
        if not len(hypotheses):
            return False
        heading = math.atan2(weights @ np.sin(poses[:, 2]), weights @ np.cos(poses[:, 2]))
        estimate = np.array([*(weights @ poses[:, :2]), heading])
        candidates = np.vstack([estimate, hypotheses])
        if any(self.laser_mount):
            candidates = np.array([compose(p, self.laser_mount) for p in candidates])
        refined, features = self.verifier.features(scan, candidates, np.ones(len(candidates)))
        params = self.verifier.params
        away = (np.hypot(*(refined[1:, :2] - refined[0, :2]).T) > params.merge_distance) | (
            np.abs(wrap_angle(refined[1:, 2] - refined[0, 2]))
            > math.radians(params.merge_angle_deg)
        )
        explained = features[:, 0]
        return bool(away.any() and explained[1:][away].max() - explained[0] >= self.margin)


class ConstantMixing:
    """φ at every update."""

    def __init__(self, params: ConstantMixingParams) -> None:
        self.params = params
        self.updates = self.mixed_updates = 0

    def share(self, poses: np.ndarray, weights: np.ndarray) -> float:
        self.updates += 1
        share = self.decide(poses, weights)
        self.mixed_updates += share > 0
        return share

    def decide(self, poses: np.ndarray, weights: np.ndarray) -> float:
        return self.params.share

    def observe_likelihood(self, w_avg: float) -> None:
        """A constant share follows nothing."""

    def counts(self) -> dict[str, int]:
        """Updates, and those that drew proposed particles."""
        return {"n_updates": self.updates, "n_mixed_updates": int(self.mixed_updates)}


class AdaptiveMixing(ConstantMixing):
    """φ scaled by how far the scan likelihood fell (augmented MCL's averages)."""

    def __init__(self, params: AdaptiveMixingParams) -> None:
        super().__init__(params)  # type: ignore[arg-type]
        self.averages = LikelihoodAverages(params.alpha_slow, params.alpha_fast)

    def decide(self, poses: np.ndarray, weights: np.ndarray) -> float:
        p = self.params
        scale = (self.averages.lost() - p.threshold) / (1.0 - p.threshold)  # type: ignore[attr-defined]
        return p.share * min(max(scale, 0.0), 1.0)

    def observe_likelihood(self, w_avg: float) -> None:
        self.averages.follow(w_avg)


class VerifiedGateMixing(ConstantMixing):
    """φ while the verified gate is open or in the warm-up, else 0 (the module docstring)."""

    def __init__(
        self, params: VerifiedGateParams, proposal: LearnedProposal, gate: VerifiedGate
    ) -> None:
        super().__init__(params)  # type: ignore[arg-type]
        self.proposal, self.gate = proposal, gate

    def decide(self, poses: np.ndarray, weights: np.ndarray) -> float:
        self.proposal.condition()
        assert self.proposal.scan is not None
        opens = self.gate.opens(self.proposal.scan, poses, weights, self.proposal.means)
        warmup = self.params.warmup  # type: ignore[attr-defined]
        return self.params.share if opens or self.updates <= warmup else 0.0


class ImportanceWeights:
    """The hybrid's weighting of proposed particles (see the module docstring): u(x) / q(x) for
    the initialisation's and the recovery's, and bel⁻ / d for the union of the motion-predicted
    particles and the mixing's proposed ones at an update."""

    def __init__(self, proposal: LearnedProposal, params: ImportanceWeightParams) -> None:
        self.proposal, self.params = proposal, params
        self.uniform = proposal.uniform
        p = params
        self.kernel_stds = np.array([p.kernel_std_xy, p.kernel_std_xy, p.kernel_std_theta])

    def _prior_over_proposal(self, poses: np.ndarray) -> np.ndarray:
        q = self.proposal.density(poses)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(q > 0, self.uniform.density(poses) / q, 0.0)

    def initial_weights(self, poses: np.ndarray) -> np.ndarray:
        return self.uniform.density(poses) / self.proposal.density(poses)

    def injection_weights(self, poses: np.ndarray) -> np.ndarray:
        """Recovery poses stand for amcl's uniform injection: weighted u(x) / q(x)."""
        return self._prior_over_proposal(poses)

    def mixed_weights(
        self, poses: np.ndarray, weights: np.ndarray, proposed: np.ndarray
    ) -> np.ndarray:
        """Every carried weight times bel⁻ / d (the sensor update follows)."""
        n, m, eps = len(poses), len(proposed), self.params.kidnap_probability
        union = np.ascontiguousarray(np.concatenate([poses, proposed]))
        alpha, beta = n / (n + m), m / (n + m)
        bel_motion = self.motion_density(poses, weights, union)
        prior = (1.0 - eps) * bel_motion + eps * self.uniform.density(union)
        drawn = alpha * bel_motion + beta * self.proposal.density(union)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(drawn > 0, prior / drawn, 0.0)
        new = np.concatenate([alpha * weights, np.full(m, beta / m)]) * ratio
        total = new.sum()
        return new / total if total > 0 else np.full(len(union), 1.0 / len(union))

    def motion_density(self, poses: np.ndarray, weights: np.ndarray, at: np.ndarray) -> np.ndarray:
        """b̂ at `at`: the Gaussian kernel density (per m² rad) of the weighted particles, its
        kernels at `kernel_centres` of them picked by weight (deterministic systematic
        resampling, each weighing 1/M; all of them, with their weights, when there are fewer):
        the cost is O((N + m) M) instead of O((N + m) N)."""
        centres, centre_weights = poses, weights
        m = self.params.kernel_centres
        if len(poses) > m:
            cumulative = np.cumsum(weights)
            picks = np.searchsorted(cumulative, (np.arange(m) + 0.5) / m * cumulative[-1])
            centres = poses[np.minimum(picks, len(poses) - 1)]
            centre_weights = np.full(m, 1.0 / m)
        stds = np.broadcast_to(self.kernel_stds, centres.shape)
        return _mixture_density(
            np.ascontiguousarray(at, dtype=np.float64),
            np.ascontiguousarray(centres, dtype=np.float64),
            np.ascontiguousarray(stds),
            np.ascontiguousarray(centre_weights, dtype=np.float64),
        )


@PROPOSALS.register("learned", LearnedProposalParams)
def learned_proposal(params: LearnedProposalParams, context: PartsContext) -> LearnedProposal:
    """The learned localizer's hypotheses of each scan (the `learned` section's model)."""
    if context.hypotheses is None:
        raise ValueError(
            f"{context.where}: section 'proposal': type 'learned' needs a `learned` section"
        )
    return LearnedProposal(context.hypotheses(), context.uniform, params)


@WEIGHTINGS.register("importance", ImportanceWeightParams)
def importance_weights(params: ImportanceWeightParams, context: PartsContext) -> ImportanceWeights:
    return ImportanceWeights(_learned(context, "weighting", "importance"), params)


@MIXINGS.register("constant", ConstantMixingParams)
def constant_mixing(params: ConstantMixingParams, context: PartsContext) -> ConstantMixing:
    return ConstantMixing(params)


@MIXINGS.register("adaptive", AdaptiveMixingParams)
def adaptive_mixing(params: AdaptiveMixingParams, context: PartsContext) -> AdaptiveMixing:
    return AdaptiveMixing(params)


@MIXINGS.register("verified_gate", VerifiedGateParams)
def verified_gate_mixing(params: VerifiedGateParams, context: PartsContext) -> VerifiedGateMixing:
    verifier = HypothesisVerifier(
        context.grid, context.laser, context.section(VerifierParams, "verifier")
    )
    gate = VerifiedGate(verifier, params.margin, context.laser_mount, params.persistence)
    return VerifiedGateMixing(params, _learned(context, "mixing", "verified_gate"), gate)


def _learned(context: PartsContext, section: str, kind: str) -> LearnedProposal:
    if not isinstance(context.proposal, LearnedProposal):
        raise ValueError(
            f"{context.where}: section '{section}': type '{kind}' needs the proposal of type "
            "'learned'"
        )
    return context.proposal
