"""Other people's bags at the defaults (issue #41): odometry that starts after the laser or runs
at 7.5 Hz, a laser mount repeated on /tf (ROS 1's static_transform_publisher) or moving, every
driver's way of saying "no return", a 360° laser with float32 angles read with `sensor=auto`,
the sensor file `scanloc.bags.describe` writes, and bags rosbags itself cannot read."""

from __future__ import annotations

import json
import math
import os
import struct
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Writer as Writer2

from scanloc.bags import describe
from scanloc.bags.errors import BagError
from scanloc.bags.read import BagRunOptions, read_bag_run
from scanloc.bags.ros_messages import MessageFactory, yaw_quaternions
from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.world.map_server import save_map
from scanloc.world.occupancy_grid import FREE, OCCUPIED, OccupancyGrid

REPO = Path(__file__).resolve().parents[1]
START_NS = 1_700_000_000 * 10**9
BEAMS = 90
SPEC = LaserSpec(
    num_beams=BEAMS,
    angle_min=-math.pi / 2,
    angle_max=-math.pi / 2 + (BEAMS - 1) * math.pi / 90,
    range_min=0.05,
    range_max=10.0,
    rate_hz=10.0,
    no_return_value=12.5,
)
MOUNT = (0.15, -0.05, 0.1)
Message = tuple[str, int, Any]  # topic, stamp ns, message


def ns_at(seconds: np.ndarray) -> np.ndarray:
    return START_NS + np.round(np.asarray(seconds) * 1e9).astype(np.int64)


def robot_pose(ns: np.ndarray) -> np.ndarray:
    """A drive linear in x, y and θ, so that interpolating it is exact."""
    t = (np.asarray(ns, dtype=np.int64) - START_NS) / 1e9
    return np.stack([1.0 + 0.5 * t, 2.0 - 0.3 * t, np.angle(np.exp(1j * (0.4 + 0.8 * t)))], -1)


def assert_poses(got: np.ndarray, want: np.ndarray) -> None:
    """Equal within 1e-9 (θ on the circle: the drive's heading crosses ±π)."""
    error = got - want
    error[:, 2] = np.angle(np.exp(1j * error[:, 2]))
    np.testing.assert_allclose(error, 0.0, rtol=0, atol=1e-9)


def planar(pose: np.ndarray) -> tuple[float, float, float, float]:
    z, w = yaw_quaternions(np.array([pose[2]]))
    return float(pose[0]), float(pose[1]), float(z[0]), float(w[0])


def laser_scan(
    make: MessageFactory, ns: int, ranges: np.ndarray, spec: LaserSpec = SPEC, **angles: float
) -> Any:
    """A LaserScan as a driver writes it: float32 fields, `angles` override the spec's."""
    a_min = angles.get("angle_min", spec.angle_min)
    a_max = angles.get("angle_max", spec.angle_max)
    return make.types["sensor_msgs/msg/LaserScan"](
        header=make.header(ns, "laser"),
        angle_min=a_min,
        angle_max=a_max,
        angle_increment=angles.get("angle_increment", (a_max - a_min) / (len(ranges) - 1)),
        time_increment=0.0,
        scan_time=1.0 / spec.rate_hz,
        range_min=spec.range_min,
        range_max=spec.range_max,
        ranges=np.asarray(ranges, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32),
    )


