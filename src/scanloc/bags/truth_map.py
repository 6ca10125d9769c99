"""A bag's map built from the bag itself, when it has ground truth and no map is given: the real
logs' split rule (scanloc.real.split: the mapping part builds the map along the true laser
poses, the evaluation part is the run that is localized) and their log-odds mapping
(scanloc.real.log_mapping), so that no evaluated scan is in the map it is localized in."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from scanloc.real.log_mapping import build_map_from_log
from scanloc.real.split import Split, coverage, laser_poses_of, segments_of, split_log
from scanloc.sensor.laser import LaserSpec
from scanloc.trajectory.format import Trajectory
from scanloc.world.occupancy_grid import OccupancyGrid


@dataclass(frozen=True)
class SplitSettings:
    """conf/bag.yaml `split` and `mapping`, as conf/real.yaml has them."""

    mode: str = "window"
    window: tuple[float, float] = (0.25, 0.75)
    map_share: float = 0.5
    max_evaluation_scans: int | None = None
    resolution: float = 0.05
    margin: float = 1.0


@dataclass(frozen=True)
class TruthMappedRun:
    """The built map, the evaluation part as a run (its ranges, its meta additions)."""

    grid: OccupancyGrid
    run: Trajectory
    ranges: np.ndarray
    meta: dict[str, Any]


def _mount(meta: dict[str, Any]) -> np.ndarray:
    mount = meta.get("laser_mount") or {}
    return np.array([float(mount.get(k, 0.0)) for k in ("x", "y", "yaw")])


def _evaluation_run(traj: Trajectory, evaluation: np.ndarray) -> Trajectory:
    """The contiguous evaluation part as its own run: times restart at 0, poses as read."""
    return Trajectory(
        times=traj.times[evaluation] - traj.times[evaluation[0]],
        truth=traj.truth[evaluation],
        odometry=traj.odometry[evaluation],
    )


def map_from_truth(
    bag: str,
    traj: Trajectory,
    ranges: np.ndarray,
    meta: dict[str, Any],
    spec: LaserSpec,
    settings: SplitSettings,
) -> TruthMappedRun:
    """Split the bag's run (module doc), build the map from the mapping part's scans at their
    true laser poses (scans without truth are left out of it) and count which evaluated poses
    the map covers, as the real stage does."""
    count = len(traj.times)
    split: Split = split_log(
        count, settings.mode, settings.map_share, settings.window, settings.max_evaluation_scans
    )
    mapping, evaluation = split.mapping, split.evaluation
    if len(segments_of(evaluation)) != 1:
        raise ValueError(f"{bag}: the evaluation part must be contiguous, got {split.mode}")
    known = np.isfinite(traj.truth).all(axis=1)
    mapped = mapping[known[mapping]]
    if len(mapped) < 2:
        raise ValueError(
            f"{bag}: {len(mapped)} scans of the mapping part have truth; expected >= 2 to build "
            "the map from (give map_yaml instead)"
        )
    laser = np.full((count, 3), np.nan)
    laser[known] = laser_poses_of(traj.truth[known], _mount(meta))
    # As the real stage maps: a beam without return clears nothing (glass, open doors).
    hits = np.where(ranges < spec.range_max, ranges, np.float32(np.nan))
    angles = spec.beam_angles()
    grid = build_map_from_log(
        laser[mapped], hits[mapped], angles, spec.range_max,
        resolution=settings.resolution, margin=settings.margin,
    )  # fmt: skip
    scored = evaluation[known[evaluation]]  # evaluated steps with truth, as log indices
    covered = coverage(grid, laser[scored], ranges[scored], angles, spec.range_max)
    uncovered = scored[covered["uncovered_steps"]]
    run = _evaluation_run(traj, evaluation)
    missing = int((~known[evaluation]).sum())
    split_info = {
        "mode": split.mode,
        "optimistic": split.optimistic,
        "map_scans": len(mapping),
        "map_scans_with_truth": len(mapped),
        "evaluation_scans": len(evaluation),
        "map_share": round(len(mapping) / count, 4),
        "evaluation_share": round(len(evaluation) / count, 4),
    }
    if split.optimistic:
        split_info["note"] = "optimistic: the map holds every evaluated scan"
    origin = int(meta["time_origin_ns"]) + round(float(traj.times[evaluation[0]]) * 1e9)
    additions = {
        "map_source": "built from the bag's mapping part along its truth (scanloc.real.split)",
        "split": split_info,
        "coverage": {k: v for k, v in covered.items() if k != "uncovered_steps"},
        "log_scans": [int(evaluation[0]), int(evaluation[-1])],
        "uncovered_steps": np.flatnonzero(np.isin(evaluation, uncovered)).tolist(),
        "time_origin_ns": origin,
        "scans": len(evaluation),
        "truth_missing_steps": missing,
        "has_truth": missing < len(evaluation),
    }
    return TruthMappedRun(grid, run, ranges[evaluation], additions)
