"""Scan datasets: round trip, byte determinism, the split, atomic writes and bad folders."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest

from scanloc.data.scan_dataset import NOISE_BLOCK, generate_scan_dataset, load_scan_dataset
from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.noise import NoNoise
from scanloc.sensor.raycast import CastMap, cast_exact
from scanloc.world.occupancy_grid import OCCUPIED, OccupancyGrid

SPEC = LaserSpec(num_beams=31, range_max=2.0)
FILES = ("ranges.npy", "poses.npy", "is_val.npy", "meta.json")


def world() -> OccupancyGrid:
    """3 m x 2 m at 0.05 m: outer wall and a block."""
    cells = np.zeros((40, 60), np.int8)
    cells[0], cells[-1], cells[:, 0], cells[:, -1] = OCCUPIED, OCCUPIED, OCCUPIED, OCCUPIED
    cells[10:18, 25:31] = OCCUPIED
    return OccupancyGrid(cells, 0.05)


def make(path: Path, **overrides) -> dict:
    args = dict(
        grid=world(),
        spec=SPEC,
        noise_cfg={"kind": "ug01"},
        num_samples=2 * NOISE_BLOCK + 300,
        seed=5,
        clearance_radius=0.15,
        map_name="block_room",
    )
    args.update(overrides)
    return generate_scan_dataset(path, **args)


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("scans") / "block_room_small"
    make(path)
    return path


def test_round_trip(dataset_dir: Path) -> None:
    data = load_scan_dataset(dataset_dir)
    n = 2 * NOISE_BLOCK + 300
    assert len(data) == n
    assert isinstance(data.ranges, np.memmap) and data.ranges.dtype == np.float32
    assert data.ranges.shape == (n, SPEC.num_beams)
    assert data.poses.dtype == np.float64 and data.poses.shape == (n, 3)
    assert data.spec == SPEC
    meta = data.meta
    assert meta["count"] == n and meta["seed"] == 5 and meta["map"]["name"] == "block_room"
    assert meta["sensor"]["mode"] == "exact" and meta["noise"]["kind"] == "ug01"
    assert meta["clearance_radius_m"] == 0.15
    assert meta["split"] == {
        "val_fraction": 0.1,
        "train": n - round(0.1 * n),
        "val": round(0.1 * n),
    }
    assert len(data.val_idx) == round(0.1 * n)
    assert np.union1d(data.train_idx, data.val_idx).tolist() == list(range(n))
    readings = np.asarray(data.ranges)
    assert (
        (readings >= SPEC.range_min) & (readings <= SPEC.range_max)
        | (readings == SPEC.no_return_value)
    ).all()


def test_noise_free_dataset_holds_the_exact_ranges(tmp_path: Path) -> None:
    meta = make(tmp_path / "clean", noise_cfg={"kind": "none"}, num_samples=200)
    assert meta["noise"] == asdict(NoNoise())
    data = load_scan_dataset(tmp_path / "clean")
    exact = cast_exact(CastMap.from_grid(world()), data.poses, SPEC.beam_angles(), SPEC.range_max)
    want = np.where(np.isfinite(exact), exact, SPEC.no_return_value).astype(np.float32)
    np.testing.assert_array_equal(np.asarray(data.ranges), want)


def test_same_seed_same_bytes_whatever_the_chunk_size(dataset_dir: Path, tmp_path: Path) -> None:
    make(tmp_path / "again", chunk_size=1)
    make(tmp_path / "other_seed", seed=6)
    for name in FILES:
        assert (tmp_path / "again" / name).read_bytes() == (dataset_dir / name).read_bytes()
    assert (tmp_path / "other_seed" / "ranges.npy").read_bytes() != (
        dataset_dir / "ranges.npy"
    ).read_bytes()


def test_rewrite_replaces_the_folder_atomically(tmp_path: Path) -> None:
    out = tmp_path / "scans"
    make(out, num_samples=50)
    (out / "stale.txt").write_text("left over")
    make(out, num_samples=60)
    assert sorted(p.name for p in out.iterdir()) == sorted(FILES)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scans"]  # no temp folders left
    assert len(load_scan_dataset(out)) == 60


def test_bad_arguments_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="num_samples"):
        make(tmp_path / "x", num_samples=0)
    with pytest.raises(ValueError, match="val_fraction"):
        make(tmp_path / "x", val_fraction=1.5)
    with pytest.raises(ValueError, match="mode"):
        make(tmp_path / "x", mode="fast")
    with pytest.raises(ValueError, match="kind"):
        make(tmp_path / "x", noise_cfg={"kind": "loud"})
    assert not (tmp_path / "x").exists()


def copy_of(src: Path, dst: Path) -> Path:
    dst.mkdir()
    for name in FILES:
        (dst / name).write_bytes((src / name).read_bytes())
    return dst


def test_missing_or_malformed_meta_is_named(dataset_dir: Path, tmp_path: Path) -> None:
    broken = copy_of(dataset_dir, tmp_path / "broken")
    (broken / "meta.json").unlink()
    with pytest.raises(FileNotFoundError, match=r"meta\.json"):
        load_scan_dataset(broken)
    (broken / "meta.json").write_text("{not json")
    with pytest.raises(ValueError, match=r"meta\.json: not valid JSON"):
        load_scan_dataset(broken)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda m: m.pop("count"), "field 'count' is missing"),
        (lambda m: m["sensor"].pop("num_beams"), "field 'sensor.num_beams' is missing"),
        (lambda m: m.update(count="many"), "field 'count': expected int"),
        (lambda m: m["format"].update(version=2), "field 'format'"),
        (lambda m: m["split"].update(val=1), "field 'split'"),
        (lambda m: m.update(count=m["count"] + 1), r"ranges\.npy: expected float32"),
    ],
)
def test_meta_fields_are_checked(dataset_dir: Path, tmp_path: Path, edit, message: str) -> None:
    broken = copy_of(dataset_dir, tmp_path / "broken")
    meta = json.loads((broken / "meta.json").read_text())
    edit(meta)
    (broken / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=message):
        load_scan_dataset(broken)


def test_array_files_are_checked(dataset_dir: Path, tmp_path: Path) -> None:
    broken = copy_of(dataset_dir, tmp_path / "broken")
    np.save(broken / "poses.npy", np.zeros((5, 3)))
    with pytest.raises(ValueError, match=r"poses\.npy: expected float64"):
        load_scan_dataset(broken)
    np.save(broken / "poses.npy", np.load(dataset_dir / "poses.npy").astype(np.float32))
    with pytest.raises(ValueError, match=r"poses\.npy: .*got float32"):
        load_scan_dataset(broken)
    (broken / "poses.npy").write_bytes((dataset_dir / "poses.npy").read_bytes())
    (broken / "is_val.npy").unlink()
    with pytest.raises(FileNotFoundError, match=r"is_val\.npy"):
        load_scan_dataset(broken)
