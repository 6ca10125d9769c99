"""Benchmark: reading a robot's ROS 2 bag into a scanloc run (scanloc.bags.read.read_bag_run).

A synthetic recording of 10 minutes at 40 Hz (24,000 LaserScans of 1081 beams, a Hokuyo
UTM-30LX's 270° at 0.25°; /odom, /tf at every scan; /tf_static) is written as a ROS 2 sqlite3
bag by scanloc.bags.write, then read back twice:
- reference: rosbags' AnyReader over every message, each deserialised in a Python loop into
  lists (stamps, ranges, poses), as a plain script would do, without pairing or checks;
- scanloc: read_bag_run, the whole bag stage's reading: every check, odometry paired with the
  scans, ranges cleaned; the same bag, the same process.
Goal: reading the 24k scans in <= 30 s on 2 cores. Figures are one run each (a cold first read
is not separated out: the bag is in the page cache after writing).
Run: python benchmarks/bag_read.py [--quick]   (--quick: 2,400 scans)
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader

from scanloc.bags.layout import BagLayout
from scanloc.bags.read import BagRunOptions, read_bag_run
from scanloc.bags.ros_messages import planar_pose, stamp_of
from scanloc.bags.write import write_bag
from scanloc.sensor.laser import LaserSpec

RATE_HZ = 40.0
GOAL_S = 30.0
SPEC = LaserSpec(
    num_beams=1081,
    angle_min=-math.radians(135.0),
    angle_max=math.radians(135.0),
    range_min=0.1,
    range_max=30.0,
    rate_hz=RATE_HZ,
    no_return_value=37.5,
)


def synthetic_run(scans: int) -> dict[str, np.ndarray]:
    """A drive around a circle, scans of a round room with some no-returns."""
    rng = np.random.default_rng(0)
    times = np.arange(scans) / RATE_HZ
    angle = 0.05 * times
    odometry = np.stack([5 * np.cos(angle), 5 * np.sin(angle), angle + math.pi / 2], axis=1)
    odometry[:, 2] = np.angle(np.exp(1j * odometry[:, 2]))
    ranges = rng.uniform(0.5, 29.0, (scans, SPEC.num_beams)).astype(np.float32)
    ranges[rng.random(ranges.shape) < 0.05] = SPEC.no_return_value
    return {"times": times, "ranges": ranges, "odometry": odometry, "truth": odometry.copy()}


def reference_read(bag: Path) -> int:
    """rosbags' AnyReader, one deserialisation per message, into Python lists."""
    stamps, ranges, poses = [], [], []
    with AnyReader([bag]) as reader:
        wanted = [c for c in reader.connections if c.topic in ("/scan", "/odom")]
        for conn, _, raw in reader.messages(connections=wanted):
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == "/scan":
                stamps.append(stamp_of(msg.header))
                ranges.append(msg.ranges)
            else:
                poses.append(planar_pose(msg.pose.pose))
    return len(np.stack(ranges))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="2,400 scans instead of 24,000")
    scans = 2400 if parser.parse_args().quick else 24000
    root = Path(tempfile.mkdtemp(prefix="bag_read_"))
    try:
        arrays = synthetic_run(scans)
        bag = root / "robot"
        start = time.perf_counter()
        write_bag(bag, "ros2", "sqlite3", BagLayout(), arrays, SPEC, None)
        write_s = time.perf_counter() - start
        start = time.perf_counter()
        count = reference_read(bag)
        reference_s = time.perf_counter() - start
        start = time.perf_counter()
        traj, ranges, _ = read_bag_run(bag, SPEC, BagRunOptions())
        read_s = time.perf_counter() - start
        assert count == len(traj.times) == scans
        assert ranges.tobytes() == arrays["ranges"].tobytes()
        size_mb = sum(p.stat().st_size for p in bag.iterdir()) / 1e6
    finally:
        shutil.rmtree(root, ignore_errors=True)
    figures = {
        "benchmark": "bag_read",
        "scans": scans,
        "beams": SPEC.num_beams,
        "bag_mb": round(size_mb, 1),
        "write_s": round(write_s, 2),
        "reference_anyreader_s": round(reference_s, 2),
        "scanloc_read_s": round(read_s, 2),
        "scanloc_scans_per_s": round(scans / read_s),
        "goal_s_for_24k": GOAL_S,
        "scanloc_24k_estimate_s": round(read_s * 24000 / scans, 2),
        "within_goal": bool(read_s * 24000 / scans <= GOAL_S),
    }
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
