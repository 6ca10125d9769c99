"""Tracking the learned localizer's hypotheses over time with odometry: a Gaussian-sum filter.

One scan alone can be ambiguous (a symmetric map); odometry says how the robot moved since the
last one. The belief is a mixture of Gaussians over (x, y, θ), each an EKF:
- predict: every component moves by the odometry increment, with amcl's diff-corrected
  process noise (as the CNN+odometry EKF, fusion.py);
- update: the scan's K hypotheses (poses z_j, weights w_j, predicted standard deviations) act
  as a mixture likelihood, with a `clutter` share for "the network is wrong on this scan":
      L(x) = clutter · u + (1 - clutter) · Σ_j w_j N(x; z_j, R_j),
  u the uniform density over the map's free space and R_j = diag(max(inflation·std_j, floor)²).
  The posterior of component i is a clutter branch (component i unchanged, weight α_i·clutter·u)
  and one Kalman update per hypothesis (weight α_i (1 - clutter) w_j N(z_j; m_i, P_i + R_j));
- birth: a share `birth` of the prior is "the robot may be anywhere" (uniform), whose product
  with L starts a component at every hypothesis: this initialises the filter and re-localizes
  it after a kidnap, but only takes over when no tracked component explains the scans;
- components within `merge_distance` m and `merge_angle_deg` merge (moment matching) and the
  `max_components` heaviest are kept.
The estimate is the heaviest component's mean and covariance; `n_particles` counts components.
Heading innovations are wrapped to (−π, π].
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from scanloc.estimates import estimate_table
from scanloc.localize.config_params import params_from_config
from scanloc.localize.fusion import _predict
from scanloc.pose import wrap_angle


@dataclass(frozen=True)
class TrackerParams:
    """The Gaussian-sum filter's parameters (see the module docstring); the odometry alphas
    are fusion.FusionParams' (4 × the trajectory's odometry noise variances)."""

    odom_alpha1: float = 0.01
    odom_alpha2: float = 0.0016
    odom_alpha3: float = 0.01
    odom_alpha4: float = 0.0004
    measurement_inflation: float = 2.0
    min_std_xy: float = 0.05
    min_std_theta: float = 0.02
    clutter: float = 0.1
    birth: float = 1e-3
    max_components: int = 10
    merge_distance: float = 0.2
    merge_angle_deg: float = 5.0

    def __post_init__(self) -> None:
        if not (0.0 < self.clutter < 1.0 and 0.0 < self.birth < 1.0):
            raise ValueError(
                f"clutter and birth must lie in (0, 1), got {self.clutter}, {self.birth}"
            )
        if self.max_components < 1 or self.measurement_inflation <= 0:
            raise ValueError("max_components must be >= 1 and measurement_inflation > 0")
        if self.min_std_xy <= 0 or self.min_std_theta <= 0:
            raise ValueError("min_std_xy and min_std_theta must be > 0")

    @classmethod
    def from_config(cls, config: Mapping[str, object]) -> TrackerParams:
        return params_from_config(cls, config, "tracker")


def _gaussian(innovation: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """N(ν; 0, S) for innovations (..., 3) and covariances (..., 3, 3)."""
    solved = np.linalg.solve(cov, innovation[..., None])[..., 0]
    mahal = np.einsum("...i,...i->...", innovation, solved)
    det = np.linalg.det(cov)
    return np.exp(-0.5 * mahal) / np.sqrt((2.0 * math.pi) ** 3 * det)


def _merge(
    weights: np.ndarray, means: np.ndarray, covs: np.ndarray, params: TrackerParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge components close to a heavier one (moment matching), keep the heaviest ones."""
    order = np.argsort(-weights, kind="stable")
    weights, means, covs = weights[order], means[order], covs[order]
    used = np.zeros(len(weights), dtype=bool)
    out_w, out_m, out_c = [], [], []
    angle = math.radians(params.merge_angle_deg)
    for i in range(len(weights)):
        if used[i]:
            continue
        d = np.hypot(means[:, 0] - means[i, 0], means[:, 1] - means[i, 1])
        a = np.abs(wrap_angle(means[:, 2] - means[i, 2]))
        group = ~used & (d <= params.merge_distance) & (a <= angle)
        used |= group
        w = weights[group]
        total = w.sum()
        dev = means[group] - means[i]
        dev[:, 2] = wrap_angle(dev[:, 2])
        shift = (w[:, None] * dev).sum(axis=0) / total
        mean = means[i] + shift
        mean[2] = wrap_angle(mean[2])
        centred = dev - shift
        cov = (w[:, None, None] * (covs[group] + centred[:, :, None] * centred[:, None, :])).sum(
            axis=0
        ) / total
        out_w.append(total)
        out_m.append(mean)
        out_c.append(cov)
        if len(out_w) == params.max_components:
            break
    return np.array(out_w), np.array(out_m), np.array(out_c)


