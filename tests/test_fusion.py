"""CNN + odometry EKF: beats its measurements, gates outliers, wraps θ, is consistent."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from scanloc.estimates import TABLE_COLUMNS, table_covariances, table_poses
from scanloc.localize.catalog import raw_config
from scanloc.localize.config_params import parse_section
from scanloc.localize.fusion import FusionParams, fuse_odometry
from scanloc.pose import wrap_angle

CONF = Path(__file__).resolve().parents[1] / "conf" / "localizer"
RATE = 10.0
MEAS_STD = np.array([0.2, 0.2, 0.1])  # the synthetic CNN's x, y, θ noise
ODOM_ALPHAS = (0.01, 0.002, 0.01, 0.001)
EXACT = {"measurement_inflation": 1.0, "min_std_xy": 1e-4, "min_std_theta": 1e-4}


def drive(
    steps: int, speed: float, turn_rate: float, start: tuple[float, float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """True poses (T, 3) of a unicycle at constant speed and turn rate, and the per-step true
    (rot1, trans, rot2) increments (T - 1, 3)."""
    turn = turn_rate / RATE
    increments = np.tile([turn / 2, speed / RATE, turn / 2], (steps - 1, 1))
    return integrate(np.array(start), increments), increments


def integrate(start: np.ndarray, increments: np.ndarray) -> np.ndarray:
    poses = np.empty((len(increments) + 1, 3))
    poses[0] = start
    for k, (rot1, trans, rot2) in enumerate(increments):
        x, y, theta = poses[k]
        heading = theta + rot1
        poses[k + 1] = (x + trans * math.cos(heading), y + trans * math.sin(heading), 0.0)
        poses[k + 1, 2] = wrap_angle(heading + rot2)
    return poses


def noisy_increments(increments: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Odometry increments with the diff-corrected noise of ODOM_ALPHAS (turns well below π)."""
    a1, a2, a3, a4 = ODOM_ALPHAS
    rot1, trans, rot2 = increments.T
    sd = np.stack(
        [
            np.sqrt(a1 * rot1**2 + a2 * trans**2),
            np.sqrt(a3 * trans**2 + a4 * (rot1**2 + rot2**2)),
            np.sqrt(a1 * rot2**2 + a2 * trans**2),
        ],
        axis=1,
    )
    return increments + sd * rng.standard_normal(increments.shape)


