"""amcl's odometry motion models: decomposition, amcl's quirks and the sampled statistics."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from scanloc.localize.mcl.motion import angle_diff, decompose, noise_sigmas, sample_motion

ALPHAS = (0.05, 0.02, 0.03, 0.01)  # small enough that a sampled translation stays > 0
angles = st.floats(-20.0, 20.0, allow_nan=False)


@given(angles, angles)
def test_angle_diff_is_the_wrapped_difference(a: float, b: float) -> None:
    d = angle_diff(a, b)
    assert -math.pi <= d <= math.pi
    assert math.isclose(math.cos(d), math.cos(a - b), abs_tol=1e-9)
    assert math.isclose(math.sin(d), math.sin(a - b), abs_tol=1e-9)


def test_decompose_forward_turn_and_in_place_rotation() -> None:
    old = np.array([1.0, 2.0, 0.3])
    rot1, trans, rot2 = decompose(old, np.array([1.0 + math.cos(0.5), 2.0 + math.sin(0.5), 1.0]))
    assert (rot1, trans, rot2) == pytest.approx((0.2, 1.0, 0.5))
    # Under 0.01 m of translation amcl does not take a bearing: the whole turn is rot2.
    rot1, trans, rot2 = decompose(old, np.array([1.005, 2.0, 1.3]))
    assert rot1 == 0.0 and trans == pytest.approx(0.005) and rot2 == pytest.approx(1.0)


def test_reverse_driving_gets_the_noise_of_forward_driving() -> None:
    old = np.array([0.0, 0.0, 0.0])
    forward = noise_sigmas("diff-corrected", ALPHAS, old, np.array([0.5, 0.0, 0.1]))
    backward = noise_sigmas("diff-corrected", ALPHAS, old, np.array([-0.5, 0.0, 0.1]))
    rot1, _, _ = decompose(old, np.array([-0.5, 0.0, 0.1]))
    assert abs(rot1) == pytest.approx(math.pi)  # the bearing of backing up is behind the robot
    assert backward == pytest.approx(forward)


def test_diff_passes_the_variance_where_diff_corrected_passes_its_root() -> None:
    old, new = np.array([0.0, 0.0, 0.0]), np.array([0.3, 0.1, 0.4])
    rot1, trans, rot2 = decompose(old, new)
    a1, a2, a3, a4 = ALPHAS
    v_rot1 = a1 * rot1**2 + a2 * trans**2
    v_trans = a3 * trans**2 + a4 * (rot1**2 + rot2**2)
    v_rot2 = a1 * rot2**2 + a2 * trans**2
    assert noise_sigmas("diff", ALPHAS, old, new) == pytest.approx((v_rot1, v_trans, v_rot2))
    assert noise_sigmas("diff-corrected", ALPHAS, old, new) == pytest.approx(
        (math.sqrt(v_rot1), math.sqrt(v_trans), math.sqrt(v_rot2))
    )
    with pytest.raises(ValueError, match="odom_model_type"):
        noise_sigmas("omni", ALPHAS, old, new)


@pytest.mark.parametrize("model", ["diff", "diff-corrected"])
def test_sampled_increments_match_the_model_mean_and_spread(model: str) -> None:
    n = 200_000
    start = np.array([2.0, -1.0, 2.9])
    # odometry frame rotated against the particles' frame: only relative motion may matter
    old_odom = np.array([5.0, 3.0, -0.7])
    rot1, trans, rot2 = 0.35, 0.8, -0.5
    heading = old_odom[2] + rot1
    new_odom = np.array(
        [
            old_odom[0] + trans * math.cos(heading),
            old_odom[1] + trans * math.sin(heading),
            old_odom[2] + rot1 + rot2,
        ]
    )
    poses = np.tile(start, (n, 1))
    sample_motion(poses, old_odom, new_odom, model, ALPHAS, np.random.default_rng(3))
    dx, dy = poses[:, 0] - start[0], poses[:, 1] - start[1]
    got_trans = np.hypot(dx, dy)
    got_rot1 = np.angle(np.exp(1j * (np.arctan2(dy, dx) - start[2])))
    got_rot2 = np.angle(np.exp(1j * (poses[:, 2] - start[2] - got_rot1)))
    expected_sd = noise_sigmas(model, ALPHAS, old_odom, new_odom)
    for got, mean, sd in zip(
        (got_rot1, got_trans, got_rot2), (rot1, trans, rot2), expected_sd, strict=True
    ):
        assert abs(got.mean() - mean) < 5 * sd / math.sqrt(n)
        assert got.std() == pytest.approx(sd, rel=0.02)
    assert np.all(np.abs(poses[:, 2]) <= math.pi)


def test_sample_motion_is_reproducible_and_checks_its_input() -> None:
    old, new = np.zeros(3), np.array([0.2, 0.05, 0.1])
    a = np.zeros((50, 3))
    b = np.zeros((50, 3))
    sample_motion(a, old, new, "diff", ALPHAS, np.random.default_rng(1))
    sample_motion(b, old, new, "diff", ALPHAS, np.random.default_rng(1))
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        sample_motion(np.zeros((5, 2)), old, new, "diff", ALPHAS, np.random.default_rng(1))
