"""Scoring an external localizer: fed scanloc's own amcl estimates (as `t,x,y,theta`, from a
CSV or from a bag's /amcl_pose), score_estimates reproduces the evaluate stage's amcl metrics
exactly, on a small simulated kidnap run."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore

from scanloc.bags.ros_messages import EPOCH_NS, POSE_COV_STAMPED, ROS_COV_INDEX
from scanloc.bags.score import latest_estimates, score_estimates
from scanloc.evaluate.table2 import evaluate_trajectory
from scanloc.localize.kinds import LocalizeInputs, run_localizer
from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.simulate import simulate_scans
from scanloc.stages.score_estimates import main as score_main
from scanloc.trajectory.drive import drive_trajectory
from scanloc.trajectory.format import load_trajectory, save_trajectory
from scanloc.world.map_server import save_map
from scanloc.world.occupancy_grid import OccupancyGrid

REPO = Path(__file__).resolve().parents[1]
# need a covariance
CALIBRATION = ("calib_within_1sigma", "calib_within_2sigma", "false_convergences")


@pytest.fixture(scope="module")
def amcl_run(tmp_path_factory: pytest.TempPathFactory, room: OccupancyGrid) -> Path:
    """A 160-step kidnap run, scanloc's amcl on it (as the localize stage writes it) and the
    evaluate stage's metrics of it."""
    root = tmp_path_factory.mktemp("score")
    save_map(room, root / "map" / "map.yaml")
    traj = drive_trajectory(room, 160, seed=4, kidnap_steps=(100,))
    ranges = simulate_scans(room, LaserSpec(), traj.truth, None, rng_seed=2)
    save_trajectory(traj, root / "run", ranges, {"name": "run"}, room)
    cfg = yaml.safe_load((REPO / "conf" / "localizer" / "amcl.yaml").read_text())
    cfg["filter"]["max_particles"] = 500
    inputs = LocalizeInputs(traj, ranges, root / "map" / "map.yaml", LaserSpec())
    run = run_localizer(cfg, inputs)
    (root / "localize").mkdir()
    run.table.to_csv(root / "localize" / "amcl.csv", index=False, float_format="%.9g")
    return root


def reference_metrics(root: Path) -> dict[str, float]:
    return evaluate_trajectory(root / "run", [root / "localize"])["amcl"]


def test_amcl_csv_reproduces_the_evaluate_stage(amcl_run: Path) -> None:
    amcl = pd.read_csv(amcl_run / "localize" / "amcl.csv", dtype=str)  # the text, unchanged
    amcl[["t", "x", "y", "theta"]].to_csv(amcl_run / "plain.csv", index=False)
    out = amcl_run / "out"
    metrics = score_main(
        [
            f"run={amcl_run / 'run'}",
            f"estimates={amcl_run / 'plain.csv'}",
            "name=amcl",
            f"out_csv={out / 'amcl.csv'}",
            f"metrics_path={out / 'amcl.json'}",
        ]
    )
    want = reference_metrics(amcl_run)
    assert "recovery_steps_1" in want and "steps_to_converge" in want
    assert set(want) - set(metrics) == set(CALIBRATION)  # a pose CSV carries no covariance
    assert metrics == {k: v for k, v in want.items() if k not in CALIBRATION}
    table = pd.read_csv(out / "amcl.csv")
    assert list(table.columns) == list(pd.read_csv(amcl_run / "localize" / "amcl.csv").columns)
    assert json.loads((out / "amcl.json").read_text())["amcl"]["n_steps"] == 160


def test_amcl_pose_topic_with_covariance_reproduces_every_metric(amcl_run: Path) -> None:
    """The same estimates published as /amcl_pose (PoseWithCovarianceStamped) on a run's clock
    (step 0 at EPOCH_NS, as export_bag stamps it), covariance included."""
    table = pd.read_csv(amcl_run / "localize" / "amcl.csv")
    store = get_typestore(Stores.ROS2_HUMBLE)
    t = store.types
    bag = amcl_run / "amcl_bag"
    with Writer(bag, version=8) as writer:
        conn = writer.add_connection("/amcl_pose", POSE_COV_STAMPED, typestore=store)
        for row in table.itertuples():
            ns = EPOCH_NS + round(row.t * 1e9)
            cov = np.zeros(36)
            for name, index in ROS_COV_INDEX.items():
                cov[index] = getattr(row, name)
            pose = t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=row.x, y=row.y, z=0.0),
                orientation=t["geometry_msgs/msg/Quaternion"](
                    x=0.0, y=0.0, z=math.sin(row.theta / 2), w=math.cos(row.theta / 2)
                ),
            )
            stamp = t["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
            msg = t[POSE_COV_STAMPED](
                header=t["std_msgs/msg/Header"](stamp=stamp, frame_id="map"),
                pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov),
            )
            writer.write(conn, ns, bytes(store.serialize_cdr(msg, POSE_COV_STAMPED)))
    out = amcl_run / "from_bag"
    metrics = score_estimates(
        amcl_run / "run", bag, "/amcl_pose", "amcl", out / "amcl.csv", out / "amcl.json"
    )
    want = reference_metrics(amcl_run)
    assert set(metrics) == set(want)
    for key, value in want.items():  # headings pass through a quaternion: within 1e-12
        assert metrics[key] == pytest.approx(value, rel=1e-9, abs=1e-12), key


def test_steps_take_the_latest_estimate_at_or_before_them() -> None:
    ms = 1_000_000  # ns
    stamps = np.array([150, 300, 300, 700]) * ms  # two at 300 ms: the later one counts
    poses = np.arange(12, dtype=np.float64).reshape(4, 3)
    covs = np.full((4, 6), np.nan)
    got, cov = latest_estimates(stamps, poses, covs, np.array([0, 100, 200, 300, 400, 900]) * ms)
    assert np.isnan(got[:2]).all() and np.isnan(cov).all()
    np.testing.assert_array_equal(got[2:], poses[[0, 2, 2, 3]])


def test_a_run_and_estimates_of_different_lengths_still_align(amcl_run: Path) -> None:
    traj, _ = load_trajectory(amcl_run / "run")
    short = pd.DataFrame({"t": traj.times[50:80], "x": 1.0, "y": 2.0, "theta": 0.5})
    short.to_csv(amcl_run / "short.csv", index=False)
    out = amcl_run / "short"
    score_estimates(
        amcl_run / "run", amcl_run / "short.csv", "", "ext", out / "ext.csv", out / "ext.json"
    )
    table = pd.read_csv(out / "ext.csv")
    assert len(table) == 160 and table.x[:50].isna().all() and (table.x[50:] == 1.0).all()
