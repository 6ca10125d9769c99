"""A ROS 1 or ROS 2 bag (sqlite3 or mcap) made into a scanloc run (trajectory/format.py).

One step per LaserScan, at its header stamp; step times count from the first scan (its stamp
is meta `time_origin_ns`). Odometry comes from the odometry topic (nav_msgs/Odometry, or any
pose topic) or from tf odom → base_link, truth (optional) from a pose topic
(geometry_msgs/PoseStamped, PoseWithCovarianceStamped, nav_msgs/Odometry) or a CSV
`t,x,y,theta`; both are paired with the scans by timestamp (bags/pairing.py: linear, θ on the
circle, within `pairing_tolerance_s`). A scan without odometry within the tolerance is an
error; a scan without truth gets NaN truth (meta `truth_missing_steps`), and a bag without
truth gives an all-NaN truth (meta `has_truth: false`: only consistency and speed can be
scored). The laser's mounting (static tf base_link → the scans' frame) goes to meta
`laser_mount`; the run's poses stay those of base_link.

Ranges: a reading beyond the scan's range_max, +inf (REP 117: no return), −inf (too close)
or NaN becomes the sensor's "no return" value (the configured LaserSpec's no_return_value),
as scanloc's own scans encode it; everything else is kept bit for bit.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from scanloc.bags.errors import BagError
from scanloc.bags.layout import BagLayout
from scanloc.bags.pairing import first_decrease, pose_at
from scanloc.bags.pose_csv import read_pose_csv
from scanloc.bags.topics import BagTopics, frame, open_bag, read_topics
from scanloc.pose import compose
from scanloc.sensor.laser import LaserSpec
from scanloc.trajectory.format import Trajectory

GEOMETRY_TOLERANCE_RAD = 1e-5  # float32 angles of a LaserScan against the sensor config's


@dataclass(frozen=True)
class BagRunOptions:
    """How to read a bag: topics and frames, where truth comes from, the pairing tolerance.

    `truth_csv` times are seconds after the first scan (`csv_time: relative`) or on the bag's
    clock (`absolute`, e.g. 1600000000.25).
    """

    layout: BagLayout = field(default_factory=BagLayout)
    truth_topic: str | None = None
    truth_csv: str | None = None
    csv_time: str = "relative"
    pairing_tolerance_s: float = 0.05
    max_scans: int | None = None

    def __post_init__(self) -> None:
        if self.truth_topic and self.truth_csv:
            raise ValueError("bag: give truth_topic or truth_csv, not both")
        if self.csv_time not in ("relative", "absolute"):
            raise ValueError(
                f"bag field 'csv_time': expected relative or absolute, got {self.csv_time!r}"
            )
        if not self.pairing_tolerance_s >= 0:
            raise ValueError(
                f"bag field 'pairing_tolerance_s': expected >= 0, got {self.pairing_tolerance_s}"
            )


def clean_bag_ranges(raw: np.ndarray, range_max: float, no_return_value: float) -> np.ndarray:
    """float32 ranges with every reading that is not a measurement set to `no_return_value`."""
    readings = np.asarray(raw, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        missing = np.isnan(readings) | np.isneginf(readings) | (readings > np.float32(range_max))
    return np.where(missing, np.float32(no_return_value), readings).astype(np.float32)


def check_scan_geometry(
    bag: str | Path, topic: str, geometry: dict[str, Any], spec: LaserSpec
) -> None:
    """The bag's scans must be the configured sensor's: same beams and angles."""
    same = (
        geometry["num_beams"] == spec.num_beams
        and abs(geometry["angle_min"] - spec.angle_min) < GEOMETRY_TOLERANCE_RAD
        and abs(geometry["angle_max"] - spec.angle_max) < GEOMETRY_TOLERANCE_RAD
    )
    if not same:
        raise BagError(
            bag,
            topic,
            f"scans have {geometry['num_beams']} beams from {geometry['angle_min']:.6f} to "
            f"{geometry['angle_max']:.6f} rad, expected the sensor config's {spec.num_beams} "
            f"from {spec.angle_min:.6f} to {spec.angle_max:.6f}: choose the bag's sensor "
            "(conf/sensor/<robot>.yaml)",
        )


def laser_mount(
    bag: str | Path, topic: str, static: dict[tuple[str, str], tuple], base: str, laser: str
) -> tuple[float, float, float]:
    """base → laser (x, y, yaw) through the static transforms (a chain is composed)."""
    if base == laser:
        return 0.0, 0.0, 0.0
    todo: deque[tuple[str, np.ndarray]] = deque([(base, np.zeros(3))])
    seen = {base}
    while todo:
        at, pose = todo.popleft()
        for (parent, child), step in static.items():
            if parent == at and child not in seen:
                reached = compose(pose, np.asarray(step)) if at != base else np.asarray(step)
                if child == laser:
                    return float(reached[0]), float(reached[1]), float(reached[2])
                seen.add(child)
                todo.append((child, reached))
    present = [f"{p}→{c}" for p, c in static] or "none"
    raise BagError(
        bag,
        topic,
        f"no transform {base}→{laser} (the laser's mounting): expected it among the static "
        f"transforms; present: {present}",
    )


def _checked_stream(bag: str | Path, topic: str, stamps: np.ndarray, what: str) -> None:
    if len(stamps) == 0:
        raise BagError(bag, topic, f"no {what}: expected at least one message")
    back = first_decrease(stamps)
    if back >= 0:
        raise BagError(
            bag,
            topic,
            f"clock goes back at message {back}: stamp {stamps[back]} ns after "
            f"{stamps[back - 1]} ns; expected non-decreasing header stamps",
        )


def _odometry_source(bag: str | Path, layout: BagLayout) -> str:
    """ "topic" or "tf", as layout.odom_source says ("auto": the topic when the bag has it)."""
    if layout.odom_source != "auto":
        return layout.odom_source
    reader = open_bag(bag)
    try:
        return "topic" if layout.odom in reader.topics else "tf"
    finally:
        reader.close()


def _pair(
    bag: str | Path, topic: str, stamps: np.ndarray, poses: np.ndarray, scans: np.ndarray, tol: int
) -> tuple[np.ndarray, np.ndarray]:
    _checked_stream(bag, topic, stamps, "poses")
    return pose_at(stamps, poses, scans, tol)


def _unpaired_error(
    bag: str | Path, topic: str, scans: np.ndarray, stamps: np.ndarray, k: int, tol_s: float
) -> BagError:
    before = stamps[stamps <= scans[k]]
    after = stamps[stamps >= scans[k]]
    gap_b = f"{(scans[k] - before[-1]) / 1e9:.3f} s before" if len(before) else "none before"
    gap_a = f"{(after[0] - scans[k]) / 1e9:.3f} s after" if len(after) else "none after"
    return BagError(
        bag,
        topic,
        f"scan {k} (stamp {scans[k]} ns) has no odometry within pairing_tolerance_s = {tol_s} s "
        f"(nearest: {gap_b}, {gap_a}); expected odometry bracketing every scan",
    )


def read_bag_run(
    bag: str | Path, spec: LaserSpec, options: BagRunOptions = BagRunOptions()
) -> tuple[Trajectory, np.ndarray, dict[str, Any]]:
    """(Trajectory, ranges float32 (T, B), meta) of a bag (module doc); BagError on a bad bag."""
    lay = options.layout
    source = _odometry_source(bag, lay)
    pose_topics = [lay.odom] if source == "topic" else []
    if options.truth_topic:
        pose_topics.append(options.truth_topic)
    odom_pair = (lay.odom_frame, lay.base_frame)
    found: BagTopics = read_topics(
        bag,
        lay.scan,
        pose_topics,
        tf_topic=lay.tf if source == "tf" else None,
        tf_pairs=[odom_pair] if source == "tf" else [],
        tf_static_topic=lay.tf_static,
    )
    scans = np.asarray(found.scans.stamps, dtype=np.int64)
    if len(scans) == 0:
        raise BagError(bag, lay.scan, "no messages: expected LaserScans")
    back = first_decrease(scans, strict=True)
    if back >= 0:
        raise BagError(
            bag,
            lay.scan,
            f"clock goes back at message {back}: stamp {scans[back]} ns after "
            f"{scans[back - 1]} ns; expected strictly increasing header stamps",
        )
    count = len(scans) if options.max_scans is None else min(len(scans), int(options.max_scans))
    scans = scans[:count]
    geometry = found.scans.geometry
    check_scan_geometry(bag, lay.scan, geometry, spec)
    tol = round(options.pairing_tolerance_s * 1e9)
    if source == "topic":
        odom_topic, (stamps, poses, _) = lay.odom, found.poses[lay.odom].arrays()
    else:
        odom_topic = f"{lay.tf} ({lay.odom_frame}→{lay.base_frame})"
        stamps, poses, _ = found.transforms[(frame(lay.odom_frame), frame(lay.base_frame))].arrays()
        if len(stamps) == 0:
            raise BagError(
                bag,
                lay.tf,
                f"no transform {lay.odom_frame}→{lay.base_frame} in tf: expected odometry as "
                f"that transform (or a {lay.odom} topic)",
            )
    odometry, paired = _pair(bag, odom_topic, stamps, poses, scans, tol)
    if not paired.all():
        k = int(np.flatnonzero(~paired)[0])
        raise _unpaired_error(bag, odom_topic, scans, stamps, k, options.pairing_tolerance_s)
    truth = np.full((count, 3), np.nan)
    truth_source = None
    if options.truth_topic:
        truth_source = options.truth_topic
        t_stamps, t_poses, _ = found.poses[options.truth_topic].arrays()
        truth, _ = _pair(bag, truth_source, t_stamps, t_poses, scans, tol)
    elif options.truth_csv:
        truth_source = str(options.truth_csv)
        t_s, t_poses, _ = read_pose_csv(options.truth_csv)
        origin = int(scans[0]) if options.csv_time == "relative" else 0
        t_stamps = origin + np.round(t_s * 1e9).astype(np.int64)
        truth, _ = pose_at(t_stamps, t_poses, scans, tol)
    laser = geometry["frame"] or frame(lay.laser_frame)
    mount = laser_mount(bag, lay.tf_static, found.static, frame(lay.base_frame), laser)
    ranges = np.stack(found.scans.ranges[:count])
    ranges = clean_bag_ranges(ranges, geometry["range_max"], spec.no_return_value)
    missing = int((~np.isfinite(truth).all(axis=1)).sum())
    meta = {
        "source": "bag",
        "bag": str(bag),
        "scan_topic": lay.scan,
        "scan_geometry": geometry,
        "time_origin_ns": int(scans[0]),
        "odometry_source": odom_topic,
        "truth_source": truth_source,
        "has_truth": truth_source is not None and missing < count,
        "truth_missing_steps": missing,
        "pairing_tolerance_s": options.pairing_tolerance_s,
        "laser_frame": laser,
        "laser_mount": {"x": mount[0], "y": mount[1], "yaw": mount[2]},
        "scans": count,
    }
    traj = Trajectory(times=(scans - scans[0]) / 1e9, truth=truth, odometry=odometry)
    return traj, ranges, meta
