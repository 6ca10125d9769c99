"""Bags out and back in: a simulated drive through a ROS 1 bag and the CARMEN Intel log's real
run through a ROS 2 bag (sqlite3 and mcap) come back as the same run, ranges and poses bit for
bit, and localize and score the same to the last digit of the metrics; the exported topics
follow ROS's conventions (latched map, frames, REP 117 ranges)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosDurability
from rosbags.rosbag2 import Reader as Reader2

from scanloc.bags.read import BagRunOptions, read_bag_run
from scanloc.bags.ros_messages import EPOCH_NS, quaternion_yaw, yaw_quaternions
from scanloc.bags.write import export_run
from scanloc.evaluate.table2 import evaluate_all, load_truth, metrics_json
from scanloc.localize.kinds import LocalizeInputs, run_localizer
from scanloc.real.carmen import read_carmen_log
from scanloc.real.carmen_laser import clean_ranges
from scanloc.real.carmen_odometry import scan_odometry, wrap_logged_headings
from scanloc.real.log_mapping import build_map_from_log
from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.simulate import laser_spec_from_config, simulate_scans
from scanloc.stages.localize import laser_mount as stage_laser_mount
from scanloc.trajectory.drive import drive_trajectory
from scanloc.trajectory.format import Trajectory, load_trajectory, save_trajectory
from scanloc.world.map_server import load_map, save_map
from scanloc.world.occupancy_grid import OccupancyGrid

REPO = Path(__file__).resolve().parents[1]
INTEL_LOG = (
    Path(__file__).resolve().parents[2] / "shared" / "data" / "carmen" / "intel-corrected.log.gz"
)
SENSOR_KEYS = ("num_beams", "angle_min", "angle_max", "range_min", "range_max", "rate_hz")


def sensor_config(spec: LaserSpec) -> dict[str, float]:
    return {k: getattr(spec, k) for k in (*SENSOR_KEYS, "no_return_value")}


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory: pytest.TempPathFactory, room: OccupancyGrid) -> Path:
    """A 120-step simulated drive (URG-04LX scans) and its map, saved as the pipeline does."""
    root = tmp_path_factory.mktemp("sim")
    save_map(room, root / "map" / "map.yaml")
    traj = drive_trajectory(room, 120, seed=3)
    spec = LaserSpec()
    ranges = simulate_scans(room, spec, traj.truth, None, rng_seed=1)
    meta = {"sensor": sensor_config(spec), "laser_mount": {"x": 0.1, "y": -0.05, "yaw": 0.3}}
    save_trajectory(traj, root / "run", ranges, meta, room)
    return root


def assert_same_run(
    got: tuple[Trajectory, np.ndarray], want: tuple[Trajectory, np.ndarray]
) -> None:
    (traj, ranges), (ref, ref_ranges) = got, want
    assert ranges.dtype == np.float32 and ranges.tobytes() == ref_ranges.tobytes()
    assert traj.truth.tobytes() == ref.truth.tobytes()
    assert traj.odometry.tobytes() == ref.odometry.tobytes()
    np.testing.assert_allclose(traj.times, ref.times, rtol=0, atol=1e-9)  # ns stamps


def test_headings_survive_quaternions_bit_for_bit() -> None:
    yaw = np.random.default_rng(0).uniform(-np.pi, np.pi, 20000)
    yaw = np.concatenate([yaw, [np.pi, 0.0, -0.0, 1e-300, np.nextafter(-np.pi, 0)]])
    z, w = yaw_quaternions(yaw)
    back = np.array([quaternion_yaw(0.0, 0.0, a, b) for a, b in zip(z, w, strict=True)])
    assert back.tobytes() == yaw.tobytes()
    np.testing.assert_allclose(z * z + w * w, 1.0, rtol=0, atol=4e-16)  # still unit quaternions
    plain = 2 * np.arctan2(np.sin(yaw / 2), np.cos(yaw / 2))
    assert (plain != yaw).any()  # what the plain encoding would lose


def test_simulated_drive_through_a_ros1_bag(sim_run: Path) -> None:
    bag = export_run(sim_run / "run", sim_run / "map" / "map.yaml", sim_run / "drive", "ros1")
    assert bag.name == "drive.bag" and bag.is_file()
    traj, ranges, meta = read_bag_run(bag, LaserSpec(), BagRunOptions(truth_topic="/ground_truth"))
    assert_same_run((traj, ranges), load_trajectory(sim_run / "run"))
    assert meta["laser_mount"] == {"x": 0.1, "y": -0.05, "yaw": 0.3}
    assert meta["time_origin_ns"] == EPOCH_NS and meta["has_truth"]
    with AnyReader([bag]) as reader:
        topics = reader.topics
        assert {t: i.msgtype for t, i in topics.items()} == {
            "/scan": "sensor_msgs/msg/LaserScan",
            "/odom": "nav_msgs/msg/Odometry",
            "/tf": "tf2_msgs/msg/TFMessage",
            "/tf_static": "tf2_msgs/msg/TFMessage",
            "/map": "nav_msgs/msg/OccupancyGrid",
            "/ground_truth": "nav_msgs/msg/Odometry",
        }
        assert topics["/map"].connections[0].ext.latching == 1
        conn = topics["/map"].connections[0]
        _, stamp, raw = next(reader.messages(connections=[conn]))
        grid = reader.deserialize(raw, conn.msgtype)
        assert stamp == EPOCH_NS and grid.header.frame_id == "map"
        room = load_map(sim_run / "map" / "map.yaml")
        assert (grid.info.width, grid.info.height) == (room.width, room.height)
        assert grid.data.tobytes() == room.cells.tobytes()


def test_no_return_is_written_as_inf(sim_run: Path) -> None:
    bag = export_run(sim_run / "run", None, sim_run / "plain", "ros2")
    _, ranges = load_trajectory(sim_run / "run")
    with AnyReader([bag]) as reader:
        assert "/map" not in reader.topics
        conn = reader.topics["/scan"].connections[0]
        scans = [reader.deserialize(raw, conn.msgtype) for _, _, raw in reader.messages([conn])]
    written = np.stack([s.ranges for s in scans])
    no_return = ranges == np.float32(LaserSpec().no_return_value)
    assert no_return.any() and np.isposinf(written[no_return]).all()
    assert written[~no_return].tobytes() == ranges[~no_return].tobytes()
    assert scans[0].header.frame_id == "laser"


def test_export_refuses_an_existing_bag_and_leaves_no_temporary_files(sim_run: Path) -> None:
    out = sim_run / "twice"
    export_run(sim_run / "run", None, out, "ros2")
    with pytest.raises(FileExistsError, match="twice: exists already"):
        export_run(sim_run / "run", None, out, "ros2")
    with pytest.raises(ValueError, match="storage: expected one of"):
        export_run(sim_run / "run", None, sim_run / "bad_storage", "ros2", storage="zip")
    assert not (sim_run / "bad_storage").exists()
    assert not [p for p in sim_run.iterdir() if p.name.startswith(".")]


@pytest.fixture(scope="module")
def intel_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first 150 scans of the Intel log as the real stage makes them (no map)."""
    if not INTEL_LOG.is_file():
        pytest.skip(f"{INTEL_LOG} not present (../shared)")
    sensor = yaml.safe_load((REPO / "conf" / "sensor" / "carmen_intel.yaml").read_text())
    spec = laser_spec_from_config(sensor)
    log = read_carmen_log(INTEL_LOG)
    stream, count = log.front, 150
    truth = np.ascontiguousarray(stream.laser_poses[:count], dtype=np.float64)
    truth[:, 2] = wrap_logged_headings(truth[:, 2])
    traj = Trajectory(
        times=stream.times[:count] - stream.times[0],
        truth=truth,
        odometry=scan_odometry(log, "front")[:count],
    )
    ranges = clean_ranges(stream.ranges[:count], spec.range_max, spec.no_return_value)
    root = tmp_path_factory.mktemp("intel")
    save_trajectory(traj, root / "intel_real", ranges, {"sensor": sensor})
    return root


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_carmen_run_through_a_ros2_bag(intel_run: Path, storage: str) -> None:
    bag = export_run(intel_run / "intel_real", None, intel_run / f"bag_{storage}", "ros2", storage)
    meta_yaml = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta_yaml["storage_identifier"] == storage
    sensor = json.loads((intel_run / "intel_real" / "meta.json").read_text())["sensor"]
    options = BagRunOptions(truth_topic="/ground_truth")
    traj, ranges, meta = read_bag_run(bag, laser_spec_from_config(sensor), options)
    assert_same_run((traj, ranges), load_trajectory(intel_run / "intel_real"))
    assert meta["laser_mount"] == {"x": 0.0, "y": 0.0, "yaw": 0.0}  # none recorded: identity
    with Reader2(bag) as reader:
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    assert [q.durability for q in qos["/tf_static"]] == [QosDurability.TRANSIENT_LOCAL]
    assert qos["/scan"] == []


