"""Fitting amcl's odometry alphas: odometry made with known alphas gives them back, and a
perfect odometry fits to zero noise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanloc.localize.mcl.motion import noise_variances
from scanloc.localize.mcl.motion_fit import fit_odometry_alphas


def chain(parts: np.ndarray) -> np.ndarray:
    """Poses (T+1, 3) from (rot1, trans, rot2) steps, starting at the origin."""
    poses = np.zeros((len(parts) + 1, 3))
    for k, (rot1, trans, rot2) in enumerate(parts, start=1):
        x, y, theta = poses[k - 1]
        heading = theta + rot1
        poses[k] = (x + trans * math.cos(heading), y + trans * math.sin(heading), heading + rot2)
    poses[:, 2] = np.angle(np.exp(1j * poses[:, 2]))
    return poses


@pytest.mark.parametrize("alphas", [(0.05, 0.02, 0.02, 0.01), (0.2, 0.001, 0.005, 0.05)])
def test_known_alphas_come_back(alphas: tuple[float, float, float, float]) -> None:
    # amcl's generative model: the robot's true motion is the odometry's minus noise whose
    # variance follows from the odometry's own parts.
    rng = np.random.default_rng(3)
    steps = 20000
    odometry_parts = np.stack(
        [
            rng.uniform(-0.6, 0.6, steps),
            rng.uniform(0.5, 1.5, steps),
            rng.uniform(-0.6, 0.6, steps),
        ],
        axis=1,
    )
    odometry = chain(odometry_parts)
    true_parts = np.empty_like(odometry_parts)
    for k in range(steps):
        variances = noise_variances(alphas, odometry[k], odometry[k + 1])
        true_parts[k] = odometry_parts[k] - rng.standard_normal(3) * np.sqrt(variances)
        assert true_parts[k, 1] > 0.01  # a forward step stays one (else rot1 flips by π)
    fitted = fit_odometry_alphas(odometry, chain(true_parts))
    np.testing.assert_allclose(fitted, alphas, rtol=0.12, atol=2e-3)


def test_perfect_odometry_has_no_noise() -> None:
    parts = np.tile([0.1, 0.5, -0.2], (50, 1))
    truth = chain(parts)
    np.testing.assert_allclose(fit_odometry_alphas(truth, truth), 0.0, atol=1e-12)


def test_bad_shapes_are_refused() -> None:
    with pytest.raises(ValueError, match="one shape"):
        fit_odometry_alphas(np.zeros((5, 3)), np.zeros((4, 3)))
