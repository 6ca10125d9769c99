"""Wheel odometry: the true per-step motion, split as (rot1, trans, rot2), reported with
alpha-style Gaussian noise plus systematic scale errors, and integrated (see
scanloc.trajectory.drive's doc)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanloc.pose import wrap_angle


@dataclass(frozen=True)
class OdometryNoise:
    """Wheel odometry errors per step (alpha-style random part plus systematic scale errors).

    alpha1: rotation variance per squared rotation; alpha2: rotation variance per squared
    translation (rad²/m²); alpha3: translation variance per squared translation; alpha4:
    translation variance per squared rotation (m²/rad²). trans_scale / rot_scale: reported
    translation / rotation = (1 + scale) · true. The defaults model a calibrated
    differential drive: about 5 % random error per step, 0.5 % / 0.25 % scale errors.
    """

    alpha1: float = 0.0025
    alpha2: float = 0.0004
    alpha3: float = 0.0025
    alpha4: float = 0.0001
    trans_scale: float = 0.005
    rot_scale: float = 0.0025

    def __post_init__(self) -> None:
        if min(self.alpha1, self.alpha2, self.alpha3, self.alpha4) < 0:
            raise ValueError("odometry noise alphas must be >= 0")


def integrate_odometry(
    start: np.ndarray, steps: np.ndarray, noise: OdometryNoise, rng: np.random.Generator
) -> np.ndarray:
    """Odometry poses (T, 3) from true per-step (rot1, trans, rot2) increments and the noise."""
    rot1, trans, rot2 = steps.T
    sd_rot1 = np.sqrt(noise.alpha1 * rot1**2 + noise.alpha2 * trans**2)
    sd_trans = np.sqrt(noise.alpha3 * trans**2 + noise.alpha4 * (rot1**2 + rot2**2))
    sd_rot2 = np.sqrt(noise.alpha1 * rot2**2 + noise.alpha2 * trans**2)
    z = rng.standard_normal((len(steps), 3))
    r1 = (1.0 + noise.rot_scale) * rot1 + sd_rot1 * z[:, 0]
    tr = (1.0 + noise.trans_scale) * trans + sd_trans * z[:, 1]
    r2 = (1.0 + noise.rot_scale) * rot2 + sd_rot2 * z[:, 2]
    heading_before = start[2] + np.concatenate([[0.0], np.cumsum(r1 + r2)[:-1]])
    heading_mid = heading_before + r1
    out = np.empty((len(steps) + 1, 3))
    out[0] = start
    out[1:, 0] = start[0] + np.cumsum(tr * np.cos(heading_mid))
    out[1:, 1] = start[1] + np.cumsum(tr * np.sin(heading_mid))
    out[1:, 2] = wrap_angle(heading_mid + r2)
    return out