def test_the_stages_export_and_read_back(sim_run: Path, tmp_path: Path) -> None:
    """export_bag, then the bag stage (a Hydra app, output paths given) on its result."""
    env = os.environ | {"PYTHONPATH": str(REPO / "src")}
    run = [sys.executable, "-m", "scanloc.stages.export_bag", f"run={sim_run / 'run'}"]
    run += [f"map={sim_run / 'map' / 'map.yaml'}", f"out={tmp_path / 'b'}", "format=ros2"]
    subprocess.run(run, check=True, cwd=REPO, env=env, capture_output=True)
    with Reader2(tmp_path / "b") as reader:  # /map latched for `ros2 bag play`
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    assert [q.durability for q in qos["/map"]] == [QosDurability.TRANSIENT_LOCAL]
    stage = [sys.executable, "-m", "scanloc.stages.bag", f"bag={tmp_path / 'b'}", "name=robot"]
    stage += [f"out_dir={tmp_path / 'robot_real'}", f"map_dir={tmp_path / 'maps' / 'robot'}"]
    stage += [f"map_yaml={sim_run / 'map' / 'map.yaml'}", "truth_topic=/ground_truth"]
    stage += [f"timing_dir={tmp_path / 'timing'}", f"hydra.run.dir={tmp_path / 'hydra'}"]
    done = subprocess.run(stage, cwd=REPO, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert_same_run(load_trajectory(tmp_path / "robot_real")[:2], load_trajectory(sim_run / "run"))
    meta = json.loads((tmp_path / "robot_real" / "meta.json").read_text())
    assert meta["name"] == "robot_real" and meta["sensor"]["num_beams"] == 667
    # the sensor it read with, for the later stages' `~sensor +sensor_file=...`
    written = yaml.safe_load((tmp_path / "maps" / "robot" / "sensor.yaml").read_text())
    urg = yaml.safe_load((REPO / "conf" / "sensor" / "urg04lx.yaml").read_text())
    assert written == urg == meta["sensor"] and meta["sensor_source"] == "conf/sensor/urg04lx.yaml"
    assert load_map(tmp_path / "maps" / "robot" / "map.yaml").cells.tobytes() == (
        load_map(sim_run / "map" / "map.yaml").cells.tobytes()
    )


def localize_and_score(run_dir: Path, map_yaml: Path) -> tuple[dict[str, pd.DataFrame], str]:
    """Two particle filters on a saved run, as the localize stage runs them (the laser's
    mounting from the run's meta.json), and the evaluate stage's metrics JSON of them."""
    traj, ranges = load_trajectory(run_dir)
    sensor = json.loads((run_dir / "meta.json").read_text())["sensor"]
    inputs = LocalizeInputs(
        traj, ranges, map_yaml, laser_spec_from_config(sensor), stage_laser_mount(run_dir)
    )
    amcl = yaml.safe_load((REPO / "conf" / "localizer" / "amcl.yaml").read_text())
    configs = {
        "amcl": amcl | {"filter": amcl["filter"] | {"max_particles": 1000}},
        "amcl_global": amcl
        | {
            "filter": amcl["filter"] | {"mode": "global", "max_particles": 3000},
            "sensor": {"laser_model_type": "likelihood_field_prob"},
        },
    }
    tables = {name: run_localizer(cfg, inputs).table for name, cfg in configs.items()}
    truth, kidnaps = load_truth(run_dir)
    return tables, metrics_json(evaluate_all(truth, tables, kidnap_steps=kidnaps))


def assert_same_scores(bag: Path, original: Path, map_yaml: Path, tmp: Path) -> None:
    """The bag read back as the bag stage saves it localizes and scores exactly as the
    original run: the estimate tables bit for bit (times to the bag's nanosecond stamps) and
    the metrics JSON to the last digit."""
    sensor = json.loads((original / "meta.json").read_text())["sensor"]
    traj, ranges, meta = read_bag_run(
        bag, laser_spec_from_config(sensor), BagRunOptions(truth_topic="/ground_truth")
    )
    save_trajectory(traj, tmp / "from_bag", ranges, meta | {"sensor": sensor})
    got_tables, got = localize_and_score(tmp / "from_bag", map_yaml)
    want_tables, want = localize_and_score(original, map_yaml)
    assert got == want
    for name, table in want_tables.items():
        poses = [c for c in table.columns if c != "t"]
        assert got_tables[name][poses].to_numpy().tobytes() == table[poses].to_numpy().tobytes()
        np.testing.assert_allclose(got_tables[name]["t"], table["t"], rtol=0, atol=1e-9)


def test_a_simulated_drive_scores_the_same_through_a_ros1_bag(sim_run: Path) -> None:
    bag = export_run(sim_run / "run", sim_run / "map" / "map.yaml", sim_run / "scored", "ros1")
    assert stage_laser_mount(sim_run / "run") == (0.1, -0.05, 0.3)  # the mount is exercised
    assert_same_scores(bag, sim_run / "run", sim_run / "map" / "map.yaml", sim_run)


def test_the_intel_log_scores_the_same_through_a_ros2_bag(intel_run: Path, tmp_path: Path) -> None:
    traj, ranges = load_trajectory(intel_run / "intel_real")
    sensor = json.loads((intel_run / "intel_real" / "meta.json").read_text())["sensor"]
    spec = laser_spec_from_config(sensor)
    grid = build_map_from_log(traj.truth, ranges, spec.beam_angles(), spec.range_max)
    save_map(grid, tmp_path / "map" / "map.yaml")
    bag = export_run(
        intel_run / "intel_real", tmp_path / "map" / "map.yaml", tmp_path / "bag", "ros2"
    )
    assert_same_scores(bag, intel_run / "intel_real", tmp_path / "map" / "map.yaml", tmp_path)
