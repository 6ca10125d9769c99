"""amcl's odometry motion models `diff` and `diff-corrected` (ROS 1 navigation, amcl_odom.cpp).

Both sample Thrun's odometry model (Probabilistic Robotics, p. 136): the odometry change between
two filter updates is split into a first rotation `rot1`, a translation `trans` and a second
rotation `rot2`; each particle applies a noisy copy of the three. Each model is a class
registered under its ROS `odom_model_type` name (`MOTION_MODELS`); a new model is one class.

amcl's details, reproduced here:
- `rot1` is set to 0 when the translation is under 0.01 m (in-place rotation has no bearing).
- Reverse driving is treated like forward driving: the rotations enter the noise as
  min(|rot|, |rot - π|) (angles wrapped), so backing up is not mistaken for two half turns.
- `diff` (the old model, ROS 1's default) hands the *variance* expression
  alpha1·rot² + alpha2·trans² to the Gaussian sampler where a standard deviation belongs; for
  alphas and motions below 1 this gives much less noise than intended. `diff-corrected` takes
  the square root, as the textbook does. Both are reproduced as ROS runs them.
- `odom_alpha5` only matters for amcl's omni models, which scanloc does not implement; configs
  may carry it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numba
import numpy as np

from scanloc.pose import wrap_angle, wrap_pi

MIN_TRANS_FOR_BEARING: float = 0.01  # metres; amcl's threshold below which rot1 = 0


def angle_diff(a: float, b: float) -> float:
    """amcl's angle_diff: the signed difference a - b wrapped into (-π, π] (amcl's own returns
    -π where this returns π: the same turn)."""
    return float(wrap_angle(a - b))


def odometry_delta(old_odom: np.ndarray, new_odom: np.ndarray) -> np.ndarray:
    """amcl's `delta`: (dx, dy) in the odometry frame and the wrapped heading change."""
    return np.array(
        [
            new_odom[0] - old_odom[0],
            new_odom[1] - old_odom[1],
            angle_diff(float(new_odom[2]), float(old_odom[2])),
        ]
    )


def decompose(old_odom: np.ndarray, new_odom: np.ndarray) -> tuple[float, float, float]:
    """(rot1, trans, rot2) of the odometry change from `old_odom` to `new_odom`, amcl's split."""
    dx, dy, dtheta = odometry_delta(np.asarray(old_odom, float), np.asarray(new_odom, float))
    trans = math.hypot(dx, dy)
    rot1 = 0.0 if trans < MIN_TRANS_FOR_BEARING else angle_diff(math.atan2(dy, dx), old_odom[2])
    rot2 = angle_diff(float(dtheta), rot1)
    return rot1, trans, rot2


@numba.njit(cache=True, parallel=True, fastmath=False)
def _apply_motion(
    poses: np.ndarray,
    rot1: float,
    trans: float,
    rot2: float,
    sigmas: np.ndarray,
    normals: np.ndarray,
) -> None:
    """Move every particle by its noisy (rot1, trans, rot2); headings are kept in (-π, π].

    The noisy rotations need no wrapping of their own: only the heading's cosine, sine and
    final wrap use them."""
    for i in numba.prange(poses.shape[0]):
        r1 = rot1 - sigmas[0] * normals[i, 0]
        tr = trans - sigmas[1] * normals[i, 1]
        r2 = rot2 - sigmas[2] * normals[i, 2]
        heading = poses[i, 2] + r1
        poses[i, 0] += tr * math.cos(heading)
        poses[i, 1] += tr * math.sin(heading)
        poses[i, 2] = wrap_pi(heading + r2)


def noise_variances(
    alphas: tuple[float, float, float, float], old_odom: np.ndarray, new_odom: np.ndarray
) -> tuple[float, float, float]:
    """amcl's variance expressions for rot1, trans and rot2 of the odometry change."""
    a1, a2, a3, a4 = alphas
    rot1, trans, rot2 = decompose(old_odom, new_odom)
    # Backward and forward motion are treated alike: fold rotations near ±π onto 0.
    rot1_noise = min(abs(angle_diff(rot1, 0.0)), abs(angle_diff(rot1, math.pi)))
    rot2_noise = min(abs(angle_diff(rot2, 0.0)), abs(angle_diff(rot2, math.pi)))
    v_rot1 = a1 * rot1_noise**2 + a2 * trans**2
    v_trans = a3 * trans**2 + a4 * rot1_noise**2 + a4 * rot2_noise**2
    v_rot2 = a1 * rot2_noise**2 + a2 * trans**2
    return v_rot1, v_trans, v_rot2


