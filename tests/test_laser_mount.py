"""The laser's mounting on the robot in the sensor models: beams are cast from base ⊕ mount
(ROS amcl's tf), and a zero mount leaves every model's factors unchanged; the learned
localizers' laser-pose hypotheses are turned into base poses."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from scanloc.localize import kinds
from scanloc.localize.kinds import LocalizeInputs
from scanloc.localize.learned_localizer import in_base_frame
from scanloc.localize.mcl.config import build_filter
from scanloc.pose import compose, wrap_angle
from scanloc.scanlocnet.model import Hypotheses
from scanloc.stages.localize import laser_mount
from scanloc.trajectory.format import Trajectory
from small_world import SPEC, small_map, ug01_scans
from test_amcl import ros

GRID = small_map()
MOUNT = (0.3, 0.05, 0.2)  # ahead of the rotation centre, a little left, turned
MODELS = ("likelihood_field", "likelihood_field_prob", "beam")


def sensor(model: str, mount=(0.0, 0.0, 0.0)):
    return build_filter(GRID, SPEC, ros(laser_model_type=model), laser_mount=mount).sensor_model


@pytest.mark.parametrize("model", MODELS)
def test_the_true_base_pose_scores_highest_only_with_the_mount(model: str) -> None:
    """A rotation in place: the base stays at (3, 2.4), the laser 0.3 m ahead swings round it,
    so the scans differ from those of a laser on the rotation centre. Among the base poses of
    the rotation, the model with the mount scores the true one highest at every heading; the
    model without it prefers another."""
    headings = np.linspace(-np.pi, np.pi, 8, endpoint=False)
    bases = np.column_stack([np.full(8, 3.0), np.full(8, 2.4), headings])
    lasers = np.array([compose(b, np.array(MOUNT)) for b in bases])
    scans = ug01_scans(GRID, lasers, seed=0)
    on_centre = ug01_scans(GRID, bases, seed=0)
    assert np.nanmean(np.abs(scans - on_centre)) > 0.1  # the mount changes the expected scan
    offsets = np.array([[0.0, 0, 0]] + [[dx, dy, 0] for dx in (-0.2, 0.2) for dy in (-0.2, 0.2)])
    offsets = np.concatenate([offsets, [[0, 0, -0.4], [0, 0, 0.4]]])
    with_mount, without = sensor(model, MOUNT), sensor(model)
    wrong = 0
    for step in range(8):
        # the true base pose first, then the laser's pose (what a model without the mount
        # wants) and poses 0.2 m / 0.4 rad off the truth
        candidates = np.concatenate([bases[step] + offsets[:1], lasers[step][None]])
        candidates = np.concatenate([candidates, bases[step] + offsets[1:]])
        candidates[:, 2] = wrap_angle(candidates[:, 2])
        assert np.argmax(with_mount(candidates, scans[step], False)) == 0
        wrong += np.argmax(without(candidates, scans[step], False)) != 0
    assert wrong >= 6


@pytest.mark.parametrize("model", MODELS)
def test_a_zero_mount_changes_nothing(model: str) -> None:
    rng = np.random.default_rng(2)
    poses = np.column_stack([rng.uniform(0.5, 5.5, 300), rng.uniform(0.5, 4.5, 300)])
    poses = np.column_stack([poses, rng.uniform(-np.pi, np.pi, 300)])
    scan = ug01_scans(GRID, poses[:1], seed=3)[0]
    a = sensor(model)(poses, scan, False)
    b = sensor(model, (0.0, 0.0, 0.0))(poses, scan, False)
    assert a.tobytes() == b.tobytes()


def test_the_mount_is_read_from_meta_json(tmp_path) -> None:
    assert laser_mount(tmp_path) == (0.0, 0.0, 0.0)
    (tmp_path / "meta.json").write_text(json.dumps({"laser_mount": [0.08, 0.0, 0.0]}))
    assert laser_mount(tmp_path) == (0.08, 0.0, 0.0)
    (tmp_path / "meta.json").write_text(json.dumps({"laser_mount": {"x": 0.1, "y": 0, "yaw": 1}}))
    assert laser_mount(tmp_path) == (0.1, 0.0, 1.0)
    (tmp_path / "meta.json").write_text(json.dumps({"laser_mount": [0.1, 0.2]}))
    with pytest.raises(ValueError, match=r"meta.json: field 'laser_mount': expected \[x, y, yaw\]"):
        laser_mount(tmp_path)


def _laser_hypotheses(bases: np.ndarray):
    """A stand-in for the network: the laser poses (base ⊕ MOUNT) of known bases, as one
    scan's K hypotheses."""
    lasers = np.array([compose(b, np.array(MOUNT)) for b in bases])
    return lambda scan: Hypotheses(
        poses=lasers[None], weights=np.full((1, len(bases)), 0.1), stds=np.ones((1, len(bases), 3))
    )


def test_learned_hypotheses_are_turned_into_base_poses() -> None:
    """What the network finds is the laser's pose; the run's truth is the base's."""
    bases = np.array([[3.0, 2.4, 0.5], [1.0, 1.0, -3.0], [4.0, 0.5, 3.1]])
    of_base = in_base_frame(_laser_hypotheses(bases), MOUNT)
    hyp = of_base(np.zeros(SPEC.num_beams))
    assert np.allclose(hyp.poses[0], bases, atol=1e-12)
    assert hyp.weights.shape == (1, 3) and hyp.stds.shape == (1, 3, 3)
    on_base = _laser_hypotheses(bases)
    assert in_base_frame(on_base, (0.0, 0.0, 0.0)) is on_base  # simulated maps: untouched


def test_every_learned_kind_gets_base_poses_from_a_mounted_laser(monkeypatch) -> None:
    """kinds.learned_hypotheses (behind the learned, tracking and hybrid kinds) applies the
    run's mount to the network's hypotheses."""
    bases = np.array([[3.0, 2.4, 0.5], [1.0, 1.0, -3.0]])
    network = _laser_hypotheses(bases)
    monkeypatch.setattr(kinds, "scan_hypotheses", lambda *a, **k: (None, network, 0.0))
    traj = Trajectory(np.zeros(1), np.zeros((1, 3)), np.zeros((1, 3)))
    inputs = LocalizeInputs(traj, np.zeros((1, SPEC.num_beams)), Path("m.yaml"), SPEC, MOUNT)
    cfg = {"meta": {"name": "mine"}, "learned": {"model": "m.pt"}}
    hypotheses_of, _ = kinds.learned_hypotheses(cfg, inputs)
    assert np.allclose(hypotheses_of(np.zeros(SPEC.num_beams)).poses[0], bases, atol=1e-12)
