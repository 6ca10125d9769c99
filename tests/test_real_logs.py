"""The real-log pipeline's data side: the evaluation split keeps evaluated scans out of the
map, the laser mount is applied in the robot frame, laser odometry recovers known motions on
simulated scans, the sensor is read from the log, and malformed logs name file and line."""

from __future__ import annotations

import gzip
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from omegaconf import OmegaConf

from scanloc.data.scan_dataset import load_scan_dataset
from scanloc.pose import compose, inverse
from scanloc.real.carmen import CarmenFormatError, read_carmen_log
from scanloc.real.carmen_odometry import scan_odometry
from scanloc.real.log_mapping import build_map_from_log
from scanloc.real.log_sensor import (
    estimate_mount_offset,
    log_stream,
    no_return_marker,
    resolve_mount,
    sensor_from_log,
)
from scanloc.real.split import (
    kidnap_segments,
    segment_run,
    segments_of,
    split_log,
    tune_holdout,
)
from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.simulate import laser_spec_from_config, simulate_scans
from scanloc.stages.real import chosen_sensor
from scanloc.trajectory.format import load_trajectory
from scanloc.trajectory.laser_odometry import drift, increments, laser_odometry
from scanloc.world.map_server import load_map


def flaser(ranges, pose, t) -> str:
    fields = ["FLASER", len(ranges), *ranges, *pose, *pose, t - 0.5, "host", t]
    return " ".join(str(f) for f in fields)


