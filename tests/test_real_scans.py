"""Real scans in the learned localizer's training stream (scanloc.scanlocnet.real_scans): the
share of each epoch they take, the same bytes for the same (seed, epoch), only the dataset's
training split and only poses the grid has cells for, and the batches the trainer sees."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from scanloc.data.scan_dataset import generate_scan_dataset, save_scan_dataset
from scanloc.scanlocnet.pose_grid import PoseGrid
from scanloc.scanlocnet.real_scans import RealScans, load_real_scans
from scanloc.scanlocnet.scan_stream import StreamSpec
from scanloc.scanlocnet.training import _Epochs, fit_scanlocnet
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.stages.train_scanlocnet import tune_holdout_metrics
from scanloc.world.map_server import save_map
from scanloc.world.occupancy_grid import OccupancyGrid
from test_scanlocnet_interrupt import NOISE, SENSOR, TINY_NET

BEAMS = 8
pytestmark = pytest.mark.usefixtures("one_torch_thread")


def real_scans(count: int = 40, share: float = 0.25) -> RealScans:
    ranges = np.arange(count * BEAMS, dtype=np.float32).reshape(count, BEAMS) + 1000.0
    poses = np.column_stack([np.full(count, 2.0), np.full(count, 1.5), np.linspace(-3, 3, count)])
    return RealScans(ranges, poses, share)


def simulated(n: int = 200, epoch: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(epoch)
    return rng.uniform(0, 5, (n, BEAMS)).astype(np.float32), rng.uniform(0, 3, (n, 3))


def test_real_scans_take_their_share_of_the_epoch_and_nothing_else() -> None:
    real = real_scans()
    ranges, poses = simulated()
    mixed_ranges, mixed_poses = real.mix_into(ranges, poses, seed=11, epoch=3)
    replaced = np.flatnonzero(mixed_ranges[:, 0] >= 1000.0)
    assert len(replaced) == 50  # 25 % of 200
    keep = np.setdiff1d(np.arange(200), replaced)
    assert np.array_equal(mixed_ranges[keep], ranges[keep]) and np.array_equal(
        mixed_poses[keep], poses[keep]
    )
    picked = ((mixed_ranges[replaced, 0] - 1000.0) / BEAMS).astype(int)
    assert np.array_equal(mixed_ranges[replaced], real.ranges[picked])
    assert np.array_equal(mixed_poses[replaced], real.poses[picked])  # each scan with its pose
    assert ranges[:, 0].max() < 1000.0  # the inputs are left as they were


def test_the_same_seed_and_epoch_give_the_same_bytes() -> None:
    real = real_scans()
    ranges, poses = simulated()
    a = real.mix_into(ranges, poses, 11, 3)
    b = real.mix_into(ranges, poses, 11, 3)
    c = real.mix_into(ranges, poses, 11, 4)
    assert a[0].tobytes() == b[0].tobytes() and a[1].tobytes() == b[1].tobytes()
    assert a[0].tobytes() != c[0].tobytes()


def test_fewer_real_scans_than_their_share_are_drawn_again() -> None:
    mixed, _ = real_scans(count=10, share=0.5).mix_into(*simulated(), 11, 0)
    assert int((mixed[:, 0] >= 1000.0).sum()) == 100


@pytest.mark.parametrize("share", [0.0, -0.1, 1.5])
def test_a_share_outside_0_1_names_the_field(share: float) -> None:
    with pytest.raises(ValueError, match=r"real_scans.share: expected in \(0, 1\]"):
        real_scans(share=share)


def centres(pose_grid: PoseGrid, cells: np.ndarray) -> np.ndarray:
    """The centre poses of cells, in their first heading bin."""
    n = len(cells)
    return pose_grid.decode(cells, np.zeros((n, 2)), np.zeros(n, int), np.zeros(n))


def _dataset(tmp_path: Path, room: OccupancyGrid, poses: np.ndarray, is_val: np.ndarray) -> Path:
    ranges = np.tile(np.arange(len(poses), dtype=np.float32)[:, None], (1, BEAMS))
    return save_scan_dataset(
        tmp_path / "mapping", ranges, poses, is_val, {"sensor": {"num_beams": BEAMS}, "seed": 0}
    )


def test_only_the_training_split_inside_the_grid_is_loaded(tmp_path: Path, room) -> None:
    pose_grid = PoseGrid.from_map(room, 1.0, 12, 0.15)
    free = centres(pose_grid, np.arange(3))
    outside = np.array([[-5.0, -5.0, 0.0]])  # off the map: no cell
    poses = np.vstack([free, outside, free[:1]])
    is_val = np.array([False, False, True, False, False])
    real = load_real_scans(_dataset(tmp_path, room, poses, is_val), pose_grid, 0.3, BEAMS)
    assert real.ranges[:, 0].tolist() == [0.0, 1.0, 4.0]  # not the validation scan nor row 3
    assert np.array_equal(real.poses, poses[[0, 1, 4]]) and real.share == 0.3
    with pytest.raises(ValueError, match=r"mapping/ranges.npy: 8 beams, the stream's sensor has 9"):
        load_real_scans(tmp_path / "mapping", pose_grid, 0.3, BEAMS + 1)


def test_the_trainer_batches_carry_the_real_scans_in_share(room) -> None:
    """_Epochs, between the stream and Lightning: the real scans reach the batches."""
    pose_grid = PoseGrid.from_map(room, 1.0, 12, 0.15)
    sim_poses = centres(pose_grid, np.arange(256) % pose_grid.num_cells)
    sim_ranges = np.zeros((256, BEAMS), np.float32)
    stream = SimpleNamespace(
        spec=SimpleNamespace(scans_per_epoch=256), epoch=lambda e: (sim_ranges, sim_poses)
    )
    real = RealScans(np.ones((5, BEAMS), np.float32), sim_poses[:5], 0.25)
    epochs = _Epochs(stream, pose_grid, 64, 11, real)
    x = np.concatenate([batch[0].numpy() for batch in epochs])
    assert x.shape == (256, BEAMS) and int((x[:, 0] == 1.0).sum()) == 64


def test_a_training_with_real_scans_records_them_and_is_scored_on_the_holdout(
    tmp_path: Path, room: OccupancyGrid
) -> None:
    """fit_scanlocnet with real scans (here: scans simulated in the room standing in for a
    log's mapping part, half of them its tune hold-out), then the stage's hold-out figures."""
    save_map(room, tmp_path / "map.yaml")
    spec = laser_spec_from_config(SENSOR)
    generate_scan_dataset(tmp_path / "val", room, spec, NOISE, 64, 77, 0.15, 1.0, "room")
    generate_scan_dataset(tmp_path / "mapping", room, spec, NOISE, 60, 5, 0.15, 0.5, "room")
    pose_grid = PoseGrid.from_map(room, 1.0, 12, 0.15)
    real = load_real_scans(tmp_path / "mapping", pose_grid, 0.25, spec.num_beams)
    assert len(real.ranges) == 30  # the training half
    metrics = fit_scanlocnet(
        model_cfg={"_target_": "scanloc.scanlocnet.model.ScanLocNet"} | TINY_NET,
        grid=pose_grid,
        stream=StreamSpec(str(tmp_path / "map.yaml"), SENSOR, NOISE, 0.15, 128, 3),
        val_dataset=tmp_path / "val",
        out_dir=tmp_path / "model",
        epochs=1,
        batch_size=64,
        lr=3e-3,
        weight_decay=1e-4,
        pct_start=0.3,
        trainer_cfg={"precision": "32-true"},
        real_scans=real,
    )
    assert metrics["real_scans"] == 30 and metrics["real_share"] == 0.25
    holdout = tune_holdout_metrics(tmp_path / "mapping", tmp_path / "model" / "model.pt")
    assert holdout["tune_heldout_scans"] == 30
    assert 0.0 <= holdout["tune_heldout_top1_recall"] <= holdout["tune_heldout_top5_recall"] <= 1
