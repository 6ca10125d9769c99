"""The bag stage without a map: a bag with truth is split as a real log is, its mapping part
builds the map (no evaluated scan in it) and its evaluation part alone is the run; a bag with
neither truth nor a map is refused, naming the bag and both fields, and nothing is written."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from scanloc.bags.write import export_run
from scanloc.real.log_mapping import build_map_from_log
from scanloc.real.split import laser_poses_of, split_log
from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.simulate import simulate_scans
from scanloc.trajectory.drive import drive_trajectory
from scanloc.trajectory.format import load_trajectory, save_trajectory
from scanloc.world.map_server import load_map, save_map
from scanloc.world.occupancy_grid import OccupancyGrid

REPO = Path(__file__).resolve().parents[1]
STEPS = 120
MOUNT = {"x": 0.1, "y": -0.05, "yaw": 0.3}
ENV = os.environ | {"PYTHONPATH": str(REPO / "src")}


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory, room: OccupancyGrid) -> tuple[Path, Path]:
    """A simulated drive whose evaluated scans would draw a wall of their own (every reading
    2.5 m) if they reached the map, exported as a ROS 2 bag with /ground_truth."""
    root = tmp_path_factory.mktemp("bagmap")
    save_map(room, root / "map" / "map.yaml")
    traj = drive_trajectory(room, STEPS, seed=3)
    spec = LaserSpec()
    ranges = simulate_scans(room, spec, traj.truth, None, rng_seed=1)
    ranges[split_log(STEPS, "window").evaluation] = np.float32(2.5)
    sensor = {k: getattr(spec, k) for k in ("num_beams", "angle_min", "angle_max")}
    sensor |= {k: getattr(spec, k) for k in ("range_min", "range_max", "no_return_value")}
    save_trajectory(traj, root / "run", ranges, {"sensor": sensor, "laser_mount": MOUNT}, room)
    return root / "run", export_run(root / "run", root / "map" / "map.yaml", root / "bag")


def run_stage(bag: Path, out: Path, *overrides: str) -> subprocess.CompletedProcess:
    stage = [sys.executable, "-m", "scanloc.stages.bag", f"bag={bag}", "name=robot"]
    stage += [f"out_dir={out / 'robot_real'}", f"map_dir={out / 'maps' / 'robot'}"]
    stage += [f"timing_dir={out / 'timing'}", f"hydra.run.dir={out / 'hydra'}", *overrides]
    return subprocess.run(stage, cwd=REPO, env=ENV, capture_output=True, text=True)


def test_a_bag_with_truth_maps_its_mapping_part_and_runs_its_evaluation_part(
    drive: tuple[Path, Path], tmp_path: Path
) -> None:
    run_dir, bag = drive
    done = run_stage(bag, tmp_path, "truth_topic=/ground_truth")
    assert done.returncode == 0, done.stderr[-2000:]
    traj, ranges = load_trajectory(run_dir)
    split = split_log(STEPS, "window")
    m, e = split.mapping, split.evaluation
    spec = LaserSpec()
    laser = laser_poses_of(traj.truth, np.array(list(MOUNT.values())))
    hits = np.where(ranges < spec.range_max, ranges, np.float32(np.nan))
    angles = spec.beam_angles()

    built = load_map(tmp_path / "maps" / "robot" / "map.yaml")
    reference = build_map_from_log(laser[m], hits[m], angles, spec.range_max)
    assert built.cells.tobytes() == reference.cells.tobytes()
    assert np.allclose(built.origin, reference.origin, atol=1e-9)
    with_all = build_map_from_log(laser, hits, angles, spec.range_max)
    assert with_all.cells.tobytes() != reference.cells.tobytes()
    assert sorted(p.name for p in (tmp_path / "maps" / "robot").iterdir()) == [
        "map.pgm",
        "map.yaml",
        "preview.png",
        "sensor.yaml",  # the laser the run was read with, for the later stages
    ]

    got, got_ranges = load_trajectory(tmp_path / "robot_real")
    assert got_ranges.tobytes() == ranges[e].tobytes()
    assert got.truth.tobytes() == traj.truth[e].tobytes()
    assert got.odometry.tobytes() == traj.odometry[e].tobytes()
    np.testing.assert_allclose(got.times, traj.times[e] - traj.times[e[0]], rtol=0, atol=1e-9)
    meta = json.loads((tmp_path / "robot_real" / "meta.json").read_text())
    assert meta["log_scans"] == [int(e[0]), int(e[-1])] and meta["num_steps"] == len(e)
    assert meta["split"]["mode"] == "window" and not meta["split"]["optimistic"]
    assert (meta["split"]["map_scans"], meta["split"]["evaluation_scans"]) == (len(m), len(e))
    assert meta["coverage"]["steps"] == len(e) and meta["has_truth"]
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_a_bag_without_truth_or_map_is_refused(drive: tuple[Path, Path], tmp_path: Path) -> None:
    _, bag = drive
    done = run_stage(bag, tmp_path)
    assert done.returncode != 0
    message = done.stderr.replace("\n", " ")
    for part in (f"bag {bag}", "'map_yaml'", "'truth_topic'", "'truth_csv'"):
        assert part in message, message[-2000:]
    assert not (tmp_path / "robot_real").exists() and not (tmp_path / "maps").exists()
