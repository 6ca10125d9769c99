"""A log split into the part that builds the map and the part that is localized, and the runs
cut out of it (conf/real.yaml `split`).

Default `window`: a contiguous window of the log in time (`window`, fractions of the scans;
[0.25, 0.75) by default) is evaluated, and the scans before and after it build the map. Held
out in time, so the evaluated scans' passers-by, doors and furniture moves are not in the map,
and contiguous, so a localizer tracks it like any run; both logs loop through their building,
so the quarters on either side see nearly everything the middle half sees (measured: 92.5 % of
intel's and 96.5 % of fr079's evaluated poses covered, `coverage` below). `halves` maps the
first `map_share` and evaluates the rest: it leaves 34 % (intel) and 23 % (fr079) of the
evaluated poses uncovered, since both robots reach new rooms late. Uncovered poses are counted,
never dropped. `full` maps every scan and evaluates every scan: the old, optimistic figure,
labelled so in meta.json. For tuning, each stretch of the mapping part is split the same way
once more (`tune_holdout`): a tune map and a held-out tune run, never an evaluated scan.

A run is a list of segments [start, end) of scan indices: its odometry chains the log's
per-scan increments within each segment and adds no motion across the cut between two
segments (the wheels do not turn while the robot is carried), as simulated kidnap runs do.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from scanloc.pose import compose
from scanloc.trajectory.format import Trajectory
from scanloc.trajectory.laser_odometry import chain
from scanloc.world.occupancy_grid import OccupancyGrid

SPLIT_MODES = ("window", "halves", "full")


@dataclass(frozen=True)
class Split:
    """Scan indices of the mapping and the evaluation part; `optimistic` when they overlap."""

    mode: str
    mapping: np.ndarray
    evaluation: np.ndarray

    @property
    def optimistic(self) -> bool:
        return bool(np.intersect1d(self.mapping, self.evaluation).size)


def split_log(
    num_scans: int,
    mode: str,
    map_share: float = 0.5,
    window: tuple[float, float] = (0.25, 0.75),
    max_evaluation: int | None = None,
) -> Split:
    """The split of `num_scans` scans (module doc); errors name the field. `max_evaluation`
    keeps only the first scans of the evaluation part (a profile's budget); the rest of it is
    then neither mapped nor evaluated."""
    if mode not in SPLIT_MODES:
        raise ValueError(
            f"conf/real.yaml field 'split.mode': expected one of {SPLIT_MODES}, got {mode!r}"
        )
    every = np.arange(num_scans)
    if mode == "full":
        return Split(mode, every, every)
    if mode == "window":
        start, end = (float(f) for f in window)
        if not 0.0 <= start < end <= 1.0 or (start, end) == (0.0, 1.0):
            raise ValueError(
                f"conf/real.yaml field 'split.window': expected 0 <= start < end <= 1 leaving "
                f"scans to map, got {list(window)}"
            )
        first, last = round(start * num_scans), round(end * num_scans)
    else:
        if not 0.0 < map_share < 1.0:
            raise ValueError(
                f"conf/real.yaml field 'split.map_share': expected in (0, 1), got {map_share}"
            )
        first, last = round(map_share * num_scans), num_scans
    mapping = np.setdiff1d(every, every[first:last])
    evaluation = every[first:last][:max_evaluation]
    if len(mapping) < 2 or len(evaluation) < 2:
        raise ValueError(f"{mode} split of {num_scans} scans: each part needs >= 2 scans")
    return Split(mode, mapping, evaluation)


def tune_holdout(
    mapping: np.ndarray, window: tuple[float, float] = (0.25, 0.75)
) -> tuple[np.ndarray, np.ndarray]:
    """The mapping part split as the log is, for choosing settings where the map is incomplete:
    in each of its contiguous stretches the same `window` (fractions of the stretch) is held
    out and the rest builds a tune map (scan indices of both, in time order). The hold-out,
    localized in the tune map, is the `tune_heldout` run (its stretches joined by a cut, as a
    kidnap); both stay inside the mapping part, so no evaluated scan is used. The `tune` run,
    localized in the log's map, is covered by construction and cannot show what unmapped space
    does."""
    start, end = (float(f) for f in window)
    tune_map, heldout = [], []
    for a, b in segments_of(mapping):
        first, last = a + round(start * (b - a)), a + round(end * (b - a))
        if last - first < 2 or (b - a) - (last - first) < 2:
            raise ValueError(
                f"a tune hold-out needs >= 2 scans held out and >= 2 mapped in each mapping "
                f"stretch, got [{a}, {b}) with window {list(window)}"
            )
        tune_map.append(np.r_[a:first, last:b])
        heldout.append(np.arange(first, last))
    return np.concatenate(tune_map), np.concatenate(heldout)


def segments_of(indices: np.ndarray) -> list[tuple[int, int]]:
    """Sorted scan indices as runs of consecutive ones, [start, end) each."""
    breaks = np.flatnonzero(np.diff(indices) != 1) + 1
    return [(int(p[0]), int(p[-1]) + 1) for p in np.split(indices, breaks)]


def kidnap_segments(evaluation: np.ndarray, cuts: int) -> list[tuple[int, int]]:
    """The evaluation part (contiguous) in `cuts` + 1 equal stretches, reordered so that every
    cut jumps to another time: A B C D → A C B D for 3 cuts (then every other stretch swapped
    with its successor from the second on, for more cuts)."""
    start, end = int(evaluation[0]), int(evaluation[-1]) + 1
    if cuts < 1 or end - start < 4 * (cuts + 1):
        raise ValueError(f"cannot cut {end - start} scans at {cuts} points (>= 4 scans a stretch)")
    bounds = np.linspace(start, end, cuts + 2).round().astype(int)
    stretches = [(int(a), int(b)) for a, b in itertools.pairwise(bounds)]
    order = list(range(len(stretches)))
    for k in range(1, len(order) - 1, 2):
        order[k], order[k + 1] = order[k + 1], order[k]
    return [stretches[k] for k in order]


def segment_run(
    segments: list[tuple[int, int]],
    times: np.ndarray,
    truth: np.ndarray,
    wheel_steps: np.ndarray,
    laser_steps: np.ndarray,
) -> tuple[Trajectory, np.ndarray]:
    """The run of `segments` (module doc) and its scan indices: times restart at 0 and advance
    by the log's median step across a cut; `wheel_steps` / `laser_steps` (N-1, 3) are the
    log's per-scan base increments."""
    index = np.concatenate([np.arange(a, b) for a, b in segments])
    dt = float(np.median(np.diff(times)))
    wheel, laser, gaps = [], [], []
    kidnaps: list[int] = []
    for n, (a, b) in enumerate(segments):
        if n:
            kidnaps.append(sum(e - s for s, e in segments[:n]))
            wheel.append(np.zeros((1, 3)))
            laser.append(np.zeros((1, 3)))
            gaps.append([dt])
        wheel.append(wheel_steps[a : b - 1])
        laser.append(laser_steps[a : b - 1])
        gaps.append(np.diff(times[a:b]))
    run_truth = truth[index]
    traj = Trajectory(
        times=np.concatenate([[0.0], np.cumsum(np.concatenate(gaps))]),
        truth=run_truth,
        odometry=chain(run_truth[0], np.concatenate(wheel)),
        kidnap_steps=tuple(kidnaps),
        laser_odometry=chain(run_truth[0], np.concatenate(laser)),
    )
    return traj, index


def coverage(
    grid: OccupancyGrid,
    laser_poses: np.ndarray,
    ranges: np.ndarray,
    angles: np.ndarray,
    range_max: float,
    near_m: float = 0.15,
    min_share: float = 0.5,
) -> dict:
    """Which poses the map covers: a pose is `outside` when the laser's cell is not FREE in the
    map (unknown, occupied or off the grid), `unexplained` when fewer than `min_share` of its
    beams that returned end within `near_m` of an occupied cell; both are counted, the steps
    listed, and every step stays in the runs."""
    distance = ndimage.distance_transform_edt(~grid.occupied) * grid.resolution
    rows, cols = grid.cells.shape

    def cell(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        c = np.floor((xy[..., 0] - grid.origin[0]) / grid.resolution).astype(np.int64)
        r = np.floor((xy[..., 1] - grid.origin[1]) / grid.resolution).astype(np.int64)
        inside = (c >= 0) & (c < cols) & (r >= 0) & (r < rows)
        return np.clip(r, 0, rows - 1), np.clip(c, 0, cols - 1), inside

    r, c, inside = cell(laser_poses[:, :2])
    outside = ~(inside & grid.free[r, c])
    hit = ranges < range_max
    a = laser_poses[:, 2:3] + angles[None, :]
    ends = laser_poses[:, None, :2] + ranges[..., None] * np.stack([np.cos(a), np.sin(a)], -1)
    er, ec, einside = cell(ends)
    near = einside & (distance[er, ec] <= near_m) & hit
    share = near.sum(axis=1) / np.maximum(hit.sum(axis=1), 1)
    unexplained = share < min_share
    return {
        "steps": len(laser_poses),
        "outside_map": int(outside.sum()),
        "unexplained": int(unexplained.sum()),
        "covered": int((~outside & ~unexplained).sum()),
        "median_beams_near_map": round(float(np.median(share)), 4),
        "rule": (
            f"covered: the laser's cell is FREE and >= {min_share:.0%} of the returned beams end "
            f"within {near_m} m of an occupied cell"
        ),
        "uncovered_steps": np.flatnonzero(outside | unexplained).tolist(),
    }


def laser_poses_of(base: np.ndarray, mount: np.ndarray) -> np.ndarray:
    """Laser poses base ⊕ mount (N, 3)."""
    return np.array([compose(p, mount) for p in base]).reshape(-1, 3)
