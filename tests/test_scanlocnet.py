"""scanloc's learned localizer: the pose grid, the network's outputs, exact top-K decoding against
brute force, the on-the-fly scans, training on maps of any size, and bad input."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from scanloc.data.scan_dataset import generate_scan_dataset
from scanloc.models.training import load_model
from scanloc.scanlocnet.model import ScanLocNet, suppress_duplicates, top_k
from scanloc.scanlocnet.pose_grid import PoseGrid
from scanloc.scanlocnet.scan_stream import ScanStream, StreamSpec, simulate_epoch
from scanloc.scanlocnet.training import fit_scanlocnet
from scanloc.sensor.noise import noise_from_config
from scanloc.sensor.simulate import ScanSimulator, laser_spec_from_config
from scanloc.world.build import build_map
from scanloc.world.map_server import save_map
from scanloc.world.occupancy_grid import OCCUPIED, OccupancyGrid

SENSOR = {
    "num_beams": 61,
    "angle_min": -2.0,
    "angle_max": 2.0,
    "range_min": 0.02,
    "range_max": 5.6,
    "no_return_value": 7.0,
    "mode": "exact",
    "unknown_blocks": False,
}
NOISE = {"kind": "ug01", "near_sigma_m": 0.03, "knee_m": 1.0, "relative_sigma": 0.03}
SMALL_NET = {
    "_target_": "scanloc.scanlocnet.model.ScanLocNet",
    "channels": [8, 16, 16],
    "kernels": [5, 3, 3],
    "features": 64,
    "cell_embedding": 8,
    "hidden": 32,
}
pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def grid(walled_room: Callable[..., OccupancyGrid]) -> OccupancyGrid:
    """A 4 m x 3 m walled room at 0.05 m with an L-shaped wall and a block: no symmetry."""
    room = walled_room(4.0, 3.0, 0.05)
    cells, res = room.cells, room.resolution
    cells[round(0.8 / res) : round(2.0 / res), round(1.2 / res) : round(1.3 / res)] = OCCUPIED
    cells[round(1.9 / res) : round(2.0 / res), round(1.2 / res) : round(2.4 / res)] = OCCUPIED
    cells[round(0.3 / res) : round(0.7 / res), round(3.0 / res) : round(3.4 / res)] = OCCUPIED
    return room


@pytest.fixture(scope="module")
def pose_grid(grid: OccupancyGrid) -> PoseGrid:
    return PoseGrid.from_map(grid, 0.5, 12, 0.15)


# ---------------------------------------------------------------- pose grid


def test_pose_grid_follows_the_free_space(grid: OccupancyGrid, pose_grid: PoseGrid) -> None:
    # 4 m x 3 m at 0.5 m: 8 x 6 cells, all with free space (the walls are one map cell thin)
    assert pose_grid.shape == (6, 8) and pose_grid.cell_size == pytest.approx(0.5)
    assert pose_grid.num_cells == 48
    # A solid 1 m block aligned to the cells removes the four cells it fills, and only those.
    cells = grid.cells.copy()
    cells[20:40, 40:60] = OCCUPIED  # x 2-3 m, y 1-2 m
    blocked = PoseGrid.from_map(OccupancyGrid(cells, 0.05), 0.5, 12, 0.0)
    missing = {(int(r), int(c)) for r in range(6) for c in range(8)} - {
        (int(r), int(c)) for r, c in blocked.cells
    }
    assert missing == {(2, 4), (2, 5), (3, 4), (3, 5)}
    with pytest.raises(ValueError, match=r"48 cells of 0.50 m \(limit 10\)"):
        PoseGrid.from_map(grid, 0.5, 12, 0.15, max_cells=10)


@settings(max_examples=200, deadline=None)
@given(st.floats(0.3, 3.7), st.floats(0.3, 2.7), st.floats(-10.0, 10.0))
def test_encode_then_decode_gives_the_pose_back(
    grid: OccupancyGrid, x: float, y: float, theta: float
) -> None:
    cells = PoseGrid.from_map(grid, 0.5, 12, 0.0)
    enc = cells.encode(np.array([[x, y, theta]]))
    assert enc["cell"][0] >= 0  # every position in the room lies in a cell
    assert np.all(np.abs(enc["offset"]) <= 0.5) and abs(enc["bin_offset"][0]) <= 0.5
    back = cells.decode(enc["cell"], enc["offset"], enc["bin"], enc["bin_offset"])[0]
    assert back[:2] == pytest.approx([x, y], abs=1e-9)
    assert abs(math.remainder(back[2] - theta, 2 * math.pi)) < 1e-9
    assert -math.pi < back[2] <= math.pi


# ---------------------------------------------------------------- network and decoding


@pytest.fixture(scope="module")
def net(pose_grid: PoseGrid) -> ScanLocNet:
    torch.manual_seed(0)
    cfg = {k: v for k, v in SMALL_NET.items() if k != "_target_"}
    return ScanLocNet(61, 5.6, pose_grid.to_dict(), **cfg).eval()


def scans_of(grid: OccupancyGrid, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    spec = StreamSpec("unused", SENSOR, NOISE, 0.15, n, seed)
    sim = ScanSimulator(grid, laser_spec_from_config(SENSOR), noise_from_config(NOISE))
    return simulate_epoch(spec, 0, grid, sim)


def test_output_shapes_and_weights(grid: OccupancyGrid, net: ScanLocNet) -> None:
    ranges, _ = scans_of(grid, 5, 1)
    logits = net(torch.from_numpy(ranges))
    assert logits.shape == (5, net.grid.num_cells)
    hyp = top_k(net, ranges, 7)
    assert (
        hyp.poses.shape == (5, 7, 3) and hyp.weights.shape == (5, 7) and hyp.stds.shape == (5, 7, 3)
    )
    assert np.all(np.diff(hyp.weights, axis=1) <= 0)  # best first
    assert np.all(hyp.weights > 0) and np.all(hyp.weights.sum(axis=1) <= 1 + 1e-9)
    assert np.all(hyp.stds > 0) and hyp.covariances().shape == (5, 7, 3, 3)
    # every hypothesis lies in its cell of the grid
    assert np.all(net.grid.encode(hyp.poses.reshape(-1, 3))["cell"] >= 0)


def brute_force_top_k(
    model: ScanLocNet, ranges: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray]:
    """All cells × bins evaluated, the k best joint probabilities taken: (poses, weights)."""
    with torch.no_grad():
        feats = model.features(torch.from_numpy(ranges))
        p_cell = torch.softmax(model.cell_logits(feats), dim=-1)
        cells = torch.arange(model.grid.num_cells).expand(len(ranges), -1)
        cond = model.conditional_outputs(feats, cells)
        joint = p_cell[..., None] * torch.softmax(cond["bin_logits"], dim=-1)
    flat = joint.reshape(len(ranges), -1).numpy()
    order = np.argsort(-flat, axis=1, kind="stable")[:, :k]
    bins = model.grid.heading_bins
    cell, b = order // bins, order % bins
    rows = np.arange(len(ranges))[:, None]
    poses = model.grid.decode(
        cell, cond["offset"].numpy()[rows, cell], b, cond["bin_offsets"].numpy()[rows, cell, b]
    )
    return poses, np.take_along_axis(flat, order, axis=1)


@pytest.mark.parametrize("chunk", [1, 3, 16, 1000])
def test_top_k_equals_brute_force(grid: OccupancyGrid, net: ScanLocNet, chunk: int) -> None:
    ranges, _ = scans_of(grid, 9, 2)
    for k in (1, 5, 40):
        hyp = top_k(net, ranges, k, batch_size=4, chunk=chunk)
        poses, weights = brute_force_top_k(net, ranges, k)
        np.testing.assert_allclose(hyp.weights, weights, rtol=1e-6)
        np.testing.assert_allclose(hyp.poses, poses, atol=1e-5)


def test_duplicate_suppression_merges_near_hypotheses() -> None:
    from scanloc.scanlocnet.model import Hypotheses

    poses = np.array([[[1.0, 1.0, 0.0], [1.2, 1.0, 0.05], [3.0, 1.0, 0.0], [1.0, 1.0, 2.0]]])
    hyp = Hypotheses(poses, np.array([[0.4, 0.3, 0.2, 0.1]]), np.ones((1, 4, 3)))
    kept = suppress_duplicates(hyp, 0.5, math.radians(10), 3)
    # the second is within 0.5 m and 10° of the first: merged into it; the fourth faces away
    np.testing.assert_allclose(kept.poses[0], poses[0, [0, 2, 3]])
    np.testing.assert_allclose(kept.weights[0], [0.7, 0.2, 0.1])


def plain_suppression(poses, weights, distance, angle, k):
    """Greedy non-maximum suppression written plainly: (kept poses, merged weights) per scan."""
    out = []
    for p, w in zip(poses, weights, strict=True):
        kept, gained = [], {}
        for j in range(len(w)):
            near = [
                q
                for q in kept
                if math.dist(p[j, :2], p[q, :2]) <= distance
                and abs(math.remainder(p[j, 2] - p[q, 2], 2 * math.pi)) <= angle
            ]
            if near:
                gained[near[0]] = gained.get(near[0], 0.0) + w[j]
            else:
                kept.append(j)
        kept = kept[:k]
        out.append((p[kept], np.array([w[q] + gained.get(q, 0.0) for q in kept])))
    return out


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), total=st.integers(1, 30), k=st.integers(1, 12))
def test_duplicate_suppression_equals_a_plain_greedy_pass(seed: int, total: int, k: int) -> None:
    from scanloc.scanlocnet.model import Hypotheses

    rng = np.random.default_rng(seed)
    poses = np.concatenate(
        [rng.uniform(0, 2, (3, total, 2)), rng.uniform(-math.pi, math.pi, (3, total, 1))], axis=2
    )
    weights = -np.sort(-rng.random((3, total)), axis=1)
    hyp = Hypotheses(poses, weights, rng.random((3, total, 3)))
    got = suppress_duplicates(hyp, 0.5, 0.6, k)
    for i, (kept_poses, kept_weights) in enumerate(plain_suppression(poses, weights, 0.5, 0.6, k)):
        m = len(kept_weights)
        np.testing.assert_allclose(got.poses[i, :m], kept_poses)
        np.testing.assert_allclose(got.weights[i, :m], kept_weights)
        assert not got.weights[i, m:].any() and not got.poses[i, m:].any()


def test_bad_scans_are_rejected_clearly(net: ScanLocNet) -> None:
    with pytest.raises(ValueError, match=r"shape \(N, 61\)"):
        top_k(net, np.zeros((2, 60), np.float32), 3)
    scan = np.full((1, 61), 2.0, np.float32)
    scan[0, 4] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        top_k(net, scan, 3)


# ---------------------------------------------------------------- data on the fly


def test_on_the_fly_scans_are_deterministic_per_epoch(tmp_path: Path, grid: OccupancyGrid) -> None:
    save_map(grid, tmp_path / "map.yaml")
    spec = StreamSpec(str(tmp_path / "map.yaml"), SENSOR, NOISE, 0.15, 300, 5)
    with ScanStream(spec) as stream:
        first = [stream.epoch(e) for e in range(3)]
    with ScanStream(spec) as stream:
        again = stream.epoch(1)  # asked out of order: the same bytes as in order
    assert first[1][0].tobytes() == again[0].tobytes()
    assert first[1][1].tobytes() == again[1].tobytes()
    assert first[0][1].tobytes() != first[1][1].tobytes()  # a fresh epoch is fresh
    assert first[0][0].shape == (300, 61) and first[0][0].dtype == np.float32
    # the worker's scans are the simulator's: recast in this process, the same readings
    sim = ScanSimulator(grid, laser_spec_from_config(SENSOR), noise_from_config(NOISE))
    ranges, poses = simulate_epoch(spec, 2, grid, sim)
    assert ranges.tobytes() == first[2][0].tobytes() and poses.tobytes() == first[2][1].tobytes()


def test_a_dead_worker_is_reported_with_its_exit_code(tmp_path: Path, grid: OccupancyGrid) -> None:
    """Killed (by the OOM killer, say), the worker's death is a clear error naming its exit
    code and the epoch it was simulating, not a broken pipe from deep inside multiprocessing."""
    save_map(grid, tmp_path / "map.yaml")
    spec = StreamSpec(str(tmp_path / "map.yaml"), SENSOR, NOISE, 0.15, 300, 5)
    with ScanStream(spec) as stream:
        stream.epoch(0)  # the worker is up (and simulating epoch 1, or done with it)
        stream._worker.kill()
        stream._worker.join()
        with pytest.raises(RuntimeError, match=r"worker stopped \(exit code -9\) while simulat"):
            stream.epoch(4)


# ---------------------------------------------------------------- training


def _val_dataset(tmp_path: Path, grid: OccupancyGrid, n: int = 200) -> Path:
    """n validation scans of `grid` in the dataset format (what the valscans stage writes)."""
    spec = laser_spec_from_config(SENSOR)
    generate_scan_dataset(tmp_path / "val", grid, spec, NOISE, n, 77, 0.15, 1.0, "room")
    return tmp_path / "val"


def test_a_map_of_another_size_trains_without_code_changes(tmp_path: Path) -> None:
    grid = build_map(
        {
            "name": "g",
            "source": "generated",
            "kind": "rooms",
            "seed": 3,
            "width": 12.0,
            "height": 9.0,
            "resolution": 0.1,
            "room_size": [3.0, 3.5],
            "corridor_width": 1.6,
            "door_width": 1.0,
        }
    )
    save_map(grid, tmp_path / "map.yaml")
    pose_grid = PoseGrid.from_map(grid, 1.0, 12, 0.15)
    metrics = fit_scanlocnet(
        model_cfg=SMALL_NET,
        grid=pose_grid,
        stream=StreamSpec(str(tmp_path / "map.yaml"), SENSOR, NOISE, 0.15, 256, 3),
        val_dataset=_val_dataset(tmp_path, grid, 64),
        out_dir=tmp_path / "model",
        epochs=1,
        batch_size=64,
        lr=3e-3,
        weight_decay=1e-4,
        pct_start=0.3,
        trainer_cfg={"precision": "32-true"},
    )
    assert metrics["epochs"] == 1 and metrics["cells"] == pose_grid.num_cells
    model = load_model(tmp_path / "model" / "model.pt")
    assert model.grid.num_cells == pose_grid.num_cells  # the grid travels with the model
    assert (tmp_path / "model" / "history.csv").read_text().count("\n") == 2


@pytest.mark.slow
def test_the_model_learns_a_tiny_map(tmp_path: Path, grid: OccupancyGrid) -> None:
    """A small room, a small network, a few epochs of fresh scans: the truth is among the best
    hypotheses of most validation scans (an untrained network: a few per cent)."""
    save_map(grid, tmp_path / "map.yaml")
    pose_grid = PoseGrid.from_map(grid, 0.5, 12, 0.15)
    metrics = fit_scanlocnet(
        model_cfg=SMALL_NET | {"channels": [16, 32, 32], "features": 128, "hidden": 64},
        grid=pose_grid,
        stream=StreamSpec(str(tmp_path / "map.yaml"), SENSOR, NOISE, 0.15, 4096, 4),
        val_dataset=_val_dataset(tmp_path, grid),
        out_dir=tmp_path / "model",
        epochs=20,
        batch_size=128,
        lr=3e-3,
        weight_decay=1e-4,
        pct_start=0.25,
        trainer_cfg={"precision": "32-true"},
    )
    assert metrics["val_top5_recall"] > 0.7
    assert metrics["val_pos_err_median_m"] < 0.3
