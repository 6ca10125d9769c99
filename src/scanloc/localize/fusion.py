"""CNN + odometry fusion: an extended Kalman filter over (x, y, θ) (the paper's future work, §6).

The CNN localizes every scan on its own, globally, so its errors do not accumulate but do not
average out either; odometry is smooth but drifts. The filter combines them:
- Prediction: each step's odometry change, split as amcl's odometry model splits it
  (`mcl.motion.decompose`: rot1, trans, rot2), moves the estimate; the process noise is amcl's
  `diff-corrected` model (standard deviations sqrt(alpha1·rot² + alpha2·trans²) for the
  rotations, sqrt(alpha3·trans² + alpha4·(rot1² + rot2²)) for the translation, reverse driving
  folded like forward) mapped through the motion's Jacobian. Only increments are used, so the
  odometry frame may sit anywhere in the map.
- Update: the CNN ensemble's per-step mean measures the pose directly (H = I) with noise
  R = measurement_inflation · Σ + diag(min_std_xy², min_std_xy², min_std_theta²), Σ the members'
  covariance. Ensemble members trained alike agree more than they are right, hence the
  inflation; the additive floor keeps a confident-but-wrong ensemble (or a single network, whose
  Σ is NaN and counts as 0) from collapsing the filter. The θ innovation is wrapped to (−π, π].
- Gate: a measurement whose squared Mahalanobis distance to the prediction (innovation
  covariance P + R) exceeds the chi-square quantile (3 degrees of freedom) of
  `gate_probability` is rejected: a gross CNN failure does not drag the estimate away.
- Initialisation: from the first finite measurement (pose = measurement, covariance = R); no
  true pose is needed. Steps before it have no estimate (NaN). A run of `reinit_after`
  consecutive measurements outside the gate re-initialises the filter from the last of them
  (0: never), so a filter that has lost track recovers from the CNN's global estimates.
Steps whose measurement is not finite get the prediction alone.

Output: the shared per-step table (estimates.py) with the filter's posterior mean and
covariance; `n_particles` is 1, the filter's one Gaussian hypothesis.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import pandas as pd

from scanloc.estimates import estimate_table
from scanloc.localize.config_params import params_from_config
from scanloc.localize.mcl.motion import decompose, noise_sigmas
from scanloc.pose import wrap_angle


@dataclass(frozen=True)
class FusionParams:
    """Filter parameters. The alphas default to 4 × the variances of conf/trajectory.yaml's
    odometry noise (its systematic scale errors need room); the measurement noise defaults
    double the ensemble's standard deviation and keep at least 5 cm and 3°."""

    odom_alpha1: float = 0.01  # rad² rotation variance per rad² of rotation
    odom_alpha2: float = 0.0016  # rad² rotation variance per m² of translation
    odom_alpha3: float = 0.01  # m² translation variance per m² of translation
    odom_alpha4: float = 0.0004  # m² translation variance per rad² of rotation
    measurement_inflation: float = 4.0  # multiplies the ensemble covariance Σ
    min_std_xy: float = 0.05  # metres, added in quadrature to x and y
    min_std_theta: float = 0.05  # radians, added in quadrature to θ
    gate_probability: float = 0.999  # chi-square (3 dof) probability of the acceptance region
    reinit_after: int = 10  # consecutive out-of-gate measurements that re-initialise; 0: never

    def __post_init__(self) -> None:
        alphas = (self.odom_alpha1, self.odom_alpha2, self.odom_alpha3, self.odom_alpha4)
        if not all(math.isfinite(a) and a >= 0 for a in alphas):
            raise ValueError(f"odom_alpha1..4 must be finite and >= 0, got {alphas}")
        if not (math.isfinite(self.measurement_inflation) and self.measurement_inflation > 0):
            raise ValueError(f"measurement_inflation must be > 0, got {self.measurement_inflation}")
        for name in ("min_std_xy", "min_std_theta"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be > 0 (it keeps R invertible), got {value}")
        if not 0 < self.gate_probability < 1:
            raise ValueError(f"gate_probability must lie in (0, 1), got {self.gate_probability}")
        if self.reinit_after < 0:
            raise ValueError(f"reinit_after must be >= 0 (0: never), got {self.reinit_after}")

    @classmethod
    def from_config(cls, config: Mapping[str, object]) -> FusionParams:
        """Parameters from a config mapping (the `fusion` section of a localizer config).

        Raises ValueError for an unknown key (listing the known ones) or a wrong type.
        """
        return params_from_config(cls, config, "fusion")


class Fusion(NamedTuple):
    """The per-step table and which steps' measurements the gate rejected or re-initialised
    the filter (bool (T,) each)."""

    table: pd.DataFrame
    rejected: np.ndarray
    reinitialised: np.ndarray


def _predict(
    mean: np.ndarray,
    cov: np.ndarray,
    old_odom: np.ndarray,
    new_odom: np.ndarray,
    alphas: tuple[float, float, float, float],
) -> tuple[np.ndarray, np.ndarray]:
    """Apply one odometry change (rot1, trans, rot2) to the estimate and grow its covariance."""
    rot1, trans, rot2 = decompose(old_odom, new_odom)
    sigmas = np.array(noise_sigmas("diff-corrected", alphas, old_odom, new_odom))
    heading = mean[2] + rot1
    c, s = math.cos(heading), math.sin(heading)
    moved = mean + np.array([trans * c, trans * s, rot1 + rot2])
    moved[2] = wrap_angle(moved[2])
    f_state = np.array([[1.0, 0.0, -trans * s], [0.0, 1.0, trans * c], [0.0, 0.0, 1.0]])
    f_motion = np.array([[-trans * s, c, 0.0], [trans * c, s, 0.0], [1.0, 0.0, 1.0]])
    grown = f_state @ cov @ f_state.T + (f_motion * sigmas**2) @ f_motion.T
    return moved, grown


def measurement_noise(cov: np.ndarray, params: FusionParams) -> np.ndarray:
    """R = inflation · Σ + diag(floor²); a non-finite Σ (a single network) counts as 0."""
    cov = np.asarray(cov, dtype=np.float64)
    spread = 0.5 * (cov + cov.T) if np.isfinite(cov).all() else np.zeros((3, 3))
    floor = (params.min_std_xy**2, params.min_std_xy**2, params.min_std_theta**2)
    return params.measurement_inflation * spread + np.diag(floor)


def fuse_odometry(
    odometry: np.ndarray,
    times: np.ndarray,
    measurements: np.ndarray,
    measurement_covs: np.ndarray,
    params: FusionParams | None = None,
) -> Fusion:
    """Fuse per-step odometry poses (T, 3) with CNN pose measurements (T, 3) and their
    covariances (T, 3, 3) (see the module docstring); `times` (T,) is copied into the table."""
    params = params or FusionParams()
    odometry = np.asarray(odometry, dtype=np.float64)
    times = np.asarray(times, dtype=np.float64)
    measurements = np.asarray(measurements, dtype=np.float64)
    measurement_covs = np.asarray(measurement_covs, dtype=np.float64)
    if odometry.ndim != 2 or odometry.shape[1] != 3 or odometry.shape[0] < 1:
        raise ValueError(f"odometry must have shape (T, 3) with T >= 1, got {odometry.shape}")
    steps = odometry.shape[0]
    for name, array, shape in (
        ("times", times, (steps,)),
        ("measurements", measurements, (steps, 3)),
        ("measurement_covs", measurement_covs, (steps, 3, 3)),
    ):
        if array.shape != shape:
            raise ValueError(f"{name} must have shape {shape} (T from odometry), got {array.shape}")
    if not np.isfinite(odometry).all():
        raise ValueError("odometry must be finite at every step")
    alphas = (params.odom_alpha1, params.odom_alpha2, params.odom_alpha3, params.odom_alpha4)
    from scipy.stats import chi2  # imported here: scipy.stats takes a second to load

    gate = chi2.ppf(params.gate_probability, df=3)
    means = np.full((steps, 3), np.nan)
    covs = np.full((steps, 3, 3), np.nan)
    rejected = np.zeros(steps, dtype=bool)
    reinitialised = np.zeros(steps, dtype=bool)
    mean: np.ndarray | None = None
    cov = np.full((3, 3), np.nan)
    outside = 0  # consecutive measurements outside the gate
    for k in range(steps):
        if mean is not None:
            mean, cov = _predict(mean, cov, odometry[k - 1], odometry[k], alphas)
        z = measurements[k]
        if np.isfinite(z).all():
            r = measurement_noise(measurement_covs[k], params)
            if mean is None:
                mean, cov = z.copy(), r
            else:
                innovation = z - mean
                innovation[2] = wrap_angle(innovation[2])
                s = cov + r
                if innovation @ np.linalg.solve(s, innovation) <= gate:
                    gain = np.linalg.solve(s, cov).T  # P S⁻¹ (P and S symmetric)
                    mean = mean + gain @ innovation
                    keep = np.eye(3) - gain
                    cov = keep @ cov @ keep.T + gain @ r @ gain.T  # Joseph form
                    outside = 0
                else:
                    outside += 1
                    if outside == params.reinit_after:
                        mean, cov, outside = z.copy(), r, 0
                        reinitialised[k] = True
                    else:
                        rejected[k] = True
            mean[2] = wrap_angle(mean[2])
            cov = 0.5 * (cov + cov.T)
        if mean is not None:
            means[k], covs[k] = mean, cov
    table = estimate_table(np.arange(steps), times, means, covs, 1)
    return Fusion(table, rejected, reinitialised)
