"""Planar pose algebra and the one notion of "the right pose" that every package shares.

The ground floor of scanloc: any package may import it, and it imports nothing of scanloc.
Poses are (x, y, θ) with θ wrapped to (−π, π]. `recall_within` and its thresholds define when a
hypothesis counts as the truth (within 0.5 m and 10°): the learned localizer's recall, the
evaluation's convergence and the report all use this one definition.
"""

from __future__ import annotations

import math

import numba
import numpy as np

RECALL_DISTANCE_M = 0.5
RECALL_ANGLE_DEG = 10.0


def wrap_angle(angle: np.ndarray | float) -> np.ndarray:
    """Angles wrapped to (−π, π]."""
    return np.pi - np.mod(np.pi - np.asarray(angle, dtype=np.float64), 2.0 * np.pi)


@numba.njit(cache=True, inline="always")
def wrap_pi(angle: float) -> float:
    """One angle wrapped to (−π, π] in compiled code, as wrap_angle does (no trigonometry)."""
    return math.pi - np.mod(math.pi - angle, 2.0 * math.pi)


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a ⊕ b: pose b (given in a's frame) expressed in a's parent frame; θ wrapped."""
    c, s = math.cos(a[2]), math.sin(a[2])
    theta = a[2] + b[2]
    return np.array(
        [
            a[0] + c * b[0] - s * b[1],
            a[1] + s * b[0] + c * b[1],
            float(wrap_angle(theta)),
        ]
    )


def inverse(a: np.ndarray) -> np.ndarray:
    """⊖a: the pose whose composition with a gives the identity."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([-c * a[0] - s * a[1], s * a[0] - c * a[1], -a[2]])


def recall_within(
    hypotheses: np.ndarray,
    truth: np.ndarray,
    distance: float = RECALL_DISTANCE_M,
    angle_deg: float = RECALL_ANGLE_DEG,
) -> np.ndarray:
    """Whether the truth (N, 3) lies within `distance` m and `angle_deg` of at least one of each
    step's hypotheses (N, K, 3): the top-K recall of K hypotheses."""
    d = np.hypot(hypotheses[..., 0] - truth[:, None, 0], hypotheses[..., 1] - truth[:, None, 1])
    a = np.degrees(np.abs(wrap_angle(hypotheses[..., 2] - truth[:, None, 2])))
    return ((d <= distance) & (a <= angle_deg)).any(axis=1)
