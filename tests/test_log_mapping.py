"""Occupancy mapping from a log: the grid traversal against dense sampling, hand-made beams,
and a map rebuilt from scans the project's simulator takes in a known map of thin walls."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanloc.real.log_mapping import build_map_from_log, save_log_map, trace_cells
from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.simulate import ScanSimulator
from scanloc.trajectory.drive import drive_trajectory
from scanloc.world.map_server import load_map
from scanloc.world.occupancy_grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid

RES = 0.05


def traverse(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """(K, 2) cells (col, row) trace_cells visits."""
    size = 1 + abs(math.floor(x1) - math.floor(x0)) + abs(math.floor(y1) - math.floor(y0))
    cols, rows = np.empty(size, np.int64), np.empty(size, np.int64)
    n = trace_cells(x0, y0, x1, y1, cols, rows)
    return np.column_stack([cols[:n], rows[:n]])


def clipped_length(cell: tuple[int, int], p0: np.ndarray, p1: np.ndarray, tol: float) -> float:
    """Length of the segment inside the cell's square grown by tol; -1 when they do not meet
    (Liang-Barsky)."""
    t0, t1 = 0.0, 1.0
    d = p1 - p0
    for axis in range(2):
        lo, hi = cell[axis] - tol, cell[axis] + 1 + tol
        if d[axis] == 0.0:
            if not lo <= p0[axis] <= hi:
                return -1.0
            continue
        with np.errstate(over="ignore"):  # a tiny d: the bound moves to ±inf, as it should
            a, b = (lo - p0[axis]) / d[axis], (hi - p0[axis]) / d[axis]
        t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
    return (t1 - t0) * float(np.hypot(*d)) if t1 >= t0 else -1.0


coordinate = st.one_of(
    st.floats(-20.0, 20.0, allow_nan=False, allow_infinity=False),
    st.integers(-40, 40).map(lambda k: k / 2.0),  # on cell boundaries and cell centres
)


@given(x0=coordinate, y0=coordinate, x1=coordinate, y1=coordinate)
@settings(max_examples=300, deadline=None)
def test_traversal_matches_dense_sampling(x0: float, y0: float, x1: float, y1: float) -> None:
    cells = traverse(x0, y0, x1, y1)
    p0, p1 = np.array([x0, y0]), np.array([x1, y1])
    # a minimal 4-connected path from the start point's cell to the end point's cell
    assert tuple(cells[0]) == (math.floor(x0), math.floor(y0))
    assert tuple(cells[-1]) == (math.floor(x1), math.floor(y1))
    assert len({tuple(c) for c in cells}) == len(cells)
    assert np.all(np.abs(np.diff(cells, axis=0)).sum(axis=1) == 1)
    # only cells the segment touches (a corner counts, to rounding)...
    for cell in cells:
        assert clipped_length(tuple(cell), p0, p1, tol=1e-9) >= 0.0, cell
    # ...and every cell a dense sampling finds the segment truly passing through
    t = np.linspace(0.0, 1.0, 4001)[:, None]
    samples = np.unique(np.floor(p0 + t * (p1 - p0)).astype(np.int64), axis=0)
    reference = {tuple(c) for c in samples if clipped_length(tuple(c), p0, p1, 0.0) > 1e-6}
    assert reference <= {tuple(c) for c in cells}


def test_traversal_of_a_point_and_of_axis_aligned_segments() -> None:
    assert traverse(2.5, 3.5, 2.7, 3.2).tolist() == [[2, 3]]
    assert traverse(0.5, 0.5, 3.5, 0.5).tolist() == [[0, 0], [1, 0], [2, 0], [3, 0]]
    assert traverse(0.5, 0.5, 0.5, -1.5).tolist() == [[0, 0], [0, -1], [0, -2]]
    assert traverse(-0.5, 2.0, -0.5, 4.0).tolist() == [[-1, 2], [-1, 3], [-1, 4]]  # on a line


def beam_map(ranges: list[float], **kwargs: object) -> OccupancyGrid:
    """One beam straight ahead (+x) from (0, 0), one scan per reading."""
    poses = np.zeros((len(ranges), 3))
    return build_map_from_log(poses, np.array(ranges)[:, None], np.zeros(1), **kwargs)


def cells_along_x(grid: OccupancyGrid, x0: float, x1: float) -> np.ndarray:
    """The cells of row y = 0 whose centres lie in [x0, x1)."""
    xs = np.arange(x0 + RES / 2, x1, RES)
    col, row = grid.world_to_cell(xs, np.zeros_like(xs))
    return grid.cells[row, col]


def test_a_beam_clears_its_path_and_marks_its_end() -> None:
    grid = beam_map([1.0, 1.0, 1.0], max_range=5.0, resolution=RES, margin=0.5)
    assert grid.origin == pytest.approx((-0.5, -0.5, 0.0))
    assert (cells_along_x(grid, 0.0, 1.0) == FREE).all()  # three crossings: l = -1.2
    assert cells_along_x(grid, 1.0, 1.05).tolist() == [OCCUPIED]  # the face at x = 1 m
    assert (cells_along_x(grid, 1.05, 1.5) == UNKNOWN).all()  # behind the hit: never seen
    assert (cells_along_x(grid, -0.5, 0.0) == UNKNOWN).all()
    assert grid.counts() == {"occupied": 1, "free": 20, "unknown": grid.cells.size - 21}


def test_one_crossing_is_not_enough_to_call_a_cell_free() -> None:
    grid = beam_map([1.0], max_range=5.0, resolution=RES, margin=0.5)  # p(free cells) = 0.40
    assert (cells_along_x(grid, 0.0, 1.0) == UNKNOWN).all()
    assert cells_along_x(grid, 1.0, 1.05).tolist() == [OCCUPIED]  # p = 0.70


def test_no_return_clears_up_to_usable_range_only() -> None:
    for reading in (4.0, 4.5, np.inf):  # at max_range, a fill value above it, +inf
        grid = beam_map([reading] * 3, max_range=4.0, usable_range=1.5, margin=2.0)
        assert grid.counts()["occupied"] == 0
        assert (cells_along_x(grid, 0.0, 1.5) == FREE).all()
        assert (cells_along_x(grid, 1.55, 2.0) == UNKNOWN).all()
    far_hit = beam_map([2.0] * 3, max_range=4.0, usable_range=1.5, margin=2.0)
    assert far_hit.counts()["occupied"] == 0  # beyond the usable range: clears only
    assert (cells_along_x(far_hit, 1.55, 2.0) == UNKNOWN).all()


def test_unusable_readings_are_ignored() -> None:
    grid = beam_map([0.0, -1.0, np.nan], max_range=4.0, margin=0.5)
    assert (grid.cells == UNKNOWN).all()


def test_clamping_lets_a_cell_change_its_mind() -> None:
    readings = [2.0] * 100 + [1.0] * 7  # the cell at x = 1 m: crossed 100 times, then hit
    assert cells_along_x(beam_map(readings, max_range=5.0), 1.0, 1.05).tolist() == [OCCUPIED]
    unclamped = beam_map(readings, max_range=5.0, clamp=(-100.0, 100.0))
    assert cells_along_x(unclamped, 1.0, 1.05).tolist() == [FREE]


def test_too_large_a_map_is_refused_with_its_size() -> None:
    poses = np.array([[0.0, 0.0, 0.0], [1000.0, 1000.0, 0.0]])
    with pytest.raises(ValueError, match=r"= 40[\d,]{9} cells at 0.05 m .* limit of 200,000,000"):
        build_map_from_log(poses, np.full((2, 1), np.inf), np.zeros(1), max_range=5.0)


def test_inconsistent_inputs_are_refused() -> None:
    with pytest.raises(ValueError, match=r"ranges must have shape \(N=2, B=1\)"):
        build_map_from_log(np.zeros((2, 3)), np.ones((2, 2)), np.zeros(1), max_range=5.0)
    with pytest.raises(ValueError, match="poses must be finite"):
        build_map_from_log(np.zeros((2, 2)), np.ones((2, 1)), np.zeros(1), max_range=5.0)
    with pytest.raises(ValueError, match="free_thresh"):
        beam_map([1.0], max_range=5.0, free_thresh=0.7)


def thin_wall_rooms() -> OccupancyGrid:
    """10 m x 7 m: two rooms split by a 1-cell wall with a door, the right one halved by a
    second wall with a door, a 2-cell-thick wall in the left room and a closed box there."""
    cells = np.full((140, 200), FREE, dtype=np.int8)
    cells[[0, -1], :] = OCCUPIED
    cells[:, [0, -1]] = OCCUPIED
    cells[:, 100] = OCCUPIED
    cells[100:124, 100] = FREE
    cells[70, 100:] = OCCUPIED
    cells[70, 150:174] = FREE
    cells[90:92, 20:60] = OCCUPIED
    cells[[20, 40], 20:50] = OCCUPIED  # the box: rows 21..39, cols 21..48 inside
    cells[20:41, [20, 49]] = OCCUPIED
    return OccupancyGrid(cells, RES, (-2.0, -1.0, 0.0))


BOX_INSIDE = (slice(21, 40), slice(21, 49))


@dataclass(frozen=True)
class Rebuilt:
    truth: OccupancyGrid
    poses: np.ndarray
    ranges: np.ndarray
    spec: LaserSpec
    built: OccupancyGrid

    def on_truth_grid(self) -> np.ndarray:
        """The built cells at the true map's cells (same world coordinates), UNKNOWN off it."""
        shift_c = round((self.built.origin[0] - self.truth.origin[0]) / RES)
        shift_r = round((self.built.origin[1] - self.truth.origin[1]) / RES)
        rows, cols = np.mgrid[0 : self.truth.height, 0 : self.truth.width]
        rows, cols = rows - shift_r, cols - shift_c
        inside = (rows >= 0) & (rows < self.built.height) & (cols >= 0) & (cols < self.built.width)
        out = np.full(self.truth.cells.shape, UNKNOWN, dtype=np.int8)
        out[inside] = self.built.cells[rows[inside], cols[inside]]
        return out


