"""A ROS 1 or ROS 2 bag (sqlite3 or mcap) made into a scanloc run (trajectory/format.py).

One step per LaserScan, at its header stamp; step times count from the run's first scan (its
stamp is meta `time_origin_ns`). Odometry comes from the odometry topic (nav_msgs/Odometry, or
any pose topic) or from tf odom → base_link, truth (optional) from a pose topic
(geometry_msgs/PoseStamped, PoseWithCovarianceStamped, nav_msgs/Odometry) or a CSV
`t,x,y,theta`. Both are paired with the scans as tf does it (bags/pairing.py): interpolated
between the two samples around each scan when these are at most a bound apart, a bound derived
from the stream's own rate (3 x its median period; `pairing_tolerance_s` overrides it).
Scans before the first or after the last odometry sample are dropped (robots start their
laser before their odometry; meta `scans_dropped_before_odometry` / `_after_odometry`); a scan
in an odometry gap beyond the bound is an error. A scan without truth so paired gets NaN truth
(meta `truth_missing_steps`), and a bag without truth gives an all-NaN truth (meta
`has_truth: false`: only consistency and speed can be scored). The laser's mounting (base_link
→ the scans' frame, from /tf_static or a constant transform on /tf: bags/mount.py) goes to
meta `laser_mount`; the run's poses stay those of base_link.

Ranges: every reading that is no measurement (REP 117's +inf and −inf, NaN, 0 as many drivers
write it, anything below the scan's range_min or above its range_max) becomes the sensor's
"no return" value (the LaserSpec's no_return_value), as scanloc's own scans encode it, each
kind counted in meta `no_return_counts`; readings in [range_min, range_max] are kept bit for
bit.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from scanloc.bags.describe import sensor_from_scans
from scanloc.bags.errors import BagError
from scanloc.bags.layout import BagLayout
from scanloc.bags.mount import laser_mount
from scanloc.bags.pairing import (
    AFTER,
    BEFORE,
    GAP,
    GapBound,
    Pairing,
    first_decrease,
    gap_bound,
    median_period_ns,
    pair_poses,
)
from scanloc.bags.pose_csv import read_pose_csv
from scanloc.bags.topics import BagTopics, close_bag, frame, open_bag, read_topics
from scanloc.sensor.laser import LaserSpec
from scanloc.trajectory.format import Trajectory

__all__ = ["BagRunOptions", "check_scan_geometry", "clean_bag_ranges", "laser_mount"]

GEOMETRY_TOLERANCE_RAD = 1e-5  # float32 angles of a LaserScan against the sensor config's


@dataclass(frozen=True)
class BagRunOptions:
    """How to read a bag: topics and frames, where truth comes from, the pairing bound.

    `truth_csv` times are seconds after the bag's first scan (`csv_time: relative`) or on the
    bag's clock (`absolute`, e.g. 1600000000.25). `pairing_tolerance_s`: the largest gap
    between two samples (odometry or truth) that a scan may be interpolated across; None: each
    stream's own (bags/pairing.py).
    """

    layout: BagLayout = field(default_factory=BagLayout)
    truth_topic: str | None = None
    truth_csv: str | None = None
    csv_time: str = "relative"
    pairing_tolerance_s: float | None = None
    max_scans: int | None = None

    def __post_init__(self) -> None:
        if self.truth_topic and self.truth_csv:
            raise ValueError("bag: give truth_topic or truth_csv, not both")
        if self.csv_time not in ("relative", "absolute"):
            raise ValueError(
                f"bag field 'csv_time': expected relative or absolute, got {self.csv_time!r}"
            )
        tol = self.pairing_tolerance_s
        if tol is not None and not tol > 0:
            raise ValueError(
                f"bag field 'pairing_tolerance_s': expected null or > 0 (s), got {tol}"
            )


def clean_bag_ranges(
    raw: np.ndarray, range_min: float, range_max: float, no_return_value: float
) -> tuple[np.ndarray, dict[str, int]]:
    """(float32 ranges with every reading that is no measurement set to `no_return_value`,
    how many of each kind there were: module doc)."""
    r = np.asarray(raw, dtype=np.float32)
    lo, hi = np.float32(range_min), np.float32(range_max)
    finite = np.isfinite(r)
    with np.errstate(invalid="ignore"):
        kinds = {
            "inf": np.isposinf(r),
            "nan": np.isnan(r),
            "neg_inf": np.isneginf(r),
            "zero": r == 0,
            "below_range_min": finite & (r != 0) & (r < lo),
            "above_range_max": finite & (r > hi),
        }
    missing = np.logical_or.reduce(list(kinds.values()))
    cleaned = np.where(missing, np.float32(no_return_value), r).astype(np.float32)
    return cleaned, {kind: int(mask.sum()) for kind, mask in kinds.items()}


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
            "(conf/sensor/<robot>.yaml, or sensor=auto to take it from the scans)",
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
        close_bag(reader)


def _gap_error(
    bag: str | Path, topic: str, scans: np.ndarray, stamps: np.ndarray, k: int, bound: GapBound
) -> BagError:
    before = int(stamps[stamps < scans[k]].max())
    after = int(stamps[stamps > scans[k]].min())
    gap = (after - before) / 1e9
    period = bound.median_period_ns
    rate = "" if period is None else f"; the stream's median period is {period / 1e9:.4f} s"
    return BagError(
        bag,
        topic,
        f"scan {k} (stamp {scans[k]} ns) falls in a {gap:.3f} s gap of the odometry (samples "
        f"{(scans[k] - before) / 1e9:.3f} s before and {(after - scans[k]) / 1e9:.3f} s after "
        f"it), above the bound {bound.bound_ns / 1e9:.3f} s ({bound.rule}{rate}): expected "
        f"odometry around every scan; to interpolate across the gap, set pairing_tolerance_s "
        f"(conf/bag.yaml) to {gap:.3f} or more",
    )


def _odometry(
    bag: str | Path, found: BagTopics, source: str, options: BagRunOptions
) -> tuple[str, np.ndarray, np.ndarray]:
    """(the odometry's name for messages, its stamps, its poses)."""
    lay = options.layout
    if source == "topic":
        stamps, poses, _ = found.poses[lay.odom].arrays()
        _checked_stream(bag, lay.odom, stamps, "poses")
        return lay.odom, stamps, poses
    name = f"{lay.tf} ({lay.odom_frame}→{lay.base_frame})"
    stamps, poses, _ = found.transforms[(frame(lay.odom_frame), frame(lay.base_frame))].arrays()
    if len(stamps) == 0:
        raise BagError(
            bag,
            lay.tf,
            f"no transform {lay.odom_frame}→{lay.base_frame} in tf: expected odometry as "
            f"that transform (or a {lay.odom} topic)",
        )
    _checked_stream(bag, name, stamps, "poses")
    return name, stamps, poses


def _pairing_info(pairing: Pairing, bound: GapBound, keep: np.ndarray) -> dict[str, Any]:
    kept = pairing.gaps_ns[keep]
    return bound.describe() | {
        "largest_gap_s": float(kept.max()) / 1e9 if kept.size else 0.0,
        "exact_steps": int((kept == 0).sum()),
        "interpolated_steps": int((kept > 0).sum()),
    }


def _truth(
    bag: str | Path, found: BagTopics, options: BagRunOptions, all_scans: np.ndarray
) -> tuple[np.ndarray, dict[str, Any] | None]:
    """(truth at every scan of the bag, NaN where unpaired; how it was paired, or None)."""
    if options.truth_topic:
        name = options.truth_topic
        stamps, poses, _ = found.poses[name].arrays()
    elif options.truth_csv:
        name = str(options.truth_csv)
        t_s, poses, _ = read_pose_csv(options.truth_csv)
        origin = int(all_scans[0]) if options.csv_time == "relative" else 0
        stamps = origin + np.round(t_s * 1e9).astype(np.int64)
    else:
        return np.full((len(all_scans), 3), np.nan), None
    _checked_stream(bag, name, stamps, "poses")
    override = options.pairing_tolerance_s
    if override is None and np.isin(stamps, all_scans).all():
        # Stamped at the scans (a run scanloc exported): a scan without a sample of its own
        # has no truth, rather than one made up from its neighbours'.
        rule = "exact stamps only: the stream is stamped at the scans"
        bound = GapBound(0, median_period_ns(stamps), rule)
    else:
        bound = gap_bound(stamps, override)
    pairing = pair_poses(stamps, poses, all_scans, bound.bound_ns)
    info = {"source": name} | bound.describe()
    info |= {"missing_before": pairing.count(BEFORE), "missing_after": pairing.count(AFTER)}
    info["missing_in_gaps"] = pairing.count(GAP)
    return pairing.poses, info


def _auto_spec(sensor: dict[str, Any]) -> LaserSpec:
    return LaserSpec(**{f.name: sensor[f.name] for f in fields(LaserSpec)})


def read_bag_run(
    bag: str | Path, spec: LaserSpec | None, options: BagRunOptions = BagRunOptions()
) -> tuple[Trajectory, np.ndarray, dict[str, Any]]:
    """(Trajectory, ranges float32 (T, B), meta) of a bag (module doc); BagError on a bad bag.

    `spec` None: the laser is the scans' own (describe.py; meta `sensor`, `sensor_source`)."""
    lay = options.layout
    source = _odometry_source(bag, lay)
    pose_topics = [lay.odom] if source == "topic" else []
    if options.truth_topic:
        pose_topics.append(options.truth_topic)
    found: BagTopics = read_topics(
        bag,
        lay.scan,
        pose_topics,
        tf_topic=lay.tf,  # odometry, or a laser mount repeated on /tf
        tf_pairs=[(lay.odom_frame, lay.base_frame)] if source == "tf" else [],
        tf_static_topic=lay.tf_static,
        tf_required=source == "tf",
    )
    all_scans = np.asarray(found.scans.stamps, dtype=np.int64)
    if len(all_scans) == 0:
        raise BagError(bag, lay.scan, "no messages: expected LaserScans")
    back = first_decrease(all_scans, strict=True)
    if back >= 0:
        raise BagError(
            bag,
            lay.scan,
            f"clock goes back at message {back}: stamp {all_scans[back]} ns after "
            f"{all_scans[back - 1]} ns; expected strictly increasing header stamps",
        )
    geometry = found.scans.geometry
    sensor = None
    if spec is None:
        sensor = sensor_from_scans(bag, lay.scan, geometry, found.scans.stamps)
        spec = _auto_spec(sensor)
    check_scan_geometry(bag, lay.scan, geometry, spec)
    odom_topic, stamps, poses = _odometry(bag, found, source, options)
    bound = gap_bound(stamps, options.pairing_tolerance_s)
    pairing = pair_poses(stamps, poses, all_scans, bound.bound_ns)
    status = pairing.status
    keep = np.flatnonzero((status != BEFORE) & (status != AFTER))  # only the ends are dropped
    if options.max_scans is not None:
        keep = keep[: int(options.max_scans)]
    gaps = keep[status[keep] == GAP]
    if gaps.size:
        raise _gap_error(bag, odom_topic, all_scans, stamps, int(gaps[0]), bound)
    early, late = pairing.count(BEFORE), pairing.count(AFTER)
    if keep.size == 0:
        raise BagError(
            bag,
            odom_topic,
            f"no scan lies within the odometry (stamps {stamps[0]} to {stamps[-1]} ns; scans "
            f"{all_scans[0]} to {all_scans[-1]} ns): expected odometry while the laser runs",
        )
    if early or late:
        print(
            f"scanloc: {bag}: dropped {early} scan(s) before the first odometry sample and "
            f"{late} after the last ({odom_topic}; meta.json scans_dropped_*_odometry)",
            file=sys.stderr,
        )
    scans = all_scans[keep]
    truth, truth_info = _truth(bag, found, options, all_scans)
    truth = truth[keep]
    laser = geometry["frame"] or frame(lay.laser_frame)
    mount, mount_source = laser_mount(
        bag, found.static, found.dynamic, frame(lay.base_frame), laser, (lay.tf_static, lay.tf)
    )
    ranges = np.stack(found.scans.ranges[keep[0] : keep[-1] + 1])
    ranges, no_returns = clean_bag_ranges(
        ranges, geometry["range_min"], geometry["range_max"], spec.no_return_value
    )
    missing = int((~np.isfinite(truth).all(axis=1)).sum())
    count = len(scans)
    meta = {
        "source": "bag",
        "bag": str(bag),
        "scan_topic": lay.scan,
        "scan_geometry": geometry,
        "time_origin_ns": int(scans[0]),
        "bag_scans": len(all_scans),
        "scans_dropped_before_odometry": early,
        "scans_dropped_after_odometry": late,
        "odometry_source": odom_topic,
        "odometry_pairing": _pairing_info(pairing, bound, keep),
        "truth_source": None if truth_info is None else truth_info["source"],
        "truth_pairing": truth_info,
        "has_truth": truth_info is not None and missing < count,
        "truth_missing_steps": missing,
        "pairing_tolerance_s": options.pairing_tolerance_s,
        "laser_frame": laser,
        "laser_mount": {"x": mount[0], "y": mount[1], "yaw": mount[2]},
        "laser_mount_source": mount_source,
        "no_return_counts": no_returns,
        "scans": count,
    }
    if sensor is not None:
        meta["sensor"] = sensor
        meta["sensor_source"] = f"auto: the bag's {lay.scan} LaserScans (scanloc.bags.describe)"
    traj = Trajectory(times=(scans - scans[0]) / 1e9, truth=truth, odometry=pairing.poses[keep])
    return traj, ranges, meta
