"""The driven trajectory: collision-free, broad, deterministic, within limits, drifting as asked."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from scanloc.pose import wrap_angle
from scanloc.trajectory.drive import drive_trajectory
from scanloc.trajectory.format import FILES, Trajectory, load_trajectory, save_trajectory
from scanloc.trajectory.odometry import OdometryNoise
from scanloc.world.occupancy_grid import OCCUPIED, UNKNOWN, OccupancyGrid

RATE = 10.0


def rooms_map(res: float = 0.05) -> OccupancyGrid:
    """8 m x 6 m: two rooms joined by a 1.2 m door, a pillar, unknown space outside the walls."""
    cells = np.full((round(6.4 / res), round(8.4 / res)), UNKNOWN, dtype=np.int8)
    cells[round(0.2 / res) : round(6.2 / res), round(0.2 / res) : round(8.2 / res)] = 0

    def box(x0: float, y0: float, x1: float, y1: float) -> None:
        cells[round(y0 / res) : round(y1 / res), round(x0 / res) : round(x1 / res)] = OCCUPIED

    for x0, y0, x1, y1 in [
        (0.2, 0.2, 8.2, 0.3),
        (0.2, 6.1, 8.2, 6.2),
        (0.2, 0.2, 0.3, 6.2),
        (8.1, 0.2, 8.2, 6.2),
        (4.1, 0.2, 4.2, 2.6),  # the dividing wall, a door from y 2.6 to 3.8
        (4.1, 3.8, 4.2, 6.2),
        (1.8, 3.6, 2.3, 4.1),  # a pillar
    ]:
        box(x0, y0, x1, y1)
    return OccupancyGrid(cells, res, origin=(-1.0, 2.0, 0.0))


@pytest.fixture(scope="module")
def grid() -> OccupancyGrid:
    return rooms_map()


def exact_clearance(grid: OccupancyGrid, xy: np.ndarray) -> np.ndarray:
    """Distance from each point to the nearest occupied or unknown cell square (brute force)."""
    rows, cols = np.nonzero(~grid.free)
    x0 = grid.origin[0] + cols * grid.resolution
    y0 = grid.origin[1] + rows * grid.resolution
    dx = np.maximum(np.maximum(x0[None] - xy[:, :1], xy[:, :1] - x0[None] - grid.resolution), 0)
    dy = np.maximum(np.maximum(y0[None] - xy[:, 1:], xy[:, 1:] - y0[None] - grid.resolution), 0)
    return np.hypot(dx, dy).min(axis=1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_pose_keeps_the_clearance(grid: OccupancyGrid, seed: int) -> None:
    traj = drive_trajectory(grid, 600, seed=seed, clearance=0.3)
    assert exact_clearance(grid, traj.truth[:, :2]).min() >= 0.3


def test_the_route_covers_the_map(grid: OccupancyGrid) -> None:
    traj = drive_trajectory(grid, 1200, seed=4, clearance=0.3)
    # both rooms, and most 1 m x 1 m squares of the free space, are visited
    x, y = traj.truth[:, 0] - grid.origin[0], traj.truth[:, 1] - grid.origin[1]
    assert (x < 4.1).any() and (x > 4.2).any()
    visited = {(int(a), int(b)) for a, b in zip(x, y, strict=True)}
    free_squares = {
        (c, r) for c in range(1, 8) for r in range(1, 6) if grid.free[r * 20 + 10, c * 20 + 10]
    }
    assert len(visited & free_squares) >= 0.6 * len(free_squares)


def test_limits_and_timing(grid: OccupancyGrid) -> None:
    traj = drive_trajectory(grid, 400, seed=3, max_speed=0.6, max_turn_rate=0.8)
    assert traj.truth.shape == traj.odometry.shape == (400, 3)
    np.testing.assert_allclose(traj.times, np.arange(400) / RATE)
    step = np.hypot(*np.diff(traj.truth[:, :2], axis=0).T)
    turn = np.abs(wrap_angle(np.diff(traj.truth[:, 2])))
    assert step.max() <= 0.6 / RATE + 1e-12
    assert turn.max() <= 0.8 / RATE + 1e-12
    assert step.mean() > 0.3 / RATE  # it really drives
    assert np.all(np.abs(traj.truth[:, 2]) <= math.pi)
    np.testing.assert_array_equal(traj.odometry[0], traj.truth[0])


def test_deterministic_for_a_seed(grid: OccupancyGrid) -> None:
    a = drive_trajectory(grid, 200, seed=11)
    b = drive_trajectory(grid, 200, seed=11)
    c = drive_trajectory(grid, 200, seed=12)
    np.testing.assert_array_equal(a.truth, b.truth)
    np.testing.assert_array_equal(a.odometry, b.odometry)
    assert not np.allclose(a.truth, c.truth)


def step_motion(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-step translation and heading change."""
    return np.hypot(*np.diff(poses[:, :2], axis=0).T), wrap_angle(np.diff(poses[:, 2]))


