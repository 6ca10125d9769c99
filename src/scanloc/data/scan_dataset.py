"""Scan datasets on disk: poses drawn over a map's free space, the scans simulated there.

A dataset is a folder (data/scans/<dataset>/):
- ranges.npy  float32 (N, B) readings in metres, "no return" = sensor.no_return_value;
- poses.npy   float64 (N, 3) x [m], y [m], θ [rad] in (-pi, pi], map frame;
- is_val.npy  bool (N,) True for the validation split;
- meta.json   sensor, noise, map, count, seed, split counts, clearance and this format.

The bytes depend only on the arguments: poses, split and each block of NOISE_BLOCK samples'
noise come from their own streams of np.random.SeedSequence(seed), so neither chunk_size
(memory per step) nor the machine changes them. ranges.npy is written chunk by chunk into a
memory map and read back memory-mapped: a 200k x 667 dataset is never held in memory whole.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import sys
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from scanloc.io import atomic_dir, write_json
from scanloc.progress import interactive, print_line, step_line
from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.noise import NoiseModel, noise_from_config
from scanloc.sensor.simulate import ScanSimulator, laser_spec_from_config
from scanloc.world.free_space import sample_free_poses
from scanloc.world.occupancy_grid import OccupancyGrid

FORMAT_NAME = "scanloc.scans"
FORMAT_VERSION = 1
NOISE_BLOCK = 1024
SIM_CHUNK = 8192  # scans simulated at a time by default: bounds memory, not the bytes
_STREAM_POSES, _STREAM_SPLIT, _STREAM_NOISE = 0, 1, 2
_FILES = {
    "ranges.npy": "float32 (count, sensor.num_beams) readings in metres; no return = "
    "sensor.no_return_value",
    "poses.npy": "float64 (count, 3) x [m], y [m], theta [rad] in (-pi, pi], map frame",
    "is_val.npy": "bool (count,) True for validation samples",
}


def _stream(seed: int, key: int, *sub: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(key, *sub)))


def _map_meta(grid: OccupancyGrid, name: str) -> dict[str, Any]:
    return {
        "name": name,
        "width": grid.width,
        "height": grid.height,
        "resolution": float(grid.resolution),
        "origin": [float(v) for v in grid.origin],
        "cells_sha256": hashlib.sha256(np.ascontiguousarray(grid.cells).tobytes()).hexdigest(),
    }


def generate_scan_dataset(
    out_dir: str | os.PathLike[str],
    grid: OccupancyGrid,
    spec: LaserSpec,
    noise_cfg: Mapping[str, Any] | NoiseModel,
    num_samples: int,
    seed: int,
    clearance_radius: float,
    val_fraction: float = 0.1,
    map_name: str = "<unnamed>",
    mode: str = "exact",
    unknown_blocks: bool = False,
    chunk_size: int = SIM_CHUNK,
) -> dict[str, Any]:
    """Simulate `num_samples` scans at poses uniform over `grid`'s free space into `out_dir`.

    The folder appears complete or not at all (written next to it, then renamed). Returns the
    meta.json content. chunk_size (samples per step) only bounds memory, it is rounded up to
    a multiple of NOISE_BLOCK.
    """
    if not (isinstance(num_samples, int | np.integer) and num_samples >= 1):
        raise ValueError(f"num_samples must be an integer >= 1, got {num_samples!r}")
    if not (isinstance(seed, int | np.integer) and seed >= 0):
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    num_samples, seed = int(num_samples), int(seed)
    if not 0.0 <= val_fraction <= 1.0:
        raise ValueError(f"val_fraction must be in [0, 1], got {val_fraction!r}")
    if not (isinstance(chunk_size, int) and chunk_size >= 1):
        raise ValueError(f"chunk_size must be an integer >= 1, got {chunk_size!r}")
    noise = noise_cfg if isinstance(noise_cfg, NoiseModel) else noise_from_config(noise_cfg)
    simulator = ScanSimulator(grid, spec, noise, mode, unknown_blocks)

    poses = sample_free_poses(
        grid, num_samples, clearance_radius, _stream(seed, _STREAM_POSES), map_name
    )
    n_val = round(val_fraction * num_samples)
    is_val = np.zeros(num_samples, dtype=bool)
    is_val[_stream(seed, _STREAM_SPLIT).permutation(num_samples)[:n_val]] = True
    meta = {
        "format": {"name": FORMAT_NAME, "version": FORMAT_VERSION, "files": _FILES},
        "map": _map_meta(grid, map_name),
        "sensor": {**asdict(spec), "mode": mode, "unknown_blocks": bool(unknown_blocks)},
        "noise": asdict(noise),
        "count": num_samples,
        "seed": seed,
        "split": {"val_fraction": float(val_fraction), "train": num_samples - n_val, "val": n_val},
        "clearance_radius_m": float(clearance_radius),
        "noise_block_size": NOISE_BLOCK,
    }

    with atomic_dir(out_dir) as tmp:
        ranges = np.lib.format.open_memmap(
            tmp / "ranges.npy", mode="w+", dtype=np.float32, shape=(num_samples, spec.num_beams)
        )
        step = math.ceil(chunk_size / NOISE_BLOCK) * NOISE_BLOCK
        label = f"scans {map_name}"
        progress = tqdm(
            total=num_samples, desc=label, unit="scan", file=sys.stderr, disable=not interactive()
        )
        started, tenths_done = time.perf_counter(), 0
        with progress:
            for start in range(0, num_samples, step):
                stop = min(start + step, num_samples)
                cast = simulator.cast(poses[start:stop])
                for block in range(start, stop, NOISE_BLOCK):
                    end = min(block + NOISE_BLOCK, stop)
                    rng = _stream(seed, _STREAM_NOISE, block // NOISE_BLOCK)
                    ranges[block:end] = simulator.finish(cast[block - start : end - start], rng)
                progress.update(stop - start)
                if not interactive() and stop * 10 // num_samples > tenths_done:
                    tenths_done = stop * 10 // num_samples  # a line per tenth done
                    print_line(step_line(label, stop, num_samples, time.perf_counter() - started))
        ranges.flush()
        del ranges
        np.save(tmp / "poses.npy", poses)
        np.save(tmp / "is_val.npy", is_val)
        write_json(tmp / "meta.json", meta)
    return meta


def save_scan_dataset(
    out_dir: str | os.PathLike[str],
    ranges: np.ndarray,
    poses: np.ndarray,
    is_val: np.ndarray,
    meta: Mapping[str, Any],
) -> Path:
    """Write scans made elsewhere (tests, benchmarks, other simulators) in the dataset format.

    `meta` gives what only the caller knows (at least `sensor` and `seed`; also `map`...); the
    format, count and split are filled in from the arrays. Checked by reading it back.
    """
    count = len(is_val)
    n_val = int(np.count_nonzero(is_val))
    with atomic_dir(out_dir) as tmp:
        np.save(tmp / "ranges.npy", np.asarray(ranges, dtype=np.float32))
        np.save(tmp / "poses.npy", np.asarray(poses, dtype=np.float64))
        np.save(tmp / "is_val.npy", np.asarray(is_val, dtype=bool))
        write_json(
            tmp / "meta.json",
            {
                **meta,
                "format": {"name": FORMAT_NAME, "version": FORMAT_VERSION, "files": _FILES},
                "count": count,
                "split": {"val_fraction": n_val / count, "train": count - n_val, "val": n_val},
            },
        )
    load_scan_dataset(out_dir)
    return Path(out_dir)


@dataclass(frozen=True)
class ScanDataset:
    """A dataset folder opened for reading; `ranges` is memory-mapped, not loaded."""

    path: Path
    ranges: np.ndarray
    poses: np.ndarray
    is_val: np.ndarray
    meta: dict[str, Any]

    def __len__(self) -> int:
        return int(self.poses.shape[0])

    @property
    def train_idx(self) -> np.ndarray:
        """Indices of the training samples, ascending."""
        return np.flatnonzero(~self.is_val)

    @property
    def val_idx(self) -> np.ndarray:
        """Indices of the validation samples, ascending."""
        return np.flatnonzero(self.is_val)

    @property
    def spec(self) -> LaserSpec:
        """The laser the scans were simulated with."""
        return laser_spec_from_config(self.meta["sensor"])


def _field(meta_path: Path, meta: Mapping[str, Any], dotted: str, kind: type) -> Any:
    node: Any = meta
    for part in dotted.split("."):
        if not isinstance(node, Mapping) or part not in node:
            raise ValueError(f"{meta_path}: field '{dotted}' is missing")
        node = node[part]
    if not isinstance(node, kind) or (kind is int and isinstance(node, bool)):
        raise ValueError(f"{meta_path}: field '{dotted}': expected {kind.__name__}, got {node!r}")
    return node


def _array(path: Path, mmap: bool, dtype: type, shape: tuple[int, ...], what: str) -> np.ndarray:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: file not found")
    try:
        array = np.load(path, mmap_mode="r" if mmap else None, allow_pickle=False)
    except ValueError as err:
        raise ValueError(f"{path}: not a readable .npy array ({err})") from None
    if array.dtype != dtype or array.shape != shape:
        raise ValueError(
            f"{path}: expected {np.dtype(dtype).name} {what} = {shape}, "
            f"got {array.dtype.name} {array.shape}"
        )
    return array


def load_scan_dataset(path: str | os.PathLike[str]) -> ScanDataset:
    """Open a dataset folder written by `generate_scan_dataset`, checking it against meta.json."""
    path = Path(path)
    meta_path = path / "meta.json"
    if not meta_path.is_file():
        raise FileNotFoundError(f"{meta_path}: file not found")
    try:
        meta = json.loads(meta_path.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{meta_path}: not valid JSON ({err})") from None
    if not isinstance(meta, dict):
        raise ValueError(f"{meta_path}: expected a JSON object, got {type(meta).__name__}")
    name = _field(meta_path, meta, "format.name", str)
    version = _field(meta_path, meta, "format.version", int)
    if (name, version) != (FORMAT_NAME, FORMAT_VERSION):
        raise ValueError(
            f"{meta_path}: field 'format': expected {FORMAT_NAME} version {FORMAT_VERSION}, "
            f"got {name} version {version}"
        )
    count = _field(meta_path, meta, "count", int)
    beams = _field(meta_path, meta, "sensor.num_beams", int)
    n_train = _field(meta_path, meta, "split.train", int)
    n_val = _field(meta_path, meta, "split.val", int)
    _field(meta_path, meta, "seed", int)
    ranges = _array(
        path / "ranges.npy", True, np.float32, (count, beams), "(count, sensor.num_beams)"
    )
    poses = _array(path / "poses.npy", False, np.float64, (count, 3), "(count, 3)")
    is_val = _array(path / "is_val.npy", False, np.bool_, (count,), "(count,)")
    if (n_train, n_val) != (count - int(is_val.sum()), int(is_val.sum())):
        raise ValueError(
            f"{meta_path}: field 'split': says {n_train} train / {n_val} val, "
            f"is_val.npy holds {count - int(is_val.sum())} / {int(is_val.sum())}"
        )
    return ScanDataset(path=path, ranges=ranges, poses=poses, is_val=is_val, meta=meta)
