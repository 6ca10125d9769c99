"""Fit amcl's odometry noise (`odom_alpha1..4`) to a run's odometry against its true poses.

amcl's motion models (motion.py) give each part of an odometry change (rot1, trans, rot2) a
noise variance that is linear in the alphas:

    var(rot1)  = α1·rot1² + α2·trans²        var(rot2) = α1·rot2² + α2·trans²
    var(trans) = α3·trans² + α4·(rot1² + rot2²)

(rotations folded as amcl folds them: backing up counts as forward). The residuals between the
odometry's change and the truth's are draws of that noise, so their squares have the variances
as their means: a non-negative least-squares fit of the squared residuals on the squared
motions is the moment estimate of the alphas. The rotations are fitted through the heading
change rot1 + rot2, whose variance is α1·(rot1² + rot2²) + 2·α2·trans² (the two draws are
independent): rot1 alone is the bearing of the translation, which a short step leaves
undetermined (a 3 cm step's bearing can be off by any angle while the heading is right), so
its residual says nothing about the noise. These are the `diff-corrected` model's alphas (true
standard deviations); ROS 1's `diff` passes the variance as a standard deviation, so its
alphas do not have this meaning.

Used to choose a real-log configuration on the mapping part of a log (its corrected poses are
the truth there), never on the part that is scored.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import nnls

from scanloc.localize.mcl.motion import angle_diff, decompose
from scanloc.pose import wrap_angle


def folded(rotation: float) -> float:
    """amcl's rotation magnitude for the noise: min(|rot|, |rot − π|), wrapped."""
    return min(abs(angle_diff(rotation, 0.0)), abs(angle_diff(rotation, math.pi)))


def motion_residuals(odometry: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per step: the odometry's folded (rot1, trans, rot2) magnitudes (T−1, 3) and the residuals
    (T−1, 3) odometry − truth of the same three parts."""
    odometry, truth = np.asarray(odometry, np.float64), np.asarray(truth, np.float64)
    if odometry.shape != truth.shape or odometry.ndim != 2 or odometry.shape[1] != 3:
        raise ValueError(
            f"odometry and truth must be (T, 3) arrays of one shape, got {odometry.shape} "
            f"and {truth.shape}"
        )
    if len(odometry) < 3:
        raise ValueError(f"need at least 3 poses to fit motion noise, got {len(odometry)}")
    motions, residuals = [], []
    for k in range(1, len(odometry)):
        odo = decompose(odometry[k - 1], odometry[k])
        true = decompose(truth[k - 1], truth[k])
        motions.append((folded(odo[0]), odo[1], folded(odo[2])))
        residuals.append(
            (angle_diff(odo[0], true[0]), odo[1] - true[1], angle_diff(odo[2], true[2]))
        )
    return np.array(motions), np.array(residuals)


def fit_odometry_alphas(
    odometry: np.ndarray, truth: np.ndarray, cuts: tuple[int, ...] = ()
) -> tuple[float, float, float, float]:
    """(α1, α2, α3, α4) of the `diff-corrected` model that best explain the odometry's errors
    against the truth (module doc). The steps into `cuts` (a run's kidnap steps: the truth
    jumps there, the odometry does not) and steps with non-finite poses are left out."""
    motions, residuals = motion_residuals(odometry, truth)
    keep = np.isfinite(motions).all(axis=1) & np.isfinite(residuals).all(axis=1)
    keep[[k - 1 for k in cuts if 0 < k < len(odometry)]] = False
    motions, residuals = motions[keep], residuals[keep]
    rot1, trans, rot2 = motions.T
    heading_sq = wrap_angle(residuals[:, 0] + residuals[:, 2]) ** 2
    rotation_rows = np.stack([rot1**2 + rot2**2, 2.0 * trans**2], axis=1)
    translation_rows = np.stack([trans**2, rot1**2 + rot2**2], axis=1)
    a12, _ = nnls(rotation_rows, heading_sq)
    a34, _ = nnls(translation_rows, residuals[:, 1] ** 2)
    return float(a12[0]), float(a12[1]), float(a34[0]), float(a34[1])
