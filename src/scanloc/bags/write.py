"""A scanloc run (data/trajectories/<name>/) exported as a ROS 2 bag (sqlite3 or mcap) or a
ROS 1 bag, so that ROS tools (rviz, nav2_amcl, slam_toolbox, ...) can replay it.

Topics (names and frames: BagLayout): /scan (sensor_msgs/LaserScan in the laser frame), /odom
(nav_msgs/Odometry odom → base_link), /tf (the same transform at every scan), /tf_static
(base_link → laser: the run's meta `laser_mount`, identity when absent), /map
(nav_msgs/OccupancyGrid, latched: ROS 1 `latching=1`, ROS 2 transient-local durability in the
topic's offered_qos_profiles, so that `ros2 bag play` republishes it to late subscribers; so is
/tf_static) and /ground_truth (nav_msgs/Odometry map → base_link, left out where the run has no
truth). Step k is stamped EPOCH_NS + times[k]; messages are written in time order, the latched
ones first. The bag is written in a temporary folder and renamed into place when complete.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2

from scanloc.bags.layout import BagLayout
from scanloc.bags.ros_messages import (
    EPOCH_NS,
    GRID,
    LATCHED_QOS,
    ODOMETRY,
    SCAN,
    TF,
    MessageFactory,
    stamps_ns,
    yaw_quaternions,
)
from scanloc.io import read_json
from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.trajectory.format import load_trajectory
from scanloc.world.map_server import load_map
from scanloc.world.occupancy_grid import OccupancyGrid

FORMATS = ("ros2", "ros1")
STORAGES = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}
ROS2_BAG_VERSION = 8  # rosbag2 metadata version 8 (Jazzy)


def laser_mount(meta: dict[str, Any], source: str) -> tuple[float, float, float]:
    """The run's base_link → laser pose (x, y, yaw) from meta `laser_mount`; identity if absent."""
    mount = meta.get("laser_mount")
    if mount is None:
        return 0.0, 0.0, 0.0
    try:
        return float(mount["x"]), float(mount["y"]), float(mount["yaw"])
    except (KeyError, TypeError, ValueError):
        raise ValueError(
            f"{source}: field 'laser_mount': expected {{x, y, yaw}} numbers, got {mount!r}"
        ) from None


def run_laser_spec(meta: dict[str, Any], fallback: LaserSpec | None, source: str) -> LaserSpec:
    """The run's laser: its meta `sensor` (the config it was made with), else `fallback`."""
    if "sensor" in meta:
        return laser_spec_from_config(meta["sensor"])
    if fallback is None:
        raise ValueError(f"{source}: field 'sensor' missing: give the run's sensor config")
    return fallback


