"""The beam model and nav2's likelihood_field_prob against literal transcriptions of ROS's code,
the beam model's range table against exact casts, and beam skipping."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanloc.localize.beam_model import (
    BeamMixture,
    beam_model_weights,
    beam_pz,
    build_range_table,
    exit_distance,
    select_beams_beam_model,
)
from scanloc.localize.likelihood_field import distance_map
from scanloc.localize.likelihood_field_prob import (
    build_likelihood_field_prob,
    converged,
    prob_weights,
    select_beams_prob,
)
from scanloc.localize.mcl.sensor_models import BeamParams, LikelihoodFieldProbParams
from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.raycast import CastMap, cast_exact
from scanloc.world.free_space import sample_free_poses
from scanloc.world.occupancy_grid import OccupancyGrid
from small_world import small_map, ug01_scans
from test_amcl import amcl_filter

SPEC = LaserSpec()
ROS1 = BeamParams()  # z_hit 0.95, z_short 0.1, z_max 0.05, z_rand 0.05, σ 0.2, λ 0.1
RANGE_MAX = 5.6


def ros_beam_pz(obs: float, map_range: float, p: BeamParams, range_max: float) -> float:
    """amcl_laser.cpp BeamModel's per-beam probability, statement by statement."""
    pz = 0.0
    z = obs - map_range
    pz += p.laser_z_hit * math.exp(-(z * z) / (2 * p.laser_sigma_hit * p.laser_sigma_hit))
    if z < 0:
        pz += p.laser_z_short * p.laser_lambda_short * math.exp(-p.laser_lambda_short * obs)
    if obs == range_max:
        pz += p.laser_z_max * 1.0
    if obs < range_max:
        pz += p.laser_z_rand * 1.0 / range_max
    return pz