@pytest.fixture(scope="module")
def rebuilt() -> Rebuilt:
    truth = thin_wall_rooms()
    spec = LaserSpec()  # 667 beams over 240°, 5.6 m, no return = 7.0 m
    poses = drive_trajectory(truth, num_steps=1600, seed=1).truth[::4]
    ranges = ScanSimulator(truth, spec).simulate(poses, rng=0)  # exact caster, no noise
    built = build_map_from_log(poses, ranges, spec.beam_angles(), spec.range_max, resolution=RES)
    return Rebuilt(truth, poses, ranges, spec, built)


def test_rebuilt_map_matches_the_true_walls(rebuilt: Rebuilt) -> None:
    built = rebuilt.on_truth_grid() == OCCUPIED
    true = rebuilt.truth.occupied
    iou = (built & true).sum() / (built | true).sum()
    assert iou >= 0.9, iou
    # what is missed are cells no ray can reach: room corners and where walls meet
    assert (built & ~true).sum() == 0
    assert (rebuilt.on_truth_grid()[true] == FREE).sum() == 0
    # off the true map (the margin beyond the outer walls) nothing was seen
    assert rebuilt.built.counts()["occupied"] == built.sum()


def test_unseen_region_stays_unknown(rebuilt: Rebuilt) -> None:
    cells = rebuilt.on_truth_grid()
    assert (cells[BOX_INSIDE] == UNKNOWN).all()
    assert (cells[20, 21:49] == OCCUPIED).mean() > 0.9  # its outside faces were seen
    margin = np.ones(rebuilt.built.cells.shape, dtype=bool)
    shift_c = round((rebuilt.truth.origin[0] - rebuilt.built.origin[0]) / RES)
    shift_r = round((rebuilt.truth.origin[1] - rebuilt.built.origin[1]) / RES)
    margin[shift_r : shift_r + rebuilt.truth.height, shift_c : shift_c + rebuilt.truth.width] = 0
    assert margin.any() and (rebuilt.built.cells[margin] == UNKNOWN).all()