@dataclass(frozen=True)
class OdometryParams:
    """The odometry keys of a localizer config, named and defaulted as in ROS 1 amcl."""

    odom_model_type: str = "diff"
    odom_alpha1: float = 0.2
    odom_alpha2: float = 0.2
    odom_alpha3: float = 0.2
    odom_alpha4: float = 0.2
    odom_alpha5: float = 0.2

    def __post_init__(self) -> None:
        if self.odom_model_type not in MOTION_MODELS:
            raise ValueError(
                f"odom_model_type must be one of {sorted(MOTION_MODELS)}, "
                f"got {self.odom_model_type!r}"
            )
        if min(self.alphas) < 0:
            raise ValueError("odom_alpha1..4 must be >= 0")

    @property
    def alphas(self) -> tuple[float, float, float, float]:
        return (self.odom_alpha1, self.odom_alpha2, self.odom_alpha3, self.odom_alpha4)

    def model(self) -> MotionModel:
        """The motion model `odom_model_type` names, with these alphas."""
        return MOTION_MODELS[self.odom_model_type](self.alphas)


class MotionModel(Protocol):
    """Moves particles by a noisy copy of the odometry change between two filter updates."""

    def sample(
        self,
        poses: np.ndarray,
        old_odom: np.ndarray,
        new_odom: np.ndarray,
        rng: np.random.Generator,
    ) -> None:
        """Move `poses` (N, 3) in place."""
        ...


@dataclass(frozen=True)
class DiffMotion:
    """ROS 1's `diff`: the variance expressions used as standard deviations."""

    alphas: tuple[float, float, float, float]

    def sigmas(self, old_odom: np.ndarray, new_odom: np.ndarray) -> tuple[float, float, float]:
        return noise_variances(self.alphas, old_odom, new_odom)

    def sample(
        self,
        poses: np.ndarray,
        old_odom: np.ndarray,
        new_odom: np.ndarray,
        rng: np.random.Generator,
    ) -> None:
        """Apply the model to `poses` (N, 3) in place: one (N, 3) block of standard normals
        from `rng` per call, so a run is reproducible for a seed whatever the thread count."""
        if poses.ndim != 2 or poses.shape[1] != 3 or poses.dtype != np.float64:
            raise ValueError(f"poses must be float64 (N, 3), got {poses.dtype} {poses.shape}")
        sigmas = np.asarray(self.sigmas(old_odom, new_odom), dtype=np.float64)
        rot1, trans, rot2 = decompose(old_odom, new_odom)
        normals = rng.standard_normal((poses.shape[0], 3))
        _apply_motion(poses, rot1, trans, rot2, sigmas, normals)


@dataclass(frozen=True)
class DiffCorrectedMotion(DiffMotion):
    """ROS 1's `diff-corrected` (and nav2's differential model): true standard deviations."""

    def sigmas(self, old_odom: np.ndarray, new_odom: np.ndarray) -> tuple[float, float, float]:
        v_rot1, v_trans, v_rot2 = noise_variances(self.alphas, old_odom, new_odom)
        return math.sqrt(v_rot1), math.sqrt(v_trans), math.sqrt(v_rot2)


MOTION_MODELS: dict[str, Callable[[tuple[float, float, float, float]], DiffMotion]] = {
    "diff": DiffMotion,
    "diff-corrected": DiffCorrectedMotion,
}


def noise_sigmas(
    model: str,
    alphas: tuple[float, float, float, float],
    old_odom: np.ndarray,
    new_odom: np.ndarray,
) -> tuple[float, float, float]:
    """The values the model `model` passes to its Gaussian sampler for rot1, trans and rot2."""
    if model not in MOTION_MODELS:
        raise ValueError(f"odom_model_type must be one of {sorted(MOTION_MODELS)}, got {model!r}")
    return MOTION_MODELS[model](alphas).sigmas(old_odom, new_odom)


def sample_motion(
    poses: np.ndarray,
    old_odom: np.ndarray,
    new_odom: np.ndarray,
    model: str,
    alphas: tuple[float, float, float, float],
    rng: np.random.Generator,
) -> None:
    """Apply the motion model `model` (a ROS name) to `poses` (N, 3) in place."""
    if model not in MOTION_MODELS:
        raise ValueError(f"odom_model_type must be one of {sorted(MOTION_MODELS)}, got {model!r}")
    MOTION_MODELS[model](alphas).sample(poses, old_odom, new_odom, rng)