def recording(
    make: MessageFactory,
    scan_s: np.ndarray,
    odom_s: np.ndarray,
    mount: str = "static",
    ranges: Callable[[int], np.ndarray] = lambda k: np.full(BEAMS, 3.0, np.float32),
) -> list[Message]:
    """/scan at `scan_s`, /odom at `odom_s` (seconds after START_NS) along robot_pose, and the
    laser's mount on /tf_static ("static"), repeated on /tf at 10 Hz ("tf") or turning on /tf
    ("moving")."""
    out: list[Message] = []
    mount_q = planar(np.array(MOUNT))
    if mount == "static":
        out.append(("/tf_static", START_NS, make.tf(START_NS, "base_link", "laser", mount_q)))
    else:
        for k, ns in enumerate(ns_at(np.arange(0.0, scan_s[-1] + 0.1, 0.1))):
            yaw = MOUNT[2] + (0.1 * math.sin(k) if mount == "moving" else 0.0)
            q = planar(np.array([MOUNT[0], MOUNT[1], yaw]))
            out.append(("/tf", int(ns), make.tf(int(ns), "base_link", "laser", q)))
    for ns, pose in zip(ns_at(odom_s), robot_pose(ns_at(odom_s)), strict=True):
        out.append(("/odom", int(ns), make.odometry(int(ns), "odom", "base_link", planar(pose))))
    for k, ns in enumerate(ns_at(scan_s)):
        out.append(("/scan", int(ns), laser_scan(make, int(ns), ranges(k))))
    return sorted(out, key=lambda m: m[1])


def write_bag(path: Path, make: MessageFactory, messages: list[Message]) -> Path:
    """A ROS 1 bag (path + .bag) or a ROS 2 bag folder of `messages`, as rosbags writes them."""
    if make.ros1:
        path = path.with_suffix(".bag")
        writer: Any = Writer1(path)
    else:
        writer = Writer2(path, version=8)
    with writer:
        conns: dict[str, Any] = {}
        for topic, ns, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=make.store)
            writer.write(conns[topic], ns, make.serialize(msg))
    return path


ROS2, ROS1 = MessageFactory(ros1=False), MessageFactory(ros1=True)
SCANS_10HZ = 0.1 * np.arange(40) + 0.003  # 4 s of scans, 3 ms off any odometry stamp