def track_hypotheses(
    odometry: np.ndarray,
    times: np.ndarray,
    hypotheses: Mapping[str, np.ndarray],
    uniform_density: float,
    params: TrackerParams | None = None,
):
    """The Gaussian-sum filter over a run: odometry (T, 3), the learned localizer's hypotheses
    ("poses" (T, K, 3), "weights" (T, K), "stds" (T, K, 3)) and u, the uniform density over
    the free space (1 / (free area · 2π)). Returns the per-step table."""
    params = params or TrackerParams()
    poses = np.asarray(hypotheses["poses"], dtype=np.float64)
    hyp_w = np.asarray(hypotheses["weights"], dtype=np.float64)
    stds = np.asarray(hypotheses["stds"], dtype=np.float64)
    steps = len(odometry)
    if poses.shape[:1] != (steps,) or hyp_w.shape != poses.shape[:2] or stds.shape != poses.shape:
        raise ValueError(
            f"hypotheses must cover the {steps} steps: poses {poses.shape}, weights "
            f"{hyp_w.shape}, stds {stds.shape}"
        )
    alphas = (params.odom_alpha1, params.odom_alpha2, params.odom_alpha3, params.odom_alpha4)
    floor = np.array([params.min_std_xy, params.min_std_xy, params.min_std_theta])
    weights = np.zeros(0)
    means = np.zeros((0, 3))
    covs = np.zeros((0, 3, 3))
    out_mean = np.full((steps, 3), np.nan)
    out_cov = np.full((steps, 3, 3), np.nan)
    counts = np.zeros(steps, dtype=np.int64)
    eye = np.eye(3)
    for t in range(steps):
        if t and len(weights):
            moved = [
                _predict(m, c, odometry[t - 1], odometry[t], alphas)
                for m, c in zip(means, covs, strict=True)
            ]
            means = np.array([m for m, _ in moved])
            covs = np.array([c for _, c in moved])
        z = poses[t]
        w = hyp_w[t] / max(hyp_w[t].sum(), 1e-300)
        sd = np.maximum(params.measurement_inflation * stds[t], floor)
        r = eye * (sd**2)[:, :, None]
        u, clutter = uniform_density, params.clutter
        prior = weights * (1.0 - params.birth) if len(weights) else weights
        # clutter branches: each component as predicted
        new_w = [prior * clutter * u]
        new_m, new_c = [means], [covs]
        if len(weights):
            nu = z[None, :, :] - means[:, None, :]  # (M, K, 3)
            nu[..., 2] = wrap_angle(nu[..., 2])
            s = covs[:, None] + r[None]  # (M, K, 3, 3)
            like = _gaussian(nu, s)
            gain = np.linalg.solve(s, np.broadcast_to(covs[:, None], s.shape)).swapaxes(-1, -2)
            upd_m = means[:, None] + np.einsum("mkij,mkj->mki", gain, nu)
            upd_m[..., 2] = wrap_angle(upd_m[..., 2])
            keep = eye - gain
            upd_c = keep @ covs[:, None] @ keep.swapaxes(-1, -2) + gain @ r[None] @ gain.swapaxes(
                -1, -2
            )
            new_w.append((prior[:, None] * (1.0 - clutter) * w[None] * like).ravel())
            new_m.append(upd_m.reshape(-1, 3))
            new_c.append(upd_c.reshape(-1, 3, 3))
        birth = params.birth if len(weights) else 1.0
        new_w.append(birth * (1.0 - clutter) * w * u)
        new_m.append(z)
        new_c.append(r)
        weights = np.concatenate(new_w)
        means = np.concatenate(new_m)
        covs = np.concatenate(new_c)
        total = weights.sum()
        weights = weights / total if total > 0 else np.full(len(weights), 1.0 / len(weights))
        weights, means, covs = _merge(weights, means, covs, params)
        covs = 0.5 * (covs + covs.swapaxes(-1, -2))
        out_mean[t], out_cov[t], counts[t] = means[0], covs[0], len(weights)
    return estimate_table(np.arange(steps), times, out_mean, out_cov, counts)
