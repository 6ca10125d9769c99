"""Bags that scanloc did not write, made with rosbags' own writer: odometry from tf only, a
laser mounted off the robot's centre through a chain of static transforms, stamps off the
odometry's, REP 117 ranges, truth from a CSV; and each kind of bad bag, with its message."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore

from scanloc.bags.errors import BagError
from scanloc.bags.layout import BagLayout
from scanloc.bags.read import BagRunOptions, read_bag_run
from scanloc.sensor.laser import LaserSpec
from scanloc.world.map_server import save_map
from scanloc.world.occupancy_grid import FREE, OCCUPIED, OccupancyGrid

REPO = Path(__file__).resolve().parents[1]
STORE = get_typestore(Stores.ROS2_HUMBLE)
T = STORE.types
BEAMS = 90
SPEC = LaserSpec(
    num_beams=BEAMS,
    angle_min=-math.pi / 2,
    angle_max=-math.pi / 2 + (BEAMS - 1) * math.pi / 90,
    range_min=0.05,
    range_max=10.0,
    rate_hz=40.0,
    no_return_value=12.5,
)
START_NS = 1_700_000_000 * 10**9
SCAN_NS = START_NS + 3_000_000 + 25_000_000 * np.arange(80)  # 40 Hz, 3 ms after the tf
TF_NS = START_NS + 20_000_000 * np.arange(106)  # 50 Hz, 2.1 s
MOUNT = (0.2, -0.1, math.pi / 2)  # base_link → laser_mount → base_scan, composed


def robot_pose(ns: np.ndarray) -> np.ndarray:
    """A drive whose heading crosses ±π (at t = 0.25 s): x, y linear in time."""
    t = (np.asarray(ns) - START_NS) / 1e9
    yaw = np.angle(np.exp(1j * (math.pi - 0.2 + 0.8 * t)))
    return np.stack([1.0 + 0.5 * t, 2.0 - 0.3 * t, yaw], axis=-1)


def header(ns: int, frame: str) -> Any:
    stamp = T["builtin_interfaces/msg/Time"](sec=int(ns) // 10**9, nanosec=int(ns) % 10**9)
    return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def transform(ns: int, parent: str, child: str, x: float, y: float, yaw: float) -> Any:
    return T["geometry_msgs/msg/TransformStamped"](
        header=header(ns, parent),
        child_frame_id=child,
        transform=T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.3),
            rotation=T["geometry_msgs/msg/Quaternion"](
                x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)
            ),
        ),
    )


def scan(ns: int, ranges: np.ndarray, frame: str = "base_scan") -> Any:
    return T["sensor_msgs/msg/LaserScan"](
        header=header(ns, frame),
        angle_min=SPEC.angle_min,
        angle_max=SPEC.angle_max,
        angle_increment=SPEC.angle_increment,
        time_increment=0.0,
        scan_time=0.025,
        range_min=SPEC.range_min,
        range_max=SPEC.range_max,
        ranges=np.asarray(ranges, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32),
    )


def scan_ranges(k: int) -> np.ndarray:
    r = np.linspace(0.5, 9.5, BEAMS, dtype=np.float32) + np.float32(0.001 * k)
    r[:5] = [np.inf, np.nan, -np.inf, 0.0, 10.5]  # no return, invalid, too close, below min, far
    return r


TF = "tf2_msgs/msg/TFMessage"
SCAN = "sensor_msgs/msg/LaserScan"


def messages(
    scans: bool = True,
    odom_child: str = "base_link",
    tf_until_s: float = 9.0,
    tf_gap_s: tuple[float, float] = (0.0, 0.0),
    static: bool = True,
    scan_stamps: np.ndarray = SCAN_NS,
    beams: int = BEAMS,
) -> list[tuple[str, str, int, Any]]:
    """(topic, type, bag time, message) of a recording; the arguments spoil one thing each."""
    out: list[tuple[str, str, int, Any]] = []
    if static:
        chain = [
            transform(START_NS, "base_link", "laser_mount", MOUNT[0], 0.0, 0.0),
            transform(START_NS, "laser_mount", "base_scan", 0.0, MOUNT[1], MOUNT[2]),
        ]
        out.append(("/tf_static", TF, START_NS, T[TF](transforms=chain)))
    for ns, (x, y, yaw) in zip(TF_NS, robot_pose(TF_NS), strict=True):
        t = (ns - START_NS) / 1e9
        if t <= tf_until_s and not tf_gap_s[0] < t < tf_gap_s[1]:
            odom = transform(int(ns), "odom", odom_child, float(x), float(y), float(yaw))
            out.append(("/tf", TF, int(ns), T[TF](transforms=[odom])))
    if scans:
        for k, ns in enumerate(scan_stamps):
            ranges = np.resize(scan_ranges(k), beams)
            out.append(("/scan", SCAN, int(SCAN_NS[k]), scan(int(ns), ranges)))
    return sorted(out, key=lambda m: m[2])


def write_bag(path: Path, recording: list[tuple[str, str, int, Any]]) -> Path:
    with Writer(path, version=8) as writer:
        conns = {}
        for topic, msgtype, ns, msg in recording:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=STORE)
            writer.write(conns[topic], ns, bytes(STORE.serialize_cdr(msg, msgtype)))
    return path


def test_tf_only_odometry_and_a_mounted_laser(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "robot", messages())
    truth_csv = tmp_path / "truth.csv"
    truth = robot_pose(SCAN_NS)
    times = (SCAN_NS - SCAN_NS[0]) / 1e9
    rows = [",".join(repr(float(v)) for v in row) for row in np.column_stack([times, truth])]
    truth_csv.write_text("t,x,y,theta\n" + "\n".join(rows) + "\n")
    options = BagRunOptions(truth_csv=str(truth_csv))
    traj, ranges, meta = read_bag_run(bag, SPEC, options)
    assert meta["odometry_source"] == "/tf (odom→base_link)"
    assert meta["laser_frame"] == "base_scan"
    mount = meta["laser_mount"]
    np.testing.assert_allclose([mount["x"], mount["y"], mount["yaw"]], MOUNT, atol=1e-12)
    np.testing.assert_allclose(traj.times, (SCAN_NS - SCAN_NS[0]) / 1e9, atol=1e-12)
    # odometry interpolated between tf samples: exact for this drive, across ±π too
    error = traj.odometry - truth
    error[:, 2] = np.angle(np.exp(1j * error[:, 2]))
    np.testing.assert_allclose(error, 0.0, atol=1e-9)
    np.testing.assert_allclose(traj.truth, truth, atol=1e-9)
    assert meta["has_truth"] and meta["truth_missing_steps"] == 0
    want = np.stack([scan_ranges(k) for k in range(len(SCAN_NS))])
    want[:, :5] = SPEC.no_return_value  # +inf, NaN, -inf, 0, beyond range_max
    assert ranges.tobytes() == want.astype(np.float32).tobytes()
    assert meta["no_return_counts"] == {
        "inf": 80, "nan": 80, "neg_inf": 80, "zero": 80, "below_range_min": 0,
        "above_range_max": 80,
    }  # fmt: skip
    assert meta["laser_mount_source"] == "/tf_static"


def test_without_truth_the_run_has_nan_truth(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "robot", messages())
    traj, _, meta = read_bag_run(bag, SPEC, BagRunOptions())
    assert np.isnan(traj.truth).all() and not meta["has_truth"] and meta["truth_source"] is None


BAD_BAGS = {
    "no_scans": (dict(scans=False), "/scan: missing: expected sensor_msgs/msg/LaserScan"),
    "odometry_gap": (
        dict(tf_gap_s=(0.5, 1.0)),
        r"/tf \(odom→base_link\): scan 20 .* falls in a 0.500 s gap of the odometry .* above "
        r"the bound 0.060 s \(3 x the median period; the stream's median period is 0.0200 s\)"
        r".* set pairing_tolerance_s \(conf/bag.yaml\) to 0.500 or more",
    ),
    "no_odom_transform": (
        dict(odom_child="base_footprint"),
        "/tf: no transform odom→base_link in tf",
    ),
    "no_mounting": (dict(static=False), "/tf_static: no transform base_link→base_scan"),
    "clock_back": (
        dict(scan_stamps=np.concatenate([SCAN_NS[:10], SCAN_NS[9:10] - 5, SCAN_NS[11:]])),
        "/scan: clock goes back at message 10",
    ),
    "beam_count": (dict(beams=BEAMS + 1), "/scan: message 0 .* has 91 ranges, but angle_min"),
}


@pytest.mark.parametrize("case", sorted(BAD_BAGS))
def test_bad_bags_get_clear_errors(tmp_path: Path, case: str) -> None:
    spoil, message = BAD_BAGS[case]
    bag = write_bag(tmp_path / case, messages(**spoil))
    with pytest.raises(BagError, match=message) as caught:
        read_bag_run(bag, SPEC, BagRunOptions(layout=BagLayout(odom_source="auto")))
    assert str(caught.value).startswith(f"{bag}: topic /")


def test_a_bag_of_another_laser_is_refused(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "robot", messages())
    with pytest.raises(BagError, match=r"scans have 90 beams .* expected the sensor config's 667"):
        read_bag_run(bag, LaserSpec(), BagRunOptions())


def test_the_bag_stage_writes_nothing_for_a_bad_bag(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "robot", messages(static=False))
    out = tmp_path / "robot_real"
    # A map given, so that the stage reads the bag (without a map or truth it stops before).
    grid = np.full((40, 40), FREE, dtype=np.int8)
    grid[[0, -1], :] = grid[:, [0, -1]] = OCCUPIED
    save_map(OccupancyGrid(grid, 0.1, (-2.0, -2.0, 0.0)), tmp_path / "office" / "map.yaml")
    stage = [sys.executable, "-m", "scanloc.stages.bag", f"bag={bag}", "name=robot"]
    stage += [f"map_yaml={tmp_path / 'office' / 'map.yaml'}"]
    stage += [f"out_dir={out}", f"map_dir={tmp_path / 'map'}", f"timing_dir={tmp_path / 't'}"]
    stage += [f"hydra.run.dir={tmp_path / 'hydra'}", "sensor.num_beams=90"]
    stage += [f"sensor.angle_min={SPEC.angle_min!r}", f"sensor.angle_max={SPEC.angle_max!r}"]
    done = subprocess.run(stage, cwd=REPO, env=os.environ.copy(), capture_output=True, text=True)
    assert done.returncode != 0
    assert f"{bag}: topic /tf_static: no transform base_link→base_scan" in done.stderr
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