def measure(truth: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """CNN-like measurements: truth plus N(0, diag(MEAS_STD²)), with that covariance."""
    z = truth + MEAS_STD * rng.standard_normal(truth.shape)
    z[:, 2] = wrap_angle(z[:, 2])
    return z, np.tile(np.diag(MEAS_STD**2), (len(truth), 1, 1))


def pose_errors(est: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.hypot(*(est[:, :2] - truth[:, :2]).T), np.abs(wrap_angle(est[:, 2] - truth[:, 2]))


def times(steps: int) -> np.ndarray:
    return np.arange(steps) / RATE


@pytest.mark.parametrize("turn_rate", [0.0, 0.4])
def test_perfect_odometry_beats_the_raw_measurements(turn_rate: float) -> None:
    rng = np.random.default_rng(1)
    truth, _ = drive(300, 0.5, turn_rate, (1.0, 2.0, 0.3))
    z, z_cov = measure(truth, rng)
    # The odometry frame is the map frame moved and turned: only increments may matter.
    c, s = math.cos(1.0), math.sin(1.0)
    odometry = np.column_stack(
        [5 + c * truth[:, 0] - s * truth[:, 1], -3 + s * truth[:, 0] + c * truth[:, 1]]
    )
    odometry = np.column_stack([odometry, wrap_angle(truth[:, 2] + 1.0)])
    params = FusionParams(1e-4, 1e-4, 1e-4, 1e-4, **EXACT)
    fused = fuse_odometry(odometry, times(300), z, z_cov, params)
    assert list(fused.table.columns) == list(TABLE_COLUMNS)
    assert (fused.table["n_particles"] == 1).all()
    fused_pos, fused_head = pose_errors(table_poses(fused.table), truth)
    raw_pos, raw_head = pose_errors(z, truth)
    assert fused_pos[50:].mean() < 0.25 * raw_pos[50:].mean()
    assert fused_head[50:].mean() < 0.25 * raw_head[50:].mean()
    assert fused.rejected.sum() <= 2 and not fused.reinitialised.any()
    # The first step is the first measurement itself, with its covariance.
    np.testing.assert_allclose(table_poses(fused.table)[0], z[0])
    np.testing.assert_allclose(table_covariances(fused.table)[0], z_cov[0], rtol=1e-6)


def test_gross_outlier_is_gated_out() -> None:
    rng = np.random.default_rng(2)
    truth, increments = drive(200, 0.5, 0.2, (0.0, 0.0, 0.0))
    odometry = integrate(truth[0], noisy_increments(increments, rng))
    z, z_cov = measure(truth, rng)
    z[120] += (3.0, -2.0, 2.0)  # a CNN failure, confident as ever
    z[120, 2] = wrap_angle(z[120, 2])
    params = FusionParams(*ODOM_ALPHAS, **EXACT)
    fused = fuse_odometry(odometry, times(200), z, z_cov, params)
    assert fused.rejected[120]
    assert fused.rejected.sum() <= 2  # 0.999 gate: the odd good measurement may fall outside
    pos, head = pose_errors(table_poses(fused.table), truth)
    assert pos[120] < 0.2 and head[120] < 0.1
    var_xx = fused.table["cov_xx"].to_numpy()
    assert var_xx[120] > var_xx[119] and var_xx[121] < var_xx[120]  # step 120: prediction only


def test_heading_wraps_across_pi() -> None:
    rng = np.random.default_rng(3)
    # Several full circles, and a straight run at θ ≈ π where measurements straddle ±π.
    for turn_rate, heading in ((0.8, 0.0), (0.0, math.pi - 0.01)):
        truth, increments = drive(400, 0.4, turn_rate, (0.0, 0.0, heading))
        odometry = integrate(truth[0], noisy_increments(increments, rng))
        z, z_cov = measure(truth, rng)
        fused = fuse_odometry(odometry, times(400), z, z_cov, FusionParams(*ODOM_ALPHAS, **EXACT))
        theta = fused.table["theta"].to_numpy()
        # the estimate itself crosses ±π and stays wrapped
        assert ((theta > -math.pi) & (theta <= math.pi)).all()
        assert (theta > 3.0).any() and (theta < -3.0).any()
        _, head = pose_errors(table_poses(fused.table), truth)
        assert head.max() < 0.2 and head[50:].mean() < 0.5 * pose_errors(z, truth)[1].mean()
        assert fused.rejected.sum() <= 2


def test_nees_is_consistent_on_a_gentle_curve() -> None:
    """With the true noise models the normalised estimation error squared averages ~3."""
    nees = []
    for seed in range(16):
        rng = np.random.default_rng(10 + seed)
        truth, increments = drive(300, 0.5, 0.15, (0.0, 0.0, 0.5))
        odometry = integrate(truth[0], noisy_increments(increments, rng))
        z, z_cov = measure(truth, rng)
        params = FusionParams(*ODOM_ALPHAS, **EXACT, gate_probability=1 - 1e-12)
        fused = fuse_odometry(odometry, times(300), z, z_cov, params)
        error = table_poses(fused.table) - truth
        error[:, 2] = wrap_angle(error[:, 2])
        covs = table_covariances(fused.table)
        nees.append(
            np.einsum("ti,ti->t", error, np.linalg.solve(covs, error[:, :, None])[:, :, 0])[20:]
        )
    mean_nees = float(np.concatenate(nees).mean())
    assert 2.3 < mean_nees < 3.7, mean_nees  # 40 runs: 2.95 ± 0.8 each


def test_lost_filter_reinitialises_and_missing_measurements_predict() -> None:
    rng = np.random.default_rng(4)
    truth, increments = drive(150, 0.5, 0.3, (0.0, 0.0, 0.0))
    odometry = integrate(truth[0], noisy_increments(increments, rng))
    z, z_cov = measure(truth, rng)
    z[0] += (4.0, 4.0, 0.0)  # the filter starts from a CNN failure
    z[60:70] = np.nan  # no CNN estimate for a second: odometry carries the filter
    params = FusionParams(*ODOM_ALPHAS, **EXACT, reinit_after=5)
    fused = fuse_odometry(odometry, times(150), z, z_cov, params)
    assert fused.rejected[1:5].all() and fused.reinitialised[5]
    assert fused.reinitialised.sum() == 1
    pos, _ = pose_errors(table_poses(fused.table), truth)
    assert pos[5:].max() < 0.5 and pos[0] > 5.0
    var_xx = fused.table["cov_xx"].to_numpy()
    assert (np.diff(var_xx[59:70]) > 0).all()  # uncertainty grows while only odometry speaks
    default = fuse_odometry(odometry, times(150), z, z_cov, FusionParams(*ODOM_ALPHAS, **EXACT))
    assert default.reinitialised[10] and default.reinitialised.sum() == 1
    never = FusionParams(*ODOM_ALPHAS, **EXACT, reinit_after=0)
    lost = fuse_odometry(odometry, times(150), z, z_cov, never)
    assert pose_errors(table_poses(lost.table), truth)[0][-1] > 3.0
    assert lost.rejected[1:60].all()


def test_single_network_without_covariance_uses_the_floor() -> None:
    truth, _ = drive(20, 0.5, 0.0, (0.0, 0.0, 0.0))
    z_cov = np.full((20, 3, 3), np.nan)
    params = FusionParams(min_std_xy=0.1, min_std_theta=0.07)
    fused = fuse_odometry(truth, times(20), truth, z_cov, params)
    np.testing.assert_allclose(table_covariances(fused.table)[0], np.diag([0.01, 0.01, 0.07**2]))
    assert np.isfinite(table_poses(fused.table)).all()


def test_config_and_bad_params_are_rejected_clearly() -> None:
    cfg = raw_config("cnn_ekf", CONF)
    section = cfg.get("fusion") or {}  # the config writes what departs from the defaults
    # every key of the shipped section reaches its field, with the field's type
    shipped = parse_section(FusionParams, cfg, "fusion", "conf/localizer/cnn_ekf.yaml")
    for key, value in section.items():
        assert getattr(shipped, key) == value, key
        assert type(getattr(shipped, key)) is type(getattr(FusionParams(), key)), key
    # the process noise, shipped and default, is 4 × the simulated odometry's variances
    noise = yaml.safe_load((CONF.parent / "trajectory.yaml").read_text())["trajectory"]
    for k in range(1, 5):
        alpha = 4 * noise["odometry_noise"][f"alpha{k}"]
        assert getattr(shipped, f"odom_alpha{k}") == pytest.approx(alpha)
        assert getattr(FusionParams(), f"odom_alpha{k}") == pytest.approx(alpha)
    # an int is accepted for a float parameter and stored as a float; other fields keep defaults
    loaded = FusionParams.from_config({"min_std_xy": 1, "reinit_after": 3})
    assert loaded == FusionParams(min_std_xy=1.0, reinit_after=3)
    assert isinstance(loaded.min_std_xy, float)
    with pytest.raises(ValueError, match="unknown fusion parameter 'alpha1'"):
        FusionParams.from_config({"alpha1": 0.1})
    with pytest.raises(ValueError, match=r"x\.yaml: section 'fusion': unknown key 'alpha1'"):
        parse_section(FusionParams, {"fusion": {"alpha1": 0.1}}, "fusion", "conf/localizer/x.yaml")
    with pytest.raises(ValueError, match="'reinit_after' must be of type int"):
        FusionParams.from_config({"reinit_after": 2.5})
    with pytest.raises(ValueError, match="measurement_inflation"):
        FusionParams(measurement_inflation=0.0)
    with pytest.raises(ValueError, match="min_std_theta"):
        FusionParams(min_std_theta=0.0)
    with pytest.raises(ValueError, match="gate_probability"):
        FusionParams(gate_probability=1.0)
    with pytest.raises(ValueError, match="odom_alpha"):
        FusionParams(odom_alpha3=-0.1)
    with pytest.raises(ValueError, match="reinit_after"):
        FusionParams(reinit_after=-1)
    poses = np.zeros((5, 3))
    with pytest.raises(ValueError, match=r"measurement_covs must have shape \(5, 3, 3\)"):
        fuse_odometry(poses, times(5), poses, np.zeros((5, 3)))
    with pytest.raises(ValueError, match="odometry must have shape"):
        fuse_odometry(np.zeros((5, 2)), times(5), poses, np.zeros((5, 3, 3)))
    with pytest.raises(ValueError, match="odometry must be finite"):
        fuse_odometry(np.full((5, 3), np.nan), times(5), poses, np.zeros((5, 3, 3)))