def write(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("mode", ["window", "halves"])
def test_split_never_lets_an_evaluated_scan_into_the_map(mode: str) -> None:
    split = split_log(100, mode, 0.5, (0.25, 0.75))
    assert not np.intersect1d(split.mapping, split.evaluation).size
    assert len(split.mapping) + len(split.evaluation) == 100 and not split.optimistic
    assert segments_of(split.evaluation) == [(25, 75) if mode == "window" else (50, 100)]
    assert split_log(100, "full").optimistic
    rng = np.random.default_rng(0)
    poses = np.column_stack([np.linspace(0, 5, 100), np.zeros(100), np.zeros(100)])
    ranges = rng.uniform(1.0, 4.0, (100, 31)).astype(np.float32)
    ranges[split.evaluation] = 2.5  # evaluated scans that would draw their own wall
    angles = np.linspace(-1.5, 1.5, 31)
    built = build_map_from_log(poses[split.mapping], ranges[split.mapping], angles, 10.0)
    kept = np.setdiff1d(np.arange(100), split.evaluation)
    reference = build_map_from_log(poses[kept], ranges[kept], angles, 10.0)
    assert np.array_equal(built.cells, reference.cells) and built.origin == reference.origin
    with_all = build_map_from_log(poses, ranges, angles, 10.0)
    assert not np.array_equal(with_all.cells, built.cells)


def test_a_capped_evaluation_leaves_the_rest_of_the_window_unmapped() -> None:
    split = split_log(100, "window", window=(0.25, 0.75), max_evaluation=10)
    assert segments_of(split.evaluation) == [(25, 35)]
    assert segments_of(split.mapping) == [(0, 25), (75, 100)]  # 35..74: in neither part


def test_split_fields_are_checked() -> None:
    with pytest.raises(ValueError, match=r"'split\.mode'"):
        split_log(100, "blocks")
    with pytest.raises(ValueError, match=r"'split\.window'"):
        split_log(100, "window", window=(0.0, 1.0))


def test_kidnap_run_jumps_in_truth_but_not_in_odometry() -> None:
    n = 60
    truth = np.column_stack([np.arange(n) * 0.1, np.zeros(n), np.zeros(n)])
    steps = increments(truth)
    segments = kidnap_segments(np.arange(20, n), 3)
    assert len(segments) == 4 and segments[0][0] == 20
    traj, index = segment_run(segments, np.arange(n) * 0.25, truth, steps, steps)
    assert len(traj.kidnap_steps) == 3 and sorted(index.tolist()) == list(range(20, n))
    for k in traj.kidnap_steps:
        assert abs(truth[index[k], 0] - truth[index[k - 1], 0]) > 0.15  # truth jumps
        assert np.allclose(traj.odometry[k], traj.odometry[k - 1])  # odometry stands still
        assert np.allclose(traj.laser_odometry[k], traj.laser_odometry[k - 1])
    assert np.all(np.diff(traj.times) > 0)


def test_rotation_in_place_moves_the_laser_along_an_arc(tmp_path: Path) -> None:
    """A base turning 90° in place: the laser 0.1 m ahead moves by the arc's chord 0.1·√2,
    and scan_odometry applies the wheel increment to the base, not to the laser."""
    d, turn = 0.1, math.pi / 2
    mount = np.array([d, 0.0, 0.0])
    base0, base1 = np.zeros(3), np.array([0.0, 0.0, turn])
    laser0, laser1 = compose(base0, mount), compose(base1, mount)
    assert math.hypot(*(laser1[:2] - laser0[:2])) == pytest.approx(d * math.sqrt(2))
    ranges = [1.0] * 5
    log = write(
        tmp_path / "turn.log",
        [
            flaser(ranges, tuple(laser0), 1.0),
            f"ODOM {laser0[0]} {laser0[1]} {laser0[2]} 0 0 0 1.0 host 1.0",  # echo
            f"ODOM {laser0[0]} {laser0[1]} {turn} 0 0 0 1.5 host 1.5",  # wheels: turn only
            flaser(ranges, tuple(laser1), 2.0),
        ],
    )
    parsed = read_carmen_log(log)
    odometry = scan_odometry(parsed, "front", mount)
    assert np.allclose(odometry[1], base1, atol=1e-9)
    assert np.allclose(compose(odometry[1], mount), laser1, atol=1e-9)
    flat = scan_odometry(parsed, "front")  # mount 0: the laser would turn on the spot
    assert np.allclose(flat[1][:2], laser0[:2])
    true_step = increments(np.array([laser0, laser1]))
    assert estimate_mount_offset(true_step, increments(odometry)) == (pytest.approx(d, abs=1e-9))


@pytest.mark.parametrize("motion", [(0.3, 0.05, 0.1), (0.6, -0.1, -0.3), (0.0, 0.0, 0.4)])
def test_laser_odometry_recovers_known_motions(room, motion) -> None:
    """Simulated noiseless scans in a drawn room (5 cm cells): from a wheel seed off by 0.1 m
    and 3°, the registration recovers the step within 5 mm and 0.1° (measured: 0.1 mm and
    0.002°; flat point-to-point ICP stops 0.6-3 cm and 0.5-0.8° off)."""
    spec = LaserSpec(num_beams=361, angle_min=-math.pi / 2, angle_max=math.pi / 2, range_max=8.0)
    mount = np.array([0.08, 0.0, 0.0])
    base0 = np.array([2.5, 2.0, 0.2])
    base1 = compose(base0, np.array(motion))
    lasers = np.array([compose(base0, mount), compose(base1, mount)])
    scans = simulate_scans(room, spec, lasers, None, rng_seed=0)
    wheel = np.array([base0, compose(base0, np.add(motion, [0.1, 0.0, math.radians(3)]))])
    angles = np.linspace(spec.angle_min, spec.angle_max, spec.num_beams)
    odo, fallbacks = laser_odometry(scans, angles, spec.range_max, wheel, mount)
    truth = np.array([base0, base1])
    err = drift(odo, truth)
    assert fallbacks == 0
    assert err["step_xy_rms_m"] < 0.005 and err["step_theta_rms_deg"] < 0.1
    assert drift(wheel, truth)["step_xy_rms_m"] > 0.09


def test_sensor_and_mount_read_from_the_log(tmp_path: Path) -> None:
    beams = [1.0, 2.0, 81.91, 3.0] + [2.0] * 357
    log = write(
        tmp_path / "third.log",
        [
            "PARAM robot_frontlaser_offset 0.05 1 host 1",
            flaser(beams, (0, 0, 0), 1.0),
            "ODOM 0 0 0 0 0 0 1.0 host 1.0",
            flaser(beams, (0, 0, 0), 1.25),
        ],
    )
    parsed = read_carmen_log(log)
    sensor = sensor_from_log(log_stream(parsed, "front"), {"mode": "exact"})
    assert sensor["num_beams"] == 361 and sensor["angle_max"] == pytest.approx(math.pi / 2)
    assert sensor["range_max"] == pytest.approx(81.91, abs=1e-4)
    assert sensor["no_return_value"] > sensor["range_max"] and sensor["rate_hz"] == 4.0
    assert no_return_marker(np.array([[1.0, 2.0, 2.5]])) is None
    mount, info = resolve_mount(parsed, "front", np.zeros((1, 3)), np.zeros((1, 3)))
    assert mount.tolist() == [0.05, 0.0, 0.0] and "PARAM" in info["source"]


@pytest.mark.parametrize(
    ("lines", "message"),
    [
        (["ODOM 0 0 0 0 0 0 1 host 1"], r"no front laser scans: expected FLASER or ROBOTLASER1"),
        (
            [flaser([1.0, 2.0], (0, 0, 0), 1.0), flaser([1.0, 2.0, 3.0], (0, 0, 0), 2.0)],
            r"bad\.log:2: FLASER field 'n': expected 2 readings like the stream's first scan",
        ),
        (
            [flaser([1.0, 2.0], (0, 0, 0), 1.0), "FLASER 3 1.0 2.0"],
            r"bad\.log:2: FLASER field 'r3'",
        ),
    ],
)
def test_malformed_logs_name_file_line_and_what_was_expected(
    tmp_path: Path, lines: list[str], message: str
) -> None:
    with pytest.raises(CarmenFormatError, match=message):
        log_stream(read_carmen_log(write(tmp_path / "bad.log", lines)), "front")


def test_a_broken_gzip_names_the_line(tmp_path: Path) -> None:
    text = "\n".join(flaser([1.0, 2.0], (0, 0, 0), t) for t in range(1, 400)) + "\n"
    data = gzip.compress(text.encode())
    path = tmp_path / "cut.log.gz"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(CarmenFormatError, match=r"cut\.log\.gz:\d+: cannot read line \d+"):
        read_carmen_log(path)


REPO = Path(__file__).resolve().parents[1]


def synthetic_log(path: Path, room, scans: int = 80) -> tuple[np.ndarray, np.ndarray]:
    """A CARMEN log simulated in the drawn room: 361 beams, a laser 6 cm ahead of the base
    (PARAM), two loops of an ellipse, wheels 2 % long; returns (laser poses, ranges)."""
    spec = LaserSpec(num_beams=361, angle_min=-math.pi / 2, angle_max=math.pi / 2, range_max=8.0)
    mount = np.array([0.06, 0.0, 0.0])
    t = np.linspace(0.0, 4.0 * math.pi, scans)
    base = np.column_stack([3.0 + 0.9 * np.cos(t), 2.4 + 0.45 * np.sin(t), t + math.pi / 2])
    lasers = np.array([compose(b, mount) for b in base])
    ranges = simulate_scans(room, spec, lasers, None, rng_seed=0).round(3)
    lines = ["PARAM robot_frontlaser_offset 0.06 0 host 0"]
    for k, (laser, scan) in enumerate(zip(lasers, ranges, strict=True)):
        lines.append(flaser(list(scan), tuple(laser), 1.0 + 0.25 * k))
        lines.append("ODOM " + " ".join(map(str, laser)) + f" 0 0 0 {1 + 0.25 * k} host 0")
        if k + 1 < scans:
            step = compose(inverse(base[k]), base[k + 1]) * [1.02, 1.0, 1.0]
            moved = compose(laser, step)  # the anchor's heading is the base's (mount θ = 0)
            lines.append("ODOM " + " ".join(map(str, moved)) + f" 0 0 0 {1.1 + 0.25 * k} host 0")
    write(path, lines)
    return lasers, ranges


def test_the_stage_maps_only_the_mapping_part_of_a_third_log(tmp_path: Path, room) -> None:
    """A log nobody tuned on, its entry's command, through the `real` stage."""
    lasers, ranges = synthetic_log(tmp_path / "third.log", room)
    out = tmp_path / "out"
    args = [f"{k}={out / v}" for k, v in [
        ("map_dir", "maps/third"), ("real_dir", "third_real"), ("sim_dir", "third_sim"),
        ("kidnap_dir", "third_kidnap"), ("tune_dir", "third_tune"),
        ("tune_heldout_dir", "third_tune_heldout"), ("mapping_scans_dir", "third_mapping"),
        ("metrics_file", "real_third.json"), ("timing_dir", "timing"),
    ]]  # fmt: skip
    stage = [sys.executable, "-m", "scanloc.stages.real", "log_name=third"]
    stage += [f"log={tmp_path / 'third.log'}", *args]
    stage += [f"hydra.run.dir={tmp_path / 'hydra'}"]
    done = subprocess.run(stage, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    meta = json.loads((out / "third_real" / "meta.json").read_text())
    assert meta["laser_mount"] == {"x": 0.06, "y": 0.0, "yaw": 0.0}
    assert meta["sensor"]["num_beams"] == 361 and meta["num_steps"] == 40
    assert meta["split"] == {
        "mode": "window", "optimistic": False, "map_scans": 40, "evaluation_scans": 40,
        "map_share": 0.5, "evaluation_share": 0.5,
    }  # fmt: skip
    assert meta["coverage"]["covered"] == 40
    assert meta["odometry"]["laser"]["step_xy_rms_m"] < meta["odometry"]["wheel"]["step_xy_rms_m"]
    kidnap = json.loads((out / "third_kidnap" / "meta.json").read_text())
    assert len(kidnap["kidnap_steps"]) == 3
    traj, _ = load_trajectory(out / "third_real")
    assert traj.laser_odometry is not None and traj.laser_odometry.shape == (40, 3)
    base = np.array([compose(p, inverse(np.array([0.06, 0.0, 0.0]))) for p in lasers])
    assert np.allclose(traj.truth, base[20:60], atol=1e-6)  # the base, not the laser
    # the map is the one built without the evaluated scans
    kept = np.r_[0:20, 60:80]
    reference = build_map_from_log(
        lasers[kept], np.where(ranges < 8.0, ranges, np.nan)[kept],
        np.linspace(-math.pi / 2, math.pi / 2, 361), meta["sensor"]["range_max"],
    )  # fmt: skip
    assert (
        load_map(out / "maps" / "third" / "map.yaml").cells.tobytes() == reference.cells.tobytes()
    )
    sensor = yaml.safe_load((out / "maps" / "third" / "sensor.yaml").read_text())
    assert laser_spec_from_config(sensor).num_beams == 361
    # the tune hold-out: the middle of each mapping quarter, in a map of the rest of them
    heldout, _ = load_trajectory(out / "third_tune_heldout")
    held, rest = np.r_[5:15, 65:75], np.r_[0:5, 15:20, 60:65, 75:80]
    assert np.allclose(heldout.truth, base[held], atol=1e-6) and heldout.kidnap_steps == (10,)
    rest_map = build_map_from_log(
        lasers[rest], np.where(ranges < 8.0, ranges, np.nan)[rest],
        np.linspace(-math.pi / 2, math.pi / 2, 361), meta["sensor"]["range_max"],
    )  # fmt: skip
    tune_map = load_map(out / "third_tune_heldout" / "map" / "map.yaml")
    assert tune_map.cells.tobytes() == rest_map.cells.tobytes()
    # the mapping part's real scans for training: laser poses, the hold-out as validation
    mapping = load_scan_dataset(out / "third_mapping")
    assert np.allclose(mapping.poses, lasers[kept], atol=1e-6)  # the laser, not the base
    assert np.array_equal(np.asarray(mapping.ranges), ranges[kept].astype(np.float32))
    assert np.array_equal(np.flatnonzero(mapping.is_val), np.flatnonzero(np.isin(kept, held)))


def test_an_entry_may_name_a_sensor_override(monkeypatch) -> None:
    """`overrides: "sensor_override=carmen_intel"` in a `real_logs` entry."""
    monkeypatch.setenv("SCANLOC_CONF", str(REPO / "conf"))
    cfg = OmegaConf.create({"sensor_override": "carmen_intel", "log_name": "intel"})
    cfg.log = "intel.log"
    beams = {"num_beams": 180, "angle_min": -math.pi / 2, "angle_max": math.radians(89)}
    assert chosen_sensor(cfg, beams | {"range_max": 81.83})["range_max"] == 50.0
    with pytest.raises(ValueError, match=r"carmen_intel\.yaml: field 'num_beams'"):
        chosen_sensor(cfg, beams | {"num_beams": 181})
    cfg.sensor_override = None  # none: the log's own sensor
    assert chosen_sensor(cfg, beams | {"range_max": 81.83})["range_max"] == 81.83


@pytest.mark.skipif(
    not (REPO.parent / "shared/data/carmen/intel-corrected.log.gz").is_file(),
    reason="needs ../shared/data/carmen (the real logs)",
)
def test_laser_odometry_beats_the_wheels_on_intel(quick_benchmark) -> None:
    """The registration chosen (extruded GICP) against the wheels and flat ICP, 100 scans."""
    intel = quick_benchmark("laser_odometry.py")["intel"]
    wheel, flat, chosen = intel["wheel"], intel["ICP"], intel["GICP@0.1"]
    assert chosen["step_theta_rms_deg"] < 0.5 * wheel["step_theta_rms_deg"]
    assert chosen["drift_percent"] < flat["drift_percent"] < wheel["drift_percent"]


@pytest.mark.parametrize("mode", ["window", "halves", "full"])
def test_the_tune_holdout_stays_in_the_mapping_part_and_apart(mode: str) -> None:
    split = split_log(100, mode, 0.5, (0.25, 0.75))
    tune_map, heldout = tune_holdout(split.mapping, (0.25, 0.75))
    assert not np.intersect1d(tune_map, heldout).size
    assert np.array_equal(np.union1d(tune_map, heldout), split.mapping)
    if not split.optimistic:
        assert not np.intersect1d(split.mapping, split.evaluation).size
    # the same window in each mapping stretch: mapped on both sides in time
    for a, b in segments_of(split.mapping):
        held = heldout[(heldout >= a) & (heldout < b)]
        assert held.min() > a and held.max() < b - 1
    if mode == "window":  # [0, 25) and [75, 100)
        assert segments_of(heldout) == [(6, 19), (81, 94)]
    with pytest.raises(ValueError, match="tune hold-out"):
        tune_holdout(np.arange(3))