def test_scans_outside_the_odometry_are_dropped_and_counted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A TurtleBot 4: the laser starts 0.2 s before the odometry (and here outlives it)."""
    scans_ms = 25 * np.arange(120)  # 40 Hz from t = 0
    scans = scans_ms / 1e3
    odom = (200 + 20 * np.arange(120)) / 1e3  # 50 Hz from 0.2 s to 2.58 s
    truth_ms = 500 + 10 * np.arange(250)  # 100 Hz truth from 0.5 s, none from 1.0 to 2.0 s
    truth_s = truth_ms[(truth_ms < 1000) | (truth_ms > 2000)] / 1e3
    messages = recording(ROS2, scans, odom)
    for ns, pose in zip(ns_at(truth_s), robot_pose(ns_at(truth_s)), strict=True):
        gt = ROS2.odometry(int(ns), "map", "base_link", planar(pose))
        messages.append(("/ground_truth", int(ns), gt))
    bag = write_bag(tmp_path / "tb4", ROS2, sorted(messages, key=lambda m: m[1]))
    traj, ranges, meta = read_bag_run(bag, SPEC, BagRunOptions(truth_topic="/ground_truth"))
    kept_ms = scans_ms[(scans_ms >= 200) & (scans_ms <= 2580)]
    kept = kept_ms / 1e3
    assert meta["scans_dropped_before_odometry"] == 8  # 0, 25, ..., 175 ms
    assert meta["scans_dropped_after_odometry"] == 120 - 8 - len(kept)
    assert meta["bag_scans"] == 120 and meta["scans"] == len(kept) == len(ranges)
    assert meta["time_origin_ns"] == ns_at(0.2)
    np.testing.assert_allclose(traj.times, kept - 0.2, atol=1e-9)
    assert_poses(traj.odometry, robot_pose(ns_at(kept)))
    pairing = meta["odometry_pairing"]
    assert pairing["median_period_s"] == pytest.approx(0.02)
    assert pairing["bound_s"] == pytest.approx(0.06) and pairing["bound_rule"].startswith("3 x")
    assert "dropped 8 scan(s) before the first odometry sample" in capsys.readouterr().err
    # Truth: its own bound (30 ms); scans before 0.5 s or in the hole have none.
    no_truth = (kept_ms < 500) | ((kept_ms > 990) & (kept_ms < 2010))
    assert np.isnan(traj.truth[no_truth]).all()
    assert_poses(traj.truth[~no_truth], robot_pose(ns_at(kept[~no_truth])))
    info = meta["truth_pairing"]
    assert info["bound_s"] == pytest.approx(0.03) and info["missing_in_gaps"] > 0
    assert meta["truth_missing_steps"] == no_truth.sum() and meta["has_truth"]


def test_slow_odometry_is_interpolated(tmp_path: Path) -> None:
    """A Neato: odometry at 7.5 Hz (0.133 s apart), scans at 10 Hz between its samples."""
    odom = np.arange(32) / 7.5
    bag = write_bag(tmp_path / "neato", ROS2, recording(ROS2, SCANS_10HZ, odom))
    traj, _, meta = read_bag_run(bag, SPEC, BagRunOptions())
    kept = SCANS_10HZ[SCANS_10HZ <= odom[-1]]
    assert meta["scans"] == len(kept) and meta["scans_dropped_before_odometry"] == 0
    assert_poses(traj.odometry, robot_pose(ns_at(kept)))
    pairing = meta["odometry_pairing"]
    assert pairing["median_period_s"] == pytest.approx(1 / 7.5, abs=1e-9)
    assert pairing["bound_s"] == pytest.approx(0.4, abs=1e-8)  # 3 x 133333333 ns
    assert pairing["interpolated_steps"] == len(kept) and pairing["exact_steps"] == 0


def test_a_huge_odometry_gap_is_refused_unless_allowed(tmp_path: Path) -> None:
    odom = 0.02 * np.arange(200)
    odom = odom[(odom < 1.0) | (odom > 3.0)]  # 2 s without odometry at 50 Hz
    bag = write_bag(tmp_path / "gap", ROS2, recording(ROS2, SCANS_10HZ, odom))
    message = (
        r"gap: topic /odom: scan 10 \(stamp \d+ ns\) falls in a 2.040 s gap of the odometry .* "
        r"above the bound 0.060 s \(3 x the median period; the stream's median period is "
        r"0.0200 s\): .* set pairing_tolerance_s \(conf/bag.yaml\) to 2.040 or more"
    )
    with pytest.raises(BagError, match=message):
        read_bag_run(bag, SPEC, BagRunOptions())
    traj, _, meta = read_bag_run(bag, SPEC, BagRunOptions(pairing_tolerance_s=2.5))
    assert meta["odometry_pairing"]["bound_rule"] == "pairing_tolerance_s (given)"
    assert meta["odometry_pairing"]["largest_gap_s"] == pytest.approx(2.04)
    assert_poses(traj.odometry, robot_pose(ns_at(SCANS_10HZ)))


def test_a_laser_mount_repeated_on_tf_is_read(tmp_path: Path) -> None:
    """A ROS 1 robot: static_transform_publisher repeats base_link → laser on /tf."""
    odom = 0.02 * np.arange(210)
    bag = write_bag(tmp_path / "ros1", ROS1, recording(ROS1, SCANS_10HZ, odom, mount="tf"))
    _, _, meta = read_bag_run(bag, SPEC, BagRunOptions())
    mount = meta["laser_mount"]
    np.testing.assert_allclose([mount["x"], mount["y"], mount["yaw"]], MOUNT, atol=1e-12)
    assert meta["laser_mount_source"] == "/tf (constant: base_link→laser x 41)"


def test_a_moving_laser_mount_is_refused(tmp_path: Path) -> None:
    odom = 0.02 * np.arange(210)
    bag = write_bag(tmp_path / "tilt", ROS2, recording(ROS2, SCANS_10HZ, odom, mount="moving"))
    message = (
        r"tilt: topic /tf: the laser's mounting base_link→laser moves: its link base_link→laser "
        r"varies by up to 0.0000 m and 5.7\d+ deg over 41 messages; expected a fixed mount"
    )
    with pytest.raises(BagError, match=message):
        read_bag_run(bag, SPEC, BagRunOptions())


def test_every_no_return_convention_is_counted(tmp_path: Path) -> None:
    special = np.array([np.inf, np.nan, -np.inf, 0.0, -0.0, 0.01, -1.0, 10.5], dtype=np.float32)
    edges = np.array([0.05, 10.0], dtype=np.float32)  # range_min and range_max: measurements

    def ranges(k: int) -> np.ndarray:
        r = np.linspace(0.5, 9.5, BEAMS, dtype=np.float32) + np.float32(0.001 * k)
        r[: len(special)], r[-2:] = special, edges
        return r

    odom = 0.02 * np.arange(210)
    bag = write_bag(tmp_path / "rep117", ROS2, recording(ROS2, SCANS_10HZ, odom, ranges=ranges))
    _, got, meta = read_bag_run(bag, SPEC, BagRunOptions())
    n = len(SCANS_10HZ)
    assert meta["no_return_counts"] == {
        "inf": n, "nan": n, "neg_inf": n, "zero": 2 * n, "below_range_min": 2 * n,
        "above_range_max": n,
    }  # fmt: skip
    want = np.stack([ranges(k) for k in range(n)])
    want[:, : len(special)] = SPEC.no_return_value
    assert got.tobytes() == want.tobytes()  # the rest, range limits included, bit for bit


# A 360° laser as drivers publish it: float32 angles, angle_max = float32(π) > π.
WIDE = LaserSpec(
    num_beams=720, angle_min=-math.pi, angle_max=math.pi, range_min=0.15, range_max=12.0
)
WIDE_ANGLES = {
    "angle_min": float(np.float32(-math.pi)),
    "angle_max": float(np.float32(math.pi)),
    "angle_increment": float(np.float32(2 * math.pi / 719)),
}


def wide_bag(path: Path) -> Path:
    odom = 0.02 * np.arange(210)
    messages = [m for m in recording(ROS2, SCANS_10HZ, odom) if m[0] != "/scan"]
    for ns in ns_at(SCANS_10HZ):
        ranges = np.full(720, 2.5, np.float32)
        messages.append(("/scan", int(ns), laser_scan(ROS2, int(ns), ranges, WIDE, **WIDE_ANGLES)))
    return write_bag(path, ROS2, sorted(messages, key=lambda m: m[1]))


def test_describe_prints_the_sensor_file_of_a_bag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = wide_bag(tmp_path / "wide")
    assert WIDE_ANGLES["angle_max"] == 3.1415927410125732
    text = describe.main([f"bag={bag}"])
    assert capsys.readouterr().out == text and text.startswith("# The laser of ")
    assert "# 1 / the median time between the scans' header stamps" in text
    sensor = yaml.safe_load(text)
    spec = laser_spec_from_config(sensor)
    assert spec == LaserSpec(
        num_beams=720,
        angle_min=-math.pi,  # float32 ±π clipped to ±π
        angle_max=math.pi,
        range_min=0.15,  # float32 0.15 as its shortest decimal
        range_max=12.0,
        rate_hz=10.0,
        no_return_value=15.0,  # 1.25 x range_max
    )
    assert (sensor["mode"], sensor["unknown_blocks"]) == ("exact", False)
    with pytest.raises(SystemExit) as stop:
        describe.main([f"bag={bag}", "scan_topic=/front_scan"])
    assert stop.value.code == 2
    assert (
        "topic /front_scan: missing: expected sensor_msgs/msg/LaserScan" in capsys.readouterr().err
    )


def test_sensor_auto_reads_a_360_laser_through_the_bag_stage(tmp_path: Path) -> None:
    bag = wide_bag(tmp_path / "wide")
    grid = np.full((60, 60), FREE, dtype=np.int8)
    grid[[0, -1], :] = grid[:, [0, -1]] = OCCUPIED
    save_map(OccupancyGrid(grid, 0.1, (-1.0, -1.0, 0.0)), tmp_path / "office" / "map.yaml")
    out, maps = tmp_path / "robot_real", tmp_path / "maps" / "robot"
    stage = [sys.executable, "-m", "scanloc.stages.bag", f"bag={bag}", "name=robot"]
    stage += ["sensor=auto", f"map_yaml={tmp_path / 'office' / 'map.yaml'}"]
    stage += [f"out_dir={out}", f"map_dir={maps}", f"timing_dir={tmp_path / 't'}"]
    stage += [f"hydra.run.dir={tmp_path / 'hydra'}"]
    done = subprocess.run(stage, cwd=REPO, env=os.environ.copy(), capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    written = yaml.safe_load((maps / "sensor.yaml").read_text())
    assert (maps / "sensor.yaml").read_text().startswith("# The laser of ")
    meta = json.loads((out / "meta.json").read_text())
    assert meta["sensor"] == written and meta["sensor_source"].startswith("auto: the bag's /scan")
    spec = laser_spec_from_config(written)
    assert (spec.num_beams, spec.angle_min, spec.angle_max) == (720, -math.pi, math.pi)
    assert meta["no_return_counts"]["inf"] == 0 and meta["laser_mount_source"] == "/tf_static"


def ros1_bag_with_a_damaged_index(path: Path) -> Path:
    """A ROS 1 bag whose index gives one message another time than its record: what
    `rosbag reindex` repairs, and what rosbags meets with a bare AssertionError."""
    odom = 0.02 * np.arange(210)
    bag = write_bag(path, ROS1, recording(ROS1, SCANS_10HZ, odom))
    data = bytearray(bag.read_bytes())
    pos = len(b"#ROSBAG V2.0\n")
    while True:  # records: header length, header fields `name=value`, data length, data
        head_len = struct.unpack_from("<I", data, pos)[0]
        head, fields, i = bytes(data[pos + 4 : pos + 4 + head_len]), {}, 0
        while i < head_len:
            size = struct.unpack_from("<I", head, i)[0]
            name, _, value = head[i + 4 : i + 4 + size].partition(b"=")
            fields[name], i = value, i + 4 + size
        start = pos + 4 + head_len
        count = struct.unpack_from("<I", fields.get(b"count", bytes(4)))[0]
        if fields[b"op"] == b"\x04" and count > 3:  # index data: (sec, nsec, offset) each
            nsec = struct.unpack_from("<I", data, start + 4 + 12 * 3 + 4)[0]
            struct.pack_into("<I", data, start + 4 + 12 * 3 + 4, nsec + 1)
            break
        pos = start + 4 + struct.unpack_from("<I", data, start)[0]
    bag.write_bytes(bytes(data))
    return bag


def garbage_bag(path: Path) -> Path:
    """A ROS 1 bag's first line, then nothing a bag holds."""
    path = path.with_suffix(".bag")
    path.write_bytes(b"#ROSBAG V2.0\n" + bytes(999))
    return path


UNREADABLE = {"garbage": garbage_bag, "damaged_index": ros1_bag_with_a_damaged_index}


@pytest.mark.parametrize("case", sorted(UNREADABLE))
def test_an_unreadable_bag_is_a_bag_error(tmp_path: Path, case: str) -> None:
    bag = UNREADABLE[case](tmp_path / case)
    with pytest.raises(
        BagError, match=r"topic \(none\): .*reindex it with `rosbag reindex`"
    ) as err:
        read_bag_run(bag, SPEC, BagRunOptions())
    if case == "damaged_index":  # rosbags' bare assert, named
        assert isinstance(err.value.__cause__, AssertionError)
        assert "rosbags could not read message" in str(err.value)