def test_free_space_along_beams_is_free(rebuilt: Rebuilt) -> None:
    angles = rebuilt.spec.beam_angles()
    scan, beam = np.nonzero(rebuilt.ranges <= rebuilt.spec.range_max)
    heading = rebuilt.poses[scan, 2] + angles[beam]
    for fraction in (0.25, 0.5, 0.75):
        reach = fraction * rebuilt.ranges[scan, beam]
        x = rebuilt.poses[scan, 0] + reach * np.cos(heading)
        y = rebuilt.poses[scan, 1] + reach * np.sin(heading)
        col, row = rebuilt.built.world_to_cell(x, y)
        assert (rebuilt.built.cells[row, col] == FREE).all()
    assert (rebuilt.on_truth_grid()[rebuilt.truth.free] == FREE).mean() > 0.95


def test_map_building_is_deterministic(rebuilt: Rebuilt) -> None:
    again = build_map_from_log(
        rebuilt.poses, rebuilt.ranges, rebuilt.spec.beam_angles(), rebuilt.spec.range_max
    )
    assert again.origin == rebuilt.built.origin
    assert again.cells.tobytes() == rebuilt.built.cells.tobytes()


def test_saved_map_reads_back(rebuilt: Rebuilt, tmp_path: Path) -> None:
    yaml_path, preview = save_log_map(rebuilt.built, tmp_path / "maps" / "rooms.yaml")
    assert preview == tmp_path / "maps" / "rooms.png" and preview.is_file()
    assert (tmp_path / "maps" / "rooms.pgm").is_file()
    loaded = load_map(yaml_path)
    assert loaded.cells.tobytes() == rebuilt.built.cells.tobytes()
    assert loaded.origin == pytest.approx(rebuilt.built.origin, abs=1e-12)
    assert loaded.resolution == RES
