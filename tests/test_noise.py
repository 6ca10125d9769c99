"""Range noise statistics, config parsing, and the simulator's range limits and "no return"."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.noise import NoNoise, RangeGaussianNoise, noise_from_config
from scanloc.sensor.raycast import CastMap, cast_exact
from scanloc.sensor.simulate import (
    ScanSimulator,
    laser_spec_from_config,
    simulate_scans,
)
from scanloc.world.occupancy_grid import OCCUPIED, OccupancyGrid

UG01 = RangeGaussianNoise()


@pytest.mark.parametrize(("true_range", "sigma"), [(0.5, 0.03), (3.0, 0.09)])
def test_ug01_noise_is_unbiased_with_the_datasheet_sigma(true_range: float, sigma: float) -> None:
    n = 200_000
    readings = UG01.apply(np.full(n, true_range), np.random.default_rng(7))
    error = readings - true_range
    assert abs(error.mean()) < 4 * sigma / math.sqrt(n)
    assert error.std() == pytest.approx(sigma, rel=0.01)


def test_ug01_sigma_is_piecewise_and_continuous() -> None:
    np.testing.assert_allclose(
        UG01.sigma(np.array([0.06, 0.999, 1.0, 4.095, 5.5])), [0.03, 0.03, 0.03, 0.12285, 0.165]
    )


def test_noise_is_deterministic_and_leaves_no_hit_alone() -> None:
    ranges = np.array([[0.5, np.inf, 2.0], [np.inf, 1.0, 3.0]])
    a = UG01.apply(ranges, np.random.default_rng(1))
    b = UG01.apply(ranges, np.random.default_rng(1))
    c = UG01.apply(ranges, np.random.default_rng(2))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    np.testing.assert_array_equal(np.isinf(a), np.isinf(ranges))
    np.testing.assert_array_equal(NoNoise().apply(ranges, np.random.default_rng(1)), ranges)


def test_noise_config() -> None:
    assert noise_from_config({"kind": "none"}) == NoNoise()
    assert noise_from_config({"kind": "ug01"}) == UG01
    custom = noise_from_config({"kind": "ug01", "near_sigma_m": 0.01, "relative_sigma": 0.01})
    assert custom.sigma(np.array([0.5]))[0] == 0.01
    with pytest.raises(ValueError, match="kind"):
        noise_from_config({"kind": "laser"})
    with pytest.raises(ValueError, match="sigma_m"):
        noise_from_config({"kind": "ug01", "sigma_m": 0.01})
    with pytest.raises(ValueError, match="near_sigma_m"):
        noise_from_config({"kind": "ug01", "near_sigma_m": -1})
    with pytest.raises(ValueError, match="takes no fields"):
        noise_from_config({"kind": "none", "near_sigma_m": 0.03})


def test_laser_spec_config() -> None:
    cfg = {"num_beams": 5, "range_max": 4.0, "mode": "exact", "unknown_blocks": False}
    spec = laser_spec_from_config(cfg)
    assert spec == LaserSpec(num_beams=5, range_max=4.0)
    with pytest.raises(ValueError, match="num_beam"):
        laser_spec_from_config({"num_beam": 5})
    with pytest.raises(ValueError, match="'num_beams'"):
        laser_spec_from_config({"num_beams": 5.5})
    with pytest.raises(ValueError, match="'range_max'"):
        laser_spec_from_config({"range_max": "far"})
    with pytest.raises(ValueError, match="range_min"):
        laser_spec_from_config({"range_min": 6.0})


@pytest.fixture(scope="module")
def box(walled_room: Callable[..., OccupancyGrid]) -> OccupancyGrid:
    """1 m x 1 m of free space at 0.02 m inside a one-cell wall."""
    return walled_room(1.04, 1.04, 0.02)


def test_simulated_readings_respect_range_limits_and_fill(box: OccupancyGrid) -> None:
    grid = box
    spec = LaserSpec(range_min=0.3, range_max=0.6, no_return_value=7.0)
    poses = np.array([[0.3, 0.3, 0.0], [0.52, 0.52, 1.0]])
    exact = cast_exact(CastMap.from_grid(grid), poses, spec.beam_angles(), spec.range_max)
    readings = simulate_scans(grid, spec, poses, None, rng_seed=0)
    assert readings.dtype == np.float32 and readings.shape == (2, spec.num_beams)
    inside = np.isfinite(exact) & (exact >= 0.3)
    np.testing.assert_array_equal(readings[inside], exact[inside].astype(np.float32))
    assert (readings[~inside] == np.float32(7.0)).all()
    assert inside.any() and (~inside).any()  # both cases occur
    noisy = simulate_scans(grid, spec, poses, UG01, rng_seed=0)
    kept = noisy != np.float32(7.0)
    assert (noisy[kept] >= np.float32(0.3)).all() and (noisy[kept] <= np.float32(0.6)).all()


def test_simulation_is_deterministic_for_a_seed(box: OccupancyGrid) -> None:
    grid, spec = box, LaserSpec()
    poses = np.array([[0.3, 0.4, 0.5], [0.7, 0.6, -2.0]])
    a = simulate_scans(grid, spec, poses, UG01, rng_seed=11)
    b = ScanSimulator(grid, spec, UG01).simulate(poses, np.random.SeedSequence(11))
    c = simulate_scans(grid, spec, poses, UG01, rng_seed=12)
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != c.tobytes()


def test_stdr_mode_encodes_stdr_infinities_as_the_author_did() -> None:
    cells = np.zeros((3, 20), np.int8)
    cells[:, 3] = OCCUPIED
    grid = OccupancyGrid(cells, 0.02)
    spec = LaserSpec(3, -math.pi / 2, math.pi / 2, range_min=0.05, range_max=5.6)
    readings = simulate_scans(grid, spec, np.array([[0.046, 0.03, 0.0]]), None, 0, mode="stdr")
    assert readings[0, 1] == np.float32(0.0)  # STDR's -inf (closer than range_min)
    open_room = OccupancyGrid(np.zeros((3, 400), np.int8), 0.02)
    readings = simulate_scans(open_room, spec, np.array([[0.046, 0.03, 0.0]]), None, 0, "stdr")
    assert readings[0, 1] == np.float32(7.0)  # STDR's +inf
    with pytest.raises(ValueError, match="mode"):
        ScanSimulator(grid, spec, mode="fast")
