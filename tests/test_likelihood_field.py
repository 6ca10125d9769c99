"""amcl's likelihood-field model against brute force and a literal Python transcription."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanloc.localize.likelihood_field import (
    beam_step,
    beam_weights,
    build_likelihood_field,
    distance_map,
    select_beams,
)
from scanloc.world.occupancy_grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid

Z_HIT, Z_RAND, SIGMA, MAX_DIST, RANGE_MAX = 0.95, 0.05, 0.2, 0.4, 5.6


def random_grid(seed: int, shape: tuple[int, int] = (23, 31), p_occ: float = 0.05) -> OccupancyGrid:
    rng = np.random.default_rng(seed)
    cells = np.full(shape, FREE, dtype=np.int8)
    cells[rng.random(shape) < p_occ] = OCCUPIED
    cells[rng.random(shape) < 0.05] = UNKNOWN
    return OccupancyGrid(cells, resolution=0.05, origin=(-0.4, 0.3, 0.0))


def brute_distance(grid: OccupancyGrid, max_dist: float) -> np.ndarray:
    occ_rows, occ_cols = np.nonzero(grid.occupied)
    rows, cols = np.indices(grid.cells.shape)
    d = np.hypot(
        rows[..., None] - occ_rows[None, None, :], cols[..., None] - occ_cols[None, None, :]
    ).min(axis=-1)
    return np.minimum(d * grid.resolution, max_dist)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 10_000))
def test_distance_map_matches_brute_force(seed: int) -> None:
    grid = random_grid(seed)
    np.testing.assert_allclose(
        distance_map(grid, MAX_DIST), brute_distance(grid, MAX_DIST), atol=1e-12
    )


def test_distance_map_without_obstacles_is_the_cap() -> None:
    grid = OccupancyGrid(np.zeros((4, 5), dtype=np.int8), 0.1)
    assert np.all(distance_map(grid, 2.0) == 2.0)


def amcl_weight(
    grid: OccupancyGrid, pose: np.ndarray, ranges: np.ndarray, bearings: np.ndarray, offset: float
) -> float:
    """LikelihoodFieldModel for one particle, transcribed literally (brute-force distances)."""
    dist = brute_distance(grid, MAX_DIST)
    p = 1.0
    for r, b in zip(ranges, bearings, strict=True):
        if r >= RANGE_MAX or r != r:
            continue
        hx = pose[0] + r * math.cos(pose[2] + b)
        hy = pose[1] + r * math.sin(pose[2] + b)
        i = math.floor((hx - grid.origin[0]) / grid.resolution + offset)
        j = math.floor((hy - grid.origin[1]) / grid.resolution + offset)
        z = dist[j, i] if 0 <= i < grid.width and 0 <= j < grid.height else MAX_DIST
        pz = Z_HIT * math.exp(-(z * z) / (2 * SIGMA * SIGMA)) + Z_RAND / RANGE_MAX
        p += pz * pz * pz
    return p


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 10_000), st.booleans())
def test_beam_weights_match_a_plain_transcription_of_amcl(seed: int, half_cell: bool) -> None:
    grid = random_grid(seed)
    rng = np.random.default_rng(seed)
    field = build_likelihood_field(grid, Z_HIT, Z_RAND, SIGMA, MAX_DIST, RANGE_MAX, half_cell)
    w, h = grid.size_m
    # poses near and beyond the map edges: some end points fall off the map
    poses = np.column_stack(
        [
            rng.uniform(-0.6, w, 7) + grid.origin[0],
            rng.uniform(-0.6, h, 7) + grid.origin[1],
            rng.uniform(-math.pi, math.pi, 7),
        ]
    )
    ranges = rng.uniform(0.05, 1.5, 12)
    bearings = rng.uniform(-2.0, 2.0, 12)
    got = beam_weights(field, poses, ranges, bearings)
    offset = 0.5 if half_cell else 0.0
    want = [amcl_weight(grid, pose, ranges, bearings, offset) for pose in poses]
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_weight_of_a_beam_ending_in_an_obstacle_and_off_the_map() -> None:
    cells = np.zeros((10, 10), dtype=np.int8)
    cells[:, 7] = OCCUPIED  # a wall at x in [0.7, 0.8)
    grid = OccupancyGrid(cells, 0.1)
    field = build_likelihood_field(grid, Z_HIT, Z_RAND, SIGMA, MAX_DIST, RANGE_MAX)
    pose = np.array([[0.25, 0.55, 0.0]])
    pz_hit = Z_HIT + Z_RAND / RANGE_MAX
    pz_far = Z_HIT * math.exp(-(MAX_DIST**2) / (2 * SIGMA**2)) + Z_RAND / RANGE_MAX
    # 0.5 m ahead ends in the wall; 3 m ahead leaves the map
    got = beam_weights(field, pose, np.array([0.5, 3.0]), np.array([0.0, 0.0]))
    assert got[0] == pytest.approx(1.0 + pz_hit**3 + pz_far**3)


def test_amcl_half_cell_offset_shifts_the_lookup_by_half_a_cell() -> None:
    cells = np.zeros((10, 10), dtype=np.int8)
    cells[:, 5] = OCCUPIED  # x in [0.5, 0.6)
    grid = OccupancyGrid(cells, 0.1)
    exact = build_likelihood_field(grid, Z_HIT, Z_RAND, SIGMA, MAX_DIST, RANGE_MAX)
    ros = build_likelihood_field(grid, Z_HIT, Z_RAND, SIGMA, MAX_DIST, RANGE_MAX, True)
    pose = np.array([[0.0, 0.55, 0.0]])
    hit = Z_HIT + Z_RAND / RANGE_MAX
    # x = 0.47 lies in free cell 4 (0.1 m from the wall); amcl rounds it into cell 5, the wall.
    assert beam_weights(ros, pose, np.array([0.47]), np.zeros(1))[0] == pytest.approx(1 + hit**3)
    assert beam_weights(exact, pose, np.array([0.47]), np.zeros(1))[0] < 1 + hit**3 - 0.05


def test_beam_selection_follows_amcl() -> None:
    assert beam_step(667, 30) == 22  # 666 // 29: 31 beams
    assert beam_step(667, 60) == 11
    assert beam_step(10, 30) == 1
    angles = np.linspace(-2.0, 2.0, 667)
    ranges = np.full(667, 2.0)
    r, b = select_beams(ranges, angles, 0.02, 5.6, 30)
    assert len(r) == 31
    np.testing.assert_array_equal(b, angles[::22])
    ranges[0] = 7.0  # "no return" fill value: at or above range_max, skipped
    ranges[22] = 5.6  # exactly range_max: skipped
    ranges[44] = 0.01  # below range_min: counted as range_max, skipped
    ranges[66] = np.nan  # NaN: skipped
    r, b = select_beams(ranges, angles, 0.02, 5.6, 30)
    assert len(r) == 27
    np.testing.assert_array_equal(b, angles[::22][4:])
    # float32 scans: a reading of float32(5.6) is at range_max (as amcl's float32 comparison)
    r32, _ = select_beams(ranges.astype(np.float32), angles, 0.02, 5.6, 30)
    assert len(r32) == 27 and r32.dtype == np.float64
