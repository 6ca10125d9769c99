"""Free-space pose sampling: footprint clearance (checked by brute force), uniformity, errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from scanloc.world.free_space import sample_free_poses
from scanloc.world.map_server import load_map
from scanloc.world.occupancy_grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid


def nearest_obstacle(grid: OccupancyGrid, poses: np.ndarray) -> np.ndarray:
    """Brute force: distance (m) from each position to the nearest non-free cell square,
    the outside of the grid included."""
    rows, cols = np.nonzero(~grid.free)
    x0 = grid.origin[0] + cols * grid.resolution
    y0 = grid.origin[1] + rows * grid.resolution
    out = np.empty(len(poses))
    for i, (px, py, _) in enumerate(poses):
        gx = np.maximum(np.maximum(x0 - px, px - (x0 + grid.resolution)), 0.0)
        gy = np.maximum(np.maximum(y0 - py, py - (y0 + grid.resolution)), 0.0)
        inner = np.hypot(gx, gy).min() if len(gx) else np.inf
        width_m, height_m = grid.size_m
        to_edge = min(
            px - grid.origin[0],
            grid.origin[0] + width_m - px,
            py - grid.origin[1],
            grid.origin[1] + height_m - py,
        )
        out[i] = min(inner, to_edge)
    return out


@st.composite
def maps_with_room(draw: st.DrawFn) -> tuple[OccupancyGrid, float, int]:
    """A random grid of free / occupied / unknown cells, a clearance radius and a seed, with a
    free square carved in wherever the draw puts it: 2·radius + 2 cells wide, so some positions
    are valid by construction (a 2 x 2 cell region at least) and no case has to be thrown away."""
    radius = draw(st.floats(0.0, 4.0))  # cells
    side = math.ceil(2 * radius) + 2
    height, width = draw(st.integers(max(3, side), 30)), draw(st.integers(max(3, side), 30))
    occupied, unknown = draw(st.floats(0.0, 0.3)), draw(st.floats(0.0, 0.1))
    res = draw(st.sampled_from([0.02, 0.05, 0.1]))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    u = rng.random((height, width))
    codes = np.where(u < occupied, OCCUPIED, np.where(u < occupied + unknown, UNKNOWN, FREE))
    row, col = draw(st.integers(0, height - side)), draw(st.integers(0, width - side))
    codes[row : row + side, col : col + side] = FREE
    grid = OccupancyGrid(codes.astype(np.int8), res, (rng.normal(), rng.normal(), 0.0))
    return grid, radius * res, seed


@settings(max_examples=60, deadline=None)
@given(maps_with_room())
def test_footprint_never_touches_an_obstacle(case: tuple[OccupancyGrid, float, int]) -> None:
    grid, clearance, seed = case
    poses = sample_free_poses(grid, 50, clearance, np.random.default_rng(seed))
    assert poses.shape == (50, 3) and poses.dtype == np.float64
    assert (nearest_obstacle(grid, poses) >= clearance - 1e-9).all()
    assert ((poses[:, 2] > -math.pi) & (poses[:, 2] <= math.pi)).all()


def test_no_room_for_the_footprint_is_an_error() -> None:
    """Free cells exist but none has the clearance: the error names map and radius."""
    cells = np.zeros((12, 12), np.int8)
    cells[::3, :] = OCCUPIED  # free corridors two cells (0.2 m) wide
    grid = OccupancyGrid(cells, 0.1)
    tight = sample_free_poses(grid, 10, 0.09, np.random.default_rng(0))
    assert tight.shape == (10, 3) and (nearest_obstacle(grid, tight) >= 0.09).all()
    with pytest.raises(ValueError, match=r"map corridors has no free cell with clearance 0\.11 m"):
        sample_free_poses(grid, 1, 0.11, np.random.default_rng(0), map_name="corridors")


def test_paper_map_poses_keep_the_robot_clear(stdr_maps_dir: Path) -> None:
    grid = load_map(stdr_maps_dir / "sparse_obstacles.yaml")
    poses = sample_free_poses(grid, 300, 0.2, np.random.default_rng(0), "sparse_obstacles")
    assert (nearest_obstacle(grid, poses) >= 0.2).all()


def test_positions_and_headings_are_uniform() -> None:
    # an empty 2 m x 1 m room: the valid region is the rectangle shrunk by the radius
    grid = OccupancyGrid(np.zeros((20, 40), np.int8), 0.05)
    poses = sample_free_poses(grid, 20_000, 0.23, np.random.default_rng(4))
    for column, lo, hi in [(0, 0.23, 1.77), (1, 0.23, 0.77), (2, -math.pi, math.pi)]:
        assert stats.kstest(poses[:, column], stats.uniform(lo, hi - lo).cdf).pvalue > 1e-3
    assert poses[:, 0].min() >= 0.23 and poses[:, 0].max() <= 1.77


def test_valid_region_next_to_a_corner_is_filled_exactly() -> None:
    # one occupied cell in an open room: positions within the radius of its square never
    # occur, positions just beyond do (rounded corner, not the cell-centre disc)
    cells = np.zeros((40, 40), np.int8)
    cells[20, 20] = OCCUPIED
    grid = OccupancyGrid(cells, 1.0)
    poses = sample_free_poses(grid, 40_000, 3.0, np.random.default_rng(5))
    gap = np.hypot(
        np.maximum(np.maximum(20 - poses[:, 0], poses[:, 0] - 21), 0),
        np.maximum(np.maximum(20 - poses[:, 1], poses[:, 1] - 21), 0),
    )
    assert gap.min() >= 3.0
    assert gap.min() < 3.05


def test_sampling_is_deterministic_and_errors_are_clear() -> None:
    grid = OccupancyGrid(np.zeros((10, 10), np.int8), 0.1)
    a = sample_free_poses(grid, 100, 0.1, np.random.default_rng(9))
    b = sample_free_poses(grid, 100, 0.1, np.random.default_rng(9))
    assert a.tobytes() == b.tobytes()
    assert sample_free_poses(grid, 0, 0.1, np.random.default_rng(9)).shape == (0, 3)
    with pytest.raises(ValueError, match=r"map tiny has no free cell with clearance 0\.6 m"):
        sample_free_poses(grid, 1, 0.6, np.random.default_rng(0), map_name="tiny")
    with pytest.raises(ValueError, match="clearance_radius"):
        sample_free_poses(grid, 1, -0.1, np.random.default_rng(0))
