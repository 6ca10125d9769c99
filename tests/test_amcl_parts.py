"""amcl's behaviours that a plain tracking run does not show: KLD adaptivity, recovery, the update
trigger, the resampling interval, its configs against ROS's defaults, and NaN readings."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanloc.localize.catalog import raw_config
from scanloc.localize.kld_resampling import _pick_indices
from scanloc.localize.mcl.config import run_mcl
from scanloc.localize.mcl.filter import FilterParams, ParticleFilter
from scanloc.localize.show import resolved
from scanloc.pose import compose, inverse, wrap_angle, wrap_pi
from scanloc.sensor.laser import LaserSpec
from scanloc.trajectory.drive import drive_trajectory
from small_world import small_map, ug01_scans
from test_amcl import CONF, amcl_filter, ros, shipped

SPEC = LaserSpec()

# ROS 1 amcl (noetic amcl_node.cpp `private_nh_.param` defaults) and nav2_amcl (amcl_node.cpp
# `add_parameter` defaults), written out here by hand from the sources, under ROS 1 names.
ROS1_DEFAULTS = {
    "min_particles": 100,
    "max_particles": 5000,
    "kld_err": 0.01,
    "kld_z": 0.99,
    "update_min_d": 0.2,
    "update_min_a": math.pi / 6,
    "resample_interval": 2,
    "selective_resampling": False,
    "recovery_alpha_slow": 0.001,
    "recovery_alpha_fast": 0.1,
    "initial_cov_xx": 0.25,
    "initial_cov_yy": 0.25,
    "initial_cov_aa": (math.pi / 12) ** 2,
    "laser_model_type": "likelihood_field",
    "laser_min_range": -1.0,
    "laser_max_range": -1.0,
    "laser_max_beams": 30,
    "laser_z_hit": 0.95,
    "laser_z_short": 0.1,
    "laser_z_max": 0.05,
    "laser_z_rand": 0.05,
    "laser_sigma_hit": 0.2,
    "laser_lambda_short": 0.1,
    "laser_likelihood_max_dist": 2.0,
    "do_beamskip": False,
    "beam_skip_distance": 0.5,
    "beam_skip_threshold": 0.3,
    "beam_skip_error_threshold": 0.9,
    "odom_model_type": "diff",
    "odom_alpha1": 0.2,
    "odom_alpha2": 0.2,
    "odom_alpha3": 0.2,
    "odom_alpha4": 0.2,
    "odom_alpha5": 0.2,
}
NAV2_DEFAULTS = ROS1_DEFAULTS | {
    "min_particles": 500,
    "max_particles": 2000,
    "kld_err": 0.05,  # pf_err
    "update_min_d": 0.25,
    "update_min_a": 0.2,
    "resample_interval": 1,
    "recovery_alpha_slow": 0.0,
    "recovery_alpha_fast": 0.0,
    "laser_max_range": 100.0,
    "laser_max_beams": 60,
    "laser_z_hit": 0.5,
    "laser_z_short": 0.05,
    "laser_z_rand": 0.5,
    "odom_model_type": "diff-corrected",  # nav2_amcl::DifferentialMotionModel
}
# Where a shipped config departs from its reference on purpose (the comments in the YAML say so).
TRACKING_START = {"initial_cov_xx", "initial_cov_yy", "initial_cov_aa"}
SCANLOC_SWITCHES = {
    "map_half_cell_offset",
    "publish_every_update",
    "beam_lut_resolution",
    "beam_lut_angles",
    "mode",
    "seed",
}
# The filter's policies (the `filter` section) and parts (their own sections) that amcl runs.
AMCL_POLICIES = {"update_trigger": "on_motion", "resampler": "kld", "estimator": "heaviest_cluster"}
AMCL_PARTS = {
    "proposal": {"type": "uniform"},
    "mixing": {"type": "none"},
    "weighting": {"type": "prior"},
}
FILTER_SECTIONS = ("filter", "motion", "sensor")


# ---------------------------------------------------------------- configs


@pytest.mark.parametrize(
    ("name", "reference", "departures"),
    [
        ("amcl", ROS1_DEFAULTS, TRACKING_START),
        ("amcl_nav2", NAV2_DEFAULTS, TRACKING_START),
        ("amcl_ros_exact", ROS1_DEFAULTS, set()),
    ],
)
def test_configs_hold_the_reference_defaults(name: str, reference: dict, departures: set) -> None:
    """What each config amounts to (every key of its `filter`, `motion` and `sensor` sections,
    the parts' defaults filled in) is its reference's, but for its documented departures."""
    whole = resolved(raw_config(name, CONF))
    cfg = {key: value for section in FILTER_SECTIONS for key, value in whole[section].items()}
    assert sum(len(whole[section]) for section in FILTER_SECTIONS) == len(cfg)  # no key twice
    # Every parameter of the reference is one of the port's.
    assert set(reference) <= set(cfg)
    for key, value in reference.items():
        if key not in departures:
            assert cfg[key] == pytest.approx(value), (name, key)
    params = shipped(name)
    assert params.map_half_cell_offset is (name == "amcl_ros_exact")
    for key in departures:
        assert cfg[key] != pytest.approx(reference[key]), (name, key, "a documented departure")
    assert set(cfg) - set(reference) == SCANLOC_SWITCHES | set(AMCL_POLICIES)
    assert {key: cfg[key] for key in AMCL_POLICIES} == AMCL_POLICIES
    assert cfg["mode"] == "tracking"
    assert {section: whole[section] for section in AMCL_PARTS} == AMCL_PARTS


def test_a_config_without_parameters_runs_as_ross_defaults_written_out() -> None:
    """The parts' built-in defaults are ROS 1's: a filter built from no parameters at all and
    one built from ROS1_DEFAULTS written out draw and weigh exactly alike."""
    grid = small_map()
    traj = drive_trajectory(grid, 40, seed=2, clearance=0.25)
    ranges = ug01_scans(grid, traj.truth, seed=5)
    for mode in ("tracking", "global"):
        implicit = run_mcl(grid, SPEC, traj, ranges, ros(), mode=mode, seed=1).table
        written = run_mcl(grid, SPEC, traj, ranges, ros(**ROS1_DEFAULTS), mode=mode, seed=1).table
        assert implicit.equals(written), mode
    nav2 = run_mcl(grid, SPEC, traj, ranges, ros(**NAV2_DEFAULTS), seed=1).table
    assert not nav2.equals(run_mcl(grid, SPEC, traj, ranges, ros(), seed=1).table)


# ---------------------------------------------------------------- update trigger


class CountingModel:
    """A sensor model that counts its calls and weights every particle alike."""

    def __init__(self) -> None:
        self.calls = 0

    def __call__(self, poses: np.ndarray, scan: np.ndarray, converged: bool) -> np.ndarray:
        self.calls += 1
        return np.full(len(poses), 2.0)


def counting_filter(**params) -> tuple[ParticleFilter, CountingModel]:
    amcl = amcl_filter(small_map(), seed=0, **params)
    model = CountingModel()
    amcl.sensor_model = model
    amcl.initialize_pose(np.array([2.5, 2.0, 0.3]), np.diag([1e-4, 1e-4, 1e-4]))
    return amcl, model


SCAN = np.full(SPEC.num_beams, 2.0, dtype=np.float32)


def test_update_thresholds_are_per_axis_not_euclidean() -> None:
    amcl, model = counting_filter()
    amcl.update(np.zeros(3), SCAN)  # the first scan always updates
    assert model.calls == 1
    # 0.15 m in x and in y: 0.21 m in all, but neither axis passes 0.2 m (amcl compares each).
    assert not amcl.update(np.array([0.15, 0.15, 0.0]), SCAN).updated
    assert amcl.update(np.array([0.15, 0.21, 0.0]), SCAN).updated
    assert model.calls == 2


def test_small_motions_accumulate_until_a_threshold() -> None:
    amcl, _ = counting_filter()
    amcl.update(np.zeros(3), SCAN)
    updated = [amcl.update(np.array([0.05 * k, 0.0, 0.0]), SCAN).updated for k in range(1, 9)]
    # measured from the last update's odometry: 0.25 m > 0.2 at k = 5, then again at k = 10
    assert updated == [False, False, False, False, True, False, False, False]
    # turning: π/6 is the angular threshold (strictly more than it updates)
    assert not amcl.update(np.array([0.25, 0.0, math.pi / 6 - 0.01]), SCAN).updated
    assert amcl.update(np.array([0.25, 0.0, math.pi / 6 + 0.01]), SCAN).updated
    # a turn through ±π is measured wrapped: 0.2 rad, not 2π − 0.2
    amcl2, _ = counting_filter()
    amcl2.update(np.array([0.0, 0.0, math.pi - 0.1]), SCAN)
    assert not amcl2.update(np.array([0.0, 0.0, -math.pi + 0.1]), SCAN).updated


def test_resample_interval_counts_updates_and_the_estimate_follows_it() -> None:
    amcl, _ = counting_filter(resample_interval=3, update_min_d=0.0, update_min_a=0.0)
    resampled = []
    original = amcl.resample

    def spy() -> None:
        resampled.append(True)
        original()

    amcl.resample = spy
    odom = [np.array([0.01 * k, 0.002 * k, 0.01 * k]) for k in range(7)]
    estimates = [amcl.update(o, SCAN) for o in odom]
    assert all(e.updated for e in estimates)
    # updates 1..7 (the first scan counts): resampling after the 3rd and the 6th only
    assert len(resampled) == 2
    # amcl re-estimates only after resampling; in between the estimate is the last one carried
    # by odometry. Steps 0-1, 1-2, 3-4 and 4-5 (0-based) are carried; 2 and 5 re-estimate.
    for k in range(6):
        carried = compose(estimates[k].mean, compose(inverse(odom[k]), odom[k + 1]))
        same = np.allclose(estimates[k + 1].mean, carried, atol=1e-12)
        assert same == (k + 1 not in (2, 5)), k


def test_first_estimate_is_the_initialisations_as_in_ros() -> None:
    """amcl publishes pf_init's cluster statistics on the first scan (before its sensor update):
    a filter whose sensor model pulls everything towards one corner still reports the mean of
    its initial particles."""
    amcl = amcl_filter(small_map(), seed=0)
    amcl.initialize_pose(np.array([3.0, 2.5, 0.0]), np.diag([0.3**2, 0.3**2, 0.01]))
    initial_mean = amcl.poses[:, :2].mean(axis=0)
    amcl.sensor_model = lambda poses, scan, c: np.exp(-20.0 * poses[:, 0])  # favours small x
    est = amcl.update(np.zeros(3), SCAN)
    np.testing.assert_allclose(est.mean[:2], initial_mean, atol=1e-9)
    weighted = (amcl.weights[:, None] * amcl.poses[:, :2]).sum(axis=0)
    assert weighted[0] < initial_mean[0] - 0.1  # the weights did move: the estimate did not


# ---------------------------------------------------------------- recovery


def test_recovery_averages_follow_amcls_ema() -> None:
    amcl, _ = counting_filter(recovery_alpha_slow=0.01, recovery_alpha_fast=0.5)
    n = len(amcl.poses)
    recovery = amcl.recovery
    assert recovery.slow == recovery.fast == 0.0  # pf_init
    factors = iter([2.0, 1.0, 4.0])
    amcl.sensor_model = lambda poses, scan, c: np.full(len(poses), next(factors))
    amcl.sensor_update(SCAN)  # w_avg = 2 / n: the first value is taken as it is
    assert recovery.slow == pytest.approx(2.0 / n) and recovery.fast == pytest.approx(2.0 / n)
    amcl.sensor_update(SCAN)  # weights were normalised: w_avg = 1 / n
    assert recovery.slow == pytest.approx(2 / n + 0.01 * (1 / n - 2 / n))
    assert recovery.fast == pytest.approx(2 / n + 0.5 * (1 / n - 2 / n))
    slow, fast = recovery.slow, recovery.fast
    amcl.sensor_update(SCAN)
    assert recovery.slow == pytest.approx(slow + 0.01 * (4 / n - slow))
    assert recovery.fast == pytest.approx(fast + 0.5 * (4 / n - fast))
    assert amcl.recovery is recovery  # the filter's own averages, followed in place


def test_injection_only_when_the_fast_average_falls_below_the_slow_one() -> None:
    grid = small_map()
    amcl, _ = counting_filter()
    start = np.array([2.5, 2.0, 0.3])
    # w_fast > w_slow: things are getting better, w_diff = 1 − w_fast / w_slow < 0, no injection
    amcl.recovery.slow, amcl.recovery.fast = 1.0, 1.5
    amcl.resample()
    assert np.allclose(amcl.poses, start, atol=0.1)
    assert (amcl.recovery.slow, amcl.recovery.fast) == (1.0, 1.5)  # kept
    # w_fast = 0.2 w_slow: w_diff = 0.8, four fifths of the draws are random free poses
    amcl.recovery.slow, amcl.recovery.fast = 1.0, 0.2
    amcl.resample()
    injected = np.hypot(*(amcl.poses[:, :2] - start[:2]).T) > 0.1
    assert 0.7 < injected.mean() < 0.9
    assert (amcl.recovery.slow, amcl.recovery.fast) == (0.0, 0.0)  # amcl resets after injecting
    # Injected particles are free-cell centres, headings spread over the circle.
    col, row = grid.world_to_cell(amcl.poses[injected, 0], amcl.poses[injected, 1])
    assert grid.free[row, col].all()
    x_centre = grid.origin[0] + (col + 0.5) * grid.resolution
    np.testing.assert_allclose(amcl.poses[injected, 0], x_centre, atol=1e-9)
    assert np.ptp(amcl.poses[injected, 2]) > 6.0


@pytest.fixture(scope="module")
def kidnapped() -> tuple:
    grid = small_map()
    traj = drive_trajectory(grid, 500, seed=3, clearance=0.25, kidnap_steps=(150,))
    return grid, traj, ug01_scans(grid, traj.truth, seed=4)


def test_kidnap_trajectory_odometry_does_not_see_the_jump(kidnapped) -> None:
    _, traj, _ = kidnapped
    jump = np.hypot(*(traj.truth[150, :2] - traj.truth[149, :2]))
    odom_step = np.hypot(*(traj.odometry[150, :2] - traj.odometry[149, :2]))
    assert jump > 0.5 and odom_step == 0.0 and traj.odometry[150, 2] == traj.odometry[149, 2]
    assert traj.kidnap_steps == (150,)


def test_kidnapped_robot_recovers_with_recovery_and_not_without(kidnapped) -> None:
    """Recovery with averages quick enough to notice the kidnap (0.05 / 0.5). ROS's own
    0.001 / 0.1 do not trigger here within 350 steps: amcl's w_avg is the mean weight divided
    by the particle count, which grows as KLD shrinks the converged cloud, and w_slow keeps
    the first update's level for ~1000 updates, so w_fast stays above it (docs/amcl.md)."""
    grid, traj, ranges = kidnapped

    def errors(**params) -> np.ndarray:
        table = run_mcl(grid, SPEC, traj, ranges, ros(**params), seed=0).table
        err = np.hypot(table.x - traj.truth[:, 0], table.y - traj.truth[:, 1]).to_numpy()
        assert err[100:150].max() < 0.3  # tracking before the kidnap
        assert err[150] > 1.0  # and lost by it
        return err

    on = errors(recovery_alpha_slow=0.05, recovery_alpha_fast=0.5)
    off = errors(recovery_alpha_slow=0.0, recovery_alpha_fast=0.0)
    assert np.median(on[350:]) < 0.1
    assert np.median(off[350:]) > 1.0


# ---------------------------------------------------------------- KLD adaptivity


def test_particle_count_falls_as_the_cloud_concentrates() -> None:
    grid = small_map()
    traj = drive_trajectory(grid, 300, seed=2, clearance=0.25)
    ranges = ug01_scans(grid, traj.truth, seed=5)
    params = FilterParams()
    table = run_mcl(grid, SPEC, traj, ranges, ros(), mode="global", seed=0).table
    counts = table.n_particles.to_numpy()
    assert counts[0] == params.max_particles  # a uniform cloud over the room
    # one tight cluster: a few hundred particles (more while turning spreads the headings)
    assert np.median(counts[-100:]) <= params.max_particles // 10
    assert counts[-100:].min() >= params.min_particles


# ---------------------------------------------------------------- NaN readings and helpers


def test_nan_readings_are_skipped_like_max_range_readings() -> None:
    grid = small_map()
    truth = np.array([[2.5, 2.0, 0.3]])
    scan = ug01_scans(grid, truth, seed=1)[0]
    for model in ("likelihood_field", "likelihood_field_prob", "beam"):
        amcl = amcl_filter(grid, seed=0, laser_model_type=model)
        amcl.initialize_pose(truth[0])
        with_nan = scan.copy()
        with_nan[::7] = np.nan
        weights = amcl.sensor_model(amcl.poses, with_nan, False)
        assert np.isfinite(weights).all() and (weights > 0).all(), model
        if model != "beam":  # the field models skip max-range readings too: the same weights
            at_max = scan.copy()
            at_max[::7] = SPEC.range_max
            np.testing.assert_allclose(weights, amcl.sensor_model(amcl.poses, at_max, False))
        amcl.update(np.zeros(3), with_nan)  # and the filter runs on


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(0.0, 1.0), min_size=1, max_size=40),
    st.lists(st.floats(0.0, 1.0, exclude_max=True), min_size=1, max_size=40),
)
def test_guided_picks_equal_a_bisection(weights: list[float], uniforms: list[float]) -> None:
    w = np.asarray(weights)
    w = w / w.sum() if w.sum() > 0 else np.full(len(w), 1 / len(w))
    cum = np.concatenate([[0.0], np.cumsum(w)])
    u = np.asarray(uniforms)
    expected = np.clip(np.searchsorted(cum, u, side="right") - 1, 0, len(w) - 1)
    np.testing.assert_array_equal(_pick_indices(cum, u, len(w)), expected)


@settings(max_examples=100, deadline=None)
@given(st.floats(-50.0, 50.0, allow_nan=False))
def test_compiled_wrap_equals_the_array_wrap(angle: float) -> None:
    assert wrap_pi(angle) == float(wrap_angle(angle))
    assert -math.pi < wrap_pi(angle) <= math.pi