def test_odometry_random_drift_has_the_configured_spread(grid: OccupancyGrid) -> None:
    noise = OdometryNoise(
        alpha1=0.0, alpha2=0.0, alpha3=0.01, alpha4=0.0, trans_scale=0, rot_scale=0
    )
    traj = drive_trajectory(grid, 2000, seed=5, odometry_noise=noise)
    true_step, true_turn = step_motion(traj.truth)
    odo_step, odo_turn = step_motion(traj.odometry)
    moving = true_step > 0.01
    z = (odo_step - true_step)[moving] / (0.1 * true_step[moving])
    assert abs(z.mean()) < 0.1
    assert z.std() == pytest.approx(1.0, abs=0.1)
    np.testing.assert_allclose(odo_turn, true_turn, atol=1e-12)  # no rotation noise asked for


def test_odometry_systematic_drift_scales_the_motion(grid: OccupancyGrid) -> None:
    noise = OdometryNoise(0.0, 0.0, 0.0, 0.0, trans_scale=0.02, rot_scale=-0.01)
    traj = drive_trajectory(grid, 300, seed=6, odometry_noise=noise)
    true_step, true_turn = step_motion(traj.truth)
    odo_step, odo_turn = step_motion(traj.odometry)
    np.testing.assert_allclose(odo_step, 1.02 * true_step, atol=1e-12)
    np.testing.assert_allclose(odo_turn, 0.99 * true_turn, atol=1e-12)
    assert np.hypot(*(traj.odometry[-1, :2] - traj.truth[-1, :2])) > 0.1  # it drifts away


def test_default_odometry_drifts_but_stays_plausible(grid: OccupancyGrid) -> None:
    traj = drive_trajectory(grid, 1500, seed=8)
    drift = np.hypot(*(traj.odometry[:, :2] - traj.truth[:, :2]).T)
    path = np.hypot(*np.diff(traj.truth[:, :2], axis=0).T).sum()
    assert 0.001 * path < drift[-1] < 0.1 * path


def test_save_and_load_round_trip_with_stable_bytes(grid: OccupancyGrid, tmp_path: Path) -> None:
    traj = drive_trajectory(grid, 50, seed=1)
    ranges = np.random.default_rng(0).uniform(0.1, 5.0, (50, 667)).astype(np.float32)
    meta = {"name": "test_drive", "map": "rooms"}
    save_trajectory(traj, tmp_path / "a", ranges, meta, grid=grid)
    save_trajectory(traj, tmp_path / "b", ranges, meta, grid=grid)
    for name in FILES:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    loaded, loaded_ranges = load_trajectory(tmp_path / "a")
    assert isinstance(loaded, Trajectory)
    np.testing.assert_array_equal(loaded.truth, traj.truth)
    np.testing.assert_array_equal(loaded.odometry, traj.odometry)
    np.testing.assert_array_equal(loaded.times, traj.times)
    np.testing.assert_array_equal(loaded_ranges, ranges)
    np.testing.assert_allclose(loaded.waypoints, traj.waypoints, atol=1e-6)
    saved_meta = json.loads((tmp_path / "a" / "meta.json").read_text())
    assert saved_meta["name"] == "test_drive" and saved_meta["num_steps"] == 50
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == sorted(FILES)  # no temp files


def test_bad_input_is_rejected(grid: OccupancyGrid, tmp_path: Path) -> None:
    traj = drive_trajectory(grid, 20, seed=1)
    with pytest.raises(ValueError, match=r"shape \(T=20, B\)"):
        save_trajectory(traj, tmp_path, np.zeros((19, 667), np.float32), {})
    with pytest.raises(ValueError, match="float32"):
        save_trajectory(traj, tmp_path, np.zeros((20, 667)), {})
    with pytest.raises(FileNotFoundError, match=r"truth\.npy"):
        load_trajectory(tmp_path / "missing")
    with pytest.raises(ValueError, match="clearance"):
        drive_trajectory(grid, 20, clearance=3.0)
    with pytest.raises(ValueError, match="num_steps"):
        drive_trajectory(grid, 0)