@contextmanager
def staged(out: Path) -> Iterator[Path]:
    """A path to write `out` at, in a temporary folder beside it; moved onto `out` only when
    the block succeeds (a failed export leaves nothing behind)."""
    if out.exists():
        raise FileExistsError(f"{out}: exists already; remove it or choose another out")
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        yield staging / out.name
        os.replace(staging / out.name, out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


class _BagSink:
    """One writer interface over rosbags' ROS 1 and ROS 2 writers."""

    def __init__(self, path: Path, fmt: str, storage: str) -> None:
        self.factory = MessageFactory(ros1=fmt == "ros1")
        if fmt == "ros1":
            self.writer: Any = Writer1(path)
        else:
            self.writer = Writer2(path, version=ROS2_BAG_VERSION, storage_plugin=STORAGES[storage])
        self.writer.open()
        self.connections: dict[str, Any] = {}

    def topic(self, name: str, msgtype: str, latched: bool = False) -> None:
        store = self.factory.store
        if self.factory.ros1:
            latching = 1 if latched else None
            conn = self.writer.add_connection(name, msgtype, typestore=store, latching=latching)
        else:
            qos = [LATCHED_QOS] if latched else []
            conn = self.writer.add_connection(
                name, msgtype, typestore=store, offered_qos_profiles=qos
            )
        self.connections[name] = conn

    def write(self, topic: str, ns: int, msg: Any) -> None:
        self.writer.write(self.connections[topic], int(ns), self.factory.serialize(msg))

    def close(self) -> None:
        self.writer.close()


def write_bag(
    path: Path,
    fmt: str,
    storage: str,
    layout: BagLayout,
    arrays: dict[str, np.ndarray],
    spec: LaserSpec,
    grid: OccupancyGrid | None,
    mount: tuple[float, float, float] = (0.0, 0.0, 0.0),
    epoch_ns: int = EPOCH_NS,
) -> None:
    """Write a bag at `path` (which must not exist) from run arrays: times (T,), ranges
    (T, B) float32, odometry (T, 3), truth (T, 3) (steps with non-finite truth get none)."""
    if fmt not in FORMATS:
        raise ValueError(f"format: expected one of {FORMATS}, got {fmt!r}")
    if storage not in STORAGES:
        raise ValueError(f"storage: expected one of {sorted(STORAGES)}, got {storage!r}")
    ns = stamps_ns(arrays["times"], epoch_ns)
    odom, truth = arrays["odometry"], arrays["truth"]
    odom_q = np.stack([odom[:, 0], odom[:, 1], *yaw_quaternions(odom[:, 2])], axis=1)
    truth_q = np.stack([truth[:, 0], truth[:, 1], *yaw_quaternions(truth[:, 2])], axis=1)
    has_truth = np.isfinite(truth).all(axis=1)
    mount_q = (mount[0], mount[1], *(float(v) for v in yaw_quaternions(np.array(mount[2]))))
    sink = _BagSink(path, fmt, storage)
    lay, make = layout, sink.factory
    sink.topic(lay.tf_static, TF, latched=True)
    if grid is not None:
        sink.topic(lay.map, GRID, latched=True)
    for name, msgtype in ((lay.tf, TF), (lay.odom, ODOMETRY), (lay.scan, SCAN)):
        sink.topic(name, msgtype)
    if has_truth.any():
        sink.topic(lay.ground_truth, ODOMETRY)
    sink.write(lay.tf_static, ns[0], make.tf(ns[0], lay.base_frame, lay.laser_frame, mount_q))
    if grid is not None:
        sink.write(lay.map, ns[0], make.occupancy_grid(ns[0], lay.map_frame, grid))
    ranges = arrays["ranges"]
    for k, stamp in enumerate(ns):
        pose = tuple(odom_q[k])
        sink.write(lay.tf, stamp, make.tf(stamp, lay.odom_frame, lay.base_frame, pose))
        sink.write(lay.odom, stamp, make.odometry(stamp, lay.odom_frame, lay.base_frame, pose))
        if has_truth[k]:
            msg = make.odometry(stamp, lay.map_frame, lay.base_frame, tuple(truth_q[k]))
            sink.write(lay.ground_truth, stamp, msg)
        sink.write(lay.scan, stamp, make.laser_scan(stamp, lay.laser_frame, spec, ranges[k]))
    sink.close()


def export_run(
    run_dir: str | Path,
    map_yaml: str | Path | None,
    out: str | Path,
    fmt: str = "ros2",
    storage: str = "sqlite3",
    layout: BagLayout | None = None,
    sensor: LaserSpec | None = None,
) -> Path:
    """Export the run in `run_dir` (with the map at `map_yaml`, None: no /map) as a bag at
    `out` (ROS 2: a folder; ROS 1: a file, `.bag` appended when missing). Returns its path."""
    run = Path(run_dir)
    traj, ranges = load_trajectory(run)
    meta_path = run / "meta.json"
    meta = read_json(meta_path) if meta_path.is_file() else {}
    spec = run_laser_spec(meta, sensor, str(meta_path))
    if ranges.shape[1] != spec.num_beams:
        raise ValueError(
            f"{run / 'ranges.npy'}: {ranges.shape[1]} beams per scan, but the sensor has "
            f"{spec.num_beams}"
        )
    out = Path(out)
    if fmt == "ros1" and out.suffix != ".bag":
        out = out.with_name(out.name + ".bag")
    grid = None if map_yaml is None else load_map(map_yaml)
    arrays = {
        "times": traj.times,
        "ranges": ranges,
        "odometry": traj.odometry,
        "truth": traj.truth,
    }
    mount = laser_mount(meta, str(meta_path))
    epoch_ns = int(meta.get("time_origin_ns", EPOCH_NS))
    with staged(out) as path:
        write_bag(path, fmt, storage, layout or BagLayout(), arrays, spec, grid, mount, epoch_ns)
    return out