ranges = st.floats(0.0, 7.0, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(ranges, ranges, st.booleans())
def test_beam_pz_is_rosss_formula(obs: float, map_range: float, at_max: bool) -> None:
    obs = RANGE_MAX if at_max else obs
    p = ROS1
    got = beam_pz(
        obs,
        map_range,
        RANGE_MAX,
        p.laser_z_hit,
        p.laser_z_short,
        p.laser_z_max,
        p.laser_z_rand,
        p.laser_sigma_hit,
        p.laser_lambda_short,
    )
    assert got == pytest.approx(ros_beam_pz(obs, map_range, p, RANGE_MAX), rel=1e-12, abs=1e-15)
    # ROS asserts pz <= 1, which its own defaults can break (z_hit + z_short + z_max + z_rand is
    # 1.15): a reading at range_max just short of the map's range scores 1.0057. The bound the
    # formula does keep:
    bound = p.laser_z_hit + p.laser_z_short * p.laser_lambda_short + p.laser_z_max
    assert 0.0 <= got <= bound + p.laser_z_rand / RANGE_MAX


def test_the_beam_model_takes_its_mixture_from_the_ros_keys() -> None:
    """The config's laser_* keys reach the beam model: its weights are the kernel's with the
    mixture they name, not with the defaults."""
    grid = small_map()
    truth = np.array([[2.5, 2.0, 0.3]])
    scan = ug01_scans(grid, truth, seed=3)[0]
    scan[::50] = 0.4  # some short readings, so that z_short matters
    mixture = {"z_hit": 0.5, "z_short": 0.3, "z_max": 0.1, "z_rand": 0.2, "sigma_hit": 0.1}
    ros = {f"laser_{key}": value for key, value in mixture.items()}
    amcl = amcl_filter(grid, laser_model_type="beam", laser_lambda_short=0.5, **ros)
    poses = truth + np.random.default_rng(2).normal(0.0, 0.2, (50, 3))
    obs, b = select_beams_beam_model(scan, SPEC.beam_angles(), SPEC.range_min, RANGE_MAX, 30)
    table = amcl.sensor_model.table
    expected = beam_model_weights(table, poses, obs, b, BeamMixture(**mixture, lambda_short=0.5))
    got = amcl.sensor_model(poses, scan, False)
    np.testing.assert_array_equal(got, expected)
    assert not np.allclose(got, beam_model_weights(table, poses, obs, b, BeamMixture()))


def test_beam_pz_cases_by_hand() -> None:
    p = ROS1
    args = (p.laser_z_hit, p.laser_z_short, p.laser_z_max, p.laser_z_rand, 0.2, 0.1)
    rand = 0.05 / RANGE_MAX
    assert beam_pz(3.0, 3.0, RANGE_MAX, *args) == pytest.approx(0.95 + rand)  # a perfect hit
    short = 0.1 * 0.1 * math.exp(-0.1 * 1.0)  # a person 2 m before the wall
    assert beam_pz(1.0, 3.0, RANGE_MAX, *args) == pytest.approx(short + rand, rel=1e-9)
    assert beam_pz(RANGE_MAX, 3.0, RANGE_MAX, *args) == pytest.approx(0.05, rel=1e-9)  # z_max
    assert beam_pz(7.0, 3.0, RANGE_MAX, *args) < 1e-30  # above range_max: as ROS's +inf


@pytest.fixture(scope="module")
def room() -> tuple:
    grid = small_map()
    table = build_range_table(grid, RANGE_MAX)
    poses = sample_free_poses(grid, 300, 0.05, np.random.default_rng(0))
    return grid, table, poses


def test_range_table_agrees_with_exact_casts(room) -> None:
    grid, table, poses = room
    bearings = SPEC.beam_angles()[::23]
    exact = cast_exact(CastMap.from_grid(grid, unknown_blocks=True), poses, bearings, RANGE_MAX)
    w, h = grid.size_m
    leave = exit_distance(poses[:, :1], poses[:, 1:2], poses[:, 2:3] + bearings, (0, 0, w, h))
    exact = np.where(np.isfinite(exact), exact, np.minimum(leave, RANGE_MAX))
    col = np.floor(poses[:, 0] / table.resolution).astype(int)
    row = np.floor(poses[:, 1] / table.resolution).astype(int)
    k = table.index[row, col]
    assert (k >= 0).all()  # every free pose has a row
    bins = np.floor((poses[:, 2:3] + bearings + math.pi) * table.n_angles / (2 * math.pi) + 0.5)
    looked_up = table.ranges[k[:, None], bins.astype(int) % table.n_angles] * 1e-3
    error = np.abs(looked_up - exact)
    # quantised to the 0.05 m cell and the 1° bin: centimetres, except at obstacle edges
    assert np.median(error) < 0.02
    assert np.mean(error < 0.1) > 0.95


def test_beam_model_weights_equal_a_literal_loop_over_the_table(room) -> None:
    grid, table, poses = room
    scan = ug01_scans(grid, poses[:1], seed=3)[0]
    scan[22] = 0.01  # a short reading on a used beam (step 22): counts as range_max
    obs, bearings = select_beams_beam_model(scan, SPEC.beam_angles(), 0.02, RANGE_MAX, 30)
    assert len(obs) == 31 and obs[0] == pytest.approx(scan[0]) and RANGE_MAX in obs
    p = ROS1
    got = beam_model_weights(table, poses, obs, bearings, BeamMixture())
    for i, (x, y, theta) in enumerate(poses[:40]):
        k = table.index[int(y // table.resolution), int(x // table.resolution)]
        weight = 1.0
        for r, b in zip(obs, bearings, strict=True):
            kbin = math.floor((theta + b + math.pi) * table.n_angles / (2 * math.pi) + 0.5)
            expected = table.ranges[k, kbin % table.n_angles] * 1e-3
            weight += ros_beam_pz(r, expected, p, RANGE_MAX) ** 3
        assert got[i] == pytest.approx(weight, rel=1e-12), i


def test_beam_model_prefers_the_true_pose(room) -> None:
    grid, _, _ = room
    truth = np.array([[2.5, 2.0, 0.3]])
    scan = ug01_scans(grid, truth, seed=1)[0]
    amcl = amcl_filter(grid, seed=0, laser_model_type="beam")
    offsets = np.array([[0, 0, 0], [0.3, 0, 0], [0, 0.3, 0], [0, 0, 0.2], [1.0, 1.0, 1.0]])
    weights = amcl.sensor_model(truth + offsets, scan, False)
    assert weights.argmax() == 0 and weights[0] > 1.5 * weights[1:].max()


def test_a_particle_outside_free_space_sees_zero_ranges(room) -> None:
    """amcl's map_calc_range from a blocked cell returns 0 on every beam."""
    _, table, _ = room
    inside_wall = np.array([[0.05, 2.0, 0.0], [-1.0, 2.0, 0.0]])  # in the wall, off the map
    obs = np.array([0.0, 1.0])
    got = beam_model_weights(table, inside_wall, obs, np.zeros(2), BeamMixture())
    expected = 1.0 + sum(ros_beam_pz(r, 0.0, ROS1, RANGE_MAX) ** 3 for r in obs)
    np.testing.assert_allclose(got, expected)


def test_range_table_refuses_a_map_too_large_with_the_numbers() -> None:
    grid = OccupancyGrid(np.zeros((20000, 20000), np.int8), 0.05)
    with pytest.raises(ValueError, match=r"needs up to \d+ MiB \(limit 1024 MiB\)"):
        build_range_table(grid, RANGE_MAX)


# ---------------------------------------------------------------- likelihood_field_prob


def nav2_prob_weight(grid, pose, scan, p: LikelihoodFieldProbParams, max_beams: int) -> float:
    """nav2 LikelihoodFieldModelProb::sensorFunction for one particle, no beam skipping."""
    dist = distance_map(grid, p.laser_likelihood_max_dist)
    step = max(1, math.ceil(len(scan) / max_beams))
    angles = SPEC.beam_angles()
    denom = 2 * p.laser_sigma_hit**2
    max_dist_prob = math.exp(-(p.laser_likelihood_max_dist**2) / denom)
    log_p = 0.0
    for i in range(0, len(scan), step):
        obs = float(scan[i])
        if obs >= RANGE_MAX or obs != obs:
            continue
        hx = pose[0] + obs * math.cos(pose[2] + angles[i])
        hy = pose[1] + obs * math.sin(pose[2] + angles[i])
        mi, mj = math.floor(hx / grid.resolution), math.floor(hy / grid.resolution)
        if not (0 <= mi < grid.width and 0 <= mj < grid.height):
            pz = p.laser_z_hit * max_dist_prob
        else:
            z = dist[mj, mi]
            pz = p.laser_z_hit * math.exp(-(z * z) / denom)
        pz += p.laser_z_rand / RANGE_MAX
        log_p += math.log(pz)
    return math.exp(log_p)


def test_likelihood_field_prob_equals_a_literal_transcription_of_nav2() -> None:
    grid = small_map()
    rng = np.random.default_rng(4)
    poses = np.column_stack(
        [rng.uniform(-0.5, 6.5, 30), rng.uniform(-0.5, 5.5, 30), rng.normal(size=30)]
    )
    scan = ug01_scans(grid, np.array([[2.5, 2.0, 0.3]]), seed=1)[0]
    scan[5], scan[48] = np.nan, 0.0  # a NaN, a short reading
    p = LikelihoodFieldProbParams(laser_z_hit=0.5, laser_z_rand=0.5)
    field = build_likelihood_field_prob(grid, 0.5, 0.5, 0.2, 2.0, RANGE_MAX, 0.5)
    r, b = select_beams_prob(scan, SPEC.beam_angles(), 0.02, RANGE_MAX, 60)
    assert len(b) <= math.ceil(667 / 12)  # nav2's step: ceil(667 / 60) = 12
    got = prob_weights(field, poses, r, b)
    for i, pose in enumerate(poses):
        assert got[i] == pytest.approx(nav2_prob_weight(grid, pose, scan, p, 60), rel=1e-9), i


def test_beam_skipping_ignores_an_unmapped_obstacle_once_converged() -> None:
    grid = small_map()
    truth = np.array([2.5, 2.0, 0.3])
    cloud = truth + np.random.default_rng(5).normal(0.0, [0.03, 0.03, 0.01], (200, 3))
    person = ug01_scans(grid, truth[None], seed=2)[0]
    person[300:420] = 0.6  # someone 0.6 m in front of the robot, 1 m from anything mapped
    field = build_likelihood_field_prob(grid, 0.95, 0.05, 0.2, 2.0, RANGE_MAX, 0.5)
    r, b = select_beams_prob(person, SPEC.beam_angles(), 0.02, RANGE_MAX, 60)
    index = np.arange(0, 667, math.ceil(667 / 60))
    valid = (person[index] > 0.02) & (person[index] < RANGE_MAX)
    on_person = ((index >= 300) & (index < 420))[valid]
    assert on_person.sum() >= 8
    plain = prob_weights(field, cloud, r, b)
    skipped = prob_weights(field, cloud, r, b, True, 0.3, 0.9, filter_converged=True)
    # Every particle sees the person's beams far from the map, so they are skipped; the other
    # beams agree with it, so they are kept: the weights of the scan without the person.
    np.testing.assert_allclose(skipped, prob_weights(field, cloud, r[~on_person], b[~on_person]))
    assert plain.max() < 1e-6 * skipped.max()  # without skipping the person dominates
    # nav2 skips only once the filter has converged
    not_converged = prob_weights(field, cloud, r, b, True, 0.3, 0.9, filter_converged=False)
    np.testing.assert_allclose(not_converged, plain)


def test_beam_skipping_integrates_everything_when_most_beams_disagree() -> None:
    grid = small_map()
    truth = np.array([2.5, 2.0, 0.3])
    cloud = truth + np.random.default_rng(6).normal(0.0, [0.03, 0.03, 0.01], (100, 3))
    field = build_likelihood_field_prob(grid, 0.95, 0.05, 0.2, 2.0, RANGE_MAX, 0.5)
    blind = np.full(667, 0.7, dtype=np.float32)  # nothing agrees with the map
    r, b = select_beams_prob(blind, SPEC.beam_angles(), 0.02, RANGE_MAX, 60)
    np.testing.assert_allclose(
        prob_weights(field, cloud, r, b, True, 0.3, 0.9, filter_converged=True),
        prob_weights(field, cloud, r, b),
    )


def test_converged_is_amcls_half_metre_box() -> None:
    poses = np.zeros((10, 3))
    poses[:, 0] = np.linspace(0.0, 0.9, 10)  # mean 0.45: every particle within 0.45 m
    assert converged(poses)
    poses[-1, 0] = 1.2  # mean 0.48, this one 0.72 away
    assert not converged(poses)
